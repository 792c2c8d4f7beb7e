//! What `--data` names: files, folders, quoted globs, process substitutions
//! (`<(cat f.csv)`), resolved to a list of demonstration files, and read.
//!
//! * a path that does not exist but holds `*`, `?` or `[` is a glob pattern
//!   (as `--human` takes them), expanded in sorted order; a pattern that
//!   matches nothing is an error;
//! * a regular file, a named pipe or a character device is one demonstration
//!   (a pipe is read once, by its content: CSV unless its name ends in `.npy`);
//! * a folder holds the demonstrations (`fit`: its `train_*` files, or with
//!   `--action` those of that action's subfolder; the other commands: all its
//!   CSV/NPY files);
//! * a symbolic link whose target is missing is an error, named as such,
//!   whether given or found in a folder;
//! * the same file given twice (also through a link, a hard link or two
//!   patterns) is an error: a demonstration fitted twice would weigh double.

use crate::bail;
use crate::data::{self, dangling_link, is_table_name, sorted_files, Select, Table};
use crate::error::{CliError, Result};
use std::path::{Path, PathBuf};

/// Whether a path holds glob metacharacters.
fn is_pattern(p: &Path) -> bool {
    p.to_str().is_some_and(|s| s.contains(['*', '?', '[']))
}

/// What one `--data` argument names: itself, or the paths its pattern matches.
fn expand(p: &Path) -> Result<Vec<PathBuf>> {
    if std::fs::symlink_metadata(p).is_ok() || !is_pattern(p) {
        return Ok(vec![p.to_path_buf()]);
    }
    let pattern = p.to_str().unwrap_or_default();
    let paths = glob::glob(pattern)
        .map_err(|e| CliError::new(format!("{}: not a valid pattern: {e}", p.display())))?;
    let mut out = Vec::new();
    for entry in paths {
        match entry {
            Ok(path) => out.push(path),
            Err(e) => bail!(
                "{}: cannot read {}: {}",
                p.display(),
                e.path().display(),
                e.error()
            ),
        }
    }
    if out.is_empty() {
        bail!("{}: no file matches this pattern", p.display());
    }
    out.sort();
    Ok(out)
}

/// What kind of thing a path is, for `--data`.
enum Kind {
    /// One demonstration: a file, a named pipe or a character device.
    File,
    /// A folder of demonstrations.
    Folder,
}

/// Classifies a path given as data, with the errors of a missing one.
fn kind(p: &Path) -> Result<Kind> {
    if let Some(target) = dangling_link(p) {
        bail!(
            "{}: a symbolic link to {}, which does not exist",
            p.display(),
            target.display()
        );
    }
    let meta = match std::fs::metadata(p) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{}: no such file or folder", p.display())
        }
        Err(e) => bail!("{}: cannot read: {e}", p.display()),
    };
    if meta.is_dir() {
        return Ok(Kind::Folder);
    }
    if meta.is_file() {
        return Ok(Kind::File);
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        if t.is_fifo() || t.is_char_device() {
            return Ok(Kind::File);
        }
    }
    bail!(
        "{}: neither a file nor a folder (a socket or a block device?)",
        p.display()
    )
}

/// A file's identity: device and inode on Unix, the canonical path elsewhere.
pub fn identity(p: &Path) -> Option<(u64, u64)> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()))
    }
    #[cfg(not(unix))]
    {
        use std::hash::{Hash, Hasher};
        let c = std::fs::canonicalize(p).ok()?;
        let mut h = std::collections::hash_map::DefaultHasher::new();
        c.hash(&mut h);
        Some((0, h.finish()))
    }
}

/// Refuses a list in which one file appears twice (by identity, so also
/// through links and different spellings).
fn check_distinct(files: &[PathBuf]) -> Result<()> {
    let mut seen: std::collections::HashMap<(u64, u64), &PathBuf> = Default::default();
    for f in files {
        let Some(id) = identity(f) else { continue };
        if let Some(first) = seen.insert(id, f) {
            if first == f {
                bail!(
                    "{}: given twice: every demonstration must be given once",
                    f.display()
                );
            }
            bail!(
                "{} and {} are the same file: every demonstration must be given once",
                first.display(),
                f.display()
            );
        }
    }
    Ok(())
}

fn list_dir(dir: &Path, filter: impl Fn(&Path) -> bool) -> Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| CliError::new(format!("{}: cannot read folder: {e}", dir.display())))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| filter(p))
        .collect();
    v.sort();
    Ok(v)
}

/// Whether a folder holds `train_*` demonstration files (CSV or NPY) itself.
pub fn has_train_files(dir: &Path) -> Result<bool> {
    Ok(!sorted_files(dir, "train_")?.is_empty())
}

/// Action folders (subfolders holding `train_*` files) of a folder.
pub fn action_dirs(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for d in list_dir(dir, |p| p.is_dir())? {
        if !sorted_files(&d, "train_")?.is_empty() {
            out.push(d);
        }
    }
    Ok(out)
}

fn dir_name(p: &Path) -> String {
    p.file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("?")
        .to_string()
}

/// Training files for `fit`: files as given; a folder's `train_*` files; with
/// `action`, those of the folder's subfolder `action`. Quoted globs are
/// expanded; see the module documentation for links, pipes and duplicates.
pub fn fit_files(paths: &[PathBuf], action: Option<&str>) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in paths
        .iter()
        .map(|p| expand(p))
        .collect::<Result<Vec<_>>>()?
        .concat()
    {
        if let Kind::File = kind(&p)? {
            out.push(p);
            continue;
        }
        let dir = match action {
            Some(a) => {
                let d = p.join(a);
                if !d.is_dir() {
                    let have: Vec<String> = action_dirs(&p)?.iter().map(|d| dir_name(d)).collect();
                    bail!(
                        "{}: no action folder `{a}` (actions: {})",
                        p.display(),
                        if have.is_empty() {
                            "none".into()
                        } else {
                            have.join(", ")
                        }
                    );
                }
                d
            }
            None => p.clone(),
        };
        let train = sorted_files(&dir, "train_")?;
        if !train.is_empty() {
            out.extend(train);
            continue;
        }
        let actions = action_dirs(&dir)?;
        if !actions.is_empty() {
            let names: Vec<String> = actions.iter().map(|d| dir_name(d)).collect();
            bail!(
                "{}: holds several actions ({}); fit one at a time with --action NAME",
                dir.display(),
                names.join(", ")
            );
        }
        bail!(
            "{}: no train_*.csv or train_*.npy file in this folder",
            dir.display()
        );
    }
    check_distinct(&out)?;
    Ok(out)
}

/// Files for `predict`, `segment` and plots: files as given, a folder's
/// CSV/NPY files. Quoted globs are expanded; see the module documentation.
pub fn data_files(paths: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in paths
        .iter()
        .map(|p| expand(p))
        .collect::<Result<Vec<_>>>()?
        .concat()
    {
        match kind(&p)? {
            Kind::File => out.push(p),
            Kind::Folder => {
                let files = sorted_files(&p, "")?;
                if files.is_empty() {
                    bail!("{}: no .csv or .npy file in this folder", p.display());
                }
                out.extend(files);
            }
        }
    }
    check_distinct(&out)?;
    Ok(out)
}

/// One demonstration file, for commands that draw or read exactly one: a
/// folder is refused with the name of a file it holds.
pub fn one_file(path: &Path) -> Result<PathBuf> {
    let files = expand(path)?;
    if files.len() > 1 {
        bail!(
            "{}: matches {} files; this command takes one demonstration",
            path.display(),
            files.len()
        );
    }
    let p = files
        .into_iter()
        .next()
        .unwrap_or_else(|| path.to_path_buf());
    match kind(&p)? {
        Kind::File => Ok(p),
        Kind::Folder => Err(data::folder_error(&p).into()),
    }
}

/// Reads every file (all columns); with `same_columns`, all must have the columns of the first.
pub fn read_tables(files: &[PathBuf], same_columns: bool) -> Result<Vec<Table>> {
    Ok(read_tables_select(files, same_columns, Select::All)?)
}

/// Reads the columns `select` asks for from every file (see [`Select`]); with
/// `same_columns`, all must have the header of the first.
pub fn read_tables_select(
    files: &[PathBuf],
    same_columns: bool,
    select: Select<'_>,
) -> data::Result<Vec<Table>> {
    let tables = files
        .iter()
        .map(|f| data::read_table_select(f, select))
        .collect::<data::Result<Vec<_>>>()?;
    if same_columns {
        data::check_same_columns(&tables)?;
    }
    Ok(tables)
}

/// Whether `p` names a CSV or NPY file by its extension.
pub fn is_table_file(p: &Path) -> bool {
    p.is_file() && is_table_name(p)
}
