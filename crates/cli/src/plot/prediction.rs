//! The prediction plot: the robot's predicted positions against the true ones,
//! one panel per position column, with ±2σ bands of the predictive covariance.
//!
//! The band includes the fit's regularisation (added to every variance of the
//! model), which on NuiSI alone is ±20 cm: the plot says so, and how much of each
//! band's variance it is. Values are in the reported unit (cm for data in metres).
//! The prediction runs frame by frame (the causal filter of `stream`), so memory
//! does not grow with the demonstration beyond the table itself, and frames are
//! drawn in at most [`MAX_BUCKETS`](super::MAX_BUCKETS) buckets.

use super::{
    axis_label, draw_err, draw_legend, file_name, finite_runs, padded, regularisation_variance,
    tick_label, Buckets, MinMax, Swatch, LEGEND_WIDTH,
};
use crate::data::Table;
use crate::error::{CliError, Result};
use crate::model_file::ModelFile;
use crate::pipeline::{column_indices, StreamPredictor};
use crate::units::{sig4, Unit};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// One robot position column over the buckets of frames, in the reported unit.
struct Panel {
    /// Feature index.
    feature: usize,
    truth: Vec<MinMax>,
    mean: Vec<MinMax>,
    /// Largest `mean + 2σ` and smallest `mean − 2σ` of every bucket.
    upper: Vec<f64>,
    lower: Vec<f64>,
    /// Sum over frames of regularisation / predictive variance, and frames summed.
    share: (f64, usize),
}

impl Panel {
    fn range(&self) -> (f64, f64) {
        let lo = self
            .lower
            .iter()
            .chain(self.truth.iter().map(|m| &m.min.1))
            .filter(|v| v.is_finite())
            .fold(f64::INFINITY, |a, &b| a.min(b));
        let hi = self
            .upper
            .iter()
            .chain(self.truth.iter().map(|m| &m.max.1))
            .filter(|v| v.is_finite())
            .fold(f64::NEG_INFINITY, |a, &b| a.max(b));
        (lo, hi)
    }
}

/// Predicted vs true robot positions with ±2σ bands, as SVG, in `unit`.
pub fn prediction_svg(mf: &ModelFile, table: &Table, unit: &Unit) -> Result<String> {
    let l = &mf.layout;
    let n = table.n_rows();
    let width = table.columns.len();
    let human_cols = column_indices(table, &l.human_columns, "human")?;
    let robot_cols = column_indices(table, &l.robot_columns, "robot")?;
    let o = l.robot.len();
    let s = unit.scale;
    let buckets = Buckets::new(n);
    let nb = buckets.len();
    let mut panels: Vec<Panel> = l
        .robot_positions
        .iter()
        .map(|&j| Panel {
            feature: l.robot[j],
            truth: vec![MinMax::new(); nb],
            mean: vec![MinMax::new(); nb],
            upper: vec![f64::NEG_INFINITY; nb],
            lower: vec![f64::INFINITY; nb],
            share: (0.0, 0),
        })
        .collect();
    let reg: Vec<f64> = panels
        .iter()
        .map(|p| regularisation_variance(mf, p.feature, unit))
        .collect();
    // Buckets in which some of the human's values are missing: shaded in every panel.
    let mut unobserved = vec![false; nb];
    let (mut se, mut scored) = (0.0, 0usize);
    let mut online = StreamPredictor::new(mf)?;
    let mut human = vec![0.0; human_cols.len()];
    for t in 0..n {
        let row = &table.data[t * width..(t + 1) * width];
        for (h, &c) in human.iter_mut().zip(&human_cols) {
            *h = row[c];
        }
        let b = buckets.of(t);
        unobserved[b] |= human.iter().any(|v| v.is_nan());
        let (mean, cov) = online.step(&human, true).map_err(|e| {
            CliError::new(format!(
                "{}: frame {t}: prediction failed: {e}",
                table.path.display()
            ))
        })?;
        let cov = cov.ok_or_else(|| CliError::new("the predictor gave no covariance"))?;
        // Frames whose true robot position is not fully observed are not scored.
        let truth = |j: usize| row[robot_cols[j]];
        let complete = l.robot_positions.iter().all(|&j| !truth(j).is_nan());
        for (p, (&j, &r)) in panels.iter_mut().zip(l.robot_positions.iter().zip(&reg)) {
            let m = mean[j] * s;
            let var = cov[j * o + j].max(0.0) * s * s;
            let sd = var.sqrt();
            p.truth[b].push(t, truth(j) * s);
            p.mean[b].push(t, m);
            p.upper[b] = p.upper[b].max(m + 2.0 * sd);
            p.lower[b] = p.lower[b].min(m - 2.0 * sd);
            if var > 0.0 {
                p.share.0 += (r / var).min(1.0);
                p.share.1 += 1;
            }
            if complete {
                se += (m - truth(j) * s).powi(2);
            }
        }
        scored += usize::from(complete);
    }
    let mse = se / scored.max(1) as f64;
    let any_unobserved = unobserved.iter().any(|u| *u);
    let blue = RGBColor(31, 119, 180);
    let band = blue.mix(0.2);
    let grey = RGBColor(120, 120, 120).mix(0.15);
    let floor_colour = RGBColor(31, 119, 180).mix(0.6);
    let mut entries = vec![
        ("true".to_string(), Swatch::Line(BLACK, 2)),
        ("predicted".to_string(), Swatch::Line(blue, 2)),
        ("±2σ (predictive)".to_string(), Swatch::Box(band)),
    ];
    if mf.fit.regularisation > 0.0 {
        entries.push((
            "±2√r: regularisation alone".to_string(),
            Swatch::Line(RGBColor(120, 170, 210), 1),
        ));
    }
    if any_unobserved {
        entries.push(("human values missing".to_string(), Swatch::Box(grey)));
    }
    let floor = reg.first().map_or(0.0, |r| 2.0 * r.sqrt());
    let mut caption = vec![if mf.fit.regularisation > 0.0 {
        format!(
            "The bands include the fit's regularisation r = {:e} {} on every variance of the model: \
             alone it gives ±2√r = ±{} {}.",
            mf.fit.regularisation,
            if mf.standardisation.is_some() {
                "(standardised units)²"
            } else {
                "(data units)²"
            },
            sig4(floor),
            unit.name
        )
    } else {
        "The fit added no regularisation to the variances.".to_string()
    }];
    caption.extend(buckets.note().map(|n| format!("{n}.")));
    let mut svg = String::new();
    {
        let total_width = 1100u32;
        let height = 90 + 240 * panels.len() as u32;
        let root = SVGBackend::with_string(&mut svg, (total_width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let title = format!(
            "{} — {}: predicted vs true robot (MSE {} {}, ±2σ bands)",
            file_name(table),
            mf.method.spec,
            sig4(mse),
            unit.squared()
        );
        let root = root.titled(&title, ("sans-serif", 20)).map_err(draw_err)?;
        let (strip, body) = root.split_vertically(36);
        let font = ("sans-serif", 14)
            .into_font()
            .color(&RGBColor(60, 60, 60))
            .pos(Pos::new(HPos::Left, VPos::Center));
        for (i, line) in caption.iter().enumerate() {
            strip
                .draw(&Text::new(
                    line.clone(),
                    (16, 9 + 17 * i as i32),
                    font.clone(),
                ))
                .map_err(draw_err)?;
        }
        let areas = body.split_evenly((panels.len().max(1), 1));
        for (i, (area, p)) in areas.iter().zip(&panels).enumerate() {
            let (plot_area, legend_area) = area.split_horizontally(total_width - LEGEND_WIDTH);
            let (lo, hi) = p.range();
            let yr = padded(lo, hi);
            let (ylo, yhi) = (yr.start, yr.end);
            let span = yhi - ylo;
            let mut chart = ChartBuilder::on(&plot_area)
                .margin(12)
                .x_label_area_size(30)
                .y_label_area_size(70)
                .build_cartesian_2d(0f64..(n.max(2) - 1) as f64, yr)
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .x_desc("frame")
                .y_desc(axis_label(mf, p.feature, unit))
                .x_label_formatter(&|x| format!("{x:.0}"))
                .y_label_formatter(&|y| tick_label(*y, span))
                .draw()
                .map_err(draw_err)?;
            // The band: the upper edge forwards, the lower edge back; a bucket of
            // several frames spans them.
            let edge = |b: usize, v: f64| -> Vec<(f64, f64)> {
                let (a, e) = buckets.span(b);
                if e - a == 1 {
                    vec![(a as f64, v)]
                } else {
                    vec![(a as f64, v), ((e - 1) as f64, v)]
                }
            };
            let outline: Vec<(f64, f64)> = (0..nb)
                .flat_map(|b| edge(b, p.upper[b]))
                .chain((0..nb).rev().flat_map(|b| {
                    let mut e = edge(b, p.lower[b]);
                    e.reverse();
                    e
                }))
                .filter(|q| q.1.is_finite())
                .collect();
            chart
                .draw_series(std::iter::once(Polygon::new(outline, band.filled())))
                .map_err(draw_err)?;
            if any_unobserved {
                // One rectangle per run of buckets with missing human values.
                let mut b = 0;
                let mut rects = Vec::new();
                while b < nb {
                    if !unobserved[b] {
                        b += 1;
                        continue;
                    }
                    let start = b;
                    while b < nb && unobserved[b] {
                        b += 1;
                    }
                    let (a, _) = buckets.span(start);
                    let (_, e) = buckets.span(b - 1);
                    rects.push(Rectangle::new(
                        [(a as f64 - 0.5, ylo), (e as f64 - 0.5, yhi)],
                        grey.filled(),
                    ));
                }
                chart.draw_series(rects).map_err(draw_err)?;
            }
            let line = |m: &[MinMax]| finite_runs(m.iter().flat_map(MinMax::points));
            for run in line(&p.truth) {
                chart
                    .draw_series(LineSeries::new(run, BLACK.stroke_width(2)))
                    .map_err(draw_err)?;
            }
            // What the regularisation alone would give around the prediction: its
            // envelope over every bucket (one point per frame when not decimated).
            let half = 2.0 * reg[i].sqrt();
            if half > 0.0 {
                let upper = (0..nb).flat_map(|b| {
                    let m = p.mean[b];
                    edge(
                        b,
                        if m.is_empty() {
                            f64::NAN
                        } else {
                            m.max.1 + half
                        },
                    )
                });
                let lower = (0..nb).flat_map(|b| {
                    let m = p.mean[b];
                    edge(
                        b,
                        if m.is_empty() {
                            f64::NAN
                        } else {
                            m.min.1 - half
                        },
                    )
                });
                for run in finite_runs(upper).into_iter().chain(finite_runs(lower)) {
                    chart
                        .draw_series(LineSeries::new(run, floor_colour.stroke_width(1)))
                        .map_err(draw_err)?;
                }
            }
            for run in line(&p.mean) {
                chart
                    .draw_series(LineSeries::new(run, blue.stroke_width(2)))
                    .map_err(draw_err)?;
            }
            let share = if p.share.1 > 0 {
                format!(
                    "Regularisation: {:.0} % of this band's variance (mean over frames).",
                    100.0 * p.share.0 / p.share.1 as f64
                )
            } else {
                "No predictive variance.".to_string()
            };
            let shown: &[(String, Swatch)] = if i == 0 { &entries } else { &[] };
            draw_legend(&legend_area, shown, &[share])?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}
