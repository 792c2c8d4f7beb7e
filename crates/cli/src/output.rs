//! Writing results: atomic files, stdout that tolerates a closed pipe, and
//! progress shown on a terminal only.

use crate::error::{CliError, Result};
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};

/// Writes `path` atomically: the content goes to a temporary file in the same
/// folder, which is renamed over `path` only once complete. On any error no
/// file is left behind (and an existing `path` is untouched).
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    let tmp = prepare(path, write)?;
    tmp.persist(path)
        .map_err(|e| CliError::new(format!("{}: cannot write: {}", path.display(), e.error)))?;
    Ok(())
}

/// Writes the complete content of `path` to a synced temporary file beside it
/// (deleted when dropped), ready to be renamed over `path`.
fn prepare(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<tempfile::NamedTempFile> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if path.is_dir() {
        return Err(CliError::new(format!(
            "{}: is a folder, not a file",
            path.display()
        )));
    }
    if !dir.is_dir() {
        return Err(CliError::new(format!(
            "{}: cannot write: folder {} does not exist",
            path.display(),
            dir.display()
        )));
    }
    let err =
        |e: &dyn std::fmt::Display| CliError::new(format!("{}: cannot write: {e}", path.display()));
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("output");
    let mut tmp = tempfile::Builder::new()
        .prefix(&format!(".{name}."))
        .suffix(".tmp")
        .tempfile_in(&dir)
        .map_err(|e| err(&e))?;
    {
        let mut w = std::io::BufWriter::new(tmp.as_file_mut());
        write(&mut w).map_err(|e| err(&e))?;
        w.flush().map_err(|e| err(&e))?;
    }
    tmp.as_file().sync_all().map_err(|e| err(&e))?;
    #[cfg(unix)]
    {
        // A temporary file is private (0600); give the result the usual mode,
        // or keep the mode of the file it replaces.
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(path)
            .map(|m| m.permissions().mode() & 0o7777)
            .unwrap_or(0o644);
        std::fs::set_permissions(tmp.path(), std::fs::Permissions::from_mode(mode))
            .map_err(|e| err(&e))?;
    }
    Ok(tmp)
}

/// Writes several files as one set: every content first goes to a complete, synced
/// temporary file beside its destination; only when all are written are they renamed
/// over their destinations, one after the other. An error (or an interruption) while
/// writing leaves none of the new files; should a rename fail, the files of the set
/// already renamed that did not exist before are removed again.
pub fn write_files_atomic(files: &[(PathBuf, String)]) -> Result<()> {
    let mut seen = std::collections::HashSet::new();
    for (p, _) in files {
        if !seen.insert(p) {
            return Err(CliError::new(format!(
                "{}: would be written twice",
                p.display()
            )));
        }
    }
    let temps = files
        .iter()
        .map(|(p, text)| prepare(p, |w| w.write_all(text.as_bytes())))
        .collect::<Result<Vec<_>>>()?;
    let mut created = Vec::new();
    for (tmp, (path, _)) in temps.into_iter().zip(files) {
        let existed = path.exists();
        if let Err(e) = tmp.persist(path) {
            for p in &created {
                let _ = std::fs::remove_file(p);
            }
            return Err(CliError::new(format!(
                "{}: cannot write: {}",
                path.display(),
                e.error
            )));
        }
        if !existed {
            created.push(path.clone());
        }
    }
    Ok(())
}

/// Writes a string atomically to `path`.
pub fn write_string(path: &Path, content: &str) -> Result<()> {
    write_atomic(path, |w| w.write_all(content.as_bytes()))
}

/// Creates a folder (and its parents) for outputs.
pub fn create_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir)
        .map_err(|e| CliError::new(format!("{}: cannot create folder: {e}", dir.display())))
}

/// Whether an I/O error is a closed pipe (`phasekit … | head`).
pub fn is_broken_pipe(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::BrokenPipe
}

/// Writes to stdout; a closed pipe ends the process quietly with status 0.
pub fn print_stdout(text: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|_| out.flush()) {
        Ok(()) => Ok(()),
        Err(e) if is_broken_pipe(&e) => std::process::exit(0),
        Err(e) => Err(CliError::new(format!("cannot write to stdout: {e}"))),
    }
}

/// Whether stderr is a terminal (progress and chatter are shown only then).
pub fn stderr_is_terminal() -> bool {
    std::io::stderr().is_terminal()
}

/// A progress bar over `len` steps on a terminal; hidden in pipes and CI.
pub fn progress_bar(len: u64, message: &str) -> indicatif::ProgressBar {
    if !stderr_is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len);
    let style = indicatif::ProgressStyle::with_template(
        "{msg:>12} [{bar:30}] {pos}/{len} ({elapsed}, ~{eta} left)",
    )
    .map(|s| s.progress_chars("=> "))
    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
    bar.set_style(style);
    bar.set_message(message.to_string());
    bar
}

/// A spinner with a message on a terminal; hidden in pipes and CI.
pub fn spinner(message: &str) -> indicatif::ProgressBar {
    if !stderr_is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new_spinner();
    bar.set_message(message.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(100));
    bar
}

/// Formats a number for CSV output: the shortest text that reads back to the same `f64`.
pub fn num(v: f64) -> String {
    format!("{v}")
}

/// Quotes a CSV field when needed.
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}
