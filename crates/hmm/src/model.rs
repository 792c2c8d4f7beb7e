//! The HMM parameters `λ = (π, A, B)` and what follows from them directly.

use crate::error::{HmmError, Result};
use phasekit_emission::{Emission, Frames, Marginal, SequenceSet};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Format version written into serialised models; a file of another version is refused.
pub const MODEL_FORMAT_VERSION: u32 = 1;

#[derive(Serialize, Deserialize)]
struct HmmParams<E> {
    format_version: u32,
    start: Vec<f64>,
    transition: Vec<f64>,
    emission: E,
}

/// A hidden Markov model with `S` states: initial distribution `π`, transition
/// matrix `A` (row-major, `a_ij = p(z_{t+1} = j | z_t = i)`) and emissions `b_i(x)`.
///
/// Parameters are validated once, by [`Hmm::new`] (and on deserialisation).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(
    try_from = "HmmParams<E>",
    into = "HmmParams<E>",
    bound = "E: Emission + Serialize + for<'a> Deserialize<'a>"
)]
pub struct Hmm<E: Emission> {
    pub(crate) start: Vec<f64>,
    pub(crate) transition: Vec<f64>,
    pub(crate) emission: E,
    pub(crate) log_start: Vec<f64>,
    pub(crate) log_transition: Vec<f64>,
}

impl<E: Emission> TryFrom<HmmParams<E>> for Hmm<E> {
    type Error = HmmError;
    fn try_from(p: HmmParams<E>) -> Result<Self> {
        if p.format_version != MODEL_FORMAT_VERSION {
            return Err(HmmError::InvalidParameter {
                name: "format_version",
                reason: format!(
                    "model file has format version {}, this build reads version {MODEL_FORMAT_VERSION}",
                    p.format_version
                ),
            });
        }
        Hmm::new(p.start, p.transition, p.emission)
    }
}

impl<E: Emission> From<Hmm<E>> for HmmParams<E> {
    fn from(h: Hmm<E>) -> Self {
        HmmParams {
            format_version: MODEL_FORMAT_VERSION,
            start: h.start,
            transition: h.transition,
            emission: h.emission,
        }
    }
}

pub(crate) fn ln0(p: f64) -> f64 {
    if p > 0.0 {
        p.ln()
    } else {
        f64::NEG_INFINITY
    }
}

/// Checks a probability vector (entries finite, ≥ 0, sum 1 within `1e-8`).
pub(crate) fn check_distribution(name: &'static str, what: &str, p: &[f64]) -> Result<()> {
    if let Some(j) = p.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(HmmError::InvalidParameter {
            name,
            reason: format!("{what}, entry {j}: {} is not a probability", p[j]),
        });
    }
    let sum: f64 = p.iter().sum();
    if (sum - 1.0).abs() > 1e-8 {
        return Err(HmmError::InvalidParameter {
            name,
            reason: format!("{what} sums to {sum}, not 1"),
        });
    }
    Ok(())
}

impl<E: Emission> Hmm<E> {
    /// Builds an HMM; `start` has `S` entries, `transition` is `S × S` row-major,
    /// `emission` has `S` states. Probabilities must be finite, non-negative and
    /// sum to 1 (within `1e-8`; they are then renormalised, and a vector that
    /// already sums to 1 up to rounding is kept bit for bit).
    pub fn new(start: Vec<f64>, transition: Vec<f64>, emission: E) -> Result<Self> {
        let s = emission.n_states();
        if start.len() != s {
            return Err(HmmError::InvalidParameter {
                name: "start",
                reason: format!("{} entries for an emission with {s} states", start.len()),
            });
        }
        if transition.len() != s * s {
            return Err(HmmError::InvalidParameter {
                name: "transition",
                reason: format!(
                    "{} entries, expected {s} × {s} = {}",
                    transition.len(),
                    s * s
                ),
            });
        }
        check_distribution("start", "initial distribution", &start)?;
        for (i, row) in transition.chunks_exact(s).enumerate() {
            check_distribution("transition", &format!("row {i}"), row)?;
        }
        let mut hmm = Hmm {
            start,
            transition,
            emission,
            log_start: Vec::new(),
            log_transition: Vec::new(),
        };
        hmm.normalise();
        Ok(hmm)
    }

    /// Renormalises `π` and the rows of `A` and refreshes their logarithms.
    ///
    /// A vector that already sums to 1 up to rounding is kept bit for bit, so
    /// that renormalising is idempotent: a model saved and loaded again (or
    /// rebuilt from its own parameters) is bit-identical.
    pub(crate) fn normalise(&mut self) {
        fn renormalise(p: &mut [f64]) {
            let total: f64 = p.iter().sum();
            if (total - 1.0).abs() > 4.0 * f64::EPSILON * p.len() as f64 {
                p.iter_mut().for_each(|v| *v /= total);
            }
        }
        let s = self.n_states();
        renormalise(&mut self.start);
        for row in self.transition.chunks_exact_mut(s) {
            renormalise(row);
        }
        self.log_start = self.start.iter().map(|p| ln0(*p)).collect();
        self.log_transition = self.transition.iter().map(|p| ln0(*p)).collect();
    }

    /// Number of states `S`.
    pub fn n_states(&self) -> usize {
        self.start.len()
    }

    /// Frame dimension `D`.
    pub fn dim(&self) -> usize {
        self.emission.dim()
    }

    /// Initial distribution `π`.
    pub fn start(&self) -> &[f64] {
        &self.start
    }

    /// Transition matrix `A`, `S × S` row-major.
    pub fn transition(&self) -> &[f64] {
        &self.transition
    }

    /// The emission distributions.
    pub fn emission(&self) -> &E {
        &self.emission
    }

    /// Consumes the model and returns its parts `(π, A, B)`.
    pub fn into_parts(self) -> (Vec<f64>, Vec<f64>, E) {
        (self.start, self.transition, self.emission)
    }

    /// Validates a sequence against the model: non-empty, right dimension, in the emission's support.
    pub fn check_sequence(&self, seq: Frames<'_>) -> Result<()> {
        if seq.is_empty() {
            return Err(HmmError::EmptySequence { sequence: 0 });
        }
        self.emission.check_frames(seq)?;
        Ok(())
    }

    /// Validates every sequence of a set, naming the first bad one.
    pub fn check_sequences(&self, data: &SequenceSet) -> Result<()> {
        if data.is_empty() {
            return Err(HmmError::NoData);
        }
        for (k, seq) in data.iter().enumerate() {
            self.check_sequence(seq).map_err(|e| e.in_sequence(k))?;
        }
        Ok(())
    }

    /// Number of free parameters `p`:
    ///
    /// `p = (nnz(π) − 1) + Σ_i (nnz(A_i·) − 1) + p_B`,
    ///
    /// with `nnz` the number of non-zero entries and `p_B` the emission's
    /// [`Emission::n_parameters`]. A zero of `π` or `A` is structural: Baum-Welch
    /// keeps it at zero (its expected count is zero), so it is not estimated, and
    /// each distribution's entries are tied by summing to 1. A left-right chain
    /// with `S` states (`a_ii`, `a_{i,i+1}`, last state absorbing) and `π = e_0`
    /// thus has `S − 1` free chain parameters instead of `S² − 1`.
    ///
    /// hmmlearn's `_get_n_fit_scalars_per_param` counts `(S − 1) + S (S − 1)`
    /// whatever the zeros; for a model without zeros the two agree, and
    /// [`Hmm::n_parameters_dense`] gives hmmlearn's count.
    pub fn n_parameters(&self) -> usize {
        let s = self.n_states();
        // Every row sums to 1, so it has at least one non-zero entry.
        let free = |p: &[f64]| p.iter().filter(|v| **v != 0.0).count().saturating_sub(1);
        free(&self.start)
            + self.transition.chunks_exact(s).map(free).sum::<usize>()
            + self.emission.n_parameters()
    }

    /// hmmlearn's parameter count `(S − 1) + S (S − 1) + p_B`, which also
    /// counts the structural zeros of `π` and `A` (see [`Hmm::n_parameters`]).
    pub fn n_parameters_dense(&self) -> usize {
        let s = self.n_states();
        (s - 1) + s * (s - 1) + self.emission.n_parameters()
    }

    /// Akaike information criterion `−2 log p(X) + 2 p`, with `p` from [`Hmm::n_parameters`].
    pub fn aic(&self, data: &SequenceSet) -> Result<f64> {
        Ok(-2.0 * self.log_likelihood_all(data)? + 2.0 * self.n_parameters() as f64)
    }

    /// Bayesian information criterion `−2 log p(X) + p log N` with `N` the
    /// total number of frames and `p` from [`Hmm::n_parameters`].
    pub fn bic(&self, data: &SequenceSet) -> Result<f64> {
        Ok(-2.0 * self.log_likelihood_all(data)?
            + self.n_parameters() as f64 * (data.total_frames() as f64).ln())
    }

    /// Draws a sequence of `len` frames; returns the frames (`len × D` row-major) and the states.
    pub fn sample<R: Rng + ?Sized>(
        &self,
        len: usize,
        rng: &mut R,
    ) -> Result<(Vec<f64>, Vec<usize>)> {
        let (s, d) = (self.n_states(), self.dim());
        let mut frames = vec![0.0; len * d];
        let mut states = Vec::with_capacity(len);
        let mut z = 0;
        for t in 0..len {
            let p = if t == 0 {
                &self.start[..]
            } else {
                &self.transition[z * s..(z + 1) * s]
            };
            z = phasekit_emission::categorical::sample_index(p, rng);
            states.push(z);
            self.emission
                .sample_into(z, rng, &mut frames[t * d..(t + 1) * d])?;
        }
        Ok((frames, states))
    }
}

impl<E: Marginal> Hmm<E> {
    /// The same chain with emissions restricted to the dimensions `dims`:
    /// `b_i(x_dims) = ∫ b_i(x) dx_rest`. Used to run a joint human–robot model
    /// on the human's dimensions only.
    pub fn marginal(&self, dims: &[usize]) -> Result<Self> {
        Hmm::new(
            self.start.clone(),
            self.transition.clone(),
            self.emission.marginal(dims)?,
        )
    }
}
