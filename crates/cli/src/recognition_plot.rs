//! SVG pictures of recognition: the posterior of every action over one
//! demonstration, and accuracy against the fraction observed.

use crate::commands::recognise::Recognition;
use crate::error::{CliError, Result};
use crate::library_file::LibraryFile;
use phasekit_recognition::experiment::Report;
use plotters::prelude::*;

/// Colours of actions (Tableau 10).
const COLOURS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(188, 189, 34),
];

fn colour(i: usize) -> RGBColor {
    COLOURS[i % COLOURS.len()]
}

fn draw_err(e: impl std::fmt::Display) -> CliError {
    CliError::new(format!("cannot draw the picture: {e}"))
}

/// The posterior `p(a | frames so far)` of every action over one
/// demonstration, the decision as a band along the top (grey: unknown), and
/// the end of the first third marked.
pub fn posterior_svg(file: &LibraryFile, r: &Recognition) -> Result<String> {
    let n = r.decision.len();
    let names = &r.actions;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1000, 480)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let title = format!(
            "{} — which interaction? ({}, {} actions)",
            r.file
                .file_name()
                .and_then(|n| n.to_str())
                .unwrap_or("demonstration"),
            file.methods_text(),
            names.len()
        );
        let mut chart = ChartBuilder::on(&root)
            .margin(14)
            .caption(title, ("sans-serif", 20))
            .x_label_area_size(36)
            .y_label_area_size(56)
            .build_cartesian_2d(0f64..(n.max(2) - 1) as f64, 0f64..1.12)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(format!(
                "frame ({} frames per second)",
                crate::recognition_report::FRAME_RATE
            ))
            .y_desc("p(action | frames so far)")
            .y_labels(6)
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_label_formatter(&|y| {
                if *y <= 1.0 {
                    format!("{y:.1}")
                } else {
                    String::new()
                }
            })
            .draw()
            .map_err(draw_err)?;
        // The decision, frame by frame, as a band above p = 1.
        for (t, d) in r.decision.iter().enumerate() {
            let c = names
                .iter()
                .position(|a| a == d)
                .map_or(RGBColor(150, 150, 150), colour);
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(t as f64 - 0.5, 1.04), (t as f64 + 0.5, 1.10)],
                    c.filled(),
                )))
                .map_err(draw_err)?;
        }
        let third = (n.div_ceil(3).max(1) - 1) as f64;
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(third, 0.0), (third, 1.02)],
                BLACK.mix(0.4).stroke_width(1),
            )))
            .map_err(draw_err)?
            .label("end of the first third")
            .legend(|(x, y)| {
                PathElement::new(vec![(x + 7, y - 6), (x + 7, y + 6)], BLACK.mix(0.4))
            });
        for (a, name) in names.iter().enumerate() {
            let c = colour(a);
            chart
                .draw_series(LineSeries::new(
                    (0..n).map(|t| (t as f64, r.posterior[t][a])),
                    c.stroke_width(2),
                ))
                .map_err(draw_err)?
                .label(name.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 14, y)], c.stroke_width(2))
                });
        }
        if r.decision.iter().any(|d| d == "unknown") {
            chart
                .draw_series(std::iter::empty::<Rectangle<(f64, f64)>>())
                .map_err(draw_err)?
                .label("decision: unknown (band)")
                .legend(|(x, y)| {
                    Rectangle::new(
                        [(x, y - 5), (x + 14, y + 5)],
                        RGBColor(150, 150, 150).filled(),
                    )
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::MiddleRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font(("sans-serif", 12))
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// Accuracy (% of test demonstrations decided right) against the fraction of
/// each demonstration observed: one panel per method, one line per action and
/// a thick one for all test demonstrations (±1 std over seeds shaded).
pub fn accuracy_svg(r: &Report) -> Result<String> {
    let methods = &r.methods;
    if methods.is_empty() || r.recognition.is_empty() {
        return Err(CliError::new("the results hold no accuracy rows"));
    }
    let mut svg = String::new();
    {
        let width = 420 * methods.len() as u32 + 40;
        let root = SVGBackend::with_string(&mut svg, (width, 460)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let root = root
            .titled(
                &format!(
                    "Which interaction? Accuracy after observing part of each test demonstration ({} seed{}{})",
                    r.seeds,
                    if r.seeds == 1 { "" } else { "s" },
                    r.settings
                        .recognition
                        .as_ref()
                        .map_or(String::new(), |(label, _)| format!(
                            "; recognised by {label}"
                        ))
                ),
                ("sans-serif", 18),
            )
            .map_err(draw_err)?;
        let panels = root.split_evenly((1, methods.len()));
        for (panel, m) in panels.iter().zip(methods) {
            let mut chart = ChartBuilder::on(panel)
                .margin(12)
                .caption(m, ("sans-serif", 15))
                .x_label_area_size(36)
                .y_label_area_size(48)
                .build_cartesian_2d(0f64..100.0, 0f64..101.0)
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .light_line_style(BLACK.mix(0.06))
                .x_desc("observed (% of the demonstration)")
                .y_desc("accuracy (% of test demonstrations)")
                .x_label_formatter(&|x| format!("{x:.0}"))
                .y_label_formatter(&|y| format!("{y:.0}"))
                .draw()
                .map_err(draw_err)?;
            let groups: Vec<String> = r
                .actions
                .iter()
                .cloned()
                .chain(std::iter::once("all".into()))
                .collect();
            for (i, g) in groups.iter().enumerate() {
                let rows: Vec<_> = r
                    .recognition
                    .iter()
                    .filter(|x| &x.method == m && &x.action == g)
                    .collect();
                let all = g == "all";
                let c = if all { BLACK } else { colour(i) };
                let points: Vec<(f64, f64)> = rows
                    .iter()
                    .map(|x| (100.0 * x.fraction, 100.0 * x.accuracy))
                    .collect();
                if all && r.seeds > 1 {
                    let band: Vec<(f64, f64)> =
                        rows.iter()
                            .map(|x| {
                                (
                                    100.0 * x.fraction,
                                    (100.0 * (x.accuracy + x.std)).min(100.0),
                                )
                            })
                            .chain(rows.iter().rev().map(|x| {
                                (100.0 * x.fraction, (100.0 * (x.accuracy - x.std)).max(0.0))
                            }))
                            .collect();
                    chart
                        .draw_series(std::iter::once(Polygon::new(
                            band,
                            BLACK.mix(0.12).filled(),
                        )))
                        .map_err(draw_err)?;
                }
                chart
                    .draw_series(LineSeries::new(
                        points.clone(),
                        c.stroke_width(if all { 3 } else { 1 }),
                    ))
                    .map_err(draw_err)?
                    .label(if all {
                        "all (±1 std over seeds)".to_string()
                    } else {
                        g.clone()
                    })
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 14, y)], c.stroke_width(2))
                    });
                chart
                    .draw_series(
                        points
                            .iter()
                            .map(|&p| Circle::new(p, if all { 3 } else { 2 }, c.filled())),
                    )
                    .map_err(draw_err)?;
            }
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(100.0 / 3.0, 0.0), (100.0 / 3.0, 101.0)],
                    BLACK.mix(0.3),
                )))
                .map_err(draw_err)?;
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(0.0, 90.0), (100.0, 90.0)],
                    RGBColor(214, 39, 40).mix(0.5),
                )))
                .map_err(draw_err)?
                .label("aim: 90 % from a third on")
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 14, y)], RGBColor(214, 39, 40).mix(0.5))
                });
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::LowerRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .label_font(("sans-serif", 11))
                .draw()
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}
