//! The header every phasekit JSON file begins with (`"format"`, `"version"`),
//! checked the same way for model files and libraries of interactions before
//! their body is parsed, so that a wrong, truncated or newer file is named as
//! such instead of failing on some field deep inside.

use crate::error::{CliError, Result};
use serde::Deserialize;
use std::path::Path;

#[derive(Deserialize)]
struct Header {
    format: Option<serde_json::Value>,
    version: Option<serde_json::Value>,
}

/// What kind of file a reader expects.
pub struct FileKind {
    /// The `"format"` string it writes and reads.
    pub format: &'static str,
    /// The oldest `"version"` this build reads.
    pub oldest: u64,
    /// The newest `"version"` this build reads (the one it writes).
    pub version: u64,
    /// Its name in messages (`model file`, `library file`).
    pub noun: &'static str,
    /// What to do with a file of another version (`refit the model`).
    pub remedy: &'static str,
}

/// `Some(format)` of a JSON text that has a string `format` field.
pub fn file_format(text: &str) -> Option<String> {
    let h: Header = serde_json::from_str(text).ok()?;
    h.format.and_then(|f| f.as_str().map(str::to_string))
}

/// For a format of another phasekit file: the format, and the error that
/// tells the user what to do instead.
pub type OtherFormat<'a> = (&'a str, &'a dyn Fn(&Path) -> CliError);

/// Checks that `text` (the content of `path`) is JSON with `kind`'s format
/// and version. `others` says, for a format of another phasekit file, what
/// the user should do instead (e.g. a library given where a model is needed).
pub fn check_header(
    text: &str,
    path: &Path,
    kind: &FileKind,
    others: &[OtherFormat<'_>],
) -> Result<()> {
    let p = path.display();
    let noun = kind.noun;
    let header: Header = serde_json::from_str(text).map_err(|e| {
        // A file cut in the middle of a number or a word fails on its last
        // character rather than at "end of input": call that truncated too.
        let end_line = 1 + text.matches('\n').count();
        let end_col = text.len() - text.rfind('\n').map_or(0, |i| i + 1);
        let at_end = e.line() == end_line && e.column() + 1 >= end_col;
        let what = if e.is_eof() || (e.is_syntax() && at_end) {
            "it is truncated or empty"
        } else {
            "it is not valid JSON"
        };
        CliError::new(format!("{p}: not a phasekit {noun} ({what}: {e})"))
    })?;
    match header.format.as_ref().and_then(|f| f.as_str()) {
        Some(f) if f == kind.format => {}
        Some(f) => {
            if let Some((_, error)) = others.iter().find(|(o, _)| *o == f) {
                return Err(error(path));
            }
            return Err(CliError::new(format!(
                "{p}: not a phasekit {noun} (its format is `{f}`, not `{}`)",
                kind.format
            )));
        }
        None => {
            return Err(CliError::new(format!(
                "{p}: not a phasekit {noun} (no \"format\": \"{}\" field)",
                kind.format
            )))
        }
    }
    match header.version.as_ref().and_then(|v| v.as_u64()) {
        Some(v) if (kind.oldest..=kind.version).contains(&v) => Ok(()),
        Some(v) => {
            let reads = if kind.oldest == kind.version {
                format!("version {}", kind.version)
            } else {
                format!("versions {} to {}", kind.oldest, kind.version)
            };
            Err(CliError::new(format!(
                "{p}: {noun} version {v} is not supported; this phasekit ({}) reads {reads} — {} with this version",
                env!("CARGO_PKG_VERSION"),
                kind.remedy
            )))
        }
        None => Err(CliError::new(format!(
            "{p}: {noun} has no valid \"version\" number"
        ))),
    }
}
