//! SVG pictures of a model applied to demonstrations (plotters, SVG backend).
//!
//! * [`segmentation_svg`]: one demonstration over time, its states as colour
//!   bands, transition frames marked (coloured by transition cluster);
//! * [`prediction_svg`]: predicted vs true robot positions with ±2σ bands;
//! * [`states_svg`]: trajectories in a plane of two features with the 2σ
//!   ellipses of the states' and the transition clusters' Gaussians.

use crate::data::Table;
use crate::error::{CliError, Result};
use crate::model_file::ModelFile;
use crate::pipeline::{joint_features_raw, predict_table, predictor, segment_table};
use phasekit_emission::Gaussian;
use phasekit_tsc::Model;
use plotters::prelude::*;

/// Colours of states (Tableau 10).
const STATE_COLOURS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
    RGBColor(214, 39, 40),
];

/// Colours of transition clusters.
const CLUSTER_COLOURS: [RGBColor; 6] = [
    RGBColor(214, 39, 40),
    RGBColor(0, 0, 0),
    RGBColor(180, 0, 120),
    RGBColor(120, 60, 0),
    RGBColor(0, 90, 90),
    RGBColor(90, 90, 0),
];

fn state_colour(i: usize) -> RGBColor {
    STATE_COLOURS[i % STATE_COLOURS.len()]
}

fn cluster_colour(i: usize) -> RGBColor {
    CLUSTER_COLOURS[i % CLUSTER_COLOURS.len()]
}

fn draw_err(e: impl std::fmt::Display) -> CliError {
    CliError::new(format!("cannot draw the picture: {e}"))
}

/// `lo..hi` widened by 5 % (and made non-empty).
fn padded(lo: f64, hi: f64) -> std::ops::Range<f64> {
    let (lo, hi) = if lo.is_finite() && hi.is_finite() {
        (lo, hi)
    } else {
        (0.0, 1.0)
    };
    let span = (hi - lo).max(1e-9 * hi.abs().max(1.0)).max(1e-12);
    (lo - 0.05 * span)..(hi + 0.05 * span)
}

fn file_name(t: &Table) -> String {
    t.path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("demonstration")
        .to_string()
}

/// Runs of equal labels: `(start, end_exclusive, label)`.
fn label_runs(labels: &[usize]) -> Vec<(usize, usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    for t in 1..=labels.len() {
        if t == labels.len() || labels[t] != labels[start] {
            out.push((start, t, labels[start]));
            start = t;
        }
    }
    out
}

/// The segmentation of one demonstration as SVG.
pub fn segmentation_svg(mf: &ModelFile, table: &Table) -> Result<String> {
    let seg = segment_table(mf, table)?;
    let joint = joint_features_raw(mf, table)?;
    let d = mf.layout.features.len();
    let n = table.n_rows();
    let l = &mf.layout;
    let nh_raw = l.human_columns.len();
    let robot_pos: Vec<usize> = l.robot_positions.iter().map(|&j| l.robot[j]).collect();
    let panels: [(String, Vec<usize>); 2] = [
        ("human".into(), (0..nh_raw).collect()),
        ("robot".into(), robot_pos),
    ];
    let n_states = seg.labels.iter().max().map_or(0, |m| m + 1);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1100, 720)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let title = format!(
            "{} — {} ({} states, {} transition frames)",
            file_name(table),
            mf.method.spec,
            mf.n_states(),
            seg.transitions.len()
        );
        let root = root.titled(&title, ("sans-serif", 22)).map_err(draw_err)?;
        let areas = root.split_evenly((2, 1));
        for (area, (side, dims)) in areas.iter().zip(panels.iter()) {
            let joint = &joint;
            let values = || {
                dims.iter()
                    .flat_map(move |&k| (0..n).map(move |t| joint[t * d + k]))
            };
            let lo = values().fold(f64::INFINITY, f64::min);
            let hi = values().fold(f64::NEG_INFINITY, f64::max);
            let yr = padded(lo, hi);
            let (y0, y1) = (yr.start, yr.end);
            let mut chart = ChartBuilder::on(area)
                .margin(12)
                .caption(format!("{side}'s columns"), ("sans-serif", 16))
                .x_label_area_size(32)
                .y_label_area_size(60)
                .build_cartesian_2d(0f64..(n.max(2) - 1) as f64, yr)
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("frame")
                .y_desc("value")
                .x_label_formatter(&|x| format!("{x:.0}"))
                .draw()
                .map_err(draw_err)?;
            let runs = label_runs(&seg.labels);
            for s in 0..n_states {
                let c = state_colour(s);
                let rects: Vec<_> = runs
                    .iter()
                    .filter(|r| r.2 == s)
                    .map(|&(a, b, _)| {
                        Rectangle::new(
                            [(a as f64 - 0.5, y0), (b as f64 - 0.5, y1)],
                            c.mix(0.18).filled(),
                        )
                    })
                    .collect();
                if rects.is_empty() {
                    continue;
                }
                chart
                    .draw_series(rects)
                    .map_err(draw_err)?
                    .label(format!("state {s}"))
                    .legend(move |(x, y)| {
                        Rectangle::new([(x, y - 6), (x + 14, y + 6)], c.mix(0.5).filled())
                    });
            }
            // Transition frames: ticks along the top, coloured by cluster.
            let tick = (y1 - y0) * 0.06;
            let mut clusters_seen: Vec<Option<usize>> = Vec::new();
            for (i, &t) in seg.transitions.iter().enumerate() {
                let c = seg.clusters.get(i).copied().flatten();
                let colour = c.map_or(BLACK, cluster_colour);
                let first = !clusters_seen.contains(&c);
                let s = chart
                    .draw_series(std::iter::once(PathElement::new(
                        vec![(t as f64, y1), (t as f64, y1 - tick)],
                        colour.stroke_width(2),
                    )))
                    .map_err(draw_err)?;
                if first {
                    clusters_seen.push(c);
                    s.label(c.map_or("transition frame".into(), |c| {
                        format!("transition cluster {c}")
                    }))
                    .legend(move |(x, y)| {
                        PathElement::new(
                            vec![(x + 7, y - 6), (x + 7, y + 6)],
                            colour.stroke_width(2),
                        )
                    });
                }
            }
            for (j, &k) in dims.iter().enumerate() {
                let style = [BLACK, RGBColor(90, 90, 90), RGBColor(160, 160, 160)][j % 3];
                chart
                    .draw_series(LineSeries::new(
                        (0..n).map(|t| (t as f64, joint[t * d + k])),
                        style.stroke_width(2),
                    ))
                    .map_err(draw_err)?
                    .label(l.features[k].clone())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 14, y)], style.stroke_width(2))
                    });
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .label_font(("sans-serif", 12))
                .draw()
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// Predicted vs true robot positions with ±2σ bands, as SVG.
pub fn prediction_svg(mf: &ModelFile, table: &Table) -> Result<String> {
    let pred = predict_table(mf, &predictor(mf)?, table, true)?;
    let joint = joint_features_raw(mf, table)?;
    let d = mf.layout.features.len();
    let o = pred.n_out;
    let n = table.n_rows();
    let l = &mf.layout;
    let cov = pred
        .covariance
        .as_ref()
        .ok_or_else(|| CliError::new("the predictor gave no covariance"))?;
    let dims: Vec<usize> = l.robot_positions.clone();
    let mut se = 0.0;
    for t in 0..n {
        for &j in &dims {
            se += (pred.mean[t * o + j] - joint[t * d + l.robot[j]]).powi(2);
        }
    }
    let mse = se / n.max(1) as f64;
    let mut svg = String::new();
    {
        let height = 60 + 240 * dims.len() as u32;
        let root = SVGBackend::with_string(&mut svg, (1100, height)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let title = format!(
            "{} — {}: predicted vs true robot (MSE {:.4} data units², ±2σ bands)",
            file_name(table),
            mf.method.spec,
            mse
        );
        let root = root.titled(&title, ("sans-serif", 20)).map_err(draw_err)?;
        let areas = root.split_evenly((dims.len().max(1), 1));
        for (area, &j) in areas.iter().zip(&dims) {
            let k = l.robot[j];
            let mean: Vec<f64> = (0..n).map(|t| pred.mean[t * o + j]).collect();
            let sd: Vec<f64> = (0..n)
                .map(|t| cov[t * o * o + j * o + j].max(0.0).sqrt())
                .collect();
            let truth: Vec<f64> = (0..n).map(|t| joint[t * d + k]).collect();
            let lo = (0..n)
                .map(|t| (mean[t] - 2.0 * sd[t]).min(truth[t]))
                .fold(f64::INFINITY, f64::min);
            let hi = (0..n)
                .map(|t| (mean[t] + 2.0 * sd[t]).max(truth[t]))
                .fold(f64::NEG_INFINITY, f64::max);
            let mut chart = ChartBuilder::on(area)
                .margin(12)
                .x_label_area_size(30)
                .y_label_area_size(60)
                .build_cartesian_2d(0f64..(n.max(2) - 1) as f64, padded(lo, hi))
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .x_desc("frame")
                .y_desc(l.features[k].as_str())
                .x_label_formatter(&|x| format!("{x:.0}"))
                .draw()
                .map_err(draw_err)?;
            let blue = RGBColor(31, 119, 180);
            let band: Vec<(f64, f64)> = (0..n)
                .map(|t| (t as f64, mean[t] + 2.0 * sd[t]))
                .chain((0..n).rev().map(|t| (t as f64, mean[t] - 2.0 * sd[t])))
                .collect();
            chart
                .draw_series(std::iter::once(Polygon::new(band, blue.mix(0.2).filled())))
                .map_err(draw_err)?
                .label("±2σ")
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 6), (x + 14, y + 6)], blue.mix(0.2).filled())
                });
            chart
                .draw_series(LineSeries::new(
                    (0..n).map(|t| (t as f64, truth[t])),
                    BLACK.stroke_width(2),
                ))
                .map_err(draw_err)?
                .label("true")
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 14, y)], BLACK.stroke_width(2))
                });
            chart
                .draw_series(LineSeries::new(
                    (0..n).map(|t| (t as f64, mean[t])),
                    blue.stroke_width(2),
                ))
                .map_err(draw_err)?
                .label("predicted")
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 14, y)], blue.stroke_width(2))
                });
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .label_font(("sans-serif", 12))
                .draw()
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// A Gaussian in a plane: mean and 2×2 covariance, in data units.
#[derive(Debug, Clone, PartialEq)]
pub struct Ellipse {
    /// Centre.
    pub mean: [f64; 2],
    /// Covariance `[[a, b], [b, c]]` as `[a, b, c]`.
    pub cov: [f64; 3],
    /// Legend label.
    pub label: String,
    /// Whether it is a transition cluster.
    pub transition: bool,
    /// Index within its kind.
    pub index: usize,
}

impl Ellipse {
    /// Points of the `k`σ contour.
    pub fn contour(&self, k: f64, n: usize) -> Vec<(f64, f64)> {
        let [a, b, c] = self.cov;
        let half = 0.5 * (a + c);
        let r = (0.25 * (a - c).powi(2) + b * b).sqrt();
        let (l1, l2) = ((half + r).max(0.0), (half - r).max(0.0));
        let theta = 0.5 * (2.0 * b).atan2(a - c);
        let (s1, s2) = (k * l1.sqrt(), k * l2.sqrt());
        (0..=n)
            .map(|i| {
                let phi = 2.0 * std::f64::consts::PI * i as f64 / n as f64;
                let (u, v) = (s1 * phi.cos(), s2 * phi.sin());
                (
                    self.mean[0] + u * theta.cos() - v * theta.sin(),
                    self.mean[1] + u * theta.sin() + v * theta.cos(),
                )
            })
            .collect()
    }
}

fn gaussians(
    g: &Gaussian,
    take: &[usize],
    dims: [usize; 2],
    mf: &ModelFile,
    transition: bool,
) -> Vec<Ellipse> {
    let (sx, sy, mx, my) = match &mf.standardisation {
        Some(s) => (
            s.std[dims[0]],
            s.std[dims[1]],
            s.mean[dims[0]],
            s.mean[dims[1]],
        ),
        None => (1.0, 1.0, 0.0, 0.0),
    };
    take.iter()
        .enumerate()
        .map(|(index, &i)| {
            let m = g.mean(i);
            let c = g.covariance(i);
            Ellipse {
                mean: [m[dims[0]] * sx + mx, m[dims[1]] * sy + my],
                cov: [
                    c[(dims[0], dims[0])] * sx * sx,
                    c[(dims[0], dims[1])] * sx * sy,
                    c[(dims[1], dims[1])] * sy * sy,
                ],
                label: if transition {
                    format!("transition cluster {index}")
                } else {
                    format!("state {index}")
                },
                transition,
                index,
            }
        })
        .collect()
}

/// The states' and transition clusters' Gaussians of a model, projected on two features.
pub fn model_ellipses(mf: &ModelFile, dims: [usize; 2]) -> Vec<Ellipse> {
    let all = |n: usize| (0..n).collect::<Vec<_>>();
    match &mf.model {
        Model::Hmm(h) => gaussians(h.emission(), &all(h.n_states()), dims, mf, false),
        Model::TscHmm { model, .. } => {
            let mut v = gaussians(
                model.base.emission(),
                &all(model.base.n_states()),
                dims,
                mf,
                false,
            );
            v.extend(gaussians(
                model.transition.emission(),
                &all(model.transition.n_states()),
                dims,
                mf,
                true,
            ));
            v
        }
        Model::Gmm(g) => gaussians(g.components(), &all(g.n_components()), dims, mf, false),
        Model::GmmTsc { tsc, mixture } => {
            let base = mixture.n_components() - tsc.kept.len();
            let mut v = gaussians(mixture.components(), &all(base), dims, mf, false);
            v.extend(gaussians(
                tsc.transition_mixture.components(),
                &tsc.kept,
                dims,
                mf,
                true,
            ));
            v
        }
    }
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
pub fn states_svg(mf: &ModelFile, tables: &[Table], dims: [usize; 2]) -> Result<String> {
    let d = mf.layout.features.len();
    let trajs: Vec<Vec<(f64, f64)>> = tables
        .iter()
        .map(|t| {
            joint_features_raw(mf, t).map(|j| {
                j.chunks_exact(d)
                    .map(|f| (f[dims[0]], f[dims[1]]))
                    .collect()
            })
        })
        .collect::<Result<_>>()?;
    let ellipses = model_ellipses(mf, dims);
    let contours: Vec<Vec<(f64, f64)>> = ellipses.iter().map(|e| e.contour(2.0, 96)).collect();
    let pts = || trajs.iter().flatten().chain(contours.iter().flatten());
    let (x0, x1) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
        (a.min(p.0), b.max(p.0))
    });
    let (y0, y1) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
        (a.min(p.1), b.max(p.1))
    });
    let names = [&mf.layout.features[dims[0]], &mf.layout.features[dims[1]]];
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 820)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let title = format!(
            "{} — 2σ ellipses of the states and transition clusters, {} demonstration{}",
            mf.method.spec,
            tables.len(),
            if tables.len() == 1 { "" } else { "s" }
        );
        let mut chart = ChartBuilder::on(&root)
            .margin(16)
            .caption(title, ("sans-serif", 18))
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(padded(x0, x1), padded(y0, y1))
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(names[0].as_str())
            .y_desc(names[1].as_str())
            .draw()
            .map_err(draw_err)?;
        let grey = RGBColor(150, 150, 150);
        for (i, tr) in trajs.iter().enumerate() {
            let s = chart
                .draw_series(LineSeries::new(
                    tr.iter().copied(),
                    grey.mix(0.7).stroke_width(1),
                ))
                .map_err(draw_err)?;
            if i == 0 {
                s.label("demonstrations").legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 14, y)], grey.stroke_width(1))
                });
            }
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
            chart
                .draw_series(std::iter::once(PathElement::new(
                    c.clone(),
                    colour.stroke_width(width),
                )))
                .map_err(draw_err)?
                .label(e.label.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 14, y)], colour.stroke_width(width))
                });
            chart
                .draw_series(std::iter::once(Cross::new(
                    (e.mean[0], e.mean[1]),
                    4,
                    colour.stroke_width(2),
                )))
                .map_err(draw_err)?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font(("sans-serif", 12))
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

#[cfg(test)]
mod tests {
    use super::Ellipse;

    #[test]
    fn two_sigma_contour_of_a_rotated_gaussian() {
        // Variances 4 and 1 along axes rotated by 30°.
        let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let cov = [4.0 * c * c + s * s, 3.0 * c * s, 4.0 * s * s + c * c];
        let e = Ellipse {
            mean: [1.0, -1.0],
            cov,
            label: String::new(),
            transition: false,
            index: 0,
        };
        let inv_det = 1.0 / (cov[0] * cov[2] - cov[1] * cov[1]);
        for (x, y) in e.contour(2.0, 64) {
            let (dx, dy) = (x - 1.0, y + 1.0);
            let m = inv_det * (cov[2] * dx * dx - 2.0 * cov[1] * dx * dy + cov[0] * dy * dy);
            assert!((m - 4.0).abs() < 1e-9, "Mahalanobis² {m}");
        }
    }
}
