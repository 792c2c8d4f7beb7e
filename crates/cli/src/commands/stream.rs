//! `phasekit stream`: frame-by-frame prediction from stdin to stdout.
//!
//! The input's columns are mapped to the model's human columns by name (a
//! header must name them all) or, without a header, by position; a line that
//! is not a frame follows `--on-bad-line`. Every frame gives exactly one
//! output line, ending with its status. Memory stays flat however long the
//! stream runs: lines are read into one buffer of bounded size, the latency
//! statistics live in a fixed-size histogram ([`LatencySketch`]), and the
//! predictor's caches are bounded.

use crate::cli::{BadLine, StreamArgs};
use crate::commands::recognise::{StreamTarget, Streamer};
use crate::data::{excerpt, name_list, parse_cell};
use crate::error::{CliError, Result};
use crate::output::{csv_header, is_broken_pipe};
use crate::pipeline::FrameStatus;
use std::io::{BufRead, Write};
use std::time::Instant;

/// Longest input line read (longer lines are bad lines, read past without being kept).
pub const MAX_LINE: usize = 1 << 20;

/// Bad lines reported one by one on stderr; later ones are counted.
const WARNED_LINES: usize = 10;

// ---------------------------------------------------------------------------
// Latency statistics in constant memory
// ---------------------------------------------------------------------------

/// Per-frame latencies (µs) in a fixed-size log-bucketed histogram: count,
/// mean, minimum and maximum are exact; a percentile is within 0.5 % of the
/// exact one (buckets are 1 % wide from 0.01 µs to 10⁹ µs). Memory: 20 KiB,
/// whatever the number of frames.
#[derive(Debug, Clone)]
pub struct LatencySketch {
    counts: Vec<u64>,
    n: u64,
    sum: f64,
    min: f64,
    max: f64,
}

/// Smallest latency with its own bucket (µs).
const SKETCH_LOW: f64 = 0.01;
/// Relative width of a bucket.
const SKETCH_GROWTH: f64 = 1.01;
/// Buckets: below `SKETCH_LOW`, then 1 % buckets up to 10⁹ µs, then above.
const SKETCH_BUCKETS: usize = 2548;

impl Default for LatencySketch {
    fn default() -> Self {
        LatencySketch {
            counts: vec![0; SKETCH_BUCKETS],
            n: 0,
            sum: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
        }
    }
}

/// Latency statistics of a stream, microseconds.
#[derive(Debug, Clone, PartialEq)]
pub struct Latency {
    /// Frames predicted.
    pub frames: u64,
    /// Mean.
    pub mean: f64,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Maximum.
    pub max: f64,
}

impl LatencySketch {
    fn bucket(v: f64) -> usize {
        if v.is_nan() || v < SKETCH_LOW {
            return 0;
        }
        let b = ((v / SKETCH_LOW).ln() / SKETCH_GROWTH.ln()).floor() as usize + 1;
        b.min(SKETCH_BUCKETS - 1)
    }

    /// The value a bucket stands for: the geometric middle of its range.
    fn value(b: usize) -> f64 {
        if b == 0 {
            return SKETCH_LOW;
        }
        SKETCH_LOW * SKETCH_GROWTH.powf(b as f64 - 0.5)
    }

    /// Records one latency (µs).
    pub fn record(&mut self, v: f64) {
        self.counts[Self::bucket(v)] += 1;
        self.n += 1;
        self.sum += v;
        self.min = self.min.min(v);
        self.max = self.max.max(v);
    }

    /// The `p`-quantile (nearest rank of `p (n − 1)`, as a sorted list would give),
    /// within half a bucket; `None` before any value.
    pub fn quantile(&self, p: f64) -> Option<f64> {
        if self.n == 0 {
            return None;
        }
        let rank = (p * (self.n - 1) as f64).round() as u64;
        let mut seen = 0;
        for (b, c) in self.counts.iter().enumerate() {
            seen += c;
            if seen > rank {
                return Some(Self::value(b).clamp(self.min, self.max));
            }
        }
        Some(self.max)
    }

    /// The summary, `None` before any value.
    pub fn summary(&self) -> Option<Latency> {
        Some(Latency {
            frames: self.n,
            mean: self.sum / self.n as f64,
            p50: self.quantile(0.5)?,
            p99: self.quantile(0.99)?,
            max: self.max,
        })
    }
}

// ---------------------------------------------------------------------------
// Reading lines in bounded memory
// ---------------------------------------------------------------------------

/// One input line.
enum Line {
    /// The line's bytes (without the newline) are in the buffer.
    Read,
    /// The line was longer than [`MAX_LINE`] bytes; it was read past.
    TooLong(usize),
}

/// Reads the next line into `buf` (cleared), keeping at most `max` bytes;
/// `None` at the end of the input.
fn next_line(
    input: &mut impl BufRead,
    buf: &mut Vec<u8>,
    max: usize,
) -> std::io::Result<Option<Line>> {
    buf.clear();
    let (mut total, mut any) = (0usize, false);
    loop {
        let chunk = match input.fill_buf() {
            Ok(c) => c,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        if chunk.is_empty() {
            break;
        }
        any = true;
        let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i, true),
            None => (chunk.len(), false),
        };
        if buf.len() < max {
            let keep = take.min(max - buf.len());
            buf.extend_from_slice(&chunk[..keep]);
        }
        total += take;
        input.consume(take + usize::from(done));
        if done {
            break;
        }
    }
    if !any {
        return Ok(None);
    }
    if buf.last() == Some(&b'\r') {
        buf.pop();
    }
    Ok(Some(if total > max {
        Line::TooLong(total)
    } else {
        Line::Read
    }))
}

// ---------------------------------------------------------------------------
// The input's columns
// ---------------------------------------------------------------------------

/// Where the human's values are in an input line.
#[derive(Debug, Clone, PartialEq)]
struct Layout {
    /// Cells per line.
    width: usize,
    /// For every cell, the position among the model's human columns it fills, if any.
    slot: Vec<Option<usize>>,
}

impl Layout {
    fn new(width: usize, indices: &[usize]) -> Self {
        let mut slot = vec![None; width];
        for (k, &i) in indices.iter().enumerate() {
            slot[i] = Some(k);
        }
        Layout { width, slot }
    }
}

/// `--columns` entries: all 1-based numbers, or names.
enum Mapping {
    Numbers(Vec<usize>),
    Names(Vec<String>),
}

fn mapping(columns: &[String], n_in: usize, names: &[String]) -> Result<Mapping> {
    let cols: Vec<&str> = columns.iter().map(|c| c.trim()).collect();
    if cols.len() != n_in {
        return Err(CliError::new(format!(
            "--columns names {} columns; the model's human has {} ({}), given in that order",
            cols.len(),
            n_in,
            names.join(", ")
        )));
    }
    if cols
        .iter()
        .all(|c| !c.is_empty() && c.bytes().all(|b| b.is_ascii_digit()))
    {
        let mut v = Vec::with_capacity(n_in);
        for c in &cols {
            match c.parse::<usize>() {
                Ok(n) if n >= 1 => v.push(n - 1),
                _ => {
                    return Err(CliError::new(format!(
                        "--columns: column numbers start at 1, not {c}"
                    )))
                }
            }
        }
        check_distinct(&v.iter().map(|i| (i + 1).to_string()).collect::<Vec<_>>())?;
        return Ok(Mapping::Numbers(v));
    }
    if let Some(c) = cols.iter().find(|c| c.is_empty()) {
        return Err(CliError::new(format!("--columns: an empty name ({c:?})")));
    }
    check_distinct(&cols.iter().map(|c| c.to_string()).collect::<Vec<_>>())?;
    Ok(Mapping::Names(cols.iter().map(|c| c.to_string()).collect()))
}

fn check_distinct(v: &[String]) -> Result<()> {
    for (i, a) in v.iter().enumerate() {
        if v[..i].contains(a) {
            return Err(CliError::new(format!("--columns names `{a}` twice")));
        }
    }
    Ok(())
}

/// Splits a line into trimmed cells (into `cells`, reused).
fn split<'a>(line: &'a str, cells: &mut Vec<&'a str>) {
    cells.clear();
    cells.extend(line.split(',').map(str::trim));
}

/// Whether every cell is a number or a missing value: a frame, not a header.
fn is_frame(cells: &[&str]) -> bool {
    cells.iter().all(|c| parse_cell(c).is_ok())
}

/// The layout a header line gives: the model's human columns by name (or the
/// `--columns` names), or an error that stops the stream.
fn header_layout(
    cells: &[&str],
    names: &[String],
    mapping: Option<&Mapping>,
    line_no: usize,
) -> Result<Layout> {
    let header: Vec<String> = cells.iter().map(|c| c.to_string()).collect();
    for (i, h) in header.iter().enumerate() {
        if !h.is_empty() && header[..i].contains(h) {
            return Err(CliError::new(format!(
                "stdin line {line_no}: the header names `{}` twice",
                name_list(std::slice::from_ref(h))
            )));
        }
    }
    let wanted: Vec<String> = match mapping {
        Some(Mapping::Numbers(v)) => {
            if let Some(&i) = v.iter().find(|&&i| i >= header.len()) {
                return Err(CliError::new(format!(
                    "stdin line {line_no}: --columns names column {}, but the header has {} columns",
                    i + 1,
                    header.len()
                )));
            }
            return Ok(Layout::new(header.len(), v));
        }
        Some(Mapping::Names(v)) => v.clone(),
        None => names.to_vec(),
    };
    let by = if mapping.is_some() {
        "--columns"
    } else {
        "the model"
    };
    let mut indices = Vec::with_capacity(wanted.len());
    let mut missing = Vec::new();
    for w in &wanted {
        match header.iter().position(|h| h == w) {
            Some(i) => indices.push(i),
            None => missing.push(w),
        }
    }
    if missing.is_empty() {
        return Ok(Layout::new(header.len(), &indices));
    }
    let case: Vec<String> = missing
        .iter()
        .filter_map(|m| {
            header
                .iter()
                .find(|h| h.eq_ignore_ascii_case(m))
                .map(|h| format!("`{}` is not `{m}`", name_list(std::slice::from_ref(h))))
        })
        .collect();
    let hint = if !case.is_empty() {
        format!(
            "; names must match exactly, case included ({}): rename the columns or map them with --columns",
            case.join(", ")
        )
    } else if mapping.is_none() {
        "; to read other columns as the model's, name them in the model's order with --columns"
            .into()
    } else {
        String::new()
    };
    let what = if mapping.is_some() {
        "the columns --columns names"
    } else {
        "the model's human columns"
    };
    Err(CliError::new(format!(
        "stdin line {line_no}: the header ({}) lacks {what} {}: {by} needs {}{hint}; nothing was predicted",
        name_list(&header),
        missing
            .iter()
            .map(|m| format!("`{m}`"))
            .collect::<Vec<_>>()
            .join(", "),
        wanted.join(", ")
    )))
}

// ---------------------------------------------------------------------------
// The stream
// ---------------------------------------------------------------------------

/// Counts of what the stream did, for the summary at exit.
#[derive(Debug, Default)]
struct Tally {
    frames: u64,
    ok: u64,
    unobserved: u64,
    ood: u64,
    rejected: u64,
    failed: u64,
    bad_missing: u64,
    bad_skipped: u64,
}

impl Tally {
    fn count(&mut self, s: FrameStatus) {
        match s {
            FrameStatus::Ok => self.ok += 1,
            FrameStatus::Unobserved => self.unobserved += 1,
            FrameStatus::OutOfDistribution => self.ood += 1,
            FrameStatus::Rejected => self.rejected += 1,
        }
    }

    fn describe(&self) -> String {
        let mut parts = vec![format!("{} ok", self.ok)];
        for (n, what) in [
            (self.unobserved, "unobserved"),
            (self.ood, "out of distribution"),
            (self.rejected, "rejected (no state explains them)"),
            (self.failed, "failed"),
        ] {
            if n > 0 {
                parts.push(format!("{n} {what}"));
            }
        }
        let mut s = format!(
            "{} frame{} ({})",
            self.frames,
            if self.frames == 1 { "" } else { "s" },
            parts.join(", ")
        );
        if self.bad_missing > 0 {
            s += &format!(
                "; {} bad line{} taken as frames with nothing observed",
                self.bad_missing,
                if self.bad_missing == 1 { "" } else { "s" }
            );
        }
        if self.bad_skipped > 0 {
            s += &format!(
                "; {} bad line{} skipped",
                self.bad_skipped,
                if self.bad_skipped == 1 { "" } else { "s" }
            );
        }
        s
    }
}

/// What a line is.
enum Parsed {
    /// A comment, `#reset` or the header: no frame.
    NoFrame,
    /// A frame; its human values are in the raw buffer.
    Frame,
    /// Not a frame: why.
    Bad(String),
}

struct Stream<'m> {
    a: &'m StreamArgs,
    sp: Streamer<'m>,
    names: Vec<String>,
    mapping: Option<Mapping>,
    layout: Option<Layout>,
    raw: Vec<f64>,
    frame: usize,
    tally: Tally,
    warned: usize,
    header_written: bool,
    line_out: String,
    latency: LatencySketch,
}

impl<'m> Stream<'m> {
    /// Classifies one line and fills `raw` for a frame.
    fn parse(&mut self, bytes: &[u8], line_no: usize) -> Result<Parsed> {
        let Ok(text) = std::str::from_utf8(bytes) else {
            return Ok(Parsed::Bad("not valid UTF-8 text".into()));
        };
        let text = if line_no == 1 {
            text.trim_start_matches('\u{feff}')
        } else {
            text
        };
        let line = text.trim();
        if let Some(rest) = line.strip_prefix('#') {
            // `#reset` starts a new demonstration; other `#` lines are comments.
            if rest.trim().eq_ignore_ascii_case("reset") {
                self.sp.reset();
                self.frame = 0;
            }
            return Ok(Parsed::NoFrame);
        }
        if line.is_empty() {
            return Ok(Parsed::Bad("a blank line".into()));
        }
        let mut cells = Vec::new();
        split(line, &mut cells);
        if self.layout.is_none() {
            if cells.len() == 1 && (line.contains(';') || line.contains('\t')) {
                let sep = if line.contains(';') {
                    "semicolons"
                } else {
                    "tabs"
                };
                return Err(CliError::new(format!(
                    "stdin line {line_no}: the values are separated by {sep}; stream reads comma-separated lines"
                )));
            }
            if !is_frame(&cells) {
                let named = match &self.mapping {
                    Some(Mapping::Names(v)) => v.iter().any(|n| n == cells[0]),
                    _ => self.names.iter().any(|n| n == cells[0]),
                };
                if cells.len() == 1 && !named {
                    // One word or sentence before any frame: a banner, not a header.
                    return Ok(Parsed::Bad(format!(
                        "{} is neither a header nor a frame",
                        excerpt(line)
                    )));
                }
                self.layout = Some(header_layout(
                    &cells,
                    &self.names,
                    self.mapping.as_ref(),
                    line_no,
                )?);
                return Ok(Parsed::NoFrame);
            }
            self.layout = Some(match &self.mapping {
                None => Layout::new(self.names.len(), &(0..self.names.len()).collect::<Vec<_>>()),
                Some(Mapping::Numbers(v)) => {
                    if let Some(&i) = v.iter().find(|&&i| i >= cells.len()) {
                        return Err(CliError::new(format!(
                            "stdin line {line_no}: --columns names column {}, but the line has {} values",
                            i + 1,
                            cells.len()
                        )));
                    }
                    Layout::new(cells.len(), v)
                }
                Some(Mapping::Names(_)) => {
                    return Err(CliError::new(format!(
                        "stdin line {line_no}: --columns names columns, but the input has no header (this line is a frame); give column numbers instead"
                    )))
                }
            });
        }
        let layout = self.layout.as_ref().expect("set above");
        if cells.len() != layout.width {
            let what = if layout.width == self.names.len() && self.mapping.is_none() {
                format!(" (the model's human columns {})", self.names.join(", "))
            } else {
                " (as many as the header)".into()
            };
            let hint = if is_frame(&cells) {
                String::new()
            } else {
                " and text where numbers belong".into()
            };
            return Ok(Parsed::Bad(format!(
                "{} values{hint}, expected {}{what}",
                cells.len(),
                layout.width
            )));
        }
        for (i, cell) in cells.iter().enumerate() {
            if let Some(k) = layout.slot[i] {
                match parse_cell(cell) {
                    Ok(v) => self.raw[k] = v,
                    Err(why) => {
                        return Ok(Parsed::Bad(format!(
                            "column {} (`{}`): {why}: {}",
                            i + 1,
                            self.names[k],
                            excerpt(cell)
                        )))
                    }
                }
            }
        }
        Ok(Parsed::Frame)
    }

    fn warn_bad(&mut self, line_no: usize, why: &str, action: &str) {
        self.warned += 1;
        if self.warned <= WARNED_LINES {
            eprintln!("phasekit: warning: stdin line {line_no}: {why}; {action}");
            if self.warned == WARNED_LINES {
                eprintln!("phasekit: warning: further bad lines are counted, not shown (the total is reported at exit)");
            }
        }
    }

    fn write_header(&mut self, out: &mut impl Write) -> std::io::Result<()> {
        if !self.header_written && !self.a.no_header {
            let mut h = self.sp.header(self.a.covariance);
            h.push("status".into());
            writeln!(out, "{}", csv_header(&h))?;
        }
        self.header_written = true;
        Ok(())
    }

    /// Predicts the frame in `raw` and writes its line.
    fn predict(&mut self, out: &mut impl Write, line_no: usize) -> Result<std::io::Result<()>> {
        let cov = self.a.covariance;
        match self
            .sp
            .step_line(&self.raw, self.frame, cov, &mut self.line_out)
        {
            Ok(status) => {
                self.tally.count(status);
                self.line_out.push(',');
                self.line_out.push_str(status.word());
            }
            Err(e) => {
                if self.a.on_bad_line == BadLine::Error {
                    return Err(CliError::new(format!(
                        "stdin line {line_no}: prediction failed: {e}"
                    )));
                }
                self.warn_bad(
                    line_no,
                    &format!("prediction failed: {e}"),
                    "written with empty values and status `failed`",
                );
                self.tally.failed += 1;
                let cells = self.sp.header(cov).len() - 1;
                self.line_out.clear();
                self.line_out.push_str(&self.frame.to_string());
                self.line_out.push_str(&",".repeat(cells));
                self.line_out.push_str(",failed");
            }
        }
        self.frame += 1;
        self.tally.frames += 1;
        Ok(self
            .write_header(out)
            .and_then(|_| writeln!(out, "{}", self.line_out))
            .and_then(|_| out.flush()))
    }
}

/// Runs `phasekit stream`.
pub fn run(a: &StreamArgs) -> Result<()> {
    let target = StreamTarget::load(&a.model)?;
    let sp = target.predictor(a.recogniser, a.covariance)?;
    let names = target.human_columns().to_vec();
    let n_in = sp.n_in();
    let mapping = a
        .columns
        .as_ref()
        .map(|c| mapping(c, n_in, &names))
        .transpose()?;
    if target.lacks_novelty() && !a.quiet {
        eprintln!(
            "phasekit: note: {} has no out-of-distribution threshold (written by an older phasekit): no frame is flagged `ood`; refit the model to have them flagged",
            a.model.display()
        );
    }
    let mut s = Stream {
        a,
        sp,
        names,
        mapping,
        layout: None,
        raw: vec![0.0; n_in],
        frame: 0,
        tally: Tally::default(),
        warned: 0,
        header_written: false,
        line_out: String::new(),
        latency: LatencySketch::default(),
    };
    let stdin = std::io::stdin();
    let mut input = stdin.lock();
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let write_err = |e: std::io::Error| CliError::new(format!("cannot write to stdout: {e}"));
    let mut bytes = Vec::new();
    let mut line_no = 0usize;
    loop {
        let line = match next_line(&mut input, &mut bytes, MAX_LINE) {
            Ok(None) => break,
            Ok(Some(l)) => l,
            Err(e) => return Err(CliError::new(format!("cannot read stdin: {e}"))),
        };
        line_no += 1;
        if bytes.capacity() > 4 * 65536 && bytes.len() < 65536 {
            bytes.shrink_to(65536); // a long line once does not hold its memory for ever
        }
        let start = Instant::now();
        let parsed = match line {
            Line::TooLong(n) => Parsed::Bad(format!("a line of {n} bytes, longer than {MAX_LINE}")),
            Line::Read => s.parse(&bytes, line_no)?,
        };
        match parsed {
            Parsed::NoFrame => continue,
            Parsed::Frame => {}
            Parsed::Bad(why) => match a.on_bad_line {
                BadLine::Error => {
                    let _ = out.flush();
                    return Err(CliError::new(format!(
                        "stdin line {line_no}: {why}; use --on-bad-line missing or skip to go on past such lines"
                    )));
                }
                BadLine::Skip => {
                    s.warn_bad(line_no, &why, "skipped");
                    s.tally.bad_skipped += 1;
                    continue;
                }
                BadLine::Missing => {
                    if s.layout.is_none() {
                        // Before the header or the first frame a line cannot be a frame.
                        s.warn_bad(line_no, &why, "skipped (before the first frame)");
                        s.tally.bad_skipped += 1;
                        continue;
                    }
                    s.warn_bad(line_no, &why, "taken as a frame with nothing observed");
                    s.tally.bad_missing += 1;
                    s.raw.fill(f64::NAN);
                }
            },
        }
        match s.predict(&mut out, line_no)? {
            Ok(()) => {}
            Err(e) if is_broken_pipe(&e) => break,
            Err(e) => return Err(write_err(e)),
        }
        s.latency.record(start.elapsed().as_secs_f64() * 1e6);
    }
    if let Err(e) = s.write_header(&mut out).and_then(|_| out.flush()) {
        if !is_broken_pipe(&e) {
            return Err(write_err(e));
        }
    }
    if !a.quiet {
        match s.latency.summary() {
            Some(l) => eprintln!(
                "phasekit: {}; latency per frame: mean {:.1} µs, p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs",
                s.tally.describe(),
                l.mean,
                l.p50,
                l.p99,
                l.max
            ),
            None => eprintln!("phasekit: no frame received ({})", s.tally.describe()),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn latency_percentiles() {
        let mut s = LatencySketch::default();
        assert_eq!(s.summary(), None);
        for v in (1..=100).rev() {
            s.record(f64::from(v));
        }
        let l = s.summary().unwrap();
        assert_eq!((l.frames, l.mean, l.max), (100, 50.5, 100.0));
        assert!((l.p50 - 51.0).abs() <= 0.005 * 51.0, "{}", l.p50);
        assert!((l.p99 - 99.0).abs() <= 0.005 * 99.0, "{}", l.p99);
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, failure_persistence: None, ..ProptestConfig::default() })]

        /// Every percentile is within half a bucket (0.5 %) of the sorted list's.
        #[test]
        fn sketch_quantiles_are_within_half_a_bucket(
            v in proptest::collection::vec(0.02f64..1e6, 1..2000),
            p in 0.0f64..=1.0,
        ) {
            let mut s = LatencySketch::default();
            v.iter().for_each(|x| s.record(*x));
            let mut sorted = v.clone();
            sorted.sort_by(f64::total_cmp);
            let exact = sorted[(p * (sorted.len() - 1) as f64).round() as usize];
            let got = s.quantile(p).unwrap();
            prop_assert!((got - exact).abs() <= 0.00501 * exact, "{} vs {}", got, exact);
        }
    }

    #[test]
    fn sketch_memory_does_not_grow() {
        let mut s = LatencySketch::default();
        let cap = s.counts.capacity();
        for i in 0..1_000_000u32 {
            s.record(f64::from(i % 5000) * 0.37 + 0.001);
        }
        assert_eq!(s.counts.capacity(), cap);
        assert_eq!(s.summary().unwrap().frames, 1_000_000);
        // Out of range values are counted in the end buckets.
        s.record(1e12);
        s.record(0.0);
        assert_eq!(s.summary().unwrap().max, 1e12);
    }

    #[test]
    fn lines_are_read_in_bounded_memory() {
        let text = format!("a,b\n{}\nc\r\n\nlast", "x".repeat(100));
        let mut r = std::io::BufReader::with_capacity(7, text.as_bytes());
        let mut buf = Vec::new();
        let mut got = Vec::new();
        while let Some(l) = next_line(&mut r, &mut buf, 10).unwrap() {
            got.push(match l {
                Line::Read => String::from_utf8(buf.clone()).unwrap(),
                Line::TooLong(n) => format!("too long {n}"),
            });
            assert!(buf.len() <= 10);
        }
        assert_eq!(got, ["a,b", "too long 100", "c", "", "last"]);
    }
}
