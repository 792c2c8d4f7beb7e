//! SVG pictures of a model applied to demonstrations (plotters, SVG backend).
//!
//! * [`segmentation_svg`]: one demonstration over time, its states as colour
//!   bands, transition frames marked (coloured by transition cluster);
//! * [`prediction_svg`]: predicted vs true robot positions with ±2σ bands;
//! * [`states_svg`] / [`states_svg_projected`]: trajectories in a plane of two
//!   features, or an oblique 3-D view of three, with the 2σ outlines of the
//!   predicting model's Gaussians (transition states and clusters dashed).

use crate::data::Table;
use crate::error::{CliError, Result};
use crate::model_file::ModelFile;
use crate::pipeline::{joint_features_raw, predict_table, predictor, segment_table};
use phasekit_emission::Gaussian;
use phasekit_tsc::Model;
use plotters::element::DashedPathElement;
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

/// Splits a polyline at points with a non-finite coordinate (missing values),
/// so that a gap in the data is a gap in the line, not a jump to infinity.
fn finite_runs(points: impl IntoIterator<Item = (f64, f64)>) -> Vec<Vec<(f64, f64)>> {
    let mut runs = vec![Vec::new()];
    for p in points {
        if p.0.is_finite() && p.1.is_finite() {
            runs.last_mut().expect("never empty").push(p);
        } else if !runs.last().expect("never empty").is_empty() {
            runs.push(Vec::new());
        }
    }
    runs.retain(|r| !r.is_empty());
    runs
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
                let runs = finite_runs((0..n).map(|t| (t as f64, joint[t * d + k])));
                for (r, run) in runs.into_iter().enumerate() {
                    let s = chart
                        .draw_series(LineSeries::new(run, style.stroke_width(2)))
                        .map_err(draw_err)?;
                    if r == 0 {
                        s.label(l.features[k].clone()).legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 14, y)], style.stroke_width(2))
                        });
                    }
                }
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
    let (mut se, mut scored) = (0.0, 0usize);
    for t in 0..n {
        // Frames whose true robot position is not fully observed are not scored.
        if dims.iter().any(|&j| joint[t * d + l.robot[j]].is_nan()) {
            continue;
        }
        for &j in &dims {
            se += (pred.mean[t * o + j] - joint[t * d + l.robot[j]]).powi(2);
        }
        scored += 1;
    }
    let mse = se / scored.max(1) as f64;
    // Frames where some of the human's values are missing: shaded in every panel.
    let unobserved: Vec<bool> = (0..n)
        .map(|t| l.human.iter().any(|&k| joint[t * d + k].is_nan()))
        .collect();
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
            if unobserved.iter().any(|u| *u) {
                let (ylo, yhi) = {
                    let r = padded(lo, hi);
                    (r.start, r.end)
                };
                let grey = RGBColor(120, 120, 120).mix(0.15);
                let shaded = chart
                    .draw_series((0..n).filter(|&t| unobserved[t]).map(|t| {
                        Rectangle::new(
                            [(t as f64 - 0.5, ylo), (t as f64 + 0.5, yhi)],
                            grey.filled(),
                        )
                    }))
                    .map_err(draw_err)?;
                shaded.label("human values missing").legend(move |(x, y)| {
                    Rectangle::new([(x, y - 6), (x + 14, y + 6)], grey.filled())
                });
            }
            for (r, run) in finite_runs((0..n).map(|t| (t as f64, truth[t])))
                .into_iter()
                .enumerate()
            {
                let s = chart
                    .draw_series(LineSeries::new(run, BLACK.stroke_width(2)))
                    .map_err(draw_err)?;
                if r == 0 {
                    s.label("true").legend(|(x, y)| {
                        PathElement::new(vec![(x, y), (x + 14, y)], BLACK.stroke_width(2))
                    });
                }
            }
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
    /// Whether it is a transition state (TSC-HMM) or transition cluster (gmm-tsc).
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

/// A linear map from features to the picture's plane: `(u, v) = P x` over the
/// features `dims`, `P` a 2 × `dims.len()` matrix.
///
/// A Gaussian `N(μ, Σ)` maps to `N(Pμ, PΣPᵀ)`, and the outline of the projected
/// `k`σ ellipsoid `{x : (x − μ)ᵀ Σ⁻¹ (x − μ) ≤ k²}` is exactly the `k`σ ellipse of
/// that projected Gaussian, so ellipsoids are drawn by their projected outlines.
#[derive(Debug, Clone, PartialEq)]
pub struct Projection {
    /// Feature indices.
    pub dims: Vec<usize>,
    /// Rows of `P`, one weight per entry of `dims`.
    pub rows: [Vec<f64>; 2],
}

/// Cabinet projection: depth drawn at half scale, 30° from the horizontal.
const OBLIQUE_DEPTH: f64 = 0.5;
const OBLIQUE_ANGLE_DEG: f64 = 30.0;

impl Projection {
    /// The plane of features `x` (horizontal) and `y` (vertical).
    pub fn plane(x: usize, y: usize) -> Self {
        Projection {
            dims: vec![x, y],
            rows: [vec![1.0, 0.0], vec![0.0, 1.0]],
        }
    }

    /// An oblique (cabinet) view of features `x`, `y` (depth) and `z` (up):
    /// `u = x + ½ cos 30° · y`, `v = z + ½ sin 30° · y`.
    pub fn oblique(x: usize, y: usize, z: usize) -> Self {
        let a = OBLIQUE_ANGLE_DEG.to_radians();
        Projection {
            dims: vec![x, y, z],
            rows: [
                vec![1.0, OBLIQUE_DEPTH * a.cos(), 0.0],
                vec![0.0, OBLIQUE_DEPTH * a.sin(), 1.0],
            ],
        }
    }

    /// Whether this is a 3-D view.
    pub fn is_3d(&self) -> bool {
        self.dims.len() == 3
    }

    /// The picture point of a full feature vector.
    pub fn point(&self, x: &[f64]) -> (f64, f64) {
        let at = |r: &[f64]| r.iter().zip(&self.dims).map(|(w, &k)| w * x[k]).sum();
        (at(&self.rows[0]), at(&self.rows[1]))
    }

    /// The picture point of the coordinates `c` along `dims`.
    fn point_of(&self, c: &[f64]) -> (f64, f64) {
        let at = |r: &[f64]| r.iter().zip(c).map(|(w, v)| w * v).sum();
        (at(&self.rows[0]), at(&self.rows[1]))
    }

    /// `P μ` and `P Σ Pᵀ` of a Gaussian given on `dims` (mean and covariance in data units).
    fn gaussian(&self, mean: &[f64], cov: &[f64]) -> ([f64; 2], [f64; 3]) {
        let n = self.dims.len();
        let (u, v) = self.point_of(mean);
        let quad = |a: &[f64], b: &[f64]| {
            (0..n)
                .flat_map(|i| (0..n).map(move |j| a[i] * cov[i * n + j] * b[j]))
                .sum::<f64>()
        };
        let (r0, r1) = (&self.rows[0], &self.rows[1]);
        ([u, v], [quad(r0, r0), quad(r0, r1), quad(r1, r1)])
    }
}

/// Gaussians `take` of `g` (model units), in data units, projected; those at
/// positions ≥ `first_transition` of `take` are transition states/clusters.
fn gaussians(
    g: &Gaussian,
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
            let m = g.mean(i);
            let c = g.covariance(i);
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
/// its last components (the kept clusters, re-trained) marked as transition clusters.
pub fn model_ellipses_projected(mf: &ModelFile, proj: &Projection) -> Vec<Ellipse> {
    let all = |n: usize| (0..n).collect::<Vec<_>>();
    match &mf.model {
        Model::Hmm(h) => gaussians(h.emission(), &all(h.n_states()), usize::MAX, proj, mf, ""),
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
pub fn states_svg(mf: &ModelFile, tables: &[Table], dims: [usize; 2]) -> Result<String> {
    states_svg_projected(mf, tables, &Projection::plane(dims[0], dims[1]))
}

/// Trajectories and the 2σ outlines of the predicting model's Gaussians under a
/// projection (a plane of two features, or an oblique 3-D view), as SVG.
pub fn states_svg_projected(mf: &ModelFile, tables: &[Table], proj: &Projection) -> Result<String> {
    let d = mf.layout.features.len();
    let raw: Vec<Vec<f64>> = tables
        .iter()
        .map(|t| joint_features_raw(mf, t))
        .collect::<Result<_>>()?;
    let trajs: Vec<Vec<(f64, f64)>> = raw
        .iter()
        .map(|j| j.chunks_exact(d).map(|f| proj.point(f)).collect())
        .collect();
    let ellipses = model_ellipses_projected(mf, proj);
    let contours: Vec<Vec<(f64, f64)>> = ellipses.iter().map(|e| e.contour(2.0, 96)).collect();
    // The 3-D view's axes: from the data's lowest corner along each feature to its range.
    let axes: Vec<(String, (f64, f64), (f64, f64))> = if proj.is_3d() {
        let range = |k: usize| {
            raw.iter()
                .flat_map(|j| j.chunks_exact(d).map(move |f| f[k]))
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                    (a.min(v), b.max(v))
                })
        };
        let r: Vec<(f64, f64)> = proj.dims.iter().map(|&k| range(k)).collect();
        let lo: Vec<f64> = r.iter().map(|x| x.0).collect();
        (0..3)
            .map(|a| {
                let mut hi = lo.clone();
                hi[a] = r[a].1;
                (
                    mf.layout.features[proj.dims[a]].clone(),
                    proj.point_of(&lo),
                    proj.point_of(&hi),
                )
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
            .chain(axes.iter().flat_map(|a| [&a.1, &a.2]))
    };
    let (mut x0, mut x1) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
        (a.min(p.0), b.max(p.0))
    });
    let (mut y0, mut y1) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
        (a.min(p.1), b.max(p.1))
    });
    let (width, height) = (900u32, 820u32);
    if proj.is_3d() && x1 > x0 && y1 > y0 {
        // Equal scale on both picture axes, or the projected ellipsoids are distorted.
        let (pw, ph) = (f64::from(width - 110), f64::from(height - 90));
        let per_px = ((x1 - x0) / pw).max((y1 - y0) / ph);
        let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        (x0, x1) = (cx - 0.5 * per_px * pw, cx + 0.5 * per_px * pw);
        (y0, y1) = (cy - 0.5 * per_px * ph, cy + 0.5 * per_px * ph);
    }
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
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
        let mut chart = ChartBuilder::on(&root)
            .margin(16)
            .caption(title, ("sans-serif", 18))
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(padded(x0, x1), padded(y0, y1))
            .map_err(draw_err)?;
        if proj.is_3d() {
            // Picture coordinates mix three features: no ticks, drawn axes instead.
            chart
                .configure_mesh()
                .disable_mesh()
                .disable_axes()
                .draw()
                .map_err(draw_err)?;
            for (name, from, to) in &axes {
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        vec![*from, *to],
                        BLACK.stroke_width(2),
                    )))
                    .map_err(draw_err)?;
                chart
                    .draw_series(std::iter::once(Text::new(
                        name.clone(),
                        *to,
                        ("sans-serif", 14).into_font().color(&BLACK),
                    )))
                    .map_err(draw_err)?;
            }
        } else {
            let names = [
                &mf.layout.features[proj.dims[0]],
                &mf.layout.features[proj.dims[1]],
            ];
            chart
                .configure_mesh()
                .x_desc(names[0].as_str())
                .y_desc(names[1].as_str())
                .draw()
                .map_err(draw_err)?;
        }
        let grey = RGBColor(150, 150, 150);
        let mut labelled = false;
        for tr in &trajs {
            for run in finite_runs(tr.iter().copied()) {
                let s = chart
                    .draw_series(LineSeries::new(run, grey.mix(0.7).stroke_width(1)))
                    .map_err(draw_err)?;
                if !labelled {
                    labelled = true;
                    s.label("demonstrations").legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 14, y)], grey.stroke_width(1))
                    });
                }
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
            if e.transition {
                // Transition states and clusters: dashed outline, triangle at the mean.
                chart
                    .draw_series(std::iter::once(DashedPathElement::new(
                        c.clone(),
                        8,
                        5,
                        colour.stroke_width(width),
                    )))
                    .map_err(draw_err)?
                    .label(e.label.clone())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 14, y)], colour.stroke_width(width))
                    });
                chart
                    .draw_series(std::iter::once(TriangleMarker::new(
                        (e.mean[0], e.mean[1]),
                        5,
                        colour.filled(),
                    )))
                    .map_err(draw_err)?;
            } else {
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
    fn projected_gaussian_outline_is_the_shadow_of_the_ellipsoid() {
        use super::Projection;
        // An ellipsoid's k-σ outline under a linear map P is the k-σ ellipse of N(Pμ, PΣPᵀ):
        // every point of the outline is the image of a point on the ellipsoid, and the image
        // of every ellipsoid point lies inside it.
        let p = Projection::oblique(0, 1, 2);
        let mean = [0.3, -0.2, 1.0];
        let cov = [2.0, 0.4, 0.1, 0.4, 1.0, -0.3, 0.1, -0.3, 0.5];
        let (m, c) = p.gaussian(&mean, &cov);
        assert_eq!(
            m,
            [
                0.3 + 0.5 * 30f64.to_radians().cos() * -0.2,
                1.0 + 0.5 * 30f64.to_radians().sin() * -0.2
            ]
        );
        let l = nalgebra_free_cholesky(&cov);
        let inv_det = 1.0 / (c[0] * c[2] - c[1] * c[1]);
        let mut max_m: f64 = 0.0;
        for i in 0..40 {
            for j in 0..20 {
                let (th, ph) = (
                    i as f64 / 40.0 * std::f64::consts::TAU,
                    j as f64 / 19.0 * std::f64::consts::PI,
                );
                let z = [ph.sin() * th.cos(), ph.sin() * th.sin(), ph.cos()];
                let x: Vec<f64> = (0..3)
                    .map(|r| mean[r] + 2.0 * (0..3).map(|k| l[r * 3 + k] * z[k]).sum::<f64>())
                    .collect();
                let (u, v) = p.point(&x);
                let (du, dv) = (u - m[0], v - m[1]);
                let maha = inv_det * (c[2] * du * du - 2.0 * c[1] * du * dv + c[0] * dv * dv);
                assert!(maha <= 4.0 + 1e-9, "{maha}");
                max_m = max_m.max(maha);
            }
        }
        assert!(max_m > 3.9, "the outline is reached: {max_m}");
    }

    /// Lower Cholesky factor of a 3×3 SPD matrix.
    fn nalgebra_free_cholesky(a: &[f64]) -> Vec<f64> {
        let mut l = vec![0.0; 9];
        for i in 0..3 {
            for j in 0..=i {
                let s: f64 = (0..j).map(|k| l[i * 3 + k] * l[j * 3 + k]).sum();
                l[i * 3 + j] = if i == j {
                    (a[i * 3 + i] - s).sqrt()
                } else {
                    (a[i * 3 + j] - s) / l[j * 3 + j]
                };
            }
        }
        l
    }

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
