//! The unit of the covariance regularisation, and the exact mapping of a
//! fitted model to scaled features that gives the relative unit its meaning.
//!
//! The paper's regulariser adds `r I` to every covariance at every M-step,
//! `r` in the data's units squared (`1e-2` m² for NuiSI): a value tuned on
//! metres means nothing on radians. [`RegUnits::Relative`] makes it `R · diag(v)`,
//! `v_j` the variance of feature `j` over the training frames, so that `R` is a
//! fraction of every feature's variance, the same on every data set.
//!
//! It is implemented exactly and for every method at once
//! ([`crate::Method::fit`]): with `s_j = √v_j`, the method is fitted unchanged,
//! with the absolute regularisation `R`, on the data divided column-wise by `s`
//! ([`scale_data`]); the fitted model is then mapped back to the data's units
//! ([`scale_model`]: means `× s`, covariances and Student-t scale matrices
//! `S Σ S`, `S = diag(s)`; start, transitions, durations and weights
//! unchanged). In the data's units the regulariser is `S (R I) S = R · diag(v)`.
//!
//! `v_j` is the population variance `Σ (x − x̄)² / n` over the observed values
//! of feature `j` in every training demonstration pooled (missing values
//! skipped). A constant feature (every observed value the same) or one never
//! observed gets `v_j = 1`, so nothing divides by zero: its regularisation is
//! then `R` in its own units squared.
//!
//! [`RegUnits::Positions`] is the same with other factors ([`position_scales`]):
//! a velocity `u_t = k (x_t − x_{t−1})` is a difference of its position, in the
//! position's unit times `k` (`k = 1` for the command's velocities, `σ_x / σ_u`
//! after `--standardise`), so it is regularised by the same fraction of its
//! *position's* variance, in its own unit: `R k² v_x`. On data in one unit
//! this is what the paper's absolute `reg` does (it regularises a velocity by
//! as much as its position, which all but removes it from the model, as
//! `1e-2` m² does on NuiSI), but in any unit: every factor moves with its
//! feature's unit, so the fit is the same whatever scale each feature is given
//! (`--standardise` included). `k` is read off the data: the least-squares
//! slope of `u_t` on `x_t − x_{t−1}` over the frames where both are observed
//! (exactly 1 when the velocity is the difference itself).

use crate::emission_choice::AnyEmission;
use crate::error::{Result, TscError};
use crate::model::Model;
use crate::roles::Roles;
use crate::tsc_hmm::TscHmm;
use phasekit_emission::{ScaleFeatures, SequenceSet};
use phasekit_gmm::Gmm;
use phasekit_hmm::Hmm;
use phasekit_hsmm::Hsmm;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The unit of the covariance regularisation `reg`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RegUnits {
    /// `reg` in the data's units squared, added to every covariance diagonal
    /// (the paper's; the default).
    #[default]
    Absolute,
    /// `reg` a fraction of every feature's variance over the training frames:
    /// `R · diag(v)` is added (see the module documentation).
    Relative,
    /// `reg` a fraction of every feature's *position's* variance: a
    /// position's own, a velocity's its position's in the velocity's unit
    /// (`R k² v_x`, see the module documentation and [`position_scales`]);
    /// [`RegUnits::Relative`] for data without velocities.
    Positions,
}

impl RegUnits {
    /// The default, absolute unit (not written in files, so that files
    /// written before the unit existed and new absolute ones agree).
    pub fn is_absolute(&self) -> bool {
        *self == RegUnits::Absolute
    }
}

impl fmt::Display for RegUnits {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            RegUnits::Absolute => "absolute",
            RegUnits::Relative => "relative",
            RegUnits::Positions => "positions",
        })
    }
}

impl FromStr for RegUnits {
    type Err = TscError;
    fn from_str(s: &str) -> Result<RegUnits> {
        match s {
            "absolute" => Ok(RegUnits::Absolute),
            "relative" => Ok(RegUnits::Relative),
            "positions" => Ok(RegUnits::Positions),
            _ => Err(TscError::InvalidSetting {
                name: "reg_units",
                reason: format!("unknown unit `{s}`; known: absolute, relative, positions"),
            }),
        }
    }
}

/// The variance `v_j` of every feature over the observed values of all
/// sequences pooled (population variance, two passes), `1` for a feature that
/// is constant or never observed.
pub fn feature_variances(data: &SequenceSet) -> Vec<f64> {
    let d = data.dim();
    let frames = data.all_frames();
    let mut n = vec![0usize; d];
    let mut sum = vec![0.0; d];
    let mut lo = vec![f64::INFINITY; d];
    let mut hi = vec![f64::NEG_INFINITY; d];
    for x in frames.iter() {
        for (j, &v) in x.iter().enumerate().filter(|(_, v)| !v.is_nan()) {
            n[j] += 1;
            sum[j] += v;
            lo[j] = lo[j].min(v);
            hi[j] = hi[j].max(v);
        }
    }
    let mean: Vec<f64> = (0..d).map(|j| sum[j] / n[j].max(1) as f64).collect();
    let mut sq = vec![0.0; d];
    for x in frames.iter() {
        for (j, &v) in x.iter().enumerate().filter(|(_, v)| !v.is_nan()) {
            sq[j] += (v - mean[j]) * (v - mean[j]);
        }
    }
    (0..d)
        .map(|j| {
            // Exactly constant (or unobserved): no scale to take, keep the data's.
            if n[j] == 0 || lo[j] == hi[j] {
                1.0
            } else {
                sq[j] / n[j] as f64
            }
        })
        .collect()
}

/// The factors `s_j` of [`RegUnits::Positions`] (the model is fitted on
/// `x_j / s_j` with the absolute `R`, so feature `j` is regularised by
/// `R s_j²`): `√v_j` for every feature but a velocity (`roles.velocities()`),
/// and `|k| √v_x` for a velocity of position `x`, `k` the least-squares slope
/// of the velocity on the position's first difference within each sequence
/// (frames where the velocity, the position and the position before are all
/// observed). A velocity whose slope is not defined or not finite and
/// positive in magnitude (no such frame, a constant position) keeps `√v_j`.
///
/// Errors when `roles` name a dim the data does not have.
pub fn position_scales(data: &SequenceSet, roles: &Roles) -> Result<Vec<f64>> {
    roles.check(data.dim())?;
    let v = feature_variances(data);
    let mut s: Vec<f64> = v.iter().map(|v| v.sqrt()).collect();
    let d = data.dim();
    for &(u, x) in roles.velocities() {
        // Pairs (Δx, u) over consecutive observed frames, two passes.
        let pairs = || {
            data.iter().flat_map(move |q| {
                let f = q.as_slice();
                (1..f.len() / d).filter_map(move |t| {
                    let (dx, vel) = (f[t * d + x] - f[(t - 1) * d + x], f[t * d + u]);
                    (!dx.is_nan() && !vel.is_nan()).then_some((dx, vel))
                })
            })
        };
        let (n, sum_dx, sum_u) = pairs().fold((0usize, 0.0, 0.0), |(n, a, b), (dx, vel)| {
            (n + 1, a + dx, b + vel)
        });
        if n == 0 {
            continue;
        }
        let (mean_dx, mean_u) = (sum_dx / n as f64, sum_u / n as f64);
        let (sxx, sxu) = pairs().fold((0.0, 0.0), |(a, b), (dx, vel)| {
            (
                a + (dx - mean_dx) * (dx - mean_dx),
                b + (dx - mean_dx) * (vel - mean_u),
            )
        });
        let k = (sxu / sxx).abs();
        let scale = k * v[x].sqrt();
        if k.is_finite() && scale.is_finite() && scale > 0.0 {
            s[u] = scale;
        }
    }
    Ok(s)
}

/// The data with feature `j` divided by `s[j]` (missing values stay missing).
pub fn scale_data(data: &SequenceSet, s: &[f64]) -> Result<SequenceSet> {
    phasekit_emission::check_scales(s, data.dim())?;
    let d = data.dim();
    let seqs: Vec<Vec<f64>> = data
        .iter()
        .map(|q| {
            q.as_slice()
                .iter()
                .enumerate()
                .map(|(k, v)| v / s[k % d])
                .collect()
        })
        .collect();
    Ok(SequenceSet::new(&seqs, d)?)
}

fn hmm(h: &Hmm<AnyEmission>, s: &[f64]) -> Result<Hmm<AnyEmission>> {
    Ok(Hmm::new(
        h.start().to_vec(),
        h.transition().to_vec(),
        h.emission().scale_features(s)?,
    )?)
}

fn gmm(g: &Gmm<AnyEmission>, s: &[f64]) -> Result<Gmm<AnyEmission>> {
    Ok(Gmm::new(
        g.weights().to_vec(),
        g.components().scale_features(s)?,
    )?)
}

/// The model of the frames `y = diag(s) x` given the model `model` of `x`:
/// every emission mapped by [`ScaleFeatures`] (means `× s`, covariances and
/// scale matrices `S Σ S`), start and transition probabilities, HSMM
/// durations and censoring, mixture weights, the TSC-HMM's composition and
/// the TSC's kept clusters, window and time sub-clusters (over normalised
/// time, which has no unit) unchanged. `gmm-tsc`'s frame mixture is over
/// `window` stacked frames: its factors are `s` repeated `window` times.
///
/// Every part is rebuilt by its checked constructor (caches recomputed, not
/// copied). Errors for emissions a scaling does not map (a spherical Gaussian
/// with unequal factors) and for factors that are not finite and positive.
pub fn scale_model(model: &Model, s: &[f64]) -> Result<Model> {
    phasekit_emission::check_scales(s, model.dim())?;
    Ok(match model {
        Model::Hmm(h) => Model::Hmm(hmm(h, s)?),
        Model::Hsmm(h) => Model::Hsmm(
            Hsmm::new(
                h.start().to_vec(),
                h.transition().to_vec(),
                h.durations().clone(),
                h.emission().scale_features(s)?,
            )?
            .with_censoring(h.censoring()),
        ),
        Model::TscHmm { model, window } => Model::TscHmm {
            model: TscHmm::new(
                hmm(model.base(), s)?,
                hmm(model.transition(), s)?,
                model.union().map(|u| hmm(u, s)).transpose()?,
                model.composition(),
            )?,
            window: *window,
        },
        Model::Gmm(g) => Model::Gmm(gmm(g, s)?),
        Model::Ensemble(members) => Model::Ensemble(
            members
                .iter()
                .map(|m| {
                    Ok(crate::model::EnsembleMember {
                        label: m.label.clone(),
                        weight: m.weight,
                        model: scale_model(&m.model, s)?,
                    })
                })
                .collect::<Result<Vec<_>>>()?,
        ),
        Model::GmmTsc { tsc, mixture } => {
            let stacked: Vec<f64> = s
                .iter()
                .copied()
                .cycle()
                .take(s.len() * tsc.window())
                .collect();
            Model::GmmTsc {
                tsc: tsc.with_mixtures(
                    gmm(tsc.mixture(), &stacked)?,
                    gmm(tsc.transition_mixture(), s)?,
                )?,
                mixture: gmm(mixture, s)?,
            }
        }
    })
}
