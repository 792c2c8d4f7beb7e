//! The HSMM parameters `λ = (π, A, p, B)` and what follows from them directly.

use crate::duration::{AnyDuration, Duration, NonParametricDuration};
use crate::error::{invalid, HsmmError, Result};
use crate::inference::Segment;
use phasekit_emission::{Emission, Frames, Marginal, SequenceSet};
use phasekit_hmm::Hmm;
use rand::Rng;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// Format version written into serialised models; a file of another version is refused.
pub const HSMM_FORMAT_VERSION: u32 = 1;

/// How the last segment of a sequence is scored.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Censoring {
    /// The sequence may end while its last segment is still going on: the
    /// last segment, observed for `d` frames, is scored by the survival
    /// function `P(D_i ≥ d) = Σ_{d' ≥ d} p_i(d')` (right-censoring). This is
    /// what an HMM does implicitly, so that an HSMM with geometric durations
    /// equals the HMM; and a recording cut before the state would have ended
    /// is not mistaken for a short visit. EM imputes the unobserved rest of
    /// the visit: a censored visit of `d` frames adds
    /// `p_i(d') / P(D_i ≥ d)` to the count of every duration `d' ≥ d`.
    #[default]
    RightCensored,
    /// Every sequence ends exactly when a segment ends: the last segment is
    /// scored by `p_i(d)` like the others (e.g. demonstrations trimmed at the
    /// end of the motion).
    EndsWithSegment,
}

#[derive(Serialize, Deserialize)]
struct HsmmParams<E, D> {
    format_version: u32,
    start: Vec<f64>,
    transition: Vec<f64>,
    censoring: Censoring,
    durations: D,
    emission: E,
}

/// A hidden semi-Markov model (explicit-duration HMM) with `S` states.
///
/// * `π`: the state of the first segment;
/// * `A`: transitions between segments, `a_ij = p(next segment is j | segment of i ends)`,
///   with `a_ii = 0` (the length of a visit is its duration, not a self-loop).
///   A row of zeros makes `i` **terminal**: a segment of `i` can only be the
///   last one (the last state of a left-right interaction model);
/// * `p_i(d)`, `d = 1..=D`: the [`Duration`] of a visit to state `i`;
/// * `b_i(x)`: the [`Emission`] of every frame of a visit to `i`;
/// * the [`Censoring`] of the last segment.
///
/// Parameters are validated once, by [`Hsmm::new`] (and on deserialisation).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(
    try_from = "HsmmParams<E, D>",
    into = "HsmmParams<E, D>",
    bound = "E: Emission + Serialize + DeserializeOwned, D: Duration + Serialize + DeserializeOwned"
)]
pub struct Hsmm<E: Emission, D: Duration = AnyDuration> {
    pub(crate) start: Vec<f64>,
    pub(crate) transition: Vec<f64>,
    pub(crate) durations: D,
    pub(crate) emission: E,
    pub(crate) censoring: Censoring,
    pub(crate) tables: Tables,
}

/// Logarithms of the parameters in the layouts the recursions read.
#[derive(Debug, Clone, Default)]
pub(crate) struct Tables {
    /// `log π_i`.
    pub(crate) log_start: Vec<f64>,
    /// `log a_ij`, `S × S` row-major.
    pub(crate) log_transition: Vec<f64>,
    /// `log a_ji` at `[i·S + j]` (columns of `A` contiguous).
    pub(crate) log_transition_t: Vec<f64>,
    /// `log p_i(d)` at `[i·D + d − 1]`.
    pub(crate) log_pmf: Vec<f64>,
    /// `log P(D_i ≥ d)` at `[i·D + d − 1]`.
    pub(crate) log_survival: Vec<f64>,
    /// The weight of the last segment: `log_survival` or `log_pmf` by censoring.
    pub(crate) log_last: Vec<f64>,
    /// `p_i(d)`, linear (0 below the smallest double).
    pub(crate) pmf: Vec<f64>,
    /// `P(D_i ≥ d)`, linear.
    pub(crate) survival: Vec<f64>,
}

impl<E: Emission, D: Duration> TryFrom<HsmmParams<E, D>> for Hsmm<E, D> {
    type Error = HsmmError;
    fn try_from(p: HsmmParams<E, D>) -> Result<Self> {
        if p.format_version != HSMM_FORMAT_VERSION {
            return Err(invalid(
                "format_version",
                format!(
                    "model file has format version {}, this build reads version {HSMM_FORMAT_VERSION}",
                    p.format_version
                ),
            ));
        }
        Ok(Hsmm::new(p.start, p.transition, p.durations, p.emission)?.with_censoring(p.censoring))
    }
}

impl<E: Emission, D: Duration> From<Hsmm<E, D>> for HsmmParams<E, D> {
    fn from(h: Hsmm<E, D>) -> Self {
        HsmmParams {
            format_version: HSMM_FORMAT_VERSION,
            start: h.start,
            transition: h.transition,
            censoring: h.censoring,
            durations: h.durations,
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

/// Keeps `p` bit for bit when it sums to 1 up to rounding, else divides by its sum.
pub(crate) fn renormalise(p: &mut [f64]) {
    let total: f64 = p.iter().sum();
    if total > 0.0 && (total - 1.0).abs() > 4.0 * f64::EPSILON * p.len() as f64 {
        p.iter_mut().for_each(|v| *v /= total);
    }
}

/// Checks a probability vector (entries finite, ≥ 0, sum 1 within `1e-8`).
fn check_distribution(name: &'static str, what: &str, p: &[f64]) -> Result<()> {
    if let Some(j) = p.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(invalid(
            name,
            format!("{what}, entry {j}: {} is not a probability", p[j]),
        ));
    }
    let sum: f64 = p.iter().sum();
    if (sum - 1.0).abs() > 1e-8 {
        return Err(invalid(name, format!("{what} sums to {sum}, not 1")));
    }
    Ok(())
}

impl<E: Emission, D: Duration> Hsmm<E, D> {
    /// Builds an HSMM (right-censored; see [`Hsmm::with_censoring`]).
    ///
    /// `start` has `S` entries; `transition` is `S × S` row-major with a zero
    /// diagonal, every row either summing to 1 or all zeros (a terminal
    /// state); `durations` and `emission` have `S` states. Probabilities must
    /// be finite and non-negative and sum to 1 within `1e-8` (they are then
    /// renormalised; one that sums to 1 up to rounding is kept bit for bit).
    /// Every duration pmf must sum to 1 within `1e-8` over `1..=D`.
    pub fn new(start: Vec<f64>, transition: Vec<f64>, durations: D, emission: E) -> Result<Self> {
        let s = emission.n_states();
        if s == 0 {
            return Err(invalid("emission", "the emission has no state"));
        }
        if durations.n_states() != s {
            return Err(invalid(
                "durations",
                format!(
                    "{} duration distributions for an emission with {s} states",
                    durations.n_states()
                ),
            ));
        }
        if durations.max_duration() == 0 {
            return Err(invalid("durations", "the maximum duration is 0"));
        }
        if start.len() != s {
            return Err(invalid(
                "start",
                format!("{} entries for an emission with {s} states", start.len()),
            ));
        }
        if transition.len() != s * s {
            return Err(invalid(
                "transition",
                format!(
                    "{} entries, expected {s} × {s} = {}",
                    transition.len(),
                    s * s
                ),
            ));
        }
        check_distribution("start", "initial distribution", &start)?;
        for (i, row) in transition.chunks_exact(s).enumerate() {
            if row[i] != 0.0 {
                return Err(invalid(
                    "transition",
                    format!(
                        "row {i}: a_{i}{i} = {} but an HSMM has no self-transitions (a visit's \
                         length is its duration); set it to 0",
                        row[i]
                    ),
                ));
            }
            if row.iter().all(|v| *v == 0.0) {
                continue;
            }
            check_distribution(
                "transition",
                &format!("row {i} (neither all zero, for a terminal state, nor a distribution)"),
                row,
            )?;
        }
        let mut hsmm = Hsmm {
            start,
            transition,
            durations,
            emission,
            censoring: Censoring::default(),
            tables: Tables::default(),
        };
        hsmm.refresh()?;
        Ok(hsmm)
    }

    /// The same model with the last segment scored by `censoring`.
    pub fn with_censoring(mut self, censoring: Censoring) -> Self {
        self.censoring = censoring;
        self.tables.log_last = match censoring {
            Censoring::RightCensored => self.tables.log_survival.clone(),
            Censoring::EndsWithSegment => self.tables.log_pmf.clone(),
        };
        self
    }

    /// Renormalises `π` and `A`, reads the duration pmfs and refreshes every table.
    pub(crate) fn refresh(&mut self) -> Result<()> {
        let s = self.n_states();
        let dm = self.durations.max_duration();
        renormalise(&mut self.start);
        for row in self.transition.chunks_exact_mut(s) {
            renormalise(row);
        }
        let t = &mut self.tables;
        t.log_start = self.start.iter().map(|p| ln0(*p)).collect();
        t.log_transition = self.transition.iter().map(|p| ln0(*p)).collect();
        t.log_transition_t = vec![0.0; s * s];
        for i in 0..s {
            for j in 0..s {
                t.log_transition_t[j * s + i] = t.log_transition[i * s + j];
            }
        }
        t.log_pmf = vec![0.0; s * dm];
        t.log_survival = vec![0.0; s * dm];
        for i in 0..s {
            let row = &mut t.log_pmf[i * dm..(i + 1) * dm];
            self.durations.log_pmf_into(i, row)?;
            if let Some(k) = row.iter().position(|v| v.is_nan() || *v == f64::INFINITY) {
                return Err(invalid(
                    "durations",
                    format!("state {i}, duration {}: log p = {}", k + 1, row[k]),
                ));
            }
            let z = crate::duration::lse(row);
            if z.is_nan() || z.abs() > 1e-8 {
                return Err(invalid(
                    "durations",
                    format!(
                        "state {i}: the duration probabilities sum to {}, not 1",
                        z.exp()
                    ),
                ));
            }
            if z.abs() > 4.0 * f64::EPSILON * dm as f64 {
                row.iter_mut().for_each(|v| *v -= z);
            }
            // Survival in log space, from the longest duration down, so that
            // tails far below e^{−745} stay exact.
            let surv = &mut t.log_survival[i * dm..(i + 1) * dm];
            let mut acc = f64::NEG_INFINITY;
            for k in (0..dm).rev() {
                acc = log_add(acc, row[k]);
                surv[k] = acc;
            }
            // P(D ≥ 1) = 1 exactly.
            surv[0] = 0.0;
        }
        t.pmf = t.log_pmf.iter().map(|l| l.exp()).collect();
        t.survival = t.log_survival.iter().map(|l| l.exp()).collect();
        t.log_last = match self.censoring {
            Censoring::RightCensored => t.log_survival.clone(),
            Censoring::EndsWithSegment => t.log_pmf.clone(),
        };
        Ok(())
    }

    /// Number of states `S`.
    pub fn n_states(&self) -> usize {
        self.start.len()
    }

    /// Frame dimension `D` of the emission.
    pub fn dim(&self) -> usize {
        self.emission.dim()
    }

    /// The maximum duration of a segment (frames).
    pub fn max_duration(&self) -> usize {
        self.durations.max_duration()
    }

    /// Initial distribution `π` (the state of the first segment).
    pub fn start(&self) -> &[f64] {
        &self.start
    }

    /// Transitions between segments `A`, `S × S` row-major, zero diagonal.
    pub fn transition(&self) -> &[f64] {
        &self.transition
    }

    /// Whether state `i` is terminal (its transition row is all zeros).
    pub fn is_terminal(&self, i: usize) -> bool {
        let s = self.n_states();
        i < s
            && self.transition[i * s..(i + 1) * s]
                .iter()
                .all(|v| *v == 0.0)
    }

    /// The duration distributions.
    pub fn durations(&self) -> &D {
        &self.durations
    }

    /// The emission distributions.
    pub fn emission(&self) -> &E {
        &self.emission
    }

    /// How the last segment is scored.
    pub fn censoring(&self) -> Censoring {
        self.censoring
    }

    /// `log p_i(d)` for `d = 1..=D` (`D` entries).
    pub fn duration_log_pmf(&self, state: usize) -> Result<&[f64]> {
        self.check_state(state)?;
        let dm = self.max_duration();
        Ok(&self.tables.log_pmf[state * dm..(state + 1) * dm])
    }

    /// `log P(D_i ≥ d)` for `d = 1..=D` (`D` entries).
    pub fn duration_log_survival(&self, state: usize) -> Result<&[f64]> {
        self.check_state(state)?;
        let dm = self.max_duration();
        Ok(&self.tables.log_survival[state * dm..(state + 1) * dm])
    }

    /// Mean duration `Σ_d d p_i(d)` of every state (frames).
    pub fn mean_durations(&self) -> Vec<f64> {
        let dm = self.max_duration();
        self.tables
            .log_pmf
            .chunks_exact(dm)
            .map(|row| {
                row.iter()
                    .enumerate()
                    .map(|(k, l)| (k + 1) as f64 * l.exp())
                    .sum()
            })
            .collect()
    }

    fn check_state(&self, state: usize) -> Result<()> {
        if state < self.n_states() {
            Ok(())
        } else {
            Err(invalid(
                "state",
                format!(
                    "state {state} out of range (the model has {} states)",
                    self.n_states()
                ),
            ))
        }
    }

    /// Consumes the model and returns its parts `(π, A, durations, emission)`.
    pub fn into_parts(self) -> (Vec<f64>, Vec<f64>, D, E) {
        (self.start, self.transition, self.durations, self.emission)
    }

    /// The same model with emissions restricted to the dimensions `dims`:
    /// `b_i(x_dims) = ∫ b_i(x) dx_rest`. Used to run a joint human–robot
    /// model on the human's dimensions only.
    pub fn marginal(&self, dims: &[usize]) -> Result<Self>
    where
        E: Marginal,
    {
        Ok(Hsmm::new(
            self.start.clone(),
            self.transition.clone(),
            self.durations.clone(),
            self.emission.marginal(dims)?,
        )?
        .with_censoring(self.censoring))
    }

    /// Validates a sequence: non-empty, right dimension, in the emission's support.
    pub fn check_sequence(&self, seq: Frames<'_>) -> Result<()> {
        if seq.is_empty() {
            return Err(HsmmError::EmptySequence { sequence: 0 });
        }
        self.emission.check_frames(seq)?;
        Ok(())
    }

    /// Validates every sequence of a set, naming the first bad one.
    pub fn check_sequences(&self, data: &SequenceSet) -> Result<()> {
        if data.is_empty() {
            return Err(HsmmError::NoData);
        }
        for (k, seq) in data.iter().enumerate() {
            self.check_sequence(seq).map_err(|e| e.in_sequence(k))?;
        }
        Ok(())
    }

    /// Number of free parameters:
    /// `(nnz(π) − 1) + Σ_i max(nnz(A_i·) − 1, 0) + p_durations + p_B`.
    /// Zeros of `π` and `A` are structural (EM keeps them), the diagonal of
    /// `A` is zero by definition, and a terminal state's row is not estimated.
    pub fn n_parameters(&self) -> usize {
        let s = self.n_states();
        let free = |p: &[f64]| p.iter().filter(|v| **v != 0.0).count().saturating_sub(1);
        free(&self.start)
            + self.transition.chunks_exact(s).map(free).sum::<usize>()
            + self.durations.n_parameters()
            + self.emission.n_parameters()
    }

    /// Akaike information criterion `−2 log p(X) + 2 p`.
    pub fn aic(&self, data: &SequenceSet) -> Result<f64> {
        Ok(-2.0 * self.log_likelihood_all(data)? + 2.0 * self.n_parameters() as f64)
    }

    /// Bayesian information criterion `−2 log p(X) + p log N`, `N` the total number of frames.
    pub fn bic(&self, data: &SequenceSet) -> Result<f64> {
        Ok(-2.0 * self.log_likelihood_all(data)?
            + self.n_parameters() as f64 * (data.total_frames() as f64).ln())
    }

    /// Draws a sequence of `len` frames: segments from `π`, `p_i` and `A`,
    /// frames from the emission. Returns the frames (`len × D` row-major), the
    /// state of every frame and the segments. A terminal state, having no
    /// successor, lasts until the end of the sample; the last segment is cut
    /// at `len` frames.
    pub fn sample<R: Rng + ?Sized>(
        &self,
        len: usize,
        rng: &mut R,
    ) -> Result<(Vec<f64>, Vec<usize>, Vec<Segment>)> {
        let (s, d) = (self.n_states(), self.dim());
        let dm = self.max_duration();
        let pmf: Vec<f64> = self.tables.log_pmf.iter().map(|l| l.exp()).collect();
        let mut frames = vec![0.0; len * d];
        let mut states = Vec::with_capacity(len);
        let mut segments = Vec::new();
        let mut z = phasekit_emission::categorical::sample_index(&self.start, rng);
        let mut t = 0;
        while t < len {
            let duration = if self.is_terminal(z) {
                len - t
            } else {
                1 + phasekit_emission::categorical::sample_index(&pmf[z * dm..(z + 1) * dm], rng)
            };
            let end = (t + duration).min(len);
            segments.push(Segment {
                state: z,
                start: t,
                len: end - t,
            });
            for u in t..end {
                states.push(z);
                self.emission
                    .sample_into(z, rng, &mut frames[u * d..(u + 1) * d])?;
            }
            t = end;
            if t < len {
                z = phasekit_emission::categorical::sample_index(
                    &self.transition[z * s..(z + 1) * s],
                    rng,
                );
            }
        }
        Ok((frames, states, segments))
    }
}

/// `log(e^a + e^b)`, exact for `−inf`.
pub(crate) fn log_add(a: f64, b: f64) -> f64 {
    let (hi, lo) = if a >= b { (a, b) } else { (b, a) };
    if lo == f64::NEG_INFINITY {
        hi
    } else {
        hi + (lo - hi).exp().ln_1p()
    }
}

impl<E: Emission, D: Duration + From<NonParametricDuration>> Hsmm<E, D> {
    /// The HSMM equivalent to an HMM on sequences of at most `max_duration` frames.
    ///
    /// A visit to state `i` of the HMM lasts `d` frames with the geometric
    /// probability `(1 − a_ii) a_ii^{d−1}`, then moves to `j ≠ i` with
    /// `a_ij / (1 − a_ii)`. The durations here are that geometric pmf on
    /// `1..D` with the tail `a_ii^{D−1}` lumped at `D`, so that
    /// `P(D_i ≥ d) = a_ii^{d−1}` for every `d ≤ D`: with right-censoring, the
    /// likelihood and posteriors equal the HMM's on sequences of at most `D`
    /// frames (on longer ones, the HSMM ends every visit by `D` frames). A
    /// state with `a_ii = 1` becomes terminal, all its mass at `D`.
    pub fn from_hmm(hmm: &Hmm<E>, max_duration: usize) -> Result<Self> {
        let s = hmm.n_states();
        let dm = max_duration;
        if dm == 0 {
            return Err(invalid(
                "max_duration",
                "the maximum duration must be at least 1 frame",
            ));
        }
        let a = hmm.transition();
        let mut transition = vec![0.0; s * s];
        let mut pmf = vec![0.0; s * dm];
        for i in 0..s {
            let stay = a[i * s + i];
            let leave = 1.0 - stay;
            if stay < 1.0 {
                for j in 0..s {
                    if j != i {
                        transition[i * s + j] = a[i * s + j] / leave;
                    }
                }
            }
            let row = &mut pmf[i * dm..(i + 1) * dm];
            let mut p_stay = 1.0;
            for (k, p) in row.iter_mut().enumerate() {
                *p = if k + 1 < dm { leave * p_stay } else { p_stay };
                p_stay *= stay;
            }
        }
        let durations = NonParametricDuration::new(dm, pmf)?;
        Hsmm::new(
            hmm.start().to_vec(),
            transition,
            D::from(durations),
            hmm.emission().clone(),
        )
    }
}
