//! Applying a model file to demonstrations: features by the model's own column
//! names, standardisation, prediction in data units, segmentation, and the
//! frame-by-frame predictor behind `phasekit stream`.
//!
//! Input the model cannot explain is reported, never silently predicted from:
//!
//! * a frame whose features have density zero under every state (a glitch of
//!   `1e200`, or a value whose standardisation overflows) is *rejected*: taken
//!   as not observed (the belief takes its transition step only), and the
//!   velocity of the next frame, which would difference against it, is missing
//!   too; batch prediction, `stream` and `segment` treat it alike;
//! * every predicted frame is scored by the log predictive density of its
//!   observed human features per observed value ([`score`]); a frame scoring
//!   below the model's calibrated threshold ([`crate::model_file::Novelty`])
//!   is flagged as out of distribution.

use crate::data::{Table, Velocity};
use crate::error::{CliError, Result};
use crate::model_file::ModelFile;
use phasekit_emission::{Emission, Frames};
use phasekit_tsc::{Model, OnlinePredictor, Predictor, Segmentation};

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

    /// Forgets the last frame's values: the next frame's velocities are
    /// missing (its positions are not), as after a frame that was not observed.
    pub fn forget_last(&mut self) {
        if let Some(p) = self.prev.as_mut() {
            p.fill(f64::NAN);
        }
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

/// The score of a frame: the log predictive density of its observed human
/// features divided by their number (nats per observed value); `None` when
/// nothing is observed (then there is nothing to judge), `−inf` for a rejected frame.
pub fn score(log_predictive: f64, observed: usize) -> Option<f64> {
    (observed > 0).then(|| log_predictive / observed as f64)
}

/// How the input of one predicted frame was judged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameStatus {
    /// Observed and like the training data.
    Ok,
    /// Nothing observed: predicted from the dynamics alone.
    Unobserved,
    /// Its score is below the model's threshold: unlike the training data.
    OutOfDistribution,
    /// Density zero under every state: taken as not observed.
    Rejected,
}

impl FrameStatus {
    /// The word `stream` writes in its `status` column.
    pub fn word(self) -> &'static str {
        match self {
            FrameStatus::Ok => "ok",
            FrameStatus::Unobserved => "unobserved",
            FrameStatus::OutOfDistribution => "ood",
            FrameStatus::Rejected => "rejected",
        }
    }

    /// The status of a frame with `observed` human feature values, its log
    /// predictive density and whether it was rejected, under `mf`'s threshold.
    pub fn of(mf: &ModelFile, observed: usize, log_predictive: f64, rejected: bool) -> Self {
        if rejected {
            return FrameStatus::Rejected;
        }
        match (score(log_predictive, observed), &mf.novelty) {
            (None, _) => FrameStatus::Unobserved,
            (Some(s), Some(n)) if s.is_nan() || s < n.threshold => FrameStatus::OutOfDistribution,
            _ => FrameStatus::Ok,
        }
    }
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
    /// Per frame, the log predictive density of the human's observed features
    /// (`−inf` when rejected).
    pub log_predictive: Vec<f64>,
    /// Per frame, how many human feature values were observed.
    pub observed: Vec<usize>,
    /// Per frame, how its input was judged.
    pub status: Vec<FrameStatus>,
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

    /// The frames of a status, in order.
    pub fn frames_with(&self, status: FrameStatus) -> Vec<usize> {
        (0..self.status.len())
            .filter(|&t| self.status[t] == status)
            .collect()
    }
}

/// The model's batch predictor, with the covariance calibration its fit
/// recorded (`auto`), if any.
pub fn predictor(mf: &ModelFile) -> Result<Predictor> {
    Ok(mf.model.predictor(&mf.roles)?.with_calibration(&mf.fit)?)
}

fn observed_counts(frames: &[f64], d: usize) -> Vec<usize> {
    frames
        .chunks_exact(d)
        .map(|f| f.iter().filter(|v| !v.is_nan()).count())
        .collect()
}

/// Predicts the robot's features from a table's human columns.
///
/// When a frame is rejected (see the module documentation), the table is
/// predicted again frame by frame as `stream` does, so that the velocity after
/// the rejected frame is missing rather than absurd; otherwise in one batch.
pub fn predict_table(
    mf: &ModelFile,
    predictor: &Predictor,
    table: &Table,
    with_covariance: bool,
) -> Result<RobotPrediction> {
    let h = human_input(mf, table)?;
    let nh = mf.layout.human.len();
    if h.iter().any(|v| v.is_infinite()) {
        return predict_table_online(mf, table, with_covariance);
    }
    let frames =
        Frames::new(&h, nh).map_err(|e| CliError::new(format!("{}: {e}", table.path.display())))?;
    let p = predictor
        .predict(frames, with_covariance)
        .map_err(|e| CliError::new(format!("{}: prediction failed: {e}", table.path.display())))?;
    if !p.rejected.is_empty() {
        return predict_table_online(mf, table, with_covariance);
    }
    let mut mean = p.mean;
    let mut covariance = p.covariance;
    if let Some(s) = &mf.standardisation {
        s.unapply_mean(&mut mean, &mf.layout.robot);
        if let Some(c) = covariance.as_mut() {
            s.unapply_cov(c, &mf.layout.robot);
        }
    }
    let observed = observed_counts(&h, nh);
    let status = observed
        .iter()
        .zip(&p.log_predictive)
        .map(|(&n, &lp)| FrameStatus::of(mf, n, lp, false))
        .collect();
    Ok(RobotPrediction {
        n_out: mf.layout.robot.len(),
        mean,
        covariance,
        log_predictive: p.log_predictive,
        observed,
        status,
    })
}

/// [`predict_table`] frame by frame, with [`StreamPredictor`].
fn predict_table_online(
    mf: &ModelFile,
    table: &Table,
    with_covariance: bool,
) -> Result<RobotPrediction> {
    let cols = column_indices(table, &mf.layout.human_columns, "human")?;
    let o = mf.layout.robot.len();
    let n = table.n_rows();
    let mut sp = StreamPredictor::new(mf)?;
    let mut out = RobotPrediction {
        n_out: o,
        mean: Vec::with_capacity(n * o),
        covariance: with_covariance.then(|| Vec::with_capacity(n * o * o)),
        log_predictive: Vec::with_capacity(n),
        observed: Vec::with_capacity(n),
        status: Vec::with_capacity(n),
    };
    let mut raw = vec![0.0; cols.len()];
    for (t, row) in table.data.chunks_exact(table.columns.len()).enumerate() {
        for (r, &c) in raw.iter_mut().zip(&cols) {
            *r = row[c];
        }
        let (m, c) = sp.step(&raw, with_covariance).map_err(|e| {
            CliError::new(format!(
                "{}: frame {t}: prediction failed: {e}",
                table.path.display()
            ))
        })?;
        out.mean.extend_from_slice(m);
        if let (Some(all), Some(c)) = (out.covariance.as_mut(), c) {
            all.extend_from_slice(c);
        }
        let last = sp.last();
        out.log_predictive.push(last.log_predictive);
        out.observed.push(last.observed);
        out.status.push(last.status);
    }
    Ok(out)
}

/// The features of `table` as the model sees them, frame by frame: rejected
/// frames (infinite after standardisation, or density zero under every state
/// of the model's segmenting emission) are set to missing, and so is the
/// velocity that differences against them. Returns the features and the
/// rejected frames.
fn joint_input_checked(mf: &ModelFile, table: &Table) -> Result<(Vec<f64>, Vec<usize>)> {
    let j = joint_input(mf, table)?;
    let d = mf.layout.features.len();
    let bad = unexplained(mf, &j, d, &table.path)?;
    if bad.is_empty() {
        return Ok((j, bad));
    }
    // Frame by frame, so that only the velocity right after a rejected frame goes missing.
    let hc = column_indices(table, &mf.layout.human_columns, "human")?;
    let rc = column_indices(table, &mf.layout.robot_columns, "robot")?;
    let (hv, rv) = velocities(mf.layout.velocity);
    let (mut dh, mut dr) = (Differencer::new(hv), Differencer::new(rv));
    let width = table.columns.len();
    let all: Vec<usize> = (0..d).collect();
    let mut out = Vec::with_capacity(j.len());
    let mut rejected = Vec::new();
    let (mut rh, mut rr) = (vec![0.0; hc.len()], vec![0.0; rc.len()]);
    for (t, row) in table.data.chunks_exact(width).enumerate() {
        let start = out.len();
        for (r, &c) in rh.iter_mut().zip(&hc) {
            *r = row[c];
        }
        for (r, &c) in rr.iter_mut().zip(&rc) {
            *r = row[c];
        }
        dh.push(&rh, &mut out);
        dr.push(&rr, &mut out);
        let f = &mut out[start..];
        if let Some(s) = &mf.standardisation {
            s.apply(f, &all);
        }
        if !unexplained(mf, f, d, &table.path)?.is_empty() {
            f.fill(f64::NAN);
            dh.forget_last();
            dr.forget_last();
            rejected.push(t);
        }
    }
    Ok((out, rejected))
}

/// `log b_k(x_t)`, `T × K`, of the emission a model segments with (an
/// ensemble's: its first member's).
fn segmenting_log_density(model: &Model, f: Frames<'_>) -> Result<Vec<f64>> {
    Ok(match model {
        Model::Hmm(h) => h.emission().log_density(f)?,
        Model::Hsmm(h) => h.emission().log_density(f)?,
        Model::TscHmm { model, .. } => model.base().emission().log_density(f)?,
        Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => g.components().log_density(f)?,
        Model::Ensemble(members) => match members.first() {
            Some(m) => segmenting_log_density(&m.model, f)?,
            None => return Err(CliError::new("an ensemble model has no member")),
        },
    })
}

/// Frames (`T × d`, as the model sees them) that are infinite somewhere or have
/// density zero under every state of the model's segmenting emission.
fn unexplained(
    mf: &ModelFile,
    frames: &[f64],
    d: usize,
    path: &std::path::Path,
) -> Result<Vec<usize>> {
    let mut bad: Vec<usize> = (0..frames.len() / d)
        .filter(|&t| frames[t * d..(t + 1) * d].iter().any(|v| v.is_infinite()))
        .collect();
    if !bad.is_empty() {
        return Ok(bad);
    }
    let f =
        Frames::new(frames, d).map_err(|e| CliError::new(format!("{}: {e}", path.display())))?;
    let log_b = segmenting_log_density(&mf.model, f)?;
    let s = log_b.len() / f.len().max(1);
    bad.extend(
        log_b
            .chunks_exact(s.max(1))
            .enumerate()
            .filter(|(_, row)| row.iter().all(|v| *v == f64::NEG_INFINITY))
            .map(|(t, _)| t),
    );
    Ok(bad)
}

/// Segments a table (it needs both the human's and the robot's columns).
/// Rejected frames (see the module documentation) are taken as not observed.
pub fn segment_table(mf: &ModelFile, table: &Table) -> Result<Segmentation> {
    Ok(segment_table_checked(mf, table)?.0)
}

/// [`segment_table`], also returning the rejected frames.
pub fn segment_table_checked(mf: &ModelFile, table: &Table) -> Result<(Segmentation, Vec<usize>)> {
    let (j, rejected) = joint_input_checked(mf, table)?;
    let frames = Frames::new(&j, mf.layout.features.len())
        .map_err(|e| CliError::new(format!("{}: {e}", table.path.display())))?;
    let seg = mf.model.segment(frames, &mf.roles).map_err(|e| {
        CliError::new(format!(
            "{}: segmentation failed: {e}",
            table.path.display()
        ))
    })?;
    Ok((seg, rejected))
}

/// What the last frame of a [`StreamPredictor`] was.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameReport {
    /// Human feature values observed (0 when rejected).
    pub observed: usize,
    /// Their log predictive density (`−inf` when rejected).
    pub log_predictive: f64,
    /// How the input was judged.
    pub status: FrameStatus,
}

/// Frame-by-frame prediction from raw human columns (velocities computed causally inside).
pub struct StreamPredictor<'a> {
    mf: &'a ModelFile,
    online: OnlinePredictor,
    diff: Differencer,
    features: Vec<f64>,
    mean: Vec<f64>,
    covariance: Vec<f64>,
    last: FrameReport,
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
            last: FrameReport {
                observed: 0,
                log_predictive: 0.0,
                status: FrameStatus::Unobserved,
            },
        })
    }

    /// Number of raw human values a frame has.
    pub fn n_in(&self) -> usize {
        self.mf.layout.human_columns.len()
    }

    /// Takes one raw human frame; returns the robot mean (and covariance when asked), data units.
    ///
    /// A frame of the wrong length is an error and changes nothing. A frame
    /// that no state explains is rejected (see the module documentation) and
    /// reported by [`StreamPredictor::last`].
    pub fn step(&mut self, raw: &[f64], with_covariance: bool) -> Result<(&[f64], Option<&[f64]>)> {
        if raw.len() != self.n_in() {
            return Err(CliError::new(format!(
                "a frame of {} values, the model's human has {}",
                raw.len(),
                self.n_in()
            )));
        }
        self.features.clear();
        self.diff.push(raw, &mut self.features);
        if let Some(s) = &self.mf.standardisation {
            s.apply(&mut self.features, &self.mf.layout.human);
        }
        let mut rejected = false;
        if self.features.iter().any(|v| v.is_infinite()) {
            // Overflowed in standardisation: no state can explain it.
            self.features.fill(f64::NAN);
            rejected = true;
        }
        let observed = self.features.iter().filter(|v| !v.is_nan()).count();
        let evidence = self
            .online
            .step_with_evidence(&self.features, with_covariance)?;
        rejected |= evidence.rejected;
        if rejected {
            self.diff.forget_last();
        }
        let log_predictive = if rejected {
            f64::NEG_INFINITY
        } else {
            evidence.log_predictive
        };
        let observed = if rejected { 0 } else { observed };
        self.last = FrameReport {
            observed,
            log_predictive,
            status: FrameStatus::of(self.mf, observed, log_predictive, rejected),
        };
        self.mean.copy_from_slice(self.online.mean());
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

    /// What the last frame was: observed values, evidence, status.
    pub fn last(&self) -> FrameReport {
        self.last
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
