//! The segmentation plot: one demonstration over time, the human's and the
//! robot's columns in two panels (in the reported unit), the states as colour
//! bands and transition frames as ticks coloured by transition cluster. Long
//! demonstrations are drawn in at most [`MAX_BUCKETS`](super::MAX_BUCKETS)
//! buckets of frames (a bucket's band shows its most frequent state).

use super::{
    cluster_colour, draw_err, draw_legend, file_name, finite_runs, padded, state_colour,
    tick_label, Buckets, MinMax, Swatch, LEGEND_WIDTH,
};
use crate::data::Table;
use crate::error::Result;
use crate::model_file::ModelFile;
use crate::pipeline::{joint_features_raw, segment_table};
use crate::units::Unit;
use plotters::prelude::*;

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

/// The label of every bucket: its most frequent one (the lowest on a tie).
fn bucket_labels(labels: &[usize], buckets: &Buckets, n_labels: usize) -> Vec<usize> {
    let mut counts = vec![0usize; n_labels.max(1)];
    (0..buckets.len())
        .map(|b| {
            let (a, e) = buckets.span(b);
            counts.iter_mut().for_each(|c| *c = 0);
            for &z in &labels[a..e] {
                counts[z] += 1;
            }
            (0..counts.len())
                .max_by_key(|&z| (counts[z], std::cmp::Reverse(z)))
                .unwrap_or(0)
        })
        .collect()
}

/// The segmentation of one demonstration as SVG, values in `unit`.
pub fn segmentation_svg(mf: &ModelFile, table: &Table, unit: &Unit) -> Result<String> {
    let seg = segment_table(mf, table)?;
    let joint = joint_features_raw(mf, table)?;
    let d = mf.layout.features.len();
    let n = table.n_rows();
    let l = &mf.layout;
    let s = unit.scale;
    let nh_raw = l.human_columns.len();
    let robot_pos: Vec<usize> = l.robot_positions.iter().map(|&j| l.robot[j]).collect();
    let panels: [(String, Vec<usize>); 2] = [
        ("human".into(), (0..nh_raw).collect()),
        ("robot".into(), robot_pos),
    ];
    let n_states = seg.labels.iter().max().map_or(0, |m| m + 1);
    let buckets = Buckets::new(n);
    let labels = bucket_labels(&seg.labels, &buckets, n_states);
    // Transition ticks: one per bucket and cluster.
    let mut ticks: Vec<(usize, Option<usize>)> = seg
        .transitions
        .iter()
        .enumerate()
        .map(|(i, &t)| (buckets.of(t), seg.clusters.get(i).copied().flatten()))
        .collect();
    ticks.sort_unstable();
    ticks.dedup();
    let mut svg = String::new();
    {
        let total_width = 1100u32;
        let root = SVGBackend::with_string(&mut svg, (total_width, 720)).into_drawing_area();
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
        for (i, (area, (side, dims))) in areas.iter().zip(panels.iter()).enumerate() {
            let (plot_area, legend_area) = area.split_horizontally(total_width - LEGEND_WIDTH);
            let joint = &joint;
            let values = || {
                dims.iter()
                    .flat_map(move |&k| (0..n).map(move |t| joint[t * d + k] * s))
                    .filter(|v| v.is_finite())
            };
            let lo = values().fold(f64::INFINITY, f64::min);
            let hi = values().fold(f64::NEG_INFINITY, f64::max);
            let yr = padded(lo, hi);
            let (y0, y1) = (yr.start, yr.end);
            let span = y1 - y0;
            let mut chart = ChartBuilder::on(&plot_area)
                .margin(12)
                .caption(format!("{side}'s columns"), ("sans-serif", 16))
                .x_label_area_size(32)
                .y_label_area_size(70)
                .build_cartesian_2d(0f64..(n.max(2) - 1) as f64, yr)
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("frame")
                .y_desc(format!("{side}'s position ({})", unit.name))
                .x_label_formatter(&|x| format!("{x:.0}"))
                .y_label_formatter(&|y| tick_label(*y, span))
                .draw()
                .map_err(draw_err)?;
            let mut entries: Vec<(String, Swatch)> = Vec::new();
            let runs = label_runs(&labels);
            for st in 0..n_states {
                let c = state_colour(st);
                let rects: Vec<_> = runs
                    .iter()
                    .filter(|r| r.2 == st)
                    .map(|&(a, b, _)| {
                        let (a, _) = buckets.span(a);
                        let (_, b) = buckets.span(b - 1);
                        Rectangle::new(
                            [(a as f64 - 0.5, y0), (b as f64 - 0.5, y1)],
                            c.mix(0.18).filled(),
                        )
                    })
                    .collect();
                if rects.is_empty() {
                    continue;
                }
                chart.draw_series(rects).map_err(draw_err)?;
                entries.push((format!("state {st}"), Swatch::Box(c.mix(0.5))));
            }
            // Transition frames: ticks along the top, coloured by cluster.
            let tick = (y1 - y0) * 0.06;
            let mut clusters_seen: Vec<Option<usize>> = Vec::new();
            let first_tick_entry = entries.len();
            for &(b, c) in &ticks {
                let colour = c.map_or(BLACK, cluster_colour);
                let (a, e) = buckets.span(b);
                let t = 0.5 * (a + e - 1) as f64;
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        vec![(t, y1), (t, y1 - tick)],
                        colour.stroke_width(2),
                    )))
                    .map_err(draw_err)?;
                if !clusters_seen.contains(&c) {
                    clusters_seen.push(c);
                    entries.push((
                        c.map_or("transition frame".into(), |c| {
                            format!("transition cluster {c}")
                        }),
                        Swatch::Tick(colour),
                    ));
                }
            }
            // Clusters in the legend by number, not by first appearance.
            entries[first_tick_entry..].sort_by(|a, b| a.0.cmp(&b.0));
            for (j, &k) in dims.iter().enumerate() {
                let style = [BLACK, RGBColor(90, 90, 90), RGBColor(160, 160, 160)][j % 3];
                let mut per_bucket = vec![MinMax::new(); buckets.len()];
                for t in 0..n {
                    per_bucket[buckets.of(t)].push(t, joint[t * d + k] * s);
                }
                let runs = finite_runs(per_bucket.iter().flat_map(MinMax::points));
                for run in runs {
                    chart
                        .draw_series(LineSeries::new(run, style.stroke_width(2)))
                        .map_err(draw_err)?;
                }
                entries.push((l.features[k].clone(), Swatch::Line(style, 2)));
            }
            // States and clusters are the same in both panels: listed once.
            if i > 0 {
                entries.retain(|(_, sw)| matches!(sw, Swatch::Line(..)));
            }
            let notes: Vec<String> = match buckets.note() {
                Some(n) if i == 0 => vec![
                    n,
                    "Bands: each bucket's most frequent state; ticks: one per bucket and transition cluster."
                        .into(),
                ],
                _ => Vec::new(),
            };
            draw_legend(&legend_area, &entries, &notes)?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}
