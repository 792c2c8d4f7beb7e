//! `phasekit stream`: frame-by-frame prediction from stdin to stdout.

use crate::bail;
use crate::cli::StreamArgs;
use crate::error::{CliError, Result};
use crate::model_file::ModelFile;
use crate::output::is_broken_pipe;
use crate::pipeline::{prediction_header, prediction_line, StreamPredictor};
use std::io::{BufRead, Write};
use std::time::Instant;

/// Where the human's values are in an input line.
enum Columns {
    /// The line is exactly the human's values, in the model's order.
    Positional,
    /// Indices of the human's columns in lines of `width` cells.
    Named { indices: Vec<usize>, width: usize },
}

/// Latency statistics of a stream, microseconds.
#[derive(Debug, Clone, PartialEq)]
pub struct Latency {
    /// Frames predicted.
    pub frames: usize,
    /// Mean.
    pub mean: f64,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Maximum.
    pub max: f64,
}

/// Summarises per-frame latencies (µs).
pub fn latency(mut v: Vec<f64>) -> Option<Latency> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let q = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
    Some(Latency {
        frames: v.len(),
        mean: v.iter().sum::<f64>() / v.len() as f64,
        p50: q(0.5),
        p99: q(0.99),
        max: v[v.len() - 1],
    })
}

fn parse_cells(line: &str) -> Vec<&str> {
    line.split(',').map(str::trim).collect()
}

fn looks_like_header(cells: &[&str]) -> bool {
    cells
        .iter()
        .any(|c| !c.is_empty() && c.parse::<f64>().is_err())
}

fn skipped_note(n: usize) -> String {
    match n {
        0 => String::new(),
        1 => " (1 line skipped)".into(),
        n => format!(" ({n} lines skipped)"),
    }
}

fn warn(line_no: usize, msg: &str) {
    eprintln!("phasekit: warning: stdin line {line_no}: {msg}; line skipped");
}

/// Runs `phasekit stream`.
pub fn run(a: &StreamArgs) -> Result<()> {
    let mf = ModelFile::load(&a.model)?;
    let mut sp = StreamPredictor::new(&mf)?;
    let names = &mf.layout.human_columns;
    let n_in = sp.n_in();
    let stdin = std::io::stdin();
    let mut input = stdin.lock();
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let write_err = |e: std::io::Error| CliError::new(format!("cannot write to stdout: {e}"));
    if !a.no_header {
        let header = prediction_header(&mf, a.covariance).join(",");
        if let Err(e) = writeln!(out, "{header}").and_then(|_| out.flush()) {
            if is_broken_pipe(&e) {
                return Ok(());
            }
            return Err(write_err(e));
        }
    }
    let mut columns: Option<Columns> = None;
    let mut bytes = Vec::new();
    let mut raw = vec![0.0; n_in];
    let mut line_out = String::new();
    let (mut line_no, mut frame, mut skipped) = (0usize, 0usize, 0usize);
    let mut latencies: Vec<f64> = Vec::new();
    loop {
        bytes.clear();
        match input.read_until(b'\n', &mut bytes) {
            Ok(0) => break,
            Ok(_) => {}
            Err(e) => bail!("cannot read stdin: {e}"),
        }
        line_no += 1;
        let start = Instant::now();
        let line = match std::str::from_utf8(&bytes) {
            Ok(s) => s.trim(),
            Err(_) => {
                warn(line_no, "not valid UTF-8 text");
                skipped += 1;
                continue;
            }
        };
        if line.is_empty() {
            // A new demonstration.
            sp.reset();
            frame = 0;
            continue;
        }
        let cells = parse_cells(line);
        if columns.is_none() {
            if looks_like_header(&cells) {
                let idx: Option<Vec<usize>> = names
                    .iter()
                    .map(|n| cells.iter().position(|c| c == n))
                    .collect();
                columns = Some(match idx {
                    Some(indices) => Columns::Named { indices, width: cells.len() },
                    None if cells.len() == n_in => {
                        eprintln!(
                            "phasekit: warning: stdin header `{line}` does not name the model's human columns ({}); reading its columns in that order",
                            names.join(", ")
                        );
                        Columns::Positional
                    }
                    None => bail!(
                        "stdin line {line_no}: the header `{line}` lacks the model's human columns ({}); send them in that order, with or without a header",
                        names.join(", ")
                    ),
                });
                continue;
            }
            columns = Some(Columns::Positional);
        }
        let (indices, width): (Vec<usize>, usize) = match columns.as_ref() {
            Some(Columns::Named { indices, width }) => (indices.clone(), *width),
            _ => ((0..n_in).collect(), n_in),
        };
        if cells.len() != width {
            warn(
                line_no,
                &format!("{} values, expected {width}", cells.len()),
            );
            skipped += 1;
            continue;
        }
        let mut bad = None;
        for (k, (&i, r)) in indices.iter().zip(raw.iter_mut()).enumerate() {
            match cells[i].parse::<f64>() {
                Ok(v) if v.is_finite() => *r = v,
                Ok(_) => {
                    bad = Some(format!(
                        "column {} (`{}`) is not a finite number: {:?}",
                        i + 1,
                        names[k],
                        cells[i]
                    ));
                    break;
                }
                Err(_) => {
                    bad = Some(format!(
                        "column {} (`{}`) is not a number: {:?}",
                        i + 1,
                        names[k],
                        cells[i]
                    ));
                    break;
                }
            }
        }
        if let Some(msg) = bad {
            warn(line_no, &msg);
            skipped += 1;
            continue;
        }
        let (mean, cov) = match sp.step(&raw, a.covariance) {
            Ok(x) => x,
            Err(e) => {
                warn(line_no, &format!("prediction failed: {e}"));
                skipped += 1;
                continue;
            }
        };
        prediction_line(frame, mean, cov, &mut line_out);
        frame += 1;
        if let Err(e) = writeln!(out, "{line_out}").and_then(|_| out.flush()) {
            if is_broken_pipe(&e) {
                break;
            }
            return Err(write_err(e));
        }
        latencies.push(start.elapsed().as_secs_f64() * 1e6);
    }
    if !a.quiet {
        match latency(latencies) {
            Some(l) => eprintln!(
                "phasekit: {} frames{}; latency per frame: mean {:.1} µs, p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs",
                l.frames,
                skipped_note(skipped),
                l.mean,
                l.p50,
                l.p99,
                l.max
            ),
            None => eprintln!("phasekit: no frame received{}", skipped_note(skipped)),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::latency;

    #[test]
    fn latency_percentiles() {
        assert_eq!(latency(Vec::new()), None);
        let l = latency((1..=100).rev().map(f64::from).collect()).unwrap();
        assert_eq!(
            (l.frames, l.mean, l.p50, l.p99, l.max),
            (100, 50.5, 51.0, 99.0, 100.0)
        );
    }
}
