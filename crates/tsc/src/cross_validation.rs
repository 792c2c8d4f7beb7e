//! Cross-validated prediction error over folds of whole demonstrations: the
//! criterion of the `-cv` presets and of `auto` ([`crate::auto`]).
//!
//! A candidate is a [`Method`] with a label (`hmm:states=7,reg=0.001`). Its
//! score on fold `f` is the squared prediction error of the robot's scored
//! dims ([`Roles::scored`]: all of the robot's unless narrowed; the command
//! scores the positions, as `evaluate` does) from the human's, summed over the
//! held-out demonstrations' frames, of the candidate fitted on the other
//! demonstrations; its cross-validated error is the pooled mean over every
//! held-out frame of the folds it was scored on (per frame, summed over the
//! scored dims, in data units squared: the evaluation's metric on the
//! training demonstrations). When the data given are not in the user's units
//! (z-scores), [`Roles::with_error_units`] names the user's: each scored
//! dim's residual is multiplied by its unit before squaring (and the NLPD
//! moved by `Σ ln u`), so the table and the choice are those in the user's
//! units.
//!
//! **Calibration.** Every held-out frame is also scored against the
//! predictive covariance of the scored dims: its squared Mahalanobis distance
//! and log density, hence each candidate's cross-validated coverage of the
//! 95 % region and NLPD ([`CvRow::coverage`], [`CvRow::nlpd`]). With
//! [`CrossValidation::with_calibration`] the winner's predictive covariance is
//! then multiplied by a factor fitted on those frames ([`CovarianceCalibration`]):
//! with [`Calibration::Frames`] the one that makes their pooled coverage 95 %
//! ([`phasekit_gmr::coverage_scale`]); with [`Calibration::Demonstrations`]
//! that one widened until each held-out demonstration, judged by a threshold
//! fitted on the others alone, is covered at 95 % over all
//! ([`phasekit_gmr::demonstration_inflation`]), since a new demonstration is
//! what the calibration must transfer to and its frames' errors are not
//! independent; with [`Calibration::Predictive`] (`auto`'s default) the
//! covariance first takes a share of the held-out errors' own covariance,
//! chosen by held-out likelihood ([`phasekit_gmr::residual_shape`]), and the
//! pooled factor is then multiplied by the one that covers a new
//! demonstration at 95 % in expectation when demonstrations differ in how
//! hard they are as much as the held-out ones do
//! ([`phasekit_gmr::new_demonstration_factor`]). A regulariser's `(10 cm)²`
//! bands shrink, over-confident ones widen, the mean is unchanged, and no
//! test frame is used.
//!
//! **Choice.** The lowest cross-validated error wins ([`Selection::Best`]),
//! or, with [`Selection::OneStandardError`], the most regularised candidate
//! within one standard error of it ([`winner_by`]); or, with
//! [`Selection::Mean`]`(K)`, the `K` lowest (of those [`winner`] may choose
//! from: after halving, the survivors) are each refitted on all the data and
//! predict by their equally weighted mean, a [`crate::Model::Ensemble`]
//! ([`crate::Predictor::ensemble`]). The mean's own held-out predictions are
//! its members' combined by the same formula (`y − μ = Σ w_i r_i`, `Σ = Σ w_i
//! (Σ_i + (r_i − r)(r_i − r)ᵀ)`, no refit), which gives its row of the table
//! (appended last, labelled `mean of K: a + b + …`, [`mean_label`]) and the
//! frames its covariance is calibrated on.
//!
//! **Folds.** Demonstration `k` is held out by fold `k mod K`, or, with a fold
//! seed, the demonstrations are first shuffled by `ChaCha8Rng::seed_from_u64(seed)`
//! (the `i`-th of the shuffled order goes to fold `i mod K`). Only the data
//! given are used: a caller passes the training demonstrations, never the test ones.
//!
//! **Early abandoning** ([`Halving`], successive halving): rung 0 scores every
//! candidate on the first `first_folds` folds; the candidates are ranked by
//! their error so far (ties: the earlier candidate) and the best
//! `⌈n / eta⌉` (at least `min_kept`) go on; every next rung doubles the folds
//! scored, until the last rung scores the survivors on all `K` folds and the
//! lowest error over all folds wins. A candidate that fails on a fold is out
//! at once, with its reason. Without halving every candidate is scored on
//! every fold.
//!
//! **Parallel and deterministic.** Every rung fits its (candidate, fold) pairs
//! in parallel (rayon); each fit is seeded by its method's settings alone and
//! the results are gathered in candidate and fold order, so the choice and
//! every number of the table but the timings are the same for any number of threads.

use crate::detect::select;
use crate::error::{Result, TscError};
use crate::method::{Calibration, CrossValidation, Method, Selection};
use crate::model::Model;
use crate::roles::Roles;
use crate::summary::{CovarianceCalibration, FitSummary};
use phasekit_emission::{Frames, SequenceSet};
pub use phasekit_gmr::COVERAGE_LEVEL;
use phasekit_gmr::{
    chi_squared_quantile, covariance_block, coverage_scale, new_demonstration_factor, nlpd_scaled,
    residual_shape, score_gaussian,
};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Mean squared prediction error of the robot's scored dims (in the roles'
/// error units, [`Roles::with_error_units`]; the data's when unset) per
/// frame over held-out demonstrations, for every candidate: `Ok`
/// with the error, or `Err` with why the candidate could not be scored (the
/// fold it failed on, [`TscError::InFold`], or no scorable frame,
/// [`TscError::NoScorableFrames`]).
///
/// Fold `f` holds out the demonstrations `k` with `k mod folds = f`; `folds`
/// is clamped to `2..=n`. A frame whose robot values are not all observed is
/// not scored. Errors (for all candidates) with fewer than 2 demonstrations.
/// Every candidate is scored on every fold (no halving); see [`cv_table`].
pub fn cross_validate(
    candidates: &[(String, Method)],
    folds: usize,
    data: &SequenceSet,
    roles: &Roles,
) -> Result<Vec<Result<f64>>> {
    let plan = FoldPlan::new(data.len(), folds, None)?;
    let table = score_candidates(candidates, &plan, None, data, roles, false);
    Ok(table
        .into_iter()
        .map(|r| match r.scored.failure {
            Some(e) => Err(e),
            None => Ok(r.scored.mse),
        })
        .collect())
}

/// The successive-halving rule of early abandoning (see the module's docs),
/// validated at construction (and on deserialisation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "HalvingRaw")]
pub struct Halving {
    first_folds: usize,
    eta: usize,
    min_kept: usize,
}

#[derive(Deserialize)]
struct HalvingRaw {
    first_folds: usize,
    eta: usize,
    min_kept: usize,
}

impl TryFrom<HalvingRaw> for Halving {
    type Error = TscError;
    fn try_from(r: HalvingRaw) -> Result<Self> {
        Halving::new(r.first_folds, r.eta, r.min_kept)
    }
}

impl Default for Halving {
    /// Rung 0 on 2 folds, keep the best third (at least 3), then all folds.
    fn default() -> Self {
        Halving {
            first_folds: 2,
            eta: 3,
            min_kept: 3,
        }
    }
}

impl Halving {
    /// Score everyone on `first_folds ≥ 1` folds, keep the best `⌈n / eta⌉`
    /// (`eta ≥ 2`), never fewer than `min_kept ≥ 1`, double the folds, repeat.
    pub fn new(first_folds: usize, eta: usize, min_kept: usize) -> Result<Self> {
        let bad = |name, reason: String| Err(TscError::InvalidSetting { name, reason });
        if first_folds == 0 {
            return bad("first_folds", "rung 0 must score at least one fold".into());
        }
        if eta < 2 {
            return bad(
                "eta",
                format!("keeping 1/eta of the candidates needs eta ≥ 2, got {eta}"),
            );
        }
        if min_kept == 0 {
            return bad("min_kept", "at least one candidate must go on".into());
        }
        Ok(Halving {
            first_folds,
            eta,
            min_kept,
        })
    }
    /// Folds of rung 0.
    pub fn first_folds(&self) -> usize {
        self.first_folds
    }
    /// One in `eta` candidates goes on to the next rung.
    pub fn eta(&self) -> usize {
        self.eta
    }
    /// Fewest candidates that go on.
    pub fn min_kept(&self) -> usize {
        self.min_kept
    }
    /// The cumulative folds scored after each rung: `first, 2·first, …, folds`.
    pub fn rungs(&self, folds: usize) -> Vec<usize> {
        let mut r = Vec::new();
        let mut f = self.first_folds.min(folds);
        while f < folds {
            r.push(f);
            f = (f * 2).min(folds);
        }
        r.push(folds);
        r
    }
    /// How many of `n` candidates go on.
    pub fn kept(&self, n: usize) -> usize {
        n.div_ceil(self.eta).max(self.min_kept).min(n)
    }
}

/// One row of the cross-validation table: what became of one candidate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct CvRow {
    /// The candidate's label (a method specification, `hmm:states=7,reg=0.001`).
    pub label: String,
    /// Folds it was scored on (fewer than all when abandoned or failed).
    pub folds_scored: usize,
    /// Pooled mean squared error per held-out frame over those folds (summed
    /// over the scored dims, in the roles' error units squared
    /// ([`Roles::with_error_units`]; the data's when unset)); NaN when none
    /// was scored.
    pub mse: f64,
    /// Population standard deviation over those folds of the per-fold MSE.
    pub mse_sd: f64,
    /// Seconds of fitting and predicting, summed over its folds (CPU time of
    /// the candidate, not wall-clock of the parallel search).
    pub fit_seconds: f64,
    /// Dropped by early abandoning before scoring every fold.
    pub abandoned: bool,
    /// Share of the held-out frames (of the folds scored) whose scored dims fall
    /// inside the predicted 95 % region (the χ² ellipsoid of the predictive mean
    /// and covariance), before any calibration; `None` when a predictive
    /// covariance could not be scored (not positive definite) or no frame was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coverage: Option<f64>,
    /// Mean negative log predictive density of those frames' scored dims (nats,
    /// a density per error unit, as `mse`), before any calibration; `None` as
    /// for `coverage`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nlpd: Option<f64>,
    /// Why it could not be scored (the fold and the error), if it failed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failure: Option<String>,
}

/// Internal row: the error kept as a [`TscError`] for [`cross_validate`].
struct Scored {
    mse: f64,
    failure: Option<TscError>,
}

/// Which fold holds out each demonstration.
#[derive(Debug, Clone, PartialEq)]
pub struct FoldPlan {
    fold_of: Vec<usize>,
    folds: usize,
}

impl FoldPlan {
    /// `folds` clamped to `2..=n`; demonstration `k` in fold `k mod folds`, or
    /// the `i`-th of a shuffle by `seed` in fold `i mod folds`. Errors with
    /// fewer than 2 demonstrations.
    pub fn new(n: usize, folds: usize, seed: Option<u64>) -> Result<Self> {
        if n < 2 {
            return Err(TscError::InvalidSetting {
                name: "folds",
                reason: format!("cross-validation needs at least 2 demonstrations, got {n}"),
            });
        }
        let folds = folds.clamp(2, n);
        let mut order: Vec<usize> = (0..n).collect();
        if let Some(seed) = seed {
            order.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
        }
        let mut fold_of = vec![0; n];
        for (i, &k) in order.iter().enumerate() {
            fold_of[k] = i % folds;
        }
        Ok(FoldPlan { fold_of, folds })
    }
    /// Number of folds.
    pub fn folds(&self) -> usize {
        self.folds
    }
    /// The fold that holds out each demonstration.
    pub fn fold_of(&self) -> &[usize] {
        &self.fold_of
    }
}

/// What one fold gave a candidate.
#[derive(Debug, Clone, Default)]
struct FoldOutcome {
    /// Squared error summed over the fold's scorable frames (scored dims).
    se: f64,
    /// Those frames.
    frames: usize,
    /// Seconds of fitting and predicting.
    seconds: f64,
    /// Per held-out demonstration, its scorable frames' scores; and the sum
    /// of their log densities. `None` when a covariance could not be scored
    /// (calibration is best effort: the error still counts).
    calibration: Option<(Vec<HeldOut>, f64)>,
}

/// The scorable frames of one held-out demonstration, scored dims only.
#[derive(Debug, Clone, Default)]
struct HeldOut {
    /// The fold that held it out.
    fold: usize,
    /// Per frame, `m²` under the predictive covariance.
    mahalanobis2: Vec<f64>,
    /// Per frame, `y − μ` (`p` values).
    residuals: Vec<f64>,
    /// Per frame, the predictive covariance (`p × p`).
    covariances: Vec<f64>,
}

type FoldScore = Result<FoldOutcome>;

/// Fits `method` without fold `f`'s demonstrations and scores it on them.
fn score_fold(
    method: &Method,
    plan: &FoldPlan,
    f: usize,
    data: &SequenceSet,
    roles: &Roles,
    keep: bool,
) -> FoldScore {
    let clock = Instant::now();
    let folds = plan.folds;
    let in_fold = |e: TscError| TscError::InFold {
        fold: f,
        folds,
        source: Box::new(e),
    };
    let train: Vec<usize> = (0..data.len()).filter(|&k| plan.fold_of[k] != f).collect();
    let held: Vec<usize> = (0..data.len()).filter(|&k| plan.fold_of[k] == f).collect();
    if held.is_empty() || train.is_empty() {
        return Ok(FoldOutcome {
            calibration: Some((Vec::new(), 0.0)),
            ..FoldOutcome::default()
        });
    }
    let subset = data.subset(&train).map_err(|e| in_fold(e.into()))?;
    let (model, _) = method.fit(&subset, roles).map_err(in_fold)?;
    let predictor = model.predictor(roles).map_err(in_fold)?;
    let o = roles.robot().len();
    let (scored, outputs) = (roles.scored(), roles.scored_outputs());
    let p = scored.len();
    // The error in the user's units (1 unless the data are z-scored; `r · 1`
    // is `r` to the bit, so unset units change nothing).
    let units = roles.scored_error_units();
    let (mut se, mut frames) = (0.0, 0usize);
    let (mut residual, mut block, mut scratch) =
        (vec![0.0; p], vec![0.0; p * p], vec![0.0; p * (p + 1)]);
    let mut calibration = Some((Vec::new(), 0.0));
    for &k in &held {
        if let Some((held_out, _)) = calibration.as_mut() {
            held_out.push(HeldOut {
                fold: f,
                ..HeldOut::default()
            });
        }
        let seq = data.get(k);
        let human = select(seq, roles.human());
        let input = Frames::new(&human, roles.human().len()).map_err(|e| in_fold(e.into()))?;
        // The mean is the same to the bit with or without the covariance.
        let pred = predictor.predict(input, true).map_err(in_fold)?;
        for (t, x) in seq.iter().enumerate() {
            // A frame whose scored robot values are not all observed is not scored.
            if scored.iter().any(|&r| x[r].is_nan()) {
                continue;
            }
            for (a, (&r, &j)) in scored.iter().zip(&outputs).enumerate() {
                residual[a] = x[r] - pred.mean[t * o + j];
            }
            se += residual
                .iter()
                .zip(&units)
                .map(|(v, u)| (v * u) * (v * u))
                .sum::<f64>();
            frames += 1;
            if let (Some((held_out, log_density)), Some(cov)) =
                (calibration.as_mut(), pred.covariance.as_deref())
            {
                covariance_block(&cov[t * o * o..(t + 1) * o * o], o, &outputs, &mut block);
                match score_gaussian(&residual, &block, &mut scratch) {
                    Ok(s) => {
                        if let Some(demonstration) = held_out.last_mut() {
                            demonstration.mahalanobis2.push(s.mahalanobis2);
                            if keep {
                                demonstration.residuals.extend_from_slice(&residual);
                                demonstration.covariances.extend_from_slice(&block);
                            }
                        }
                        *log_density += s.log_density;
                    }
                    Err(_) => calibration = None,
                }
            } else {
                calibration = None;
            }
        }
    }
    if !se.is_finite() {
        return Err(in_fold(TscError::InvalidSetting {
            name: "candidates",
            reason: format!("the squared prediction error is {se}"),
        }));
    }
    Ok(FoldOutcome {
        se,
        frames,
        seconds: clock.elapsed().as_secs_f64(),
        calibration,
    })
}

/// Scores every candidate by the plan, abandoning by `halving` (none: every
/// fold); one row per candidate in candidate order, with its error kept.
fn score_candidates(
    candidates: &[(String, Method)],
    plan: &FoldPlan,
    halving: Option<&Halving>,
    data: &SequenceSet,
    roles: &Roles,
    keep: bool,
) -> Vec<CvRowScored> {
    let n = candidates.len();
    let folds = plan.folds;
    let limit = chi_squared_quantile(COVERAGE_LEVEL, roles.scored().len());
    let jacobian = log_jacobian(roles);
    let mut scores: Vec<Vec<FoldOutcome>> = vec![Vec::new(); n];
    let mut failure: Vec<Option<TscError>> = vec![None; n];
    let mut alive: Vec<usize> = (0..n).collect();
    let rungs = halving.map_or_else(|| vec![folds], |h| h.rungs(folds));
    let mut done = 0;
    for (r, &upto) in rungs.iter().enumerate() {
        // Every (candidate, fold) pair of this rung, fitted in parallel and
        // gathered in order.
        let pairs: Vec<(usize, usize)> = alive
            .iter()
            .flat_map(|&c| (done..upto).map(move |f| (c, f)))
            .collect();
        let results: Vec<FoldScore> = pairs
            .par_iter()
            .map(|&(c, f)| score_fold(&candidates[c].1, plan, f, data, roles, keep))
            .collect();
        for ((c, _), res) in pairs.into_iter().zip(results) {
            if failure[c].is_some() {
                continue;
            }
            match res {
                Ok(s) => scores[c].push(s),
                Err(e) => failure[c] = Some(e),
            }
        }
        done = upto;
        alive.retain(|&c| failure[c].is_none());
        if r + 1 < rungs.len() {
            if let Some(h) = halving {
                // Rank by the error so far; ties keep the earlier candidate.
                let mut ranked: Vec<(usize, f64)> =
                    alive.iter().map(|&c| (c, pooled(&scores[c]))).collect();
                ranked.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
                ranked.truncate(h.kept(ranked.len()));
                alive = ranked.into_iter().map(|(c, _)| c).collect();
                alive.sort_unstable();
            }
        }
    }
    (0..n)
        .map(|c| {
            let s = &scores[c];
            let mse = pooled(s);
            let per_fold: Vec<f64> = s
                .iter()
                .filter(|x| x.frames > 0)
                .map(|x| x.se / x.frames as f64)
                .collect();
            let mean = per_fold.iter().sum::<f64>() / per_fold.len().max(1) as f64;
            let sd = (per_fold.iter().map(|v| (v - mean).powi(2)).sum::<f64>()
                / per_fold.len().max(1) as f64)
                .sqrt();
            let mut fail = failure[c].take();
            if fail.is_none() && s.len() == folds && s.iter().all(|x| x.frames == 0) {
                // A candidate with no scorable held-out frame has no error to compare.
                fail = Some(TscError::NoScorableFrames { folds });
            }
            // Calibration of the folds scored, if every one of them could be.
            let pooled_calibration = s
                .iter()
                .map(|x| x.calibration.as_ref())
                .collect::<Option<Vec<_>>>()
                .map(|parts| {
                    let groups: Vec<HeldOut> =
                        parts.iter().flat_map(|(h, _)| h.iter().cloned()).collect();
                    let log_density: f64 = parts.iter().map(|(_, l)| l).sum();
                    (groups, log_density)
                })
                .filter(|(groups, _)| {
                    groups.iter().any(|g| !g.mahalanobis2.is_empty()) && fail.is_none()
                });
            let (coverage, nlpd) = match (&pooled_calibration, &limit) {
                (Some((groups, log_density)), Ok(limit)) => {
                    let n: usize = groups.iter().map(|g| g.mahalanobis2.len()).sum();
                    let inside = groups
                        .iter()
                        .flat_map(|g| &g.mahalanobis2)
                        .filter(|&&v| v <= *limit)
                        .count();
                    (
                        Some(inside as f64 / n as f64),
                        Some(-log_density / n as f64 + jacobian),
                    )
                }
                _ => (None, None),
            };
            CvRowScored {
                row: CvRow {
                    label: candidates[c].0.clone(),
                    folds_scored: s.len(),
                    mse,
                    mse_sd: sd,
                    fit_seconds: s.iter().map(|x| x.seconds).sum(),
                    abandoned: fail.is_none() && s.len() < folds,
                    coverage,
                    nlpd,
                    failure: fail.as_ref().map(|e| e.to_string()),
                },
                scored: Scored { mse, failure: fail },
                held_out: pooled_calibration.map(|(groups, _)| groups),
            }
        })
        .collect()
}

/// A row, its error kept as a [`TscError`], and the scores of its held-out
/// frames grouped by demonstration (when every fold scored could be).
struct CvRowScored {
    row: CvRow,
    scored: Scored,
    held_out: Option<Vec<HeldOut>>,
}

/// Pooled squared error per frame of the folds scored (NaN when no frame was).
fn pooled(s: &[FoldOutcome]) -> f64 {
    let (se, frames) = s
        .iter()
        .fold((0.0, 0), |(a, n), x| (a + x.se, n + x.frames));
    if frames == 0 {
        f64::NAN
    } else {
        se / frames as f64
    }
}

/// The cross-validation table of `cv` on `data` (the training demonstrations
/// only): one row per candidate, in candidate order.
pub fn cv_table(cv: &CrossValidation, data: &SequenceSet, roles: &Roles) -> Result<Vec<CvRow>> {
    roles.check(data.dim())?;
    let plan = FoldPlan::new(data.len(), cv.folds(), cv.fold_seed())?;
    Ok(
        score_candidates(cv.candidates(), &plan, cv.halving(), data, roles, false)
            .into_iter()
            .map(|r| r.row)
            .collect(),
    )
}

/// The winner of a table: the lowest error among the candidates that were
/// neither abandoned nor failed, scored on the most folds any of them reached
/// (every fold unless all survivors of a late rung failed; ties: the earlier
/// one). An abandoned candidate never wins, even if every survivor failed.
pub fn winner(table: &[CvRow]) -> Option<usize> {
    let alive = |r: &&CvRow| r.failure.is_none() && !r.abandoned && r.mse.is_finite();
    let folds = table.iter().filter(alive).map(|r| r.folds_scored).max()?;
    table
        .iter()
        .enumerate()
        .filter(|(_, r)| alive(r) && r.folds_scored == folds)
        .min_by(|a, b| a.1.mse.total_cmp(&b.1.mse).then(a.0.cmp(&b.0)))
        .map(|(i, _)| i)
}

/// The winner of a table by `rule`: [`winner`] for [`Selection::Best`] (and
/// for [`Selection::Mean`], whose first member it is); for
/// [`Selection::OneStandardError`], among the candidates eligible for
/// [`winner`] whose error is at most the lowest plus its standard error
/// (`sd / √(K − 1)`, `sd` the spread of its per-fold errors over the `K`
/// folds scored, population form: the sample standard deviation over `√K`),
/// the one with the largest regularisation amount (`reg`, in the candidates'
/// units), then the fewest states or components, then the earlier.
pub fn winner_by(
    table: &[CvRow],
    candidates: &[(String, Method)],
    rule: Selection,
) -> Option<usize> {
    let best = winner(table)?;
    if rule != Selection::OneStandardError {
        // Best, and the mean's first member.
        return Some(best);
    }
    let b = &table[best];
    let k = b.folds_scored as f64;
    let se = if k > 1.0 {
        b.mse_sd / (k - 1.0).sqrt()
    } else {
        0.0
    };
    let limit = b.mse + se;
    let strength = |c: usize| {
        let m = &candidates[c].1;
        (m.regularisation().map_or(0.0, |(r, _, _)| r), states_of(m))
    };
    table
        .iter()
        .enumerate()
        .filter(|(_, r)| {
            r.failure.is_none()
                && !r.abandoned
                && r.mse.is_finite()
                && r.folds_scored == b.folds_scored
                && r.mse <= limit
        })
        .map(|(i, _)| i)
        .min_by(|&x, &y| {
            let ((rx, sx), (ry, sy)) = (strength(x), strength(y));
            ry.total_cmp(&rx).then(sx.cmp(&sy)).then(x.cmp(&y))
        })
}

/// The number of states (or mixture components) a method fits.
fn states_of(m: &Method) -> usize {
    match m {
        Method::Hmm(s) => s.states(),
        Method::Hsmm(s) => s.hmm().states(),
        Method::TscHmm(s) => s.base().states(),
        Method::Gmm(s) | Method::GmmTsc { gmm: s, .. } => s.components(),
        Method::CrossValidated(_) => 0,
    }
}

/// The calibration of the winner's predictive covariance from its held-out
/// frames, grouped by demonstration, by `rule` (see the module's docs);
/// `None` when they could not all be scored (the winner then predicts
/// uncalibrated, as it would without calibration; its row's coverage is
/// `None` too) or the rule is [`Calibration::Off`]. A note for the summary's
/// warnings is pushed on `warnings` when the rule could not be applied as
/// asked.
fn calibrate(
    rule: Calibration,
    row: &CvRow,
    held_out: Option<&[HeldOut]>,
    roles: &Roles,
    warnings: &mut Vec<String>,
) -> Result<Option<CovarianceCalibration>> {
    let (Some(groups), Some(coverage), Some(nlpd)) = (held_out, row.coverage, row.nlpd) else {
        return Ok(None);
    };
    if rule == Calibration::Off {
        return Ok(None);
    }
    let p = roles.scored().len();
    let limit = chi_squared_quantile(COVERAGE_LEVEL, p)?;
    // The shape: the model's covariance, or (predictive) plus a share of the
    // held-out errors' covariance; the frames' distances and mean log
    // density under it.
    let (added, residual_weight, distances, shaped_nlpd) = match (rule == Calibration::Predictive)
        .then(|| shaped(groups, p, log_jacobian(roles)))
    {
        Some(Ok(shaped)) => shaped,
        other => {
            if let Some(Err(e)) = other {
                // Best effort, as the rest of the calibration: the model's shape.
                warnings.push(format!(
                    "the covariance keeps the model's shape (the held-out errors' could not be mixed in): {e}"
                ));
            }
            let distances: Vec<Vec<f64>> = groups.iter().map(|g| g.mahalanobis2.clone()).collect();
            (Vec::new(), 0.0, distances, nlpd)
        }
    };
    let m2: Vec<f64> = distances.iter().flatten().copied().collect();
    let by_demonstration: Vec<&[f64]> = distances.iter().map(Vec::as_slice).collect();
    // Where a demonstration rule cannot be computed (a single held-out
    // demonstration with scored frames, a left-out quantile of zero), the
    // pooled factor, and the summary says so.
    let mut pooled_only = |e: phasekit_gmr::GmrError| {
        warnings.push(format!(
            "the covariance is calibrated on the pooled held-out frames only \
             (not widened for a new demonstration): {e}"
        ));
    };
    let (demonstration_inflation, demonstration_spread) = match rule {
        Calibration::Off | Calibration::Frames => (1.0, None),
        Calibration::Demonstrations => {
            match phasekit_gmr::demonstration_inflation(&by_demonstration, COVERAGE_LEVEL) {
                Ok(lambda) => (lambda, None),
                Err(e) => {
                    pooled_only(e);
                    (1.0, None)
                }
            }
        }
        Calibration::Predictive => {
            match new_demonstration_factor(&by_demonstration, COVERAGE_LEVEL) {
                Ok(f) => (f.factor, Some(f.log_difficulty_sd)),
                Err(e) => {
                    pooled_only(e);
                    (1.0, None)
                }
            }
        }
    };
    let Ok(scale) = coverage_scale(&m2, p, COVERAGE_LEVEL) else {
        return Ok(None);
    };
    let scale = scale * demonstration_inflation;
    if !(scale.is_finite() && scale > 0.0) {
        warnings.push(format!(
            "the covariance is not calibrated: the factor would be {scale}"
        ));
        return Ok(None);
    }
    let mean_m2 = m2.iter().sum::<f64>() / m2.len() as f64;
    // `A` on the scored dims' block of the robot's O × O covariance.
    let added_covariance = if added.is_empty() || residual_weight == 0.0 {
        Vec::new()
    } else {
        let (o, outputs) = (roles.robot().len(), roles.scored_outputs());
        let mut full = vec![0.0; o * o];
        for (a, &j) in outputs.iter().enumerate() {
            for (b, &k) in outputs.iter().enumerate() {
                full[j * o + k] = added[a * p + b];
            }
        }
        full
    };
    Ok(Some(CovarianceCalibration {
        scale,
        level: COVERAGE_LEVEL,
        demonstration_inflation,
        frames: m2.len(),
        added_covariance,
        residual_weight,
        demonstration_spread,
        coverage_before: coverage,
        coverage_after: m2.iter().filter(|&&v| v / scale <= limit).count() as f64 / m2.len() as f64,
        nlpd_before: nlpd,
        nlpd_after: nlpd_scaled(shaped_nlpd, mean_m2, p, scale),
    }))
}

/// The added covariance (`p × p`), its weight, the held-out frames'
/// distances under `Σ_t + A` per demonstration, and their mean negative log
/// density (in the user's units, as the row's).
type Shaped = (Vec<f64>, f64, Vec<Vec<f64>>, f64);

/// The `predictive` rule's shape on the held-out frames ([`residual_shape`]);
/// `jacobian` ([`log_jacobian`]) moves the NLPD to the user's units.
fn shaped(groups: &[HeldOut], p: usize, jacobian: f64) -> Result<Shaped> {
    let residuals: Vec<f64> = groups
        .iter()
        .flat_map(|g| g.residuals.iter().copied())
        .collect();
    let covariances: Vec<f64> = groups
        .iter()
        .flat_map(|g| g.covariances.iter().copied())
        .collect();
    let shape = residual_shape(&residuals, &covariances, p, COVERAGE_LEVEL)?;
    let mut scratch = vec![0.0; p * (p + 1)];
    let mut mixed = vec![0.0; p * p];
    let mut log_density = 0.0;
    let mut distances = Vec::with_capacity(groups.len());
    for g in groups {
        let mut d = Vec::with_capacity(g.mahalanobis2.len());
        for (r, cov) in g
            .residuals
            .chunks_exact(p)
            .zip(g.covariances.chunks_exact(p * p))
        {
            for ((m, c), a) in mixed.iter_mut().zip(cov).zip(&shape.added) {
                *m = c + a;
            }
            let s = score_gaussian(r, &mixed, &mut scratch)?;
            d.push(s.mahalanobis2);
            log_density += s.log_density;
        }
        distances.push(d);
    }
    let n: usize = distances.iter().map(Vec::len).sum();
    Ok((
        shape.added,
        shape.weight,
        distances,
        -log_density / n as f64 + jacobian,
    ))
}

/// Fits a [`Method::CrossValidated`]: the table on `data`, then the winner
/// (or the mean's members, [`Selection::Mean`]) refitted on all of `data`;
/// the summary is the winner's (the mean's first member's), with the choice,
/// the table and the whole time. Errors for [`Selection::Mean`]`(0)`.
pub fn fit_cross_validated(
    cv: &CrossValidation,
    data: &SequenceSet,
    roles: &Roles,
) -> Result<(Model, FitSummary)> {
    let clock = Instant::now();
    if cv.selection() == Selection::Mean(0) {
        return Err(TscError::InvalidSetting {
            name: "selection",
            reason: "the mean of 0 candidates: K must be at least 1".into(),
        });
    }
    let candidates = cv.candidates();
    let plan = FoldPlan::new(data.len(), cv.folds(), cv.fold_seed())?;
    // Residuals and covariances are kept only where the rule or the mean reads them.
    let keep = cv.calibration() == Calibration::Predictive || cv.selection() != Selection::Best;
    let scored = score_candidates(candidates, &plan, cv.halving(), data, roles, keep);
    let table: Vec<CvRow> = scored.iter().map(|r| r.row.clone()).collect();
    let Some(best) = winner_by(&table, candidates, cv.selection()) else {
        return Err(TscError::NoCandidate {
            failures: candidates
                .iter()
                .zip(scored)
                .map(|((label, _), s)| {
                    let e = match s.scored.failure {
                        Some(e) => e,
                        None => TscError::InvalidSetting {
                            name: "candidates",
                            reason: format!("cross-validated error {} is not finite", s.scored.mse),
                        },
                    };
                    (label.clone(), e)
                })
                .collect(),
        });
    };
    let members = match cv.selection() {
        Selection::Mean(k) => ranked(&table).into_iter().take(k).collect(),
        _ => vec![best],
    };
    let (model, mut summary, mut table) = if members.len() > 1 {
        fit_mean(cv, &members, &scored, table, data, roles)?
    } else {
        let (model, mut summary) = candidates[best].1.fit(data, roles)?;
        summary.covariance_calibration = calibrate(
            cv.calibration(),
            &table[best],
            scored[best].held_out.as_deref(),
            roles,
            &mut summary.warnings,
        )?;
        summary.chosen = Some(candidates[best].0.clone());
        (model, summary, table)
    };
    summary.fit_seconds = clock.elapsed().as_secs_f64();
    // The mean's own row (last) is its choice, not a candidate's error.
    let own = usize::from(members.len() > 1);
    let candidate_rows = table.len() - own;
    for row in &table[..candidate_rows] {
        match &row.failure {
            Some(e) => summary.cv_failures.push((row.label.clone(), e.clone())),
            None if !row.abandoned => summary.cv_errors.push((row.label.clone(), row.mse)),
            None => {}
        }
    }
    if own == 1 {
        let row = &table[candidate_rows];
        summary.cv_errors.push((row.label.clone(), row.mse));
    }
    summary.cv_table = std::mem::take(&mut table);
    Ok((model, summary))
}

/// The candidates [`winner`] may choose from, best first (ties: the earlier).
fn ranked(table: &[CvRow]) -> Vec<usize> {
    let alive = |r: &&CvRow| r.failure.is_none() && !r.abandoned && r.mse.is_finite();
    let Some(folds) = table.iter().filter(alive).map(|r| r.folds_scored).max() else {
        return Vec::new();
    };
    let mut order: Vec<usize> = (0..table.len())
        .filter(|&i| alive(&&table[i]) && table[i].folds_scored == folds)
        .collect();
    order.sort_by(|&a, &b| table[a].mse.total_cmp(&table[b].mse).then(a.cmp(&b)));
    order
}

/// The label of the mean of `labels`.
pub fn mean_label(labels: &[&str]) -> String {
    format!("mean of {}: {}", labels.len(), labels.join(" + "))
}

/// [`Selection::Mean`]: the `members` (candidate indices, best first) refitted
/// on all of `data` in parallel, equally weighted; the mean's held-out
/// predictions from the members' ([`mean_held_out`]) give its row of the
/// table (appended, labelled [`mean_label`]) and its calibration. The summary
/// is the first member's, with every member's warnings.
fn fit_mean(
    cv: &CrossValidation,
    members: &[usize],
    scored: &[CvRowScored],
    mut table: Vec<CvRow>,
    data: &SequenceSet,
    roles: &Roles,
) -> Result<(Model, FitSummary, Vec<CvRow>)> {
    let candidates = cv.candidates();
    let results: Vec<Result<(Model, FitSummary)>> = members
        .par_iter()
        .map(|&c| candidates[c].1.fit(data, roles))
        .collect();
    // A member whose refit on all the data fails is left out, and the summary
    // says so; the mean fails only if every member does.
    let mut kept = Vec::with_capacity(members.len());
    let mut models = Vec::with_capacity(members.len());
    let mut summary: Option<FitSummary> = None;
    let mut warnings = Vec::new();
    let mut first_error = None;
    for (&c, result) in members.iter().zip(results) {
        let name = candidates[c].0.as_str();
        match result {
            Ok((model, s)) => {
                warnings.extend(s.warnings.iter().map(|w| format!("{name}: {w}")));
                models.push((name.to_string(), model));
                kept.push(c);
                summary.get_or_insert(s);
            }
            Err(e) => {
                warnings.push(format!(
                    "{name} is left out of the mean: its refit on all the demonstrations failed: {e}"
                ));
                first_error.get_or_insert(e);
            }
        }
    }
    let (Some(mut summary), members) = (summary, kept.as_slice()) else {
        return Err(first_error.unwrap_or(TscError::InvalidSetting {
            name: "candidates",
            reason: "the mean has no member".into(),
        }));
    };
    summary.warnings = warnings;
    let labels: Vec<&str> = members.iter().map(|&c| candidates[c].0.as_str()).collect();
    let label = mean_label(&labels);
    let weights = vec![1.0 / members.len() as f64; members.len()];
    let model = Model::ensemble(models, &weights)?;
    let held: Option<Vec<&[HeldOut]>> = members
        .iter()
        .map(|&c| scored[c].held_out.as_deref())
        .collect();
    let p = roles.scored().len();
    let first = &table[members[0]];
    let mut row = CvRow {
        label: label.clone(),
        folds_scored: first.folds_scored,
        mse: f64::NAN,
        mse_sd: f64::NAN,
        fit_seconds: members.iter().map(|&c| table[c].fit_seconds).sum(),
        abandoned: false,
        coverage: None,
        nlpd: None,
        failure: None,
    };
    let mean_groups = match held.map(|h| mean_held_out(&h, &weights, p)) {
        Some(Ok(m)) => Some(m),
        Some(Err(e)) => {
            summary.warnings.push(format!(
                "the mean's held-out frames could not be scored ({e}): its row has no error and its covariance is not calibrated"
            ));
            None
        }
        None => {
            summary.warnings.push(
                "a member's held-out frames could not all be scored: the mean's row has no error and its covariance is not calibrated".into(),
            );
            None
        }
    };
    if let Some((groups, log_density)) = &mean_groups {
        let (mse, mse_sd) = fold_errors(groups, &roles.scored_error_units());
        let n: usize = groups.iter().map(|g| g.mahalanobis2.len()).sum();
        let limit = chi_squared_quantile(COVERAGE_LEVEL, p)?;
        let inside = groups
            .iter()
            .flat_map(|g| &g.mahalanobis2)
            .filter(|&&v| v <= limit)
            .count();
        row.mse = mse;
        row.mse_sd = mse_sd;
        if n > 0 {
            row.coverage = Some(inside as f64 / n as f64);
            row.nlpd = Some(-log_density / n as f64 + log_jacobian(roles));
        }
    }
    summary.covariance_calibration = calibrate(
        cv.calibration(),
        &row,
        mean_groups.as_ref().map(|(g, _)| g.as_slice()),
        roles,
        &mut summary.warnings,
    )?;
    summary.chosen = Some(label);
    table.push(row);
    Ok((model, summary, table))
}

/// The held-out frames of the weighted mean of members whose held-out frames
/// are `members[i]` (the same demonstrations and frames, in the same order):
/// per frame the residual `y − Σ w_i μ_i = Σ w_i r_i` and the moment-matched
/// covariance `Σ w_i (Σ_i + (r_i − r)(r_i − r)ᵀ)` ([`crate::Predictor::ensemble`]'s
/// formula; `μ_i − μ = −(r_i − r)`), scored; and the sum of the log densities.
/// Errors when the members' frames do not line up or a covariance cannot be
/// scored.
fn mean_held_out(members: &[&[HeldOut]], weights: &[f64], p: usize) -> Result<(Vec<HeldOut>, f64)> {
    let misaligned = |what: &str| TscError::InvalidSetting {
        name: "candidates",
        reason: format!("the members' held-out frames differ in {what}"),
    };
    let first = members[0];
    let mut out = Vec::with_capacity(first.len());
    let mut log_density = 0.0;
    let (mut residual, mut covariance, mut scratch) =
        (vec![0.0; p], vec![0.0; p * p], vec![0.0; p * (p + 1)]);
    for (g, demonstration) in first.iter().enumerate() {
        let frames = demonstration.mahalanobis2.len();
        for m in members {
            let other = m.get(g).ok_or_else(|| misaligned("demonstrations"))?;
            if other.fold != demonstration.fold
                || other.mahalanobis2.len() != frames
                || other.residuals.len() != frames * p
                || other.covariances.len() != frames * p * p
            {
                return Err(misaligned("frames"));
            }
        }
        let mut held = HeldOut {
            fold: demonstration.fold,
            ..HeldOut::default()
        };
        for t in 0..frames {
            residual.fill(0.0);
            for (m, w) in members.iter().zip(weights) {
                let r = &m[g].residuals[t * p..(t + 1) * p];
                residual.iter_mut().zip(r).for_each(|(a, b)| *a += w * b);
            }
            covariance.fill(0.0);
            for (m, w) in members.iter().zip(weights) {
                let r = &m[g].residuals[t * p..(t + 1) * p];
                let c = &m[g].covariances[t * p * p..(t + 1) * p * p];
                for i in 0..p {
                    for j in 0..p {
                        covariance[i * p + j] +=
                            w * (c[i * p + j] + (r[i] - residual[i]) * (r[j] - residual[j]));
                    }
                }
            }
            let s = score_gaussian(&residual, &covariance, &mut scratch)?;
            held.mahalanobis2.push(s.mahalanobis2);
            held.residuals.extend_from_slice(&residual);
            held.covariances.extend_from_slice(&covariance);
            log_density += s.log_density;
        }
        out.push(held);
    }
    Ok((out, log_density))
}

/// `Σ_a ln u_a` over the scored dims' error units ([`Roles::with_error_units`]):
/// what a log density per data unit loses per frame when measured per user unit.
fn log_jacobian(roles: &Roles) -> f64 {
    roles.scored_error_units().iter().map(|u| u.ln()).sum()
}

/// The pooled squared error per frame of held-out frames (in the user's
/// units: the residual of scored dim `a` times `units[a]`), and the
/// population standard deviation over folds of the per-fold error (as a
/// candidate's row).
fn fold_errors(groups: &[HeldOut], units: &[f64]) -> (f64, f64) {
    let p = units.len();
    let mut per_fold: Vec<(usize, f64, usize)> = Vec::new();
    for g in groups {
        let se: f64 = g
            .residuals
            .chunks_exact(p.max(1))
            .flat_map(|r| r.iter().zip(units).map(|(v, u)| (v * u) * (v * u)))
            .sum();
        let frames = g.residuals.len() / p.max(1);
        match per_fold.iter_mut().find(|(f, _, _)| *f == g.fold) {
            Some((_, s, n)) => {
                *s += se;
                *n += frames;
            }
            None => per_fold.push((g.fold, se, frames)),
        }
    }
    let (se, frames) = per_fold
        .iter()
        .fold((0.0, 0), |(a, n), (_, s, k)| (a + s, n + k));
    let errors: Vec<f64> = per_fold
        .iter()
        .filter(|(_, _, n)| *n > 0)
        .map(|(_, s, n)| s / *n as f64)
        .collect();
    let mean = errors.iter().sum::<f64>() / errors.len().max(1) as f64;
    let sd = (errors.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / errors.len().max(1) as f64)
        .sqrt();
    (
        if frames == 0 {
            f64::NAN
        } else {
            se / frames as f64
        },
        sd,
    )
}
