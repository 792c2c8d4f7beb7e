//! Rejecting motions that belong to no action of the library.
//!
//! Two tests, both calibrated on held-out training demonstrations
//! ([`crate::library::Calibration`]):
//!
//! * **likelihood per frame**: reject while `max_a log p(o¹_{1:t} | λ_a) / t`
//!   is below a threshold: no action explains the motion as well as the
//!   actions explained their own unseen demonstrations;
//! * **threshold model** (Lee & Kim, "An HMM-based threshold model approach for
//!   gesture recognition", IEEE PAMI 1999): an ergodic HMM over every action's
//!   states ([`threshold_hmm`]) explains any sequence of the library's poses in
//!   any order, so it beats every action model on a motion that follows none
//!   of them, and loses on a known one, whose order it does not know; reject
//!   while the log-likelihood ratio `max_a ℓ_a(t) − ℓ_T(t)` is below a
//!   threshold (Lee & Kim: 0).
//!
//! [`Rejection::Either`] rejects while either test does. They catch different unknowns: a motion that goes where no known action
//! goes is explained badly by every state, the threshold model's too, so only
//! the likelihood per frame rejects it; known poses in an order no action
//! follows are explained well frame by frame, so only the threshold model
//! does.

use crate::error::{RecognitionError, Result};
use phasekit_emission::Gaussian;
use phasekit_hmm::Hmm;
use serde::{Deserialize, Serialize};

/// Which test rejects unknown motions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Rejection {
    /// Never reject: always decide for the most probable action.
    Off,
    /// The likelihood-per-frame test.
    LikelihoodPerFrame,
    /// The threshold-model test.
    ThresholdModel,
    /// Either test (a motion is rejected while one of them rejects it).
    Either,
}

impl Rejection {
    /// Every test, `Off` first.
    pub const ALL: [Rejection; 4] = [
        Rejection::Off,
        Rejection::LikelihoodPerFrame,
        Rejection::ThresholdModel,
        Rejection::Either,
    ];

    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Rejection::Off => "off",
            Rejection::LikelihoodPerFrame => "likelihood-per-frame",
            Rejection::ThresholdModel => "threshold-model",
            Rejection::Either => "either",
        }
    }

    /// Parses [`Rejection::name`].
    pub fn parse(s: &str) -> Result<Self> {
        Rejection::ALL
            .into_iter()
            .find(|r| r.name() == s)
            .ok_or_else(|| RecognitionError::InvalidSetting {
                name: "rejection",
                reason: format!(
                    "`{s}` is not a rejection test (off, likelihood-per-frame, threshold-model, either)"
                ),
            })
    }
}

/// Lee & Kim's threshold model over the human-marginal HMMs of the actions:
/// the states of every action (`N` in all) with their emissions; each keeps
/// its self-transition `a_ii` and spreads `1 − a_ii` evenly over the `N − 1`
/// others; the initial distribution is uniform.
pub fn threshold_hmm(actions: &[Hmm<Gaussian>]) -> Result<Hmm<Gaussian>> {
    let Some(first) = actions.first() else {
        return Err(RecognitionError::InvalidLibrary(
            "a threshold model needs at least one action".into(),
        ));
    };
    let h = first.dim();
    let n: usize = actions.iter().map(|a| a.n_states()).sum();
    let (mut means, mut covs, mut stay) = (Vec::new(), Vec::new(), Vec::new());
    for a in actions {
        if a.dim() != h {
            return Err(RecognitionError::InvalidLibrary(format!(
                "the actions' human features differ in number ({h} and {})",
                a.dim()
            )));
        }
        let g = a.emission();
        let s = a.n_states();
        for i in 0..s {
            means.extend_from_slice(g.mean(i));
            covs.extend(g.covariance(i).transpose().iter().copied());
            stay.push(a.transition()[i * s + i]);
        }
    }
    let mut transition = vec![0.0; n * n];
    for (i, &a_ii) in stay.iter().enumerate() {
        let row = &mut transition[i * n..(i + 1) * n];
        if n == 1 {
            row[0] = 1.0;
            continue;
        }
        row.fill((1.0 - a_ii) / (n - 1) as f64);
        row[i] = a_ii;
    }
    Ok(Hmm::new(
        vec![1.0 / n as f64; n],
        transition,
        Gaussian::full(h, means, covs)?,
    )?)
}

/// The `q`-quantile of `v` (`q = 0`: the lowest, `1`: the highest; linear
/// interpolation between order statistics; `−inf` values are ordered first);
/// `None` for no value.
pub fn quantile(v: &[f64], q: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let pos = q.clamp(0.0, 1.0) * (s.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    if lo == hi || s[lo] == s[hi] {
        return Some(s[lo]);
    }
    Some(s[lo] + (pos - lo as f64) * (s[hi] - s[lo]))
}
