//! The states plot: trajectories in a plane of two features, or an oblique 3-D
//! view of three (with a scale along each axis), and the 2σ outlines of the
//! predicting model's Gaussians; transition states and clusters dashed. The
//! outlines include the fit's regularisation, and the legend says how wide that
//! alone makes them.

use super::geometry::{Ellipse, Projection};
use super::{
    axis_label, cluster_colour, draw_err, draw_legend, finite_runs, padded,
    regularisation_variance, state_colour, tick_label, Swatch, LEGEND_WIDTH,
};
use crate::data::Table;
use crate::error::{CliError, Result};
use crate::model_file::ModelFile;
use crate::pipeline::joint_features_raw;
use crate::units::{sig4, Unit};
use phasekit_tsc::Model;
use phasekit_tsc::StateMoments;
use plotters::element::DashedPathElement;
use plotters::prelude::*;

/// Most trajectory points drawn in all: longer demonstrations are drawn every
/// k-th frame (said on the plot).
pub const MAX_TRAJECTORY_POINTS: usize = 20_000;

/// Gaussians `take` of `g` (model units), in data units, projected; those at
/// positions ≥ `first_transition` of `take` are transition states/clusters.
fn gaussians(
    g: &dyn StateMoments,
    take: &[usize],
    first_transition: usize,
    proj: &Projection,
    mf: &ModelFile,
    transition_word: &str,
) -> Vec<Ellipse> {
    let (scale, shift): (Vec<f64>, Vec<f64>) = proj
        .dims
        .iter()
        .map(|&k| match &mf.standardisation {
            Some(s) => (s.std[k], s.mean[k]),
            None => (1.0, 0.0),
        })
        .unzip();
    let n = proj.dims.len();
    take.iter()
        .enumerate()
        .map(|(pos, &i)| {
            let m = g.state_mean(i);
            let c = g.state_covariance(i);
            let mean: Vec<f64> = (0..n)
                .map(|a| m[proj.dims[a]] * scale[a] + shift[a])
                .collect();
            let mut cov = vec![0.0; n * n];
            for a in 0..n {
                for b in 0..n {
                    cov[a * n + b] = c[(proj.dims[a], proj.dims[b])] * scale[a] * scale[b];
                }
            }
            let (mean, cov) = proj.gaussian(&mean, &cov);
            let transition = pos >= first_transition;
            let index = if transition {
                pos - first_transition
            } else {
                pos
            };
            Ellipse {
                mean,
                cov,
                label: if transition {
                    format!("{transition_word} {index}")
                } else {
                    format!("state {index}")
                },
                transition,
                index,
            }
        })
        .collect()
}

/// The Gaussians of the model that predicts, projected: an HMM's states; a union
/// TSC-HMM's re-estimated states, `λ_T`'s marked as transition states; a gated
/// TSC-HMM's `λ` and `λ_T` states; a GMM's components; gmm-tsc's predicting mixture,
/// its last components (the kept clusters, re-trained) marked as transition clusters;
/// an ensemble's first member's (the best ranked).
pub fn model_ellipses_projected(mf: &ModelFile, proj: &Projection) -> Vec<Ellipse> {
    let all = |n: usize| (0..n).collect::<Vec<_>>();
    match mf.model.representative() {
        Model::Hmm(h) => gaussians(h.emission(), &all(h.n_states()), usize::MAX, proj, mf, ""),
        Model::Hsmm(h) => gaussians(h.emission(), &all(h.n_states()), usize::MAX, proj, mf, ""),
        Model::TscHmm { model, .. } => {
            let sb = model.base().n_states();
            match model.union() {
                Some(u) => gaussians(
                    u.emission(),
                    &all(u.n_states()),
                    sb,
                    proj,
                    mf,
                    "transition state",
                ),
                None => {
                    let mut v =
                        gaussians(model.base().emission(), &all(sb), usize::MAX, proj, mf, "");
                    v.extend(gaussians(
                        model.transition().emission(),
                        &all(model.transition().n_states()),
                        0,
                        proj,
                        mf,
                        "transition state",
                    ));
                    v
                }
            }
        }
        Model::Gmm(g) => gaussians(
            g.components(),
            &all(g.n_components()),
            usize::MAX,
            proj,
            mf,
            "",
        ),
        Model::GmmTsc { tsc, mixture } => {
            // The model file was validated: the mixture has more components than kept clusters.
            let base = mixture.n_components().saturating_sub(tsc.kept().len());
            gaussians(
                mixture.components(),
                &all(mixture.n_components()),
                base,
                proj,
                mf,
                "transition cluster",
            )
        }
        // A validated ensemble has members, none of them an ensemble.
        Model::Ensemble(_) => Vec::new(),
    }
}

/// The model's Gaussians projected on the plane of two features (see [`model_ellipses_projected`]).
pub fn model_ellipses(mf: &ModelFile, dims: [usize; 2]) -> Vec<Ellipse> {
    model_ellipses_projected(mf, &Projection::plane(dims[0], dims[1]))
}

/// The robot's position columns ending in `x`, `y`, `z`, if it has all three.
pub fn default_xyz(mf: &ModelFile) -> Option<[usize; 3]> {
    let l = &mf.layout;
    let pos: Vec<usize> = l.robot_positions.iter().map(|&j| l.robot[j]).collect();
    let find = |c: char| {
        pos.iter()
            .copied()
            .find(|k| l.features[*k].to_ascii_lowercase().ends_with(c))
    };
    Some([find('x')?, find('y')?, find('z')?])
}

/// Default plane of `plot states`: the robot's `…x` and `…z` position columns, or its first two, or the first two features.
pub fn default_plane(mf: &ModelFile) -> [usize; 2] {
    let l = &mf.layout;
    let pos: Vec<usize> = l.robot_positions.iter().map(|&j| l.robot[j]).collect();
    let ends = |k: &usize, c: char| l.features[*k].to_ascii_lowercase().ends_with(c);
    if let (Some(x), Some(z)) = (
        pos.iter().find(|k| ends(k, 'x')),
        pos.iter().find(|k| ends(k, 'z')),
    ) {
        return [*x, *z];
    }
    if pos.len() >= 2 {
        return [pos[0], pos[1]];
    }
    [0, 1.min(l.features.len() - 1)]
}

/// Index of a feature by name, with a helpful error.
pub fn feature_index(mf: &ModelFile, name: &str) -> Result<usize> {
    mf.layout
        .features
        .iter()
        .position(|f| f == name)
        .ok_or_else(|| {
            CliError::new(format!(
                "no feature `{name}` in the model (features: {})",
                mf.layout.features.join(", ")
            ))
        })
}

/// Trajectories and Gaussians in the plane of features `dims`, as SVG.
pub fn states_svg(
    mf: &ModelFile,
    tables: &[Table],
    dims: [usize; 2],
    unit: &Unit,
) -> Result<String> {
    states_svg_projected(mf, tables, &Projection::plane(dims[0], dims[1]), unit)
}

/// A round step of about `span / n` (1, 2 or 5 times a power of ten).
fn nice_step(span: f64, n: f64) -> f64 {
    let raw = (span / n).abs();
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * p)
}

/// One axis of the 3-D view: its label, its ends and its ticks, in picture coordinates.
struct Axis3d {
    label: String,
    from: (f64, f64),
    to: (f64, f64),
    /// Tick position and label.
    ticks: Vec<((f64, f64), String)>,
}

/// Trajectories and the 2σ outlines of the predicting model's Gaussians under a
/// projection (a plane of two features, or an oblique 3-D view), as SVG, in `unit`.
pub fn states_svg_projected(
    mf: &ModelFile,
    tables: &[Table],
    proj: &Projection,
    unit: &Unit,
) -> Result<String> {
    let d = mf.layout.features.len();
    let s = unit.scale;
    let raw: Vec<Vec<f64>> = tables
        .iter()
        .map(|t| joint_features_raw(mf, t))
        .collect::<Result<_>>()?;
    let frames: usize = raw.iter().map(|j| j.len() / d.max(1)).sum();
    // Every k-th frame when the demonstrations are long: the picture stays small.
    let stride = frames.div_ceil(MAX_TRAJECTORY_POINTS).max(1);
    let trajs: Vec<Vec<(f64, f64)>> = raw
        .iter()
        .map(|j| {
            j.chunks_exact(d)
                .step_by(stride)
                .map(|f| {
                    let (u, v) = proj.point(f);
                    (u * s, v * s)
                })
                .collect()
        })
        .collect();
    let ellipses: Vec<Ellipse> = model_ellipses_projected(mf, proj)
        .into_iter()
        .map(|mut e| {
            e.mean = [e.mean[0] * s, e.mean[1] * s];
            e.cov = e.cov.map(|c| c * s * s);
            e
        })
        .collect();
    let contours: Vec<Vec<(f64, f64)>> = ellipses.iter().map(|e| e.contour(2.0, 96)).collect();
    // The 3-D view's axes: from the data's lowest corner along each feature to its
    // range, with round ticks (the scale of the picture).
    let axes: Vec<Axis3d> = if proj.is_3d() {
        let range = |k: usize| {
            raw.iter()
                .flat_map(|j| j.chunks_exact(d).map(move |f| f[k] * s))
                .filter(|v| v.is_finite())
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                    (a.min(v), b.max(v))
                })
        };
        let r: Vec<(f64, f64)> = proj.dims.iter().map(|&k| range(k)).collect();
        let lo: Vec<f64> = r.iter().map(|x| x.0).collect();
        (0..3)
            .map(|a| {
                let at = |v: f64| {
                    let mut c = lo.clone();
                    c[a] = v;
                    proj.point_of(&c)
                };
                let (l, h) = r[a];
                let step = nice_step(h - l, 4.0);
                let first = (l / step).ceil() as i64;
                let last = (h / step).floor() as i64;
                let ticks = (first..=last)
                    .take(20)
                    .map(|i| {
                        let v = i as f64 * step;
                        (at(v), tick_label(v, 10.0 * step))
                    })
                    .collect();
                Axis3d {
                    label: axis_label(mf, proj.dims[a], unit),
                    from: at(l),
                    to: at(h),
                    ticks,
                }
            })
            .collect()
    } else {
        Vec::new()
    };
    let pts = || {
        trajs
            .iter()
            .flatten()
            .chain(contours.iter().flatten())
            .chain(axes.iter().flat_map(|a| [&a.from, &a.to]))
            .filter(|p| p.0.is_finite() && p.1.is_finite())
    };
    let (mut x0, mut x1) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
        (a.min(p.0), b.max(p.0))
    });
    let (mut y0, mut y1) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
        (a.min(p.1), b.max(p.1))
    });
    let (width, height) = (900u32 + LEGEND_WIDTH, 820u32);
    let same_kind = proj
        .dims
        .iter()
        .all(|&k| super::is_velocity(mf, k) == super::is_velocity(mf, proj.dims[0]));
    if x1 > x0 && y1 > y0 && (proj.is_3d() || same_kind) {
        // Equal scale on both picture axes when they share a unit, or the ellipses
        // are distorted (and the 3-D projection is meaningless).
        let (pw, ph) = (
            f64::from(width - LEGEND_WIDTH - 110),
            f64::from(height - 90),
        );
        let per_px = ((x1 - x0) / pw).max((y1 - y0) / ph);
        let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        (x0, x1) = (cx - 0.5 * per_px * pw, cx + 0.5 * per_px * pw);
        (y0, y1) = (cy - 0.5 * per_px * ph, cy + 0.5 * per_px * ph);
    }
    let (xr, yr) = (padded(x0, x1), padded(y0, y1));
    let (xspan, yspan) = (xr.end - xr.start, yr.end - yr.start);
    let mut entries: Vec<(String, Swatch)> = Vec::new();
    let mut notes: Vec<String> = Vec::new();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let (plot_area, legend_area) = root.split_horizontally(width - LEGEND_WIDTH);
        let view = if proj.is_3d() {
            "oblique 3-D view, 2σ ellipsoid outlines"
        } else {
            "2σ ellipses"
        };
        let title = format!(
            "{} — {view} of the predicting model's states, {} demonstration{}",
            mf.method.spec,
            tables.len(),
            if tables.len() == 1 { "" } else { "s" }
        );
        let mut chart = ChartBuilder::on(&plot_area)
            .margin(16)
            .caption(title, ("sans-serif", 18))
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(xr, yr)
            .map_err(draw_err)?;
        if proj.is_3d() {
            // Picture coordinates mix three features: no ticks on the frame, drawn
            // axes with their own scale instead.
            chart
                .configure_mesh()
                .disable_mesh()
                .disable_axes()
                .draw()
                .map_err(draw_err)?;
            let tick_len = 0.008 * xspan.max(yspan);
            for axis in &axes {
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        vec![axis.from, axis.to],
                        BLACK.stroke_width(2),
                    )))
                    .map_err(draw_err)?;
                // Ticks across the axis (perpendicular in the picture).
                let (dx, dy) = (axis.to.0 - axis.from.0, axis.to.1 - axis.from.1);
                let len = (dx * dx + dy * dy).sqrt().max(1e-300);
                let (nx, ny) = (-dy / len * tick_len, dx / len * tick_len);
                for (p, label) in &axis.ticks {
                    chart
                        .draw_series(std::iter::once(PathElement::new(
                            vec![(p.0 - nx, p.1 - ny), (p.0 + nx, p.1 + ny)],
                            BLACK.stroke_width(1),
                        )))
                        .map_err(draw_err)?;
                    chart
                        .draw_series(std::iter::once(Text::new(
                            label.clone(),
                            (p.0 - 3.0 * nx, p.1 - 3.0 * ny),
                            ("sans-serif", 11).into_font().color(&RGBColor(60, 60, 60)),
                        )))
                        .map_err(draw_err)?;
                }
                chart
                    .draw_series(std::iter::once(Text::new(
                        axis.label.clone(),
                        axis.to,
                        ("sans-serif", 14).into_font().color(&BLACK),
                    )))
                    .map_err(draw_err)?;
            }
        } else {
            chart
                .configure_mesh()
                .x_desc(axis_label(mf, proj.dims[0], unit))
                .y_desc(axis_label(mf, proj.dims[1], unit))
                .x_label_formatter(&|v| tick_label(*v, xspan))
                .y_label_formatter(&|v| tick_label(*v, yspan))
                .draw()
                .map_err(draw_err)?;
        }
        let grey = RGBColor(150, 150, 150);
        for tr in &trajs {
            for run in finite_runs(tr.iter().copied()) {
                chart
                    .draw_series(LineSeries::new(run, grey.mix(0.7).stroke_width(1)))
                    .map_err(draw_err)?;
            }
        }
        if !trajs.is_empty() {
            entries.push(("demonstrations".into(), Swatch::Line(grey, 1)));
        }
        for (e, c) in ellipses.iter().zip(&contours) {
            let colour = if e.transition {
                cluster_colour(e.index)
            } else {
                state_colour(e.index)
            };
            let width = if e.transition { 3 } else { 2 };
            let fill = if e.transition {
                colour.mix(0.05)
            } else {
                colour.mix(0.15)
            };
            chart
                .draw_series(std::iter::once(Polygon::new(c.clone(), fill.filled())))
                .map_err(draw_err)?;
            if e.transition {
                // Transition states and clusters: dashed outline, triangle at the mean.
                chart
                    .draw_series(std::iter::once(DashedPathElement::new(
                        c.clone(),
                        8,
                        5,
                        colour.stroke_width(width),
                    )))
                    .map_err(draw_err)?;
                chart
                    .draw_series(std::iter::once(TriangleMarker::new(
                        (e.mean[0], e.mean[1]),
                        5,
                        colour.filled(),
                    )))
                    .map_err(draw_err)?;
                entries.push((e.label.clone(), Swatch::Dashed(colour, width)));
            } else {
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        c.clone(),
                        colour.stroke_width(width),
                    )))
                    .map_err(draw_err)?;
                chart
                    .draw_series(std::iter::once(Cross::new(
                        (e.mean[0], e.mean[1]),
                        4,
                        colour.stroke_width(2),
                    )))
                    .map_err(draw_err)?;
                entries.push((e.label.clone(), Swatch::Line(colour, width)));
            }
        }
        notes.push(regularisation_note(mf, proj, unit));
        if stride > 1 {
            notes.push(format!(
                "{frames} frames: trajectories drawn at one frame in {stride}"
            ));
        }
        draw_legend(&legend_area, &entries, &notes)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// What the regularisation does to the outlines: every variance of the model holds
/// the fit's `r`, so no 2σ half-axis is shorter than `2√r` (in the reported unit).
fn regularisation_note(mf: &ModelFile, proj: &Projection, unit: &Unit) -> String {
    let half: Vec<f64> = proj
        .dims
        .iter()
        .map(|&k| 2.0 * regularisation_variance(mf, k, unit).sqrt())
        .collect();
    if mf.fit.regularisation <= 0.0 {
        return "The fit added no regularisation to the variances.".into();
    }
    let same = half
        .iter()
        .all(|h| (h - half[0]).abs() <= 1e-9 * half[0].abs());
    let widths = if same {
        format!("{} {}", sig4(half[0]), unit.name)
    } else {
        proj.dims
            .iter()
            .zip(&half)
            .map(|(&k, h)| format!("{} {} along {}", sig4(*h), unit.name, mf.layout.features[k]))
            .collect::<Vec<_>>()
            .join(", ")
    };
    format!(
        "The outlines include the fit's regularisation r = {:e} {}, added to every variance: \
         no 2σ half-axis is shorter than 2√r = {widths}, whatever the data.",
        mf.fit.regularisation,
        if mf.standardisation.is_some() {
            "(standardised units)²"
        } else {
            "(data units)²"
        }
    )
}
