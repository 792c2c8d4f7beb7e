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
    /// A cell is not a finite number.
    #[error("{path}: row {row}, column {column} (`{name}`): {reason}: {value:?}")]
    BadCell {
        /// The file.
        path: PathBuf,
        /// 1-based line number in the file (the header is line 1).
        row: usize,
        /// 1-based column number.
        column: usize,
        /// Column name.
        name: String,
        /// The cell's text.
        value: String,
        /// Why it is refused.
        reason: &'static str,
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
    /// Column names (NPY files get `c0`, `c1`, …).
    pub columns: Vec<String>,
    /// `rows × columns`, row-major; finite or NaN (not observed).
    pub data: Vec<f64>,
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
    for (i, a) in columns.iter().enumerate() {
        if let Some(j) = columns[..i].iter().position(|b| b == a) {
            return Err(DataError::DuplicateColumn {
                path: path.to_path_buf(),
                name: a.clone(),
                first: j + 1,
                second: i + 1,
            });
        }
    }
    Ok(())
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

/// Reads a CSV file with a header row; every cell must be a finite number or
/// missing (empty, `NaN`, `NA`).
pub fn read_csv(path: &Path) -> Result<Table> {
    let file = std::fs::File::open(path).map_err(|e| io_err(path, e))?;
    read_csv_from(file, path)
}

/// [`read_csv`] from any reader; `path` names the source in errors.
pub fn read_csv_from<R: std::io::Read>(source: R, path: &Path) -> Result<Table> {
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(source);
    let header = reader.headers().map_err(|e| io_err(path, e))?.clone();
    if header.is_empty() || header.iter().all(|h| h.is_empty()) {
        return Err(DataError::Empty {
            path: path.to_path_buf(),
            what: "no header row",
        });
    }
    let columns: Vec<String> = header.iter().map(str::to_string).collect();
    check_unique(path, &columns)?;
    let width = columns.len();
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
            return Err(DataError::Ragged {
                path: path.to_path_buf(),
                row: line,
                expected: width,
                found: record.len(),
            });
        }
        for (c, cell) in record.iter().enumerate() {
            let bad = |reason| DataError::BadCell {
                path: path.to_path_buf(),
                row: line,
                column: c + 1,
                name: columns[c].clone(),
                value: cell.to_string(),
                reason,
            };
            data.push(parse_cell(cell).map_err(bad)?);
        }
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
    })
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
            reason: "not a finite number (infinity is refused; NaN marks a missing value)",
        });
    }
    Ok(Table {
        path: path.to_path_buf(),
        columns,
        data,
    })
}

/// Reads a demonstration by extension: `.npy` as NPY, anything else as CSV.
pub fn read_table(path: &Path) -> Result<Table> {
    match path.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("npy") => read_npy(path),
        _ => read_csv(path),
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
                available: columns.join(", "),
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

fn sorted_files(dir: &Path, prefix: &str) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| io_err(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_file()
                && p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with(prefix))
                && p.extension()
                    .and_then(|e| e.to_str())
                    .is_some_and(|e| e.eq_ignore_ascii_case("csv") || e.eq_ignore_ascii_case("npy"))
        })
        .collect();
    files.sort();
    Ok(files)
}

/// Checks that every table of a set has the columns of the first.
pub fn check_same_columns(tables: &[Table]) -> Result<()> {
    if let Some(first) = tables.first() {
        for t in &tables[1..] {
            if t.columns != first.columns {
                let detail = match t
                    .columns
                    .iter()
                    .zip(&first.columns)
                    .position(|(a, b)| a != b)
                {
                    Some(i) => format!(
                        "column {} is `{}`, not `{}`",
                        i + 1,
                        t.columns[i],
                        first.columns[i]
                    ),
                    None => format!("{} columns, not {}", t.columns.len(), first.columns.len()),
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
