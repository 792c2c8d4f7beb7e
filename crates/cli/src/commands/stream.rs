//! `phasekit stream`: frame-by-frame prediction from stdin to stdout.

use crate::bail;
use crate::cli::StreamArgs;
use crate::data::parse_cell;
use crate::error::{CliError, Result};
use crate::output::is_broken_pipe;
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
    cells.iter().any(|c| parse_cell(c).is_err())
}

fn unobserved_note(n: usize) -> String {
    match n {
        0 => String::new(),
        1 => " (1 malformed or empty line taken as a frame with nothing observed)".into(),
        n => format!(" ({n} malformed or empty lines taken as frames with nothing observed)"),
    }
}

fn warn(line_no: usize, msg: &str) {
    eprintln!(
        "phasekit: warning: stdin line {line_no}: {msg}; taken as a frame with nothing observed"
    );
}

/// Runs `phasekit stream`.
pub fn run(a: &StreamArgs) -> Result<()> {
    let target = crate::commands::recognise::StreamTarget::load(&a.model)?;
    let mut sp = target.predictor(a.recogniser, a.covariance)?;
    let names = target.human_columns();
    let n_in = sp.n_in();
    let stdin = std::io::stdin();
    let mut input = stdin.lock();
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let write_err = |e: std::io::Error| CliError::new(format!("cannot write to stdout: {e}"));
    if !a.no_header {
        let header = sp.header(a.covariance).join(",");
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
    let (mut line_no, mut frame, mut malformed) = (0usize, 0usize, 0usize);
    let positional: Vec<usize> = (0..n_in).collect();
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
        // A line that cannot be read is a frame with nothing observed: the
        // filter still takes its transition step, so the robot's prediction
        // keeps moving with the interaction and the frame count stays true.
        let unobserved = |msg: &str, raw: &mut [f64]| {
            warn(line_no, msg);
            raw.fill(f64::NAN);
        };
        match std::str::from_utf8(&bytes).map(str::trim) {
            Err(_) => {
                unobserved("not valid UTF-8 text", &mut raw);
                malformed += 1;
            }
            Ok(line) if line.starts_with('#') => {
                // `#reset` starts a new demonstration; other `#` lines are comments.
                if line[1..].trim().eq_ignore_ascii_case("reset") {
                    sp.reset();
                    frame = 0;
                }
                continue;
            }
            Ok("") => {
                unobserved("empty line", &mut raw);
                malformed += 1;
            }
            Ok(line) => {
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
                let (indices, width): (&[usize], usize) = match columns.as_ref() {
                    Some(Columns::Named { indices, width }) => (indices, *width),
                    _ => (&positional, n_in),
                };
                if cells.len() != width {
                    unobserved(
                        &format!("{} values, expected {width}", cells.len()),
                        &mut raw,
                    );
                    malformed += 1;
                } else {
                    // Empty, `NaN` or `NA` cells are missing values (not warned about).
                    let bad =
                        indices
                            .iter()
                            .zip(raw.iter_mut())
                            .enumerate()
                            .find_map(|(k, (&i, r))| match parse_cell(cells[i]) {
                                Ok(v) => {
                                    *r = v;
                                    None
                                }
                                Err(why) => Some(format!(
                                    "column {} (`{}`): {why}: {:?}",
                                    i + 1,
                                    names[k],
                                    cells[i]
                                )),
                            });
                    if let Some(msg) = bad {
                        unobserved(&msg, &mut raw);
                        malformed += 1;
                    }
                }
            }
        }
        if let Err(e) = sp.step_line(&raw, frame, a.covariance, &mut line_out) {
            eprintln!("phasekit: warning: stdin line {line_no}: prediction failed: {e}; no output for this line");
            continue;
        }
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
                unobserved_note(malformed),
                l.mean,
                l.p50,
                l.p99,
                l.max
            ),
            None => eprintln!("phasekit: no frame received{}", unobserved_note(malformed)),
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
