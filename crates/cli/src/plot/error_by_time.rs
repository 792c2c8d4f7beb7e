//! The error against normalised time (issue 17): for one action, every method's
//! MSE per bin of normalised time (`τ = t / (T − 1)`: 0 = the first frame, 1 = the
//! last frame of the test demonstration), its mean over seeds as a line and the
//! 5–95 % band of the seeds' bin MSE shaded, in the reported unit² (cm² for data
//! in metres). The numbers are `evaluate`'s ([`crate::experiment::TimeBinSummary`]),
//! the same as in `PREFIX_error_by_time.csv`.

use super::{
    draw_err, draw_legend, finite_runs, padded, state_colour, tick_label, Swatch, LEGEND_WIDTH,
};
use crate::error::Result;
use crate::experiment::Row;
use crate::units::Unit;
use plotters::prelude::*;

/// The centre of a bin, where its value is drawn.
fn centre(from: f64, to: f64) -> f64 {
    0.5 * (from + to)
}

/// The SVG of one action: one line per row of `rows` (a method; its
/// [`Row::error_by_time`]), `seeds` the seeds run per method (the title's).
pub fn error_by_time_svg(action: &str, rows: &[&Row], seeds: usize, unit: &Unit) -> Result<String> {
    let bins = rows
        .iter()
        .map(|r| r.error_by_time.len())
        .max()
        .unwrap_or(0);
    // The MSE is never negative: the axis starts at 0 and spans every band.
    let top = rows
        .iter()
        .flat_map(|r| &r.error_by_time)
        .flat_map(|b| [b.mse_mean, b.mse_p95])
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let yr = 0.0..padded(0.0, top).end;
    let span = yr.end - yr.start;
    let mut entries: Vec<(String, Swatch)> = Vec::new();
    for (i, r) in rows.iter().enumerate() {
        let label = if r.seeds == seeds {
            r.method.clone()
        } else {
            format!("{} ({} of {seeds} seeds)", r.method, r.seeds)
        };
        entries.push((label, Swatch::Line(state_colour(i), 2)));
    }
    entries.push((
        "5–95 % of seeds (band)".to_string(),
        Swatch::Box(RGBColor(120, 120, 120).mix(0.25)),
    ));
    let notes = vec![
        format!(
            "{bins} bins of normalised time, each drawn at its centre; a line: the mean over seeds of the bin's MSE."
        ),
        "Normalised time: 0 = first frame, 1 = last frame of the test demonstration.".to_string(),
    ];
    let mut svg = String::new();
    {
        let (width, height) = (1000u32, 560u32);
        let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let title = format!(
            "{action}: MSE against normalised time, {seeds} seed{} (mean, 5–95 % band over seeds)",
            if seeds == 1 { "" } else { "s" }
        );
        let root = root.titled(&title, ("sans-serif", 20)).map_err(draw_err)?;
        let (plot_area, legend_area) = root.split_horizontally(width - LEGEND_WIDTH);
        let mut chart = ChartBuilder::on(&plot_area)
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(80)
            .build_cartesian_2d(0f64..1f64, yr)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc("normalised time τ = t / (T − 1) (0 = first frame, 1 = last frame)")
            .y_desc(format!("MSE ({})", unit.squared()))
            .x_label_formatter(&|x| tick_label(*x, 1.0))
            .y_label_formatter(&|y| tick_label(*y, span))
            .draw()
            .map_err(draw_err)?;
        for (i, r) in rows.iter().enumerate() {
            let colour = state_colour(i);
            // The band: one polygon per run of bins with values (an empty bin is a gap).
            let mut run: Vec<(f64, f64, f64)> = Vec::new();
            let mut bands: Vec<Vec<(f64, f64, f64)>> = Vec::new();
            for b in &r.error_by_time {
                if b.mse_p05.is_finite() && b.mse_p95.is_finite() {
                    run.push((centre(b.time_from, b.time_to), b.mse_p05, b.mse_p95));
                } else if !run.is_empty() {
                    bands.push(std::mem::take(&mut run));
                }
            }
            if !run.is_empty() {
                bands.push(run);
            }
            for band in bands {
                let outline: Vec<(f64, f64)> = band
                    .iter()
                    .map(|&(x, _, hi)| (x, hi))
                    .chain(band.iter().rev().map(|&(x, lo, _)| (x, lo)))
                    .collect();
                chart
                    .draw_series(std::iter::once(Polygon::new(
                        outline,
                        colour.mix(0.18).filled(),
                    )))
                    .map_err(draw_err)?;
            }
            let line = r
                .error_by_time
                .iter()
                .map(|b| (centre(b.time_from, b.time_to), b.mse_mean));
            for run in finite_runs(line) {
                chart
                    .draw_series(LineSeries::new(run.clone(), colour.stroke_width(2)))
                    .map_err(draw_err)?;
                // A lone bin would be an invisible line of one point: a dot shows it.
                chart
                    .draw_series(run.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                    .map_err(draw_err)?;
            }
        }
        draw_legend(&legend_area, &entries, &notes)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}
