//! K-fold cross-validated prediction error, the criterion of the `-cv` presets.

use crate::detect::select;
use crate::error::{Result, TscError};
use crate::method::Method;
use crate::roles::Roles;
use phasekit_emission::{Frames, SequenceSet};

/// Mean squared prediction error of the robot's dims (all of them, in data
/// units) per frame over held-out demonstrations, for every candidate: `Ok`
/// with the error, or `Err` with why the candidate could not be scored (the
/// fold it failed on, [`TscError::InFold`], or no scorable frame,
/// [`TscError::NoScorableFrames`]).
///
/// Fold `f` holds out the demonstrations `k` with `k mod folds = f`; `folds`
/// is clamped to `2..=n`. A frame whose robot values are not all observed is
/// not scored. Errors (for all candidates) with fewer than 2 demonstrations.
pub fn cross_validate(
    candidates: &[(String, Method)],
    folds: usize,
    data: &SequenceSet,
    roles: &Roles,
) -> Result<Vec<Result<f64>>> {
    let n = data.len();
    let folds = folds.clamp(2, n.max(2));
    if n < 2 {
        return Err(TscError::InvalidSetting {
            name: "folds",
            reason: format!("cross-validation needs at least 2 demonstrations, got {n}"),
        });
    }
    Ok(candidates
        .iter()
        .map(|(_, method)| candidate_error(method, folds, data, roles))
        .collect())
}

/// The cross-validated error of one method (see [`cross_validate`]).
fn candidate_error(
    method: &Method,
    folds: usize,
    data: &SequenceSet,
    roles: &Roles,
) -> Result<f64> {
    let n = data.len();
    let o = roles.robot().len();
    let mut se = 0.0;
    let mut frames = 0usize;
    for f in 0..folds {
        let train: Vec<usize> = (0..n).filter(|k| k % folds != f).collect();
        let held: Vec<usize> = (0..n).filter(|k| k % folds == f).collect();
        if held.is_empty() || train.is_empty() {
            continue;
        }
        let in_fold = |e: TscError| TscError::InFold {
            fold: f,
            folds,
            source: Box::new(e),
        };
        let subset = data.subset(&train).map_err(|e| in_fold(e.into()))?;
        let (model, _) = method.fit(&subset, roles).map_err(in_fold)?;
        let predictor = model.predictor(roles).map_err(in_fold)?;
        for &k in &held {
            let seq = data.get(k);
            let human = select(seq, roles.human());
            let input = Frames::new(&human, roles.human().len()).map_err(|e| in_fold(e.into()))?;
            let pred = predictor.predict(input, false).map_err(in_fold)?;
            for (t, x) in seq.iter().enumerate() {
                // A frame whose robot values are not all observed is not scored.
                if roles.robot().iter().any(|&r| x[r].is_nan()) {
                    continue;
                }
                se += roles
                    .robot()
                    .iter()
                    .enumerate()
                    .map(|(j, &r)| (pred.mean[t * o + j] - x[r]).powi(2))
                    .sum::<f64>();
                frames += 1;
            }
        }
    }
    // A candidate with no scorable held-out frame has no error to compare.
    if frames == 0 {
        Err(TscError::NoScorableFrames { folds })
    } else {
        Ok(se / frames as f64)
    }
}
