//! Writing results: outputs that cannot destroy inputs, atomic files,
//! stdout that tolerates a closed pipe, and progress shown on a terminal only.
//!
//! Where an output goes (see [`write_atomic`]):
//!
//! * `-`: standard output;
//! * a regular file, or a path that does not exist yet: written to a temporary
//!   file beside it (`.NAME.XXXXXX.tmp`), synced, and renamed over it only when
//!   complete, keeping an existing file's permissions (and owner, where the
//!   system allows); an error or an interruption (SIGINT, SIGTERM, SIGHUP:
//!   [`crate::interrupt`]) leaves no temporary file and the old content intact;
//! * a symbolic link: resolved, and its target written as above (the link
//!   stays a link); a link whose target does not exist is refused, as `cp` does;
//! * a file with several hard links: rewritten in place once the new content
//!   is complete, so that every link sees it (as `cp` does; this last copy is
//!   not atomic);
//! * a character device (`/dev/null`, a terminal) or a named pipe: written
//!   directly, never replaced;
//! * a read-only file (no write permission bit) is refused, even for root;
//!   a folder, a socket or a block device is refused.
//!
//! [`refuse_inputs`] refuses an output that is one of the command's inputs
//! (the same file by device and inode, so also through links), before any work.

use crate::error::{CliError, Result};
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};

/// Where an output is written.
#[derive(Debug)]
enum Target {
    /// Standard output (`-o -`).
    Stdout,
    /// A regular file (or a new one), written atomically; `existing` is the
    /// metadata of the file it replaces.
    Atomic {
        path: PathBuf,
        existing: Option<std::fs::Metadata>,
    },
    /// A regular file with several hard links: rewritten in place.
    InPlace(PathBuf),
    /// A character device or a named pipe: written directly.
    Direct(PathBuf),
}

fn cannot(path: &Path, e: impl std::fmt::Display) -> CliError {
    CliError::new(format!("{}: cannot write: {e}", path.display()))
}

/// Whether an output path means standard output.
pub fn is_stdout(path: &Path) -> bool {
    path.as_os_str() == "-"
}

/// Where `path` is to be written, or why it must not be.
fn target(path: &Path) -> Result<Target> {
    if is_stdout(path) {
        return Ok(Target::Stdout);
    }
    let meta = match std::fs::symlink_metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let dir = match path.parent() {
                Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
                _ => PathBuf::from("."),
            };
            if !dir.is_dir() {
                return Err(cannot(
                    path,
                    format!("folder {} does not exist", dir.display()),
                ));
            }
            return Ok(Target::Atomic {
                path: path.to_path_buf(),
                existing: None,
            });
        }
        Err(e) => return Err(cannot(path, e)),
    };
    let ft = meta.file_type();
    if ft.is_symlink() {
        let followed = match std::fs::metadata(path) {
            Ok(m) => m,
            Err(_) => {
                let to = std::fs::read_link(path).unwrap_or_default();
                return Err(cannot(
                    path,
                    format!(
                        "a symbolic link to {}, which does not exist: not writing through it (write to the target's path, or remove the link)",
                        to.display()
                    ),
                ));
            }
        };
        if followed.is_file() {
            let resolved = std::fs::canonicalize(path).map_err(|e| cannot(path, e))?;
            return target(&resolved);
        }
        if followed.is_dir() {
            return Err(CliError::new(format!(
                "{}: is a folder, not a file",
                path.display()
            )));
        }
        return special(path, &followed);
    }
    if ft.is_dir() {
        return Err(CliError::new(format!(
            "{}: is a folder, not a file",
            path.display()
        )));
    }
    if ft.is_file() {
        if meta.permissions().readonly() {
            return Err(cannot(
                path,
                "the file is read-only (it has no write permission): make it writable or write elsewhere",
            ));
        }
        // Not ours to write (e.g. another user's file): refused as cp would.
        if let Err(e) = std::fs::OpenOptions::new().write(true).open(path) {
            return Err(cannot(path, e));
        }
        if links(&meta) > 1 {
            return Ok(Target::InPlace(path.to_path_buf()));
        }
        return Ok(Target::Atomic {
            path: path.to_path_buf(),
            existing: Some(meta),
        });
    }
    special(path, &meta)
}

/// A path that is neither a file nor a folder: devices and pipes are written directly.
fn special(path: &Path, meta: &std::fs::Metadata) -> Result<Target> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let ft = meta.file_type();
        if ft.is_char_device() || ft.is_fifo() {
            return Ok(Target::Direct(path.to_path_buf()));
        }
        if ft.is_block_device() {
            return Err(cannot(
                path,
                "a block device: phasekit does not write to disks directly",
            ));
        }
        if ft.is_socket() {
            return Err(cannot(path, "a socket"));
        }
    }
    let _ = meta;
    Err(cannot(path, "neither a file, a device nor a pipe"))
}

#[cfg(unix)]
fn links(meta: &std::fs::Metadata) -> u64 {
    use std::os::unix::fs::MetadataExt;
    meta.nlink()
}

#[cfg(not(unix))]
fn links(_: &std::fs::Metadata) -> u64 {
    1
}

/// Refuses outputs that are one of the `inputs` (the same file: compared by
/// device and inode, so also through symbolic and hard links), or that name
/// one file twice. Call it before any work.
pub fn refuse_inputs(outputs: &[&Path], inputs: &[&Path]) -> Result<()> {
    let ids: Vec<(Option<(u64, u64)>, &Path)> = inputs
        .iter()
        .map(|p| (crate::inputs::identity(p), *p))
        .collect();
    let mut seen: Vec<((u64, u64), &Path)> = Vec::new();
    for out in outputs.iter().filter(|o| !is_stdout(o)) {
        let Some(id) = crate::inputs::identity(out) else {
            continue;
        };
        if let Some((_, input)) = ids.iter().find(|(i, _)| *i == Some(id)) {
            let same = if input == out {
                String::new()
            } else {
                format!(" ({})", input.display())
            };
            return Err(CliError::new(format!(
                "{}: is also an input of this command{same}: writing it would destroy it; choose another output",
                out.display()
            )));
        }
        // Devices such as /dev/null may be given twice; files may not.
        if std::fs::metadata(out).is_ok_and(|m| m.is_file()) {
            if let Some((_, first)) = seen.iter().find(|(i, _)| *i == id) {
                return Err(CliError::new(format!(
                    "{} and {} are the same file: it would be written twice",
                    first.display(),
                    out.display()
                )));
            }
            seen.push((id, out));
        }
    }
    Ok(())
}

/// Refuses an output whose extension does not fit what the command writes:
/// `allowed` are the extensions it accepts (lowercase, without the dot), and
/// `no_extension` whether a name without one is accepted. Standard output and
/// devices are not checked.
pub fn check_extension(
    path: &Path,
    allowed: &[&str],
    no_extension: bool,
    what: &str,
) -> Result<()> {
    if is_stdout(path) || std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir()) {
        return Ok(());
    }
    match path.extension().and_then(|e| e.to_str()) {
        None if no_extension => Ok(()),
        Some(e) if allowed.contains(&e.to_ascii_lowercase().as_str()) => Ok(()),
        found => Err(CliError::new(format!(
            "{}: {what} (an output named {}), not {}",
            path.display(),
            allowed
                .iter()
                .map(|a| format!(".{a}"))
                .collect::<Vec<_>>()
                .join(" or "),
            match found {
                Some(e) => format!(".{e}"),
                None => "a name without extension".into(),
            }
        ))),
    }
}

/// Extensions that name a format `predict` and `segment` never write.
const NOT_DATA: &[&str] = &[
    "svg", "png", "pdf", "jpg", "jpeg", "md", "html", "tsv", "xlsx", "npz", "parquet", "h5",
];

/// The format of a prediction or segmentation output: `--json` or `--format`,
/// else the output file's extension (`.csv`, `.json`, `.npy`), else CSV. An
/// extension that contradicts `--format`, or that names another kind of file,
/// is refused; so is NPY to a terminal.
pub fn data_format(
    flag: Option<crate::cli::DataFormat>,
    json: bool,
    output: Option<&Path>,
    into_folder: bool,
) -> Result<crate::cli::DataFormat> {
    use crate::cli::DataFormat;
    let flag = if json { Some(DataFormat::Json) } else { flag };
    let file = output.filter(|p| {
        !into_folder && !is_stdout(p) && !std::fs::metadata(p).is_ok_and(|m| !m.is_file())
    });
    let by_ext = file.and_then(|p| {
        p.extension()
            .and_then(|e| e.to_str())
            .map(|e| (p, e.to_ascii_lowercase()))
    });
    let name = |f: DataFormat| match f {
        DataFormat::Csv => "csv",
        DataFormat::Json => "json",
        DataFormat::Npy => "npy",
    };
    let format = match by_ext {
        Some((p, e)) => {
            let from_ext = match e.as_str() {
                "csv" => Some(DataFormat::Csv),
                "json" => Some(DataFormat::Json),
                "npy" => Some(DataFormat::Npy),
                other if NOT_DATA.contains(&other) => {
                    return Err(CliError::new(format!(
                        "{}: this command writes csv, json or npy, not .{other}",
                        p.display()
                    )))
                }
                _ => None,
            };
            match (from_ext, flag) {
                (Some(x), Some(f)) if x != f => {
                    return Err(CliError::new(format!(
                        "{}: the extension .{e} does not fit --format {}",
                        p.display(),
                        name(f)
                    )))
                }
                (Some(x), _) => x,
                (None, f) => f.unwrap_or(DataFormat::Csv),
            }
        }
        None => flag.unwrap_or(DataFormat::Csv),
    };
    let to_stdout = output.is_none_or(is_stdout);
    if format == DataFormat::Npy && to_stdout && std::io::stdout().is_terminal() {
        return Err(CliError::new(
            "NPY is binary: write it to a file (-o NAME.npy) or a pipe, not to the terminal",
        ));
    }
    Ok(format)
}

/// A temporary file beside its destination, registered for removal on
/// interruption; removed when dropped unless persisted.
struct Temporary {
    file: Option<tempfile::NamedTempFile>,
    path: PathBuf,
}

impl Temporary {
    fn new(dest: &Path) -> std::io::Result<Self> {
        let dir = match dest.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = dest
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("output");
        let (file, path) = crate::interrupt::create_registered(|| {
            let file = tempfile::Builder::new()
                .prefix(&format!(".{name}."))
                .suffix(".tmp")
                .tempfile_in(&dir)?;
            let path = file.path().to_path_buf();
            Ok((file, path))
        })?;
        Ok(Temporary {
            file: Some(file),
            path,
        })
    }

    fn file(&mut self) -> &mut std::fs::File {
        self.file
            .as_mut()
            .expect("a temporary file is present until persisted")
            .as_file_mut()
    }

    /// Renames the temporary file over `dest`.
    fn persist(mut self, dest: &Path) -> std::io::Result<()> {
        let file = self.file.take().expect("persisted once");
        let r = file.persist(dest).map(|_| ()).map_err(|e| e.error);
        crate::interrupt::unregister(&self.path);
        r
    }
}

impl Drop for Temporary {
    fn drop(&mut self) {
        // The NamedTempFile (if still held) removes the file when dropped.
        self.file.take();
        crate::interrupt::unregister(&self.path);
    }
}

/// Writes the complete content for `dest` to a synced temporary file beside it.
fn prepare(
    dest: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<Temporary> {
    let err = |e: &dyn std::fmt::Display| cannot(dest, e);
    let mut tmp = Temporary::new(dest).map_err(|e| err(&e))?;
    {
        let mut w = std::io::BufWriter::new(tmp.file());
        write(&mut w).map_err(|e| err(&e))?;
        w.flush().map_err(|e| err(&e))?;
    }
    tmp.file().sync_all().map_err(|e| err(&e))?;
    test_hold();
    Ok(tmp)
}

/// Debug builds only: `PHASEKIT_TEST_HOLD_TEMPORARY_MS` keeps a complete
/// temporary file that long before it is renamed, so that the tests can
/// interrupt a write deterministically.
fn test_hold() {
    if cfg!(debug_assertions) {
        if let Some(ms) = std::env::var_os("PHASEKIT_TEST_HOLD_TEMPORARY_MS")
            .and_then(|v| v.to_str().and_then(|v| v.parse::<u64>().ok()))
        {
            std::thread::sleep(std::time::Duration::from_millis(ms));
        }
    }
}

/// Gives a new file the permissions (and, where allowed, the owner) of the one it replaces.
fn keep_mode(tmp: &mut Temporary, existing: Option<&std::fs::Metadata>, dest: &Path) -> Result<()> {
    #[cfg(unix)]
    {
        // A temporary file is private (0600); give the result the usual mode,
        // or keep the mode of the file it replaces.
        use std::os::unix::fs::{MetadataExt, PermissionsExt};
        let mode = existing.map_or(0o644, |m| m.permissions().mode() & 0o7777);
        tmp.file()
            .set_permissions(std::fs::Permissions::from_mode(mode))
            .map_err(|e| cannot(dest, e))?;
        if let Some(m) = existing {
            // Only possible for root or the owner; otherwise the writer owns the new file.
            let _ = std::os::unix::fs::fchown(&*tmp.file(), Some(m.uid()), Some(m.gid()));
        }
    }
    #[cfg(not(unix))]
    {
        let _ = (tmp, existing, dest);
    }
    Ok(())
}

/// Copies a complete temporary file's content into `dest` in place (keeping its inode).
fn copy_in_place(tmp: &mut Temporary, dest: &Path) -> Result<()> {
    use std::io::{Seek, SeekFrom};
    let src = tmp.file();
    src.seek(SeekFrom::Start(0)).map_err(|e| cannot(dest, e))?;
    let mut out = std::fs::OpenOptions::new()
        .write(true)
        .truncate(true)
        .open(dest)
        .map_err(|e| cannot(dest, e))?;
    std::io::copy(src, &mut out).map_err(|e| cannot(dest, e))?;
    out.sync_all().map_err(|e| cannot(dest, e))
}

/// Writes directly to a device or a pipe.
fn write_direct(
    dest: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    let f = std::fs::OpenOptions::new()
        .write(true)
        .open(dest)
        .map_err(|e| cannot(dest, e))?;
    let mut w = std::io::BufWriter::new(f);
    match write(&mut w).and_then(|_| w.flush()) {
        Ok(()) => Ok(()),
        // A reader that went away (`-o /dev/stdout | head`) is not an error.
        Err(e) if is_broken_pipe(&e) => Ok(()),
        Err(e) => Err(cannot(dest, e)),
    }
}

/// Writes to standard output; a closed pipe ends the process quietly with status 0.
fn write_stdout(write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    match write(&mut out).and_then(|_| out.flush()) {
        Ok(()) => Ok(()),
        Err(e) if is_broken_pipe(&e) => std::process::exit(0),
        Err(e) => Err(CliError::new(format!("cannot write to stdout: {e}"))),
    }
}

/// Writes `path` (see the module documentation for what each kind of path
/// gets): atomically for a regular file, so that on any error the old content
/// is untouched and no file is left behind.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    match target(path)? {
        Target::Stdout => write_stdout(write),
        Target::Direct(p) => write_direct(&p, write),
        Target::InPlace(p) => {
            let mut tmp = prepare(&p, write)?;
            copy_in_place(&mut tmp, &p)
        }
        Target::Atomic { path: p, existing } => {
            let mut tmp = prepare(&p, write)?;
            keep_mode(&mut tmp, existing.as_ref(), &p)?;
            tmp.persist(&p).map_err(|e| cannot(&p, e))
        }
    }
}

/// Writes several files as one set: every content first goes to a complete, synced
/// temporary file beside its destination; only when all are written are they renamed
/// over their destinations, one after the other. An error (or an interruption) while
/// writing leaves none of the new files; should a rename fail, the files of the set
/// already renamed that did not exist before are removed again. Devices, pipes and
/// standard output are written last, directly.
pub fn write_files_atomic<T: AsRef<[u8]>>(files: &[(PathBuf, T)]) -> Result<()> {
    let mut seen = std::collections::HashSet::new();
    for (p, _) in files {
        if !seen.insert(p) {
            return Err(CliError::new(format!(
                "{}: would be written twice",
                p.display()
            )));
        }
    }
    let targets = files
        .iter()
        .map(|(p, _)| target(p))
        .collect::<Result<Vec<_>>>()?;
    let mut temps = Vec::with_capacity(files.len());
    for (t, (_, text)) in targets.iter().zip(files) {
        let w = |w: &mut dyn Write| w.write_all(text.as_ref());
        temps.push(match t {
            Target::Atomic { path, existing } => {
                let mut tmp = prepare(path, w)?;
                keep_mode(&mut tmp, existing.as_ref(), path)?;
                Some(tmp)
            }
            Target::InPlace(path) => Some(prepare(path, w)?),
            Target::Stdout | Target::Direct(_) => None,
        });
    }
    let mut created: Vec<PathBuf> = Vec::new();
    let undo = |created: &[PathBuf]| {
        for p in created {
            let _ = std::fs::remove_file(p);
        }
    };
    for ((t, tmp), (_, text)) in targets.iter().zip(temps).zip(files) {
        let r = match (t, tmp) {
            (Target::Atomic { path, existing }, Some(tmp)) => {
                let r = tmp.persist(path).map_err(|e| cannot(path, e));
                if r.is_ok() && existing.is_none() {
                    created.push(path.clone());
                }
                r
            }
            (Target::InPlace(path), Some(mut tmp)) => copy_in_place(&mut tmp, path),
            (Target::Direct(path), _) => write_direct(path, |w| w.write_all(text.as_ref())),
            (Target::Stdout, _) => write_stdout(|w| w.write_all(text.as_ref())),
            _ => Ok(()),
        };
        if let Err(e) = r {
            undo(&created);
            return Err(e);
        }
    }
    Ok(())
}

/// Writes a string to `path` (see [`write_atomic`]).
pub fn write_string(path: &Path, content: &str) -> Result<()> {
    write_atomic(path, |w| w.write_all(content.as_bytes()))
}

/// Writes bytes to `path` (see [`write_atomic`]).
pub fn write_bytes(path: &Path, content: &[u8]) -> Result<()> {
    write_atomic(path, |w| w.write_all(content))
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

/// Quotes a CSV field when needed (a comma, a quote, a line break, or
/// surrounding spaces, which readers that trim would lose).
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) || s.trim() != s {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// A number as a CSV field: its shortest round-trip form, or empty when it is
/// not finite (undefined: a bin without frames, a coverage never scored).
pub fn csv_number(v: f64) -> String {
    if v.is_finite() {
        v.to_string()
    } else {
        String::new()
    }
}

/// A CSV header line (without newline) of these names, each quoted when needed.
pub fn csv_header<S: AsRef<str>>(names: &[S]) -> String {
    names
        .iter()
        .map(|n| csv_field(n.as_ref()))
        .collect::<Vec<_>>()
        .join(",")
}
