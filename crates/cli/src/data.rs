//! Demonstrations from CSV or NPY files, column selection and features.
//!
//! A demonstration is a table with one row per frame. Columns are chosen by
//! name with globs, split into the human's and the robot's, and optionally
//! extended by first differences (`v_t = x_t − x_{t−1}`, `v_0 = 0`), computed
//! per demonstration and therefore causally.
//!
//! Missing values: an empty cell, `NaN` or `NA` means "not observed" and is
//! kept as NaN (a velocity is missing where either of its two positions is);
//! the models evaluate such frames on their observed values. Infinity is refused.

use std::path::{Path, PathBuf};
use thiserror::Error;

/// What is wrong with an input file, and where.
#[derive(Debug, Error)]
pub enum DataError {
    /// The file cannot be read.
    #[error("{path}: cannot read: {message}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The system's message.
        message: String,
    },
    /// The file holds no header or no frame.
    #[error("{path}: {what}")]
    Empty {
        /// The file.
        path: PathBuf,
        /// What is missing.
        what: &'static str,
    },
    /// A cell is not a finite number (`value` is an excerpt of the cell: see [`excerpt`]).
    #[error("{path}: row {row}, column {column} (`{name}`): {reason}: {value}")]
    BadCell {
        /// The file.
        path: PathBuf,
        /// 1-based line number in the file (the header is line 1).
        row: usize,
        /// 1-based column number.
        column: usize,
        /// Column name.
        name: String,
        /// The cell's text, quoted and cut to a readable length.
        value: String,
        /// Why it is refused.
        reason: String,
    },
    /// A row has a different number of cells than the header.
    #[error("{path}: row {row} has {found} cells, the header has {expected}")]
    Ragged {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        row: usize,
        /// Header width.
        expected: usize,
        /// Cells found.
        found: usize,
    },
    /// Two columns share a name.
    #[error("{path}: column `{name}` appears twice (columns {first} and {second})")]
    DuplicateColumn {
        /// The file.
        path: PathBuf,
        /// The name.
        name: String,
        /// 1-based index of its first occurrence.
        first: usize,
        /// 1-based index of the second.
        second: usize,
    },
    /// A column pattern matches no column.
    #[error("{path}: no column matches `{pattern}` (columns: {available})")]
    UnknownColumn {
        /// The file.
        path: PathBuf,
        /// The pattern.
        pattern: String,
        /// The available names.
        available: String,
    },
    /// A pattern is not a valid glob, or the selection is otherwise unusable.
    #[error("{path}: invalid column selection: {reason}")]
    Selection {
        /// The file whose columns were being selected.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Demonstrations of one data set have different columns.
    #[error("{path}: its columns differ from those of {first} ({detail})")]
    ColumnsDiffer {
        /// The file that differs.
        path: PathBuf,
        /// The first file of the set.
        first: PathBuf,
        /// What differs.
        detail: String,
    },
    /// An NPY file is not a 2-D float array or is corrupt.
    #[error("{path}: not a usable NPY array: {message}")]
    Npy {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A column the model needs is not in the file.
    #[error("{path}: the model needs the {side} column `{name}`, which this file does not have{near} (columns: {available})")]
    MissingColumn {
        /// The file.
        path: PathBuf,
        /// The column.
        name: String,
        /// Whose column it is (`human's`, `robot's`).
        side: String,
        /// A column of another case, if any (`; it has …`).
        near: String,
        /// The file's columns (a list cut to a readable length).
        available: String,
    },
    /// A path names a folder where one file is expected.
    #[error("{path}: is a folder, not a demonstration file: {hint}")]
    Folder {
        /// The folder.
        path: PathBuf,
        /// Which file is expected.
        hint: String,
    },
    /// A folder holds no demonstration.
    #[error("{path}: no demonstration found ({what})")]
    NoDemonstrations {
        /// The folder.
        path: PathBuf,
        /// What was looked for.
        what: String,
    },
}

/// Result alias of the data module.
pub type Result<T> = std::result::Result<T, DataError>;

/// A table of frames read from one file.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    /// Where it came from.
    pub path: PathBuf,
    /// Names of the columns read (NPY files get `c0`, `c1`, …): all of the
    /// file's, or those a [`Select`] asked for, in the file's order.
    pub columns: Vec<String>,
    /// `rows × columns`, row-major; finite or NaN (not observed).
    pub data: Vec<f64>,
    /// Every column name of the file, read or not (its header).
    pub header: Vec<String>,
}

/// Which columns of a file to read. Cells of the other columns are not parsed
/// (a text column such as a timestamp or a label does not matter), but every
/// row must still have as many cells as the header.
#[derive(Debug, Clone, Copy)]
pub enum Select<'a> {
    /// Every column.
    All,
    /// The columns matching any of these glob patterns; a pattern that matches
    /// no column is an error naming the file's columns.
    Globs(&'a [String]),
    /// The columns of exactly these names (what a model needs); a name the file
    /// lacks is an error saying whose column it is.
    Names {
        /// The names.
        names: &'a [String],
        /// Whose each name is, for the error (`"human's"`, `"robot's"`).
        side: &'a [&'a str],
    },
}

/// At most this many characters of a cell or a name are quoted in an error.
const EXCERPT: usize = 40;

/// A cell or a name, quoted for an error message and cut to a readable
/// length: `"abc"`, or `"abcdef…" (52428800 bytes)` for a long one.
pub fn excerpt(s: &str) -> String {
    let n = s.chars().count();
    if n <= EXCERPT {
        format!("{s:?}")
    } else {
        let head: String = s.chars().take(EXCERPT).collect();
        format!("{:?} ({} bytes)", head + "…", s.len())
    }
}

/// A list of column names for an error, cut to its first 20 (each name cut too).
pub fn name_list(names: &[String]) -> String {
    const SHOWN: usize = 20;
    let cut = |s: &String| {
        if s.chars().count() <= EXCERPT {
            s.clone()
        } else {
            s.chars().take(EXCERPT).collect::<String>() + "…"
        }
    };
    let mut out: Vec<String> = names.iter().take(SHOWN).map(cut).collect();
    if names.len() > SHOWN {
        out.push(format!("… and {} more", names.len() - SHOWN));
    }
    out.join(", ")
}

impl Table {
    /// Number of frames.
    pub fn n_rows(&self) -> usize {
        self.data.len() / self.columns.len().max(1)
    }

    /// Column `c` as a vector.
    pub fn column(&self, c: usize) -> Vec<f64> {
        self.data
            .chunks_exact(self.columns.len())
            .map(|r| r[c])
            .collect()
    }
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> DataError {
    DataError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

fn check_unique(path: &Path, columns: &[String]) -> Result<()> {
    let mut seen: std::collections::HashMap<&str, usize> =
        std::collections::HashMap::with_capacity(columns.len());
    for (i, a) in columns.iter().enumerate() {
        if let Some(j) = seen.insert(a, i) {
            return Err(DataError::DuplicateColumn {
                path: path.to_path_buf(),
                name: name_list(std::slice::from_ref(a)),
                first: j + 1,
                second: i + 1,
            });
        }
    }
    Ok(())
}

/// The indices of the columns `select` asks for, in the file's order.
fn selected(path: &Path, header: &[String], select: Select<'_>) -> Result<Vec<usize>> {
    match select {
        Select::All => Ok((0..header.len()).collect()),
        Select::Globs(patterns) => {
            let mut keep = resolve(path, header, patterns)?;
            keep.sort_unstable();
            Ok(keep)
        }
        Select::Names { names, side } => {
            let mut keep = Vec::with_capacity(names.len());
            for (i, n) in names.iter().enumerate() {
                match header.iter().position(|h| h == n) {
                    Some(c) => keep.push(c),
                    None => {
                        let near = header.iter().find(|h| h.eq_ignore_ascii_case(n)).map(|h| {
                            format!(
                                "; it has `{}`, which differs in case: names must match exactly",
                                name_list(std::slice::from_ref(h))
                            )
                        });
                        return Err(DataError::MissingColumn {
                            path: path.to_path_buf(),
                            name: n.clone(),
                            side: side
                                .get(i)
                                .or(side.last())
                                .copied()
                                .unwrap_or("model's")
                                .to_string(),
                            near: near.unwrap_or_default(),
                            available: name_list(header),
                        });
                    }
                }
            }
            keep.sort_unstable();
            keep.dedup();
            Ok(keep)
        }
    }
}

/// The field delimiter of a CSV file, from its first line: a comma, or else
/// a semicolon or a tab when the line has those and no comma.
fn delimiter(first_line: &[u8]) -> u8 {
    let (mut quoted, mut counts) = (false, [0usize; 3]);
    for &b in first_line {
        match b {
            b'"' => quoted = !quoted,
            b',' if !quoted => counts[0] += 1,
            b';' if !quoted => counts[1] += 1,
            b'\t' if !quoted => counts[2] += 1,
            _ => {}
        }
    }
    if counts[0] == 0 && counts[1] > 0 {
        b';'
    } else if counts[0] == 0 && counts[2] > 0 {
        b'\t'
    } else {
        b','
    }
}

/// Parses a CSV cell: a number, or "not observed" (NaN) for an empty cell,
/// `NaN` (any case and sign) or `NA`. An error saying why for anything else,
/// including infinity.
pub fn parse_cell(cell: &str) -> std::result::Result<f64, &'static str> {
    let cell = cell.trim();
    if cell.is_empty() || cell.eq_ignore_ascii_case("na") {
        return Ok(f64::NAN);
    }
    match cell.parse::<f64>() {
        Ok(v) if v.is_finite() || v.is_nan() => Ok(v),
        Ok(_) => Err("not a finite number (infinity is refused; leave the cell empty or write NaN for a missing value)"),
        Err(_) => Err("not a number"),
    }
}

/// Why a cell is refused, with a hint for a decimal comma (`0,25`).
fn cell_reason(cell: &str, why: &'static str, delimiter: u8) -> String {
    let comma = cell.trim().replacen(',', ".", 1);
    if why == "not a number" && cell.contains(',') && comma.parse::<f64>().is_ok() {
        let sep = if delimiter == b';' {
            "semicolon"
        } else {
            "tab"
        };
        return format!(
            "not a number (a decimal comma? this file is {sep}-separated; write decimals with a point, 0.25)"
        );
    }
    why.to_string()
}

/// Reads a CSV file with a header row; every cell must be a finite number or
/// missing (empty, `NaN`, `NA`).
pub fn read_csv(path: &Path) -> Result<Table> {
    read_csv_select(path, Select::All)
}

/// [`read_csv`] of the columns `select` asks for (the others' cells are not parsed).
pub fn read_csv_select(path: &Path, select: Select<'_>) -> Result<Table> {
    let file = std::fs::File::open(path).map_err(|e| io_err(path, e))?;
    read_csv_from_select(file, path, select)
}

/// [`read_csv`] from any reader; `path` names the source in errors.
pub fn read_csv_from<R: std::io::Read>(source: R, path: &Path) -> Result<Table> {
    read_csv_from_select(source, path, Select::All)
}

/// [`read_csv_select`] from any reader; `path` names the source in errors.
///
/// The delimiter is a comma, or a semicolon or a tab when the header line has
/// those and no comma (see `delimiter`). A UTF-8 byte order mark is ignored.
pub fn read_csv_from_select<R: std::io::Read>(
    source: R,
    path: &Path,
    select: Select<'_>,
) -> Result<Table> {
    use std::io::{BufRead, Read};
    let mut source = std::io::BufReader::new(source);
    // The first line decides the delimiter; it is then read again by the parser.
    let mut first = Vec::new();
    source
        .by_ref()
        .take(1 << 20)
        .read_until(b'\n', &mut first)
        .map_err(|e| io_err(path, e))?;
    let delim = delimiter(&first);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(true)
        .delimiter(delim)
        .trim(csv::Trim::All)
        .from_reader(std::io::Cursor::new(first).chain(source));
    let header = reader.headers().map_err(|e| io_err(path, e))?.clone();
    if header.is_empty() || header.iter().all(|h| h.is_empty()) {
        return Err(DataError::Empty {
            path: path.to_path_buf(),
            what: "no header row",
        });
    }
    let names: Vec<String> = header.iter().map(str::to_string).collect();
    check_unique(path, &names)?;
    let keep = selected(path, &names, select)?;
    let columns: Vec<String> = keep.iter().map(|&c| names[c].clone()).collect();
    let width = names.len();
    let mut data = Vec::new();
    let mut record = csv::StringRecord::new();
    let mut line = 1;
    loop {
        match reader.read_record(&mut record) {
            Ok(false) => break,
            Ok(true) => {}
            Err(e) => return Err(io_err(path, e)),
        }
        line = record.position().map_or(line + 1, |p| p.line() as usize);
        if record.len() != width {
            return Err(ragged(
                path,
                line,
                width,
                record.len(),
                delim,
                &names,
                &record,
            ));
        }
        for &c in &keep {
            let cell = &record[c];
            let bad = |why| DataError::BadCell {
                path: path.to_path_buf(),
                row: line,
                column: c + 1,
                name: name_list(std::slice::from_ref(&names[c])),
                value: excerpt(cell),
                reason: cell_reason(cell, why, delim),
            };
            data.push(parse_cell(cell).map_err(bad)?);
        }
    }
    if data.is_empty() && keep.is_empty() {
        return Err(DataError::Selection {
            path: path.to_path_buf(),
            reason: "no column selected".into(),
        });
    }
    if data.is_empty() {
        return Err(DataError::Empty {
            path: path.to_path_buf(),
            what: "no data rows after the header",
        });
    }
    Ok(Table {
        path: path.to_path_buf(),
        columns,
        data,
        header: names,
    })
}

/// The error of a row with the wrong number of cells; when the file is
/// comma-separated but the header or the row is one cell holding semicolons or
/// tabs, it says so.
fn ragged(
    path: &Path,
    row: usize,
    expected: usize,
    found: usize,
    delim: u8,
    header: &[String],
    record: &csv::StringRecord,
) -> DataError {
    let one = |cells: &[&str], sep: char| cells.len() == 1 && cells[0].contains(sep);
    let cells: Vec<&str> = record.iter().collect();
    let hdr: Vec<&str> = header.iter().map(String::as_str).collect();
    for (sep, name) in [(';', "semicolons"), ('\t', "tabs")] {
        if delim == b',' && (one(&cells, sep) || one(&hdr, sep)) {
            return DataError::Selection {
                path: path.to_path_buf(),
                reason: format!(
                    "row {row} has {found} cells, the header has {expected}: its values seem separated by {name}, the header's by commas; use one delimiter throughout"
                ),
            };
        }
    }
    DataError::Ragged {
        path: path.to_path_buf(),
        row,
        expected,
        found,
    }
}

/// Reads a 2-D float NPY array (`f8` or `f4`, C or Fortran order).
pub fn read_npy(path: &Path) -> Result<Table> {
    let bytes = std::fs::read(path).map_err(|e| io_err(path, e))?;
    parse_npy(&bytes, path)
}

/// [`read_npy`] from the file's bytes; `path` names the source in errors.
/// Nothing is allocated for the array before its claimed size is checked
/// against the bytes present, so a header that lies cannot exhaust memory.
pub fn parse_npy(bytes: &[u8], path: &Path) -> Result<Table> {
    let npy_err = |m: String| DataError::Npy {
        path: path.to_path_buf(),
        message: m,
    };
    let crate::npy::Array { rows, cols, data } = crate::npy::parse(bytes).map_err(npy_err)?;
    if rows == 0 || cols == 0 {
        return Err(DataError::Empty {
            path: path.to_path_buf(),
            what: "the array has no rows or no columns",
        });
    }
    let columns: Vec<String> = (0..cols).map(|c| format!("c{c}")).collect();
    // NaN is a missing value; infinity is refused.
    if let Some(i) = data.iter().position(|v| v.is_infinite()) {
        return Err(DataError::BadCell {
            path: path.to_path_buf(),
            row: i / cols + 1,
            column: i % cols + 1,
            name: columns[i % cols].clone(),
            value: data[i].to_string(),
            reason: "not a finite number (infinity is refused; NaN marks a missing value)".into(),
        });
    }
    Ok(Table {
        path: path.to_path_buf(),
        header: columns.clone(),
        columns,
        data,
    })
}

/// Reads a demonstration by extension: `.npy` as NPY, anything else as CSV.
pub fn read_table(path: &Path) -> Result<Table> {
    read_table_select(path, Select::All)
}

/// [`read_table`] of the columns `select` asks for: a CSV file's other
/// columns are not parsed; an NPY array is read whole, then cut to them.
///
/// A folder is refused with the name of a file it holds.
pub fn read_table_select(path: &Path, select: Select<'_>) -> Result<Table> {
    if path.is_dir() {
        return Err(folder_error(path));
    }
    match path.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("npy") => {
            let t = read_npy(path)?;
            let keep = selected(path, &t.columns, select)?;
            Ok(t.only(&keep))
        }
        _ => read_csv_select(path, select),
    }
}

/// The error for a folder given where one demonstration file is expected.
pub fn folder_error(dir: &Path) -> DataError {
    let example = std::fs::read_dir(dir).ok().and_then(|it| {
        let mut files: Vec<PathBuf> = it
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && is_table_name(p))
            .collect();
        files.sort();
        // A test demonstration is the usual choice for a picture or a prediction.
        files
            .iter()
            .find(|p| name_has_prefix(p, "test_"))
            .or(files.first())
            .cloned()
    });
    DataError::Folder {
        path: dir.to_path_buf(),
        hint: match example {
            Some(f) => format!("give one of its files, e.g. {}", f.display()),
            None => "give one CSV or NPY file (this folder holds none)".into(),
        },
    }
}

/// Whether a path's extension is `csv` or `npy` (any case).
pub fn is_table_name(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("csv") || e.eq_ignore_ascii_case("npy"))
}

fn name_has_prefix(p: &Path, prefix: &str) -> bool {
    p.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with(prefix))
}

impl Table {
    /// The same table with only the columns `keep` (indices, in order).
    fn only(self, keep: &[usize]) -> Table {
        if keep.len() == self.columns.len() {
            return self;
        }
        let width = self.columns.len();
        let data = self
            .data
            .chunks_exact(width)
            .flat_map(|r| keep.iter().map(move |&c| r[c]))
            .collect();
        Table {
            columns: keep.iter().map(|&c| self.columns[c].clone()).collect(),
            data,
            path: self.path,
            header: self.header,
        }
    }
}

/// Which side's columns get first differences appended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Velocity {
    /// No velocities.
    None,
    /// Both sides (the seed paper).
    Both,
    /// The human's only.
    Human,
    /// The robot's only.
    Robot,
}

/// Column selection and preprocessing; stored in model files.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FeatureSpec {
    /// Glob patterns of the human's columns, in order.
    pub human: Vec<String>,
    /// Glob patterns of the robot's columns, in order.
    pub robot: Vec<String>,
    /// Velocities appended.
    pub velocity: Velocity,
}

/// The resolved feature layout of a data set.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Layout {
    /// Names of the selected human columns.
    pub human_columns: Vec<String>,
    /// Names of the selected robot columns.
    pub robot_columns: Vec<String>,
    /// Name of every feature, in model order:
    /// human columns, their velocities, robot columns, their velocities.
    pub features: Vec<String>,
    /// Indices of the human's features.
    pub human: Vec<usize>,
    /// Indices of the robot's features.
    pub robot: Vec<usize>,
    /// Indices (within the robot's features) of the selected robot columns, without velocities.
    pub robot_positions: Vec<usize>,
    /// Velocity setting.
    pub velocity: Velocity,
}

impl Layout {
    /// Checks that the feature indices are those its columns make (the human's
    /// columns and velocities first, then the robot's), as a model or library
    /// file read from disk must have them.
    pub fn check_indices(&self) -> std::result::Result<(), String> {
        let hv = matches!(self.velocity, Velocity::Both | Velocity::Human);
        let rv = matches!(self.velocity, Velocity::Both | Velocity::Robot);
        let nh = self.human_columns.len() * if hv { 2 } else { 1 };
        let nr = self.robot_columns.len() * if rv { 2 } else { 1 };
        if self.human != (0..nh).collect::<Vec<_>>()
            || self.robot != (nh..nh + nr).collect::<Vec<_>>()
            || self.features.len() != nh + nr
        {
            return Err("the layout's feature indices do not match its columns".into());
        }
        if self.robot_positions.iter().any(|&j| j >= self.robot.len()) {
            return Err("robot position index out of range".into());
        }
        Ok(())
    }

    /// The `(velocity, position)` feature pairs of `--velocity`: each side's
    /// columns are followed by their velocities in the same order.
    pub fn velocity_pairs(&self) -> Vec<(usize, usize)> {
        let hv = matches!(self.velocity, Velocity::Both | Velocity::Human);
        let rv = matches!(self.velocity, Velocity::Both | Velocity::Robot);
        let side = |dims: &[usize], columns: usize, on: bool| -> Vec<(usize, usize)> {
            if !on || dims.len() != 2 * columns {
                return Vec::new();
            }
            (0..columns).map(|i| (dims[columns + i], dims[i])).collect()
        };
        let mut pairs = side(&self.human, self.human_columns.len(), hv);
        pairs.extend(side(&self.robot, self.robot_columns.len(), rv));
        pairs
    }

    /// The roles of a model of this layout: the human's features in, the
    /// robot's out, the robot's positions scored (what `evaluate` reports,
    /// and what a cross-validated choice minimises and calibrates on).
    pub fn roles(&self) -> std::result::Result<phasekit_tsc::Roles, phasekit_tsc::TscError> {
        let roles = phasekit_tsc::Roles::new(self.human.clone(), self.robot.clone())?
            .with_velocities(self.velocity_pairs())?;
        if self.robot_positions.is_empty() {
            return Ok(roles);
        }
        let scored = self
            .robot_positions
            .iter()
            .filter_map(|&j| self.robot.get(j).copied())
            .collect();
        roles.with_scored(scored)
    }
}

fn resolve(path: &Path, columns: &[String], patterns: &[String]) -> Result<Vec<usize>> {
    let mut out: Vec<usize> = Vec::new();
    for p in patterns {
        let pat = glob::Pattern::new(p).map_err(|e| DataError::Selection {
            path: path.to_path_buf(),
            reason: format!("`{p}`: {e}"),
        })?;
        let hits: Vec<usize> = (0..columns.len())
            .filter(|&c| pat.matches(&columns[c]))
            .collect();
        if hits.is_empty() {
            return Err(DataError::UnknownColumn {
                path: path.to_path_buf(),
                pattern: p.clone(),
                available: name_list(columns),
            });
        }
        for h in hits {
            if !out.contains(&h) {
                out.push(h);
            }
        }
    }
    Ok(out)
}

impl FeatureSpec {
    /// Resolves the patterns against a table's columns.
    pub fn layout(&self, table: &Table) -> Result<(Layout, Vec<usize>, Vec<usize>)> {
        if self.human.is_empty() || self.robot.is_empty() {
            return Err(DataError::Selection {
                path: table.path.clone(),
                reason: "both --human and --robot columns are needed".into(),
            });
        }
        let h = resolve(&table.path, &table.columns, &self.human)?;
        let r = resolve(&table.path, &table.columns, &self.robot)?;
        if let Some(c) = h.iter().find(|c| r.contains(c)) {
            return Err(DataError::Selection {
                path: table.path.clone(),
                reason: format!(
                    "column `{}` is selected for both the human and the robot",
                    table.columns[*c]
                ),
            });
        }
        let names = |idx: &[usize]| {
            idx.iter()
                .map(|&c| table.columns[c].clone())
                .collect::<Vec<_>>()
        };
        let (hn, rn) = (names(&h), names(&r));
        let hv = matches!(self.velocity, Velocity::Both | Velocity::Human);
        let rv = matches!(self.velocity, Velocity::Both | Velocity::Robot);
        let mut features = hn.clone();
        if hv {
            features.extend(hn.iter().map(|n| format!("d_{n}")));
        }
        let n_human = features.len();
        features.extend(rn.iter().cloned());
        if rv {
            features.extend(rn.iter().map(|n| format!("d_{n}")));
        }
        let layout = Layout {
            human_columns: hn,
            robot_columns: rn.clone(),
            human: (0..n_human).collect(),
            robot: (n_human..features.len()).collect(),
            robot_positions: (0..rn.len()).collect(),
            features,
            velocity: self.velocity,
        };
        Ok((layout, h, r))
    }

    /// Features of one table, `T × D` row-major, in the layout's order.
    pub fn features(&self, table: &Table) -> Result<(Layout, Vec<f64>)> {
        let (layout, h, r) = self.layout(table)?;
        let hv = matches!(self.velocity, Velocity::Both | Velocity::Human);
        let rv = matches!(self.velocity, Velocity::Both | Velocity::Robot);
        let width = table.columns.len();
        let rows: Vec<&[f64]> = table.data.chunks_exact(width).collect();
        let mut out = Vec::with_capacity(rows.len() * layout.features.len());
        for (t, row) in rows.iter().enumerate() {
            let prev = if t == 0 { row } else { &rows[t - 1] };
            for (cols, vel) in [(&h, hv), (&r, rv)] {
                out.extend(cols.iter().map(|&c| row[c]));
                if vel {
                    out.extend(cols.iter().map(|&c| row[c] - prev[c]));
                }
            }
        }
        Ok((layout, out))
    }
}

/// One action of a data set: its training and test demonstrations.
#[derive(Debug, Clone)]
pub struct Action {
    /// Name (the folder's).
    pub name: String,
    /// `train_*` files, sorted by name.
    pub train: Vec<Table>,
    /// `test_*` files, sorted by name.
    pub test: Vec<Table>,
}

/// The `prefix*.csv|npy` files of a folder, sorted by name. A symbolic link of
/// that name whose target does not exist is an error (a demonstration would
/// silently be left out).
pub fn sorted_files(dir: &Path, prefix: &str) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for p in std::fs::read_dir(dir)
        .map_err(|e| io_err(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
    {
        if !(name_has_prefix(&p, prefix) && is_table_name(&p)) {
            continue;
        }
        if p.is_file() {
            files.push(p);
        } else if let Some(target) = dangling_link(&p) {
            return Err(DataError::Io {
                path: p,
                message: format!(
                    "a symbolic link to {}, which does not exist (remove the link or restore its target)",
                    target.display()
                ),
            });
        }
    }
    files.sort();
    Ok(files)
}

/// The target of `p` if `p` is a symbolic link whose target does not exist.
pub fn dangling_link(p: &Path) -> Option<PathBuf> {
    let meta = std::fs::symlink_metadata(p).ok()?;
    if meta.file_type().is_symlink() && std::fs::metadata(p).is_err() {
        std::fs::read_link(p).ok()
    } else {
        None
    }
}

/// Checks that every table of a set has the columns (the header) of the first.
pub fn check_same_columns(tables: &[Table]) -> Result<()> {
    if let Some(first) = tables.first() {
        for t in &tables[1..] {
            if t.header != first.header || t.columns != first.columns {
                let detail = match t.header.iter().zip(&first.header).position(|(a, b)| a != b) {
                    Some(i) => format!(
                        "column {} is `{}`, not `{}`",
                        i + 1,
                        name_list(std::slice::from_ref(&t.header[i])),
                        name_list(std::slice::from_ref(&first.header[i]))
                    ),
                    None => format!("{} columns, not {}", t.header.len(), first.header.len()),
                };
                return Err(DataError::ColumnsDiffer {
                    path: t.path.clone(),
                    first: first.path.clone(),
                    detail,
                });
            }
        }
    }
    Ok(())
}

/// Loads one action folder (`train_*.csv|npy`, `test_*.csv|npy`).
pub fn load_action(dir: &Path) -> Result<Action> {
    let read = |files: Vec<PathBuf>| {
        files
            .iter()
            .map(|p| read_table(p))
            .collect::<Result<Vec<_>>>()
    };
    let train = read(sorted_files(dir, "train_")?)?;
    let test = read(sorted_files(dir, "test_")?)?;
    if train.is_empty() {
        return Err(DataError::NoDemonstrations {
            path: dir.to_path_buf(),
            what: "train_*.csv or train_*.npy".into(),
        });
    }
    let all: Vec<Table> = train.iter().chain(&test).cloned().collect();
    check_same_columns(&all)?;
    let name = dir
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("data")
        .to_string();
    Ok(Action { name, train, test })
}

/// Loads a data set folder: either one action folder, or a folder of action
/// subfolders (sorted by name).
pub fn load_dataset(dir: &Path) -> Result<Vec<Action>> {
    if !sorted_files(dir, "train_")?.is_empty() {
        return Ok(vec![load_action(dir)?]);
    }
    let mut subdirs: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| io_err(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    subdirs.sort();
    let actions: Vec<Action> = subdirs
        .iter()
        .filter(|d| {
            sorted_files(d, "train_")
                .map(|f| !f.is_empty())
                .unwrap_or(false)
        })
        .map(|d| load_action(d))
        .collect::<Result<_>>()?;
    if actions.is_empty() {
        return Err(DataError::NoDemonstrations {
            path: dir.to_path_buf(),
            what: "train_* files in it or in its subfolders".into(),
        });
    }
    Ok(actions)
}

/// The memory this machine has available for new allocations (Linux:
/// `MemAvailable` of `/proc/meminfo`), if known.
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// Checks, before anything is allocated for a fit, that `features` features
/// of `frames` training frames can make a model of `states` full-covariance
/// states: a covariance of `D` features cannot be estimated from fewer than `D`
/// frames (it would be the regularisation alone), and its `S × D²` values must
/// fit in memory. The error says what to do.
pub fn check_fit_size(
    features: usize,
    frames: usize,
    states: usize,
) -> std::result::Result<(), String> {
    let bytes = (states.max(1) as f64) * (features as f64).powi(2) * 8.0;
    let gib = |b: f64| b / f64::from(1u32 << 30);
    let advice = "select fewer columns with --human and --robot (or leave out velocities with --velocity none)";
    if features > frames {
        return Err(format!(
            "{features} features from {frames} frames: the covariance of a state over {features} features cannot be estimated from fewer frames than features \
             (the fit would need {:.1} GiB for {states} covariances and describe only the regularisation); {advice}, or give more demonstrations",
            gib(bytes)
        ));
    }
    if let Some(avail) = available_memory() {
        // The fit holds the covariances, their Cholesky factors and the statistics: about 4 copies.
        if 4.0 * bytes > avail as f64 {
            return Err(format!(
                "{features} features: {states} full covariances of {features} × {features} need about {:.1} GiB, more than the {:.1} GiB available; {advice}",
                gib(4.0 * bytes),
                gib(avail as f64)
            ));
        }
    }
    Ok(())
}
