//! The commands, one module each, and what they share.

pub mod demo;
pub mod evaluate;
pub mod fit;
pub mod plot;
pub mod predict;
pub mod recognise;
pub mod segment;
pub mod stream;

use crate::bail;
use crate::cli::{ColumnArgs, Count, ModelArgs};
use crate::data::{DataError, FeatureSpec, Table, Velocity};
use crate::error::{CliError, Result};
use phasekit_tsc::{Method, PresetOptions};

/// Default human columns (NuiSI, PROTOCOL.md).
pub const DEFAULT_HUMAN: &str = "p1_wrist_*";
/// Default robot columns.
pub const DEFAULT_ROBOT: &str = "p2_wrist_*";

/// The column selection of the command line; `true` when a default was used.
pub fn feature_spec(c: &ColumnArgs) -> (FeatureSpec, bool) {
    let defaults = c.human.is_none() || c.robot.is_none();
    let clean = |v: &Option<Vec<String>>, d: &str| -> Vec<String> {
        v.as_ref()
            .map(|v| {
                v.iter()
                    .map(|s| s.trim().to_string())
                    .filter(|s| !s.is_empty())
                    .collect()
            })
            .unwrap_or_else(|| vec![d.to_string()])
    };
    (
        FeatureSpec {
            human: clean(&c.human, DEFAULT_HUMAN),
            robot: clean(&c.robot, DEFAULT_ROBOT),
            velocity: c.velocity.map_or(Velocity::Both, Into::into),
        },
        defaults,
    )
}

/// Adds a hint to column errors when the default columns were used.
pub fn column_hint(e: DataError, defaults: bool) -> CliError {
    let unknown = matches!(&e, DataError::UnknownColumn { pattern, .. } if pattern == DEFAULT_HUMAN || pattern == DEFAULT_ROBOT);
    let e = CliError::from(e);
    if unknown && defaults {
        CliError::new(format!(
            "{e}\n  (the default columns are --human '{DEFAULT_HUMAN}' --robot '{DEFAULT_ROBOT}' for NuiSI data; choose yours with --human and --robot)"
        ))
    } else {
        e
    }
}

/// The preset options of the command line (each `NAME:key=value` setting can still
/// override them; `Method::preset` checks the result).
pub fn preset_options(m: &ModelArgs) -> Result<PresetOptions> {
    if !(m.tol.is_finite() && m.tol >= 0.0) {
        bail!("--tol must be a finite number ≥ 0, not {}", m.tol);
    }
    if !(m.reg.is_finite() && m.reg >= 0.0) {
        bail!("--reg must be a finite number ≥ 0, not {}", m.reg);
    }
    if m.states == Count::Fixed(0) {
        bail!("--states must be at least 1 (or auto)");
    }
    if m.max_iter == 0 {
        bail!("--max-iter must be at least 1");
    }
    if m.restarts == 0 {
        bail!("--restarts must be at least 1");
    }
    if m.max_states < phasekit_tsc::preset::AUTO_MIN_STATES {
        bail!(
            "--max-states must be at least {}",
            phasekit_tsc::preset::AUTO_MIN_STATES
        );
    }
    if !(0.0..=1.0).contains(&m.rho) {
        bail!("--rho must lie in [0, 1], not {}", m.rho);
    }
    let options = PresetOptions::builder();
    let options = match m.states {
        Count::Fixed(n) => options.states(n),
        Count::Auto => options.auto_states(),
    };
    Ok(options
        .select(m.select.into())
        .max_states(m.max_states)
        .tsc_states(match m.tsc_states {
            Count::Fixed(n) => n,
            Count::Auto => 0,
        })
        .window(m.window)
        .rho(m.rho)
        .time_clusters(m.time_clusters)
        .reg(m.reg)
        .max_iter(m.max_iter)
        .tol(m.tol)
        .restarts(m.restarts)
        .seed(m.seed)
        .emission(m.emission)
        .build()?)
}

/// Builds rayon's global pool with `n` threads.
pub fn setup_threads(n: Option<usize>) -> Result<()> {
    if let Some(n) = n {
        if n == 0 {
            bail!("--threads must be at least 1");
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .map_err(|e| CliError::new(format!("cannot start {n} threads: {e}")))?;
    }
    Ok(())
}

/// Splits `A,B:k=v,k=v,C` into methods: a `key=value` item continues the method before it.
pub fn split_methods(items: &[String]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for item in items.iter().flat_map(|s| s.split(',')) {
        let item = item.trim();
        if item.is_empty() {
            continue;
        }
        match out.last_mut() {
            Some(prev) if item.contains('=') && !item.contains(':') => {
                prev.push(if prev.contains(':') { ',' } else { ':' });
                prev.push_str(item);
            }
            _ => out.push(item.to_string()),
        }
    }
    out
}

/// Smallest number of frames a demonstration needs for `method`, and whether per
/// demonstration (HMM states) or in all (mixture components).
pub fn min_frames(method: &Method) -> (usize, bool) {
    method.min_frames()
}

/// The window of `method` and whether it must be shorter than every demonstration
/// (a TSC-HMM's dilation ±W) or at most as long (gmm-tsc's stacked frames).
fn window_of(method: &Method) -> Vec<(usize, bool)> {
    match method {
        Method::TscHmm(s) => vec![(s.window(), true)],
        Method::GmmTsc { tsc, .. } => vec![(tsc.window(), false)],
        Method::CrossValidated(cv) => cv
            .candidates()
            .iter()
            .flat_map(|(_, m)| window_of(m))
            .collect(),
        Method::Hmm(_) | Method::Hsmm(_) | Method::Gmm(_) => Vec::new(),
    }
}

/// Checks that demonstrations are long enough for `method`: its states, and its
/// window (a TSC-HMM's dilation ±W must be shorter than every demonstration; gmm-tsc
/// cannot stack more frames than a demonstration has).
pub fn check_lengths(tables: &[Table], method: &Method, label: &str) -> Result<()> {
    let (need, per_sequence) = min_frames(method);
    if per_sequence {
        for t in tables {
            if t.n_rows() < need {
                bail!(
                    "{}: {} frame{}, fewer than the {need} states of `{label}`: every demonstration needs at least one frame per state",
                    t.path.display(),
                    t.n_rows(),
                    if t.n_rows() == 1 { "" } else { "s" }
                );
            }
        }
    } else {
        let total: usize = tables.iter().map(Table::n_rows).sum();
        if total < need {
            bail!("{total} frames in all, fewer than the {need} components of `{label}`");
        }
    }
    if let Some(shortest) = tables.iter().min_by_key(|t| t.n_rows()) {
        let n = shortest.n_rows();
        for (w, dilation) in window_of(method) {
            if dilation && w >= n {
                bail!(
                    "{}: {n} frames: `{label}` dilates every transition frame by ±{w} frames (--window {w}), which would flag the whole demonstration; use a window below {n}",
                    shortest.path.display()
                );
            }
            if !dilation && w > n {
                bail!(
                    "{}: {n} frames: `{label}` stacks {w} frames into one vector (--window {w}), more than this demonstration has; use a window of at most {n}",
                    shortest.path.display()
                );
            }
        }
    }
    Ok(())
}

// Resolving and reading `--data` lives in `crate::inputs`.
pub use crate::inputs::{action_dirs, data_files, fit_files, has_train_files, read_tables};

#[cfg(test)]
mod tests {
    use super::split_methods;

    #[test]
    fn method_lists_keep_key_value_settings_together() {
        let s = |v: &[&str]| split_methods(&v.iter().map(|x| x.to_string()).collect::<Vec<_>>());
        assert_eq!(s(&["hmm,tsc-hmm"]), ["hmm", "tsc-hmm"]);
        assert_eq!(
            s(&["hmm:states=7,reg=0.1,tsc-hmm:window=2"]),
            ["hmm:states=7,reg=0.1", "tsc-hmm:window=2"]
        );
        assert_eq!(s(&["hmm", "gmm:states=3", " ,"]), ["hmm", "gmm:states=3"]);
        assert_eq!(s(&["hmm,states=5"]), ["hmm:states=5"]);
    }
}
