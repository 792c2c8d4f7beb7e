//! Applying a model file to demonstrations: features by the model's own column
//! names, standardisation, prediction in data units, segmentation, and the
//! frame-by-frame predictor behind `phasekit stream`.

use crate::data::{Table, Velocity};
use crate::error::{CliError, Result};
use crate::model_file::ModelFile;
use phasekit_emission::Frames;
use phasekit_tsc::{OnlinePredictor, Predictor, Segmentation};

/// Indices in `table` of the columns named `names` (exact names, as stored in a model).
pub fn column_indices(table: &Table, names: &[String], side: &str) -> Result<Vec<usize>> {
    names
        .iter()
        .map(|n| {
            table.columns.iter().position(|c| c == n).ok_or_else(|| {
                CliError::new(format!(
                    "{}: the model needs the {side}'s column `{n}`, which this file does not have (columns: {})",
                    table.path.display(),
                    table.columns.join(", ")
                ))
            })
        })
        .collect()
}

/// Appends first differences to raw frames, causally (`v_0 = 0`).
#[derive(Debug, Clone)]
pub struct Differencer {
    prev: Option<Vec<f64>>,
    velocity: bool,
}

impl Differencer {
    /// A differencer; without `velocity` it copies frames unchanged.
    pub fn new(velocity: bool) -> Self {
        Differencer {
            prev: None,
            velocity,
        }
    }

    /// Appends the features of one raw frame to `out`.
    pub fn push(&mut self, raw: &[f64], out: &mut Vec<f64>) {
        out.extend_from_slice(raw);
        if self.velocity {
            let prev = self.prev.get_or_insert_with(|| raw.to_vec());
            out.extend(raw.iter().zip(prev.iter()).map(|(x, p)| x - p));
            prev.copy_from_slice(raw);
        }
    }

    /// Starts a new demonstration.
    pub fn reset(&mut self) {
        self.prev = None;
    }
}

fn velocities(v: Velocity) -> (bool, bool) {
    (
        matches!(v, Velocity::Both | Velocity::Human),
        matches!(v, Velocity::Both | Velocity::Robot),
    )
}

/// Raw columns of one side, `T × n`.
fn side_features(table: &Table, cols: &[usize], velocity: bool) -> Vec<f64> {
    let width = table.columns.len();
    let mut diff = Differencer::new(velocity);
    let mut out = Vec::with_capacity(table.n_rows() * cols.len() * 2);
    let mut raw = vec![0.0; cols.len()];
    for row in table.data.chunks_exact(width) {
        for (r, &c) in raw.iter_mut().zip(cols) {
            *r = row[c];
        }
        diff.push(&raw, &mut out);
    }
    out
}

/// The human's features of a table (in data units), `T × H`.
pub fn human_features_raw(mf: &ModelFile, table: &Table) -> Result<Vec<f64>> {
    let cols = column_indices(table, &mf.layout.human_columns, "human")?;
    Ok(side_features(
        table,
        &cols,
        velocities(mf.layout.velocity).0,
    ))
}

/// Joint features of a table in data units, `T × D`, in the model's order.
pub fn joint_features_raw(mf: &ModelFile, table: &Table) -> Result<Vec<f64>> {
    let h = human_features_raw(mf, table)?;
    let rc = column_indices(table, &mf.layout.robot_columns, "robot")?;
    let r = side_features(table, &rc, velocities(mf.layout.velocity).1);
    let (nh, nr) = (mf.layout.human.len(), mf.layout.robot.len());
    Ok(h.chunks_exact(nh)
        .zip(r.chunks_exact(nr))
        .flat_map(|(a, b)| a.iter().chain(b).copied())
        .collect())
}

/// The human's features as the model sees them (standardised if it was).
pub fn human_input(mf: &ModelFile, table: &Table) -> Result<Vec<f64>> {
    let mut h = human_features_raw(mf, table)?;
    if let Some(s) = &mf.standardisation {
        s.apply(&mut h, &mf.layout.human);
    }
    Ok(h)
}

/// Joint features as the model sees them.
pub fn joint_input(mf: &ModelFile, table: &Table) -> Result<Vec<f64>> {
    let mut j = joint_features_raw(mf, table)?;
    if let Some(s) = &mf.standardisation {
        let all: Vec<usize> = (0..mf.layout.features.len()).collect();
        s.apply(&mut j, &all);
    }
    Ok(j)
}

/// A prediction of the robot's features, in data units.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotPrediction {
    /// Number of robot features `O`.
    pub n_out: usize,
    /// Means, `T × O`.
    pub mean: Vec<f64>,
    /// Covariances, `T × O × O`, when asked for.
    pub covariance: Option<Vec<f64>>,
}

impl RobotPrediction {
    /// Number of frames.
    pub fn len(&self) -> usize {
        self.mean.len() / self.n_out.max(1)
    }

    /// Whether there is no frame.
    pub fn is_empty(&self) -> bool {
        self.mean.is_empty()
    }
}

/// The model's batch predictor.
pub fn predictor(mf: &ModelFile) -> Result<Predictor> {
    Ok(mf.model.predictor(&mf.roles)?)
}

/// Predicts the robot's features from a table's human columns.
pub fn predict_table(
    mf: &ModelFile,
    predictor: &Predictor,
    table: &Table,
    with_covariance: bool,
) -> Result<RobotPrediction> {
    let h = human_input(mf, table)?;
    let frames = Frames::new(&h, mf.layout.human.len())
        .map_err(|e| CliError::new(format!("{}: {e}", table.path.display())))?;
    let p = predictor
        .predict(frames, with_covariance)
        .map_err(|e| CliError::new(format!("{}: prediction failed: {e}", table.path.display())))?;
    let mut mean = p.mean;
    let mut covariance = p.covariance;
    if let Some(s) = &mf.standardisation {
        s.unapply_mean(&mut mean, &mf.layout.robot);
        if let Some(c) = covariance.as_mut() {
            s.unapply_cov(c, &mf.layout.robot);
        }
    }
    Ok(RobotPrediction {
        n_out: mf.layout.robot.len(),
        mean,
        covariance,
    })
}

/// Segments a table (it needs both the human's and the robot's columns).
pub fn segment_table(mf: &ModelFile, table: &Table) -> Result<Segmentation> {
    let j = joint_input(mf, table)?;
    let frames = Frames::new(&j, mf.layout.features.len())
        .map_err(|e| CliError::new(format!("{}: {e}", table.path.display())))?;
    mf.model.segment(frames, &mf.roles).map_err(|e| {
        CliError::new(format!(
            "{}: segmentation failed: {e}",
            table.path.display()
        ))
    })
}

/// Frame-by-frame prediction from raw human columns (velocities computed causally inside).
pub struct StreamPredictor<'a> {
    mf: &'a ModelFile,
    online: OnlinePredictor,
    diff: Differencer,
    features: Vec<f64>,
    mean: Vec<f64>,
    covariance: Vec<f64>,
}

impl<'a> StreamPredictor<'a> {
    /// A stream predictor for a model file.
    pub fn new(mf: &'a ModelFile) -> Result<Self> {
        let o = mf.layout.robot.len();
        Ok(StreamPredictor {
            mf,
            online: predictor(mf)?.online(),
            diff: Differencer::new(velocities(mf.layout.velocity).0),
            features: Vec::with_capacity(mf.layout.human.len()),
            mean: vec![0.0; o],
            covariance: vec![0.0; o * o],
        })
    }

    /// Number of raw human values a frame has.
    pub fn n_in(&self) -> usize {
        self.mf.layout.human_columns.len()
    }

    /// Takes one raw human frame; returns the robot mean (and covariance when asked), data units.
    pub fn step(&mut self, raw: &[f64], with_covariance: bool) -> Result<(&[f64], Option<&[f64]>)> {
        self.features.clear();
        self.diff.push(raw, &mut self.features);
        if let Some(s) = &self.mf.standardisation {
            s.apply(&mut self.features, &self.mf.layout.human);
        }
        let mean = self.online.step(&self.features, with_covariance)?;
        self.mean.copy_from_slice(mean);
        if with_covariance {
            self.covariance.copy_from_slice(self.online.covariance());
        }
        if let Some(s) = &self.mf.standardisation {
            s.unapply_mean(&mut self.mean, &self.mf.layout.robot);
            if with_covariance {
                s.unapply_cov(&mut self.covariance, &self.mf.layout.robot);
            }
        }
        Ok((&self.mean, with_covariance.then_some(&self.covariance[..])))
    }

    /// Starts a new demonstration.
    pub fn reset(&mut self) {
        self.online.reset();
        self.diff.reset();
    }
}

/// CSV header of a prediction: `frame`, the robot features, and with covariance
/// `var_X` (diagonal) and `cov_X_Y` (upper triangle) entries.
pub fn prediction_header(mf: &ModelFile, with_covariance: bool) -> Vec<String> {
    let names: Vec<&String> = mf
        .layout
        .robot
        .iter()
        .map(|&k| &mf.layout.features[k])
        .collect();
    let mut h = vec!["frame".to_string()];
    h.extend(names.iter().map(|n| n.to_string()));
    if with_covariance {
        for i in 0..names.len() {
            for j in i..names.len() {
                h.push(if i == j {
                    format!("var_{}", names[i])
                } else {
                    format!("cov_{}_{}", names[i], names[j])
                });
            }
        }
    }
    h
}

/// One CSV line of a predicted frame (without newline).
pub fn prediction_line(frame: usize, mean: &[f64], covariance: Option<&[f64]>, line: &mut String) {
    use std::fmt::Write;
    line.clear();
    let _ = write!(line, "{frame}");
    for v in mean {
        let _ = write!(line, ",{v}");
    }
    if let Some(c) = covariance {
        let o = mean.len();
        for i in 0..o {
            for j in i..o {
                let _ = write!(line, ",{}", c[i * o + j]);
            }
        }
    }
}
