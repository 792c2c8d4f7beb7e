//! SVG pictures of a model applied to demonstrations (plotters, SVG backend),
//! one module per kind of picture:
//!
//! * [`segmentation`]: one demonstration over time, its states as colour
//!   bands, transition frames marked (coloured by transition cluster);
//! * [`prediction`]: predicted vs true robot positions with ±2σ bands, the
//!   regularisation's share of the band said on the plot;
//! * [`states`]: trajectories in a plane of two features, or an oblique 3-D view
//!   of three with a scale on each axis, with the 2σ outlines of the predicting
//!   model's Gaussians (transition states and clusters dashed);
//! * [`geometry`]: the ellipses and projections the states plot draws;
//! * [`error_by_time`]: `evaluate`'s MSE against normalised time, one line per
//!   method with its 5–95 % band over seeds.
//!
//! What they share (this module): values are drawn in the reported unit (data in
//! metres as cm unless `--unit`/`--unit-scale` say otherwise, as in the evaluate
//! table), tick labels never read `-0`, legends sit beside the plotting area so
//! that they never cover data, and long demonstrations are drawn decimated (at
//! most [`MAX_BUCKETS`] buckets of frames per line, said on the plot), so a picture
//! stays small whatever the number of frames.

pub mod error_by_time;
pub mod geometry;
pub mod prediction;
pub mod segmentation;
pub mod states;

pub use error_by_time::error_by_time_svg;
pub use geometry::{Ellipse, Projection};
pub use prediction::prediction_svg;
pub use segmentation::segmentation_svg;
pub use states::{
    default_plane, default_xyz, feature_index, model_ellipses, model_ellipses_projected,
    states_svg, states_svg_projected,
};

use crate::data::Table;
use crate::error::CliError;
use crate::model_file::ModelFile;
use crate::units::Unit;
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Most buckets of frames a line over time is drawn with: a longer demonstration is
/// drawn as the minimum and maximum of every bucket (2 points per bucket), which
/// keeps every excursion visible and the file small.
pub const MAX_BUCKETS: usize = 1000;

/// Width of the legend column beside every plotting area, pixels.
const LEGEND_WIDTH: u32 = 200;

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

/// A tick label of an axis spanning `span`: as many decimals as the tick spacing
/// needs (about a tenth of the span), and `0` for a tick at a rounding of zero,
/// never `-0` or `-0.0`.
pub fn tick_label(v: f64, span: f64) -> String {
    let step = (span / 10.0).abs();
    let decimals = if step > 0.0 && step.is_finite() {
        (-(step.log10().floor()) as i64).clamp(0, 12) as usize
    } else {
        2
    };
    let s = format!("{v:.decimals$}");
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// Whether feature `k` of the model is a velocity (a first difference) rather
/// than a column of the data.
fn is_velocity(mf: &ModelFile, k: usize) -> bool {
    let l = &mf.layout;
    if let Some(p) = l.human.iter().position(|&h| h == k) {
        return p >= l.human_columns.len();
    }
    if let Some(p) = l.robot.iter().position(|&r| r == k) {
        return p >= l.robot_columns.len();
    }
    false
}

/// The axis label of feature `k`: its name and unit (`p2_wrist_x (cm)`,
/// `d_p2_wrist_x (cm/frame)`).
fn axis_label(mf: &ModelFile, k: usize, unit: &Unit) -> String {
    let u = if is_velocity(mf, k) {
        format!("{}/frame", unit.name)
    } else {
        unit.name.clone()
    };
    format!("{} ({u})", mf.layout.features[k])
}

/// The regularisation of the fit on feature `k`, as a variance in the reported unit
/// (the model adds it to every covariance diagonal in its own units: standardised
/// features carry it times their variance).
fn regularisation_variance(mf: &ModelFile, k: usize, unit: &Unit) -> f64 {
    let std = mf.standardisation.as_ref().map_or(1.0, |s| s.std[k]);
    mf.fit.regularisation * (std * unit.scale).powi(2)
}

/// What a legend entry shows beside its label.
#[derive(Debug, Clone, Copy)]
enum Swatch {
    /// A line of this colour and width.
    Line(RGBColor, u32),
    /// A dashed line.
    Dashed(RGBColor, u32),
    /// A filled box (bands, shaded frames).
    Box(RGBAColor),
    /// A short vertical tick (transition frames).
    Tick(RGBColor),
}

/// Draws a legend in its own area (beside the plotting area, so that it never
/// covers data): one entry per line, a swatch and a label; extra lines of `notes`
/// (smaller, grey) below the entries.
fn draw_legend(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    entries: &[(String, Swatch)],
    notes: &[String],
) -> crate::error::Result<()> {
    let font = ("sans-serif", 14)
        .into_font()
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center));
    let small = ("sans-serif", 13)
        .into_font()
        .color(&RGBColor(80, 80, 80))
        .pos(Pos::new(HPos::Left, VPos::Center));
    let (x, mut y) = (8, 22);
    for (label, swatch) in entries {
        match *swatch {
            Swatch::Line(c, w) => area
                .draw(&PathElement::new(
                    vec![(x, y), (x + 18, y)],
                    c.stroke_width(w),
                ))
                .map_err(draw_err)?,
            Swatch::Dashed(c, w) => area
                .draw(&DashedPathElement::new(
                    vec![(x, y), (x + 18, y)],
                    5,
                    3,
                    c.stroke_width(w),
                ))
                .map_err(draw_err)?,
            Swatch::Box(c) => area
                .draw(&Rectangle::new([(x, y - 6), (x + 18, y + 6)], c.filled()))
                .map_err(draw_err)?,
            Swatch::Tick(c) => area
                .draw(&PathElement::new(
                    vec![(x + 9, y - 7), (x + 9, y + 7)],
                    c.stroke_width(2),
                ))
                .map_err(draw_err)?,
        }
        area.draw(&Text::new(label.clone(), (x + 26, y), font.clone()))
            .map_err(draw_err)?;
        y += 19;
    }
    y += 6;
    for note in notes {
        for line in wrap(note, 30) {
            area.draw(&Text::new(line, (x, y), small.clone()))
                .map_err(draw_err)?;
            y += 15;
        }
        y += 4;
    }
    Ok(())
}

/// Words of `s` in lines of at most about `width` characters.
fn wrap(s: &str, width: usize) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    for word in s.split_whitespace() {
        match lines.last_mut() {
            Some(l) if l.chars().count() + 1 + word.chars().count() <= width => {
                l.push(' ');
                l.push_str(word);
            }
            _ => lines.push(word.to_string()),
        }
    }
    lines
}

/// Frames grouped for drawing: every frame when there are at most [`MAX_BUCKETS`],
/// else consecutive buckets of `size` frames (the last one shorter).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Buckets {
    /// Frames in all.
    pub frames: usize,
    /// Frames per bucket.
    pub size: usize,
}

impl Buckets {
    /// Buckets for `frames` frames.
    pub fn new(frames: usize) -> Self {
        let size = if frames <= MAX_BUCKETS {
            1
        } else {
            frames.div_ceil(MAX_BUCKETS)
        };
        Buckets { frames, size }
    }

    /// Number of buckets.
    pub fn len(&self) -> usize {
        self.frames.div_ceil(self.size)
    }

    /// Whether there is no frame.
    pub fn is_empty(&self) -> bool {
        self.frames == 0
    }

    /// Whether frames are grouped (the picture is decimated).
    pub fn decimated(&self) -> bool {
        self.size > 1
    }

    /// The bucket of frame `t`.
    pub fn of(&self, t: usize) -> usize {
        t / self.size
    }

    /// First frame and end (exclusive) of bucket `b`.
    pub fn span(&self, b: usize) -> (usize, usize) {
        (b * self.size, ((b + 1) * self.size).min(self.frames))
    }

    /// The note that says so on the picture, if decimated.
    pub fn note(&self) -> Option<String> {
        self.decimated().then(|| {
            format!(
                "{} frames, drawn as {} buckets of {} frames: each line's minimum and maximum per bucket",
                self.frames,
                self.len(),
                self.size
            )
        })
    }
}

/// Minimum and maximum of a value over a bucket, with the frames they occur at, so
/// that a decimated line visits both in time order.
#[derive(Debug, Clone, Copy)]
struct MinMax {
    min: (usize, f64),
    max: (usize, f64),
}

impl MinMax {
    fn new() -> Self {
        MinMax {
            min: (0, f64::INFINITY),
            max: (0, f64::NEG_INFINITY),
        }
    }

    /// Takes frame `t`'s value (non-finite values are gaps, not extremes).
    fn push(&mut self, t: usize, v: f64) {
        if !v.is_finite() {
            return;
        }
        if v < self.min.1 {
            self.min = (t, v);
        }
        if v > self.max.1 {
            self.max = (t, v);
        }
    }

    fn is_empty(&self) -> bool {
        self.min.1 > self.max.1
    }

    /// The points to draw: none for an empty bucket (a gap), one when both extremes
    /// are the same frame, else both in time order.
    fn points(&self) -> Vec<(f64, f64)> {
        if self.is_empty() {
            vec![(f64::NAN, f64::NAN)]
        } else if self.min.0 == self.max.0 {
            vec![(self.min.0 as f64, self.min.1)]
        } else {
            let (a, b) = if self.min.0 < self.max.0 {
                (self.min, self.max)
            } else {
                (self.max, self.min)
            };
            vec![(a.0 as f64, a.1), (b.0 as f64, b.1)]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_never_read_minus_zero() {
        assert_eq!(tick_label(-0.0, 1.0), "0.0");
        assert_eq!(tick_label(-1e-17, 0.5), "0.00");
        assert_eq!(tick_label(-0.04, 1.0), "0.0");
        assert_eq!(tick_label(-0.2, 2.0), "-0.2");
        assert_eq!(tick_label(20.0, 60.0), "20");
        assert_eq!(tick_label(-5.0, 60.0), "-5");
        assert_eq!(tick_label(0.004, 0.02), "0.004");
    }

    #[test]
    fn buckets_cover_every_frame_once() {
        for n in [0, 1, 999, 1000, 1001, 2_000_000, 123_457] {
            let b = Buckets::new(n);
            assert!(b.len() <= MAX_BUCKETS, "{n}");
            assert_eq!(b.decimated(), n > MAX_BUCKETS);
            let mut next = 0;
            for k in 0..b.len() {
                let (s, e) = b.span(k);
                assert_eq!(s, next);
                assert!(e > s);
                assert!((s..e).all(|t| b.of(t) == k));
                next = e;
            }
            assert_eq!(next, n);
        }
    }

    #[test]
    fn a_bucket_draws_its_extremes_in_time_order() {
        let mut m = MinMax::new();
        for (t, v) in [(10, 1.0), (11, 5.0), (12, f64::NAN), (13, -2.0), (14, 0.0)] {
            m.push(t, v);
        }
        assert_eq!(m.points(), vec![(11.0, 5.0), (13.0, -2.0)]);
        let mut one = MinMax::new();
        one.push(3, 2.0);
        assert_eq!(one.points(), vec![(3.0, 2.0)]);
        assert!(MinMax::new().points()[0].0.is_nan());
    }
}
