//! Baum-Welch (EM) over many sequences, with a parallel, deterministic E-step.
//!
//! E-step: for every sequence the posteriors `γ`, expected transitions `Σ_t ξ_t`
//! and emission statistics `Σ_t γ_t(i) φ(x_t)`. Sequences are grouped into
//! blocks of consecutive sequences that depend only on the data (never on the
//! number of threads); blocks run in parallel and their statistics are merged
//! in block order, so the result is bit-identical for any thread count.
//!
//! M-step: `π_i = Σ_k γ^k_0(i) / K`, `a_ij = Σ ξ(i,j) / Σ_j' Σ ξ(i,j')` (zeros
//! of `A` stay zero), and the emission's own M-step with the regularisation.

use crate::error::{HmmError, Result};
use crate::inference::formulas::{start_update, transition_update};
use crate::inference::{LaneWorkspace, PosteriorWorkspace, LANE_MAX_FRAMES};
use crate::init::{initialise, HmmInit};
use crate::model::Hmm;
use phasekit_emission::restarts::best_of_restarts;
use phasekit_emission::{Emission, MStepReport, Regularisation, SequenceSet, SufficientStatistics};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Frames per E-step block: blocks are consecutive sequences holding at least this many frames.
const BLOCK_FRAMES: usize = 4096;

/// Sequences per group of the lane form (one per SIMD lane).
const LANE_WIDTH: usize = 8;

/// The fewest consecutive sequences worth running through the lane form.
const LANE_MIN_GROUP: usize = 2;

/// What [`Hmm::step_counts`] counts.
#[doc(hidden)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StepCounts {
    /// Sequences the lane form finished.
    pub lanes: usize,
    /// Sequences the lane form handed back to the per-sequence path.
    pub lanes_redone: usize,
    /// Sequences that went to the per-sequence path directly.
    pub per_sequence: usize,
    /// Forward steps of the per-sequence path in the fast form.
    pub forward_fast: usize,
    /// Forward steps of the per-sequence path in the general form.
    pub forward_general: usize,
    /// Backward steps of the per-sequence path in the fast form.
    pub backward_fast: usize,
    /// Backward steps of the per-sequence path in the general form.
    pub backward_general: usize,
}

/// Buffers of [`Hmm::accumulate_group`], reused from group to group.
#[derive(Default)]
struct GroupScratch {
    lens: Vec<usize>,
    log_b: Vec<f64>,
    gamma: Vec<f64>,
    xi: Vec<f64>,
}

/// The scale on which the log-likelihood gain is compared with the tolerance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Convergence {
    /// `log p(X)` summed over sequences (hmmlearn).
    Total,
    /// Mean over sequences of `log p(x^k)` (the paper-compatible protocol).
    MeanPerSequence,
    /// `log p(X)` divided by the number of frames.
    MeanPerFrame,
}

/// Which parameters the M-step re-estimates (the others stay frozen).
///
/// A plain value: every combination of the three flags is valid, so the
/// fields are public and there is nothing to validate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Update {
    /// Re-estimate the initial distribution `π`.
    pub start: bool,
    /// Re-estimate the transition matrix `A`.
    pub transition: bool,
    /// Re-estimate the emissions.
    pub emission: bool,
}

impl Default for Update {
    fn default() -> Self {
        Update {
            start: true,
            transition: true,
            emission: true,
        }
    }
}

/// Expected sufficient statistics of an E-step over a set of sequences.
///
/// The fields are public so that statistics computed elsewhere (another
/// process, a streaming accumulator) can be merged and maximised;
/// [`ExpectedStatistics::merge`] and [`Hmm::maximise`] check their shapes.
#[derive(Debug, Clone)]
pub struct ExpectedStatistics<S> {
    /// `Σ_k log p(x^k)`.
    pub log_likelihood: f64,
    /// `Σ_k γ^k_0(i)`.
    pub start: Vec<f64>,
    /// `Σ_k Σ_t ξ^k_t(i, j)`, `S × S`.
    pub transitions: Vec<f64>,
    /// Emission statistics.
    pub emission: S,
    /// Number of sequences.
    pub n_sequences: usize,
    /// Number of frames.
    pub n_frames: usize,
}

/// Errors unless a statistics vector has the length the model needs.
fn check_stats_len(name: &'static str, expected: usize, found: usize) -> Result<()> {
    if expected == found {
        Ok(())
    } else {
        Err(HmmError::InvalidParameter {
            name,
            reason: format!("{found} entries, expected {expected}"),
        })
    }
}

impl<S: SufficientStatistics> ExpectedStatistics<S> {
    /// Number of states `S` these statistics are shaped for (`start.len()`).
    pub fn n_states(&self) -> usize {
        self.start.len()
    }

    /// Checks that `start` has `s` entries and `transitions` `s × s`.
    fn check_shape(&self, s: usize) -> Result<()> {
        check_stats_len("start statistics", s, self.start.len())?;
        check_stats_len("transition statistics", s * s, self.transitions.len())
    }

    /// Adds `other` (statistics of other sequences under the same model):
    /// every count is the sum of the two.
    ///
    /// Errors, leaving `self` unchanged, when the two are shaped for different
    /// models (number of states, or the emission's own shape), instead of
    /// silently adding only the common prefix.
    pub fn merge(&mut self, other: &Self) -> Result<()> {
        let s = self.n_states();
        self.check_shape(s)?;
        other.check_shape(s).map_err(|e| match e {
            HmmError::InvalidParameter { name, reason } => HmmError::InvalidParameter {
                name,
                reason: format!("cannot merge statistics of another model: {reason}"),
            },
            e => e,
        })?;
        // The emission merge is the only other fallible step and checks its
        // shapes before adding, so doing it first keeps `self` unchanged on error.
        self.emission.merge(&other.emission)?;
        self.log_likelihood += other.log_likelihood;
        for (a, b) in self.start.iter_mut().zip(&other.start) {
            *a += b;
        }
        for (a, b) in self.transitions.iter_mut().zip(&other.transitions) {
            *a += b;
        }
        self.n_sequences += other.n_sequences;
        self.n_frames += other.n_frames;
        Ok(())
    }
}

/// Splits sequences into blocks of consecutive sequences with at least `BLOCK_FRAMES` frames.
fn blocks(data: &SequenceSet) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut start = 0;
    let mut frames = 0;
    for (k, len) in data.lengths().enumerate() {
        frames += len;
        if frames >= BLOCK_FRAMES {
            out.push(start..k + 1);
            start = k + 1;
            frames = 0;
        }
    }
    if start < data.len() {
        out.push(start..data.len());
    }
    out
}

impl<E: Emission> Hmm<E> {
    fn empty_statistics(&self) -> ExpectedStatistics<E::Stats> {
        let s = self.n_states();
        ExpectedStatistics {
            log_likelihood: 0.0,
            start: vec![0.0; s],
            transitions: vec![0.0; s * s],
            emission: self.emission.new_stats(),
            n_sequences: 0,
            n_frames: 0,
        }
    }

    /// Adds sequence `k` to `acc`: its log-likelihood, first-frame
    /// posteriors, expected transitions and emission statistics.
    fn accumulate_sequence(
        &self,
        k: usize,
        data: &SequenceSet,
        ws: &mut PosteriorWorkspace,
        acc: &mut ExpectedStatistics<E::Stats>,
    ) -> Result<()> {
        let seq = data.get(k);
        self.emission
            .log_density_into(seq, ws.log_b_for(seq.len()))
            .map_err(|e| HmmError::from(e).in_sequence(k))?;
        let ll = ws.run().map_err(|e| e.in_sequence(k))?;
        self.add_posteriors(k, data, ll, &ws.gamma, &ws.xi, acc)
    }

    /// Adds the posteriors of sequence `k` (`log p(x)`, `γ`, `Σ_t ξ_t`) and
    /// its emission statistics to `acc`.
    fn add_posteriors(
        &self,
        k: usize,
        data: &SequenceSet,
        ll: f64,
        gamma: &[f64],
        xi: &[f64],
        acc: &mut ExpectedStatistics<E::Stats>,
    ) -> Result<()> {
        let seq = data.get(k);
        let s = self.n_states();
        acc.log_likelihood += ll;
        for (a, g) in acc.start.iter_mut().zip(&gamma[..s]) {
            *a += g;
        }
        for (a, x) in acc.transitions.iter_mut().zip(xi) {
            *a += x;
        }
        acc.n_sequences += 1;
        acc.n_frames += seq.len();
        self.emission
            .accumulate(seq, gamma, &mut acc.emission)
            .map_err(|e| HmmError::from(e).in_sequence(k))
    }

    /// Adds the sequences `group` (at most [`W`](crate::inference) of them)
    /// to `acc` through the lane form ([`LaneWorkspace`]), in sequence
    /// order; a sequence that leaves the lane form's fast steps goes through
    /// the per-sequence path (the same bits either way). If a log-density
    /// fails, the whole group goes through the per-sequence path, so that
    /// errors are reported in sequence order.
    fn accumulate_group(
        &self,
        group: std::ops::Range<usize>,
        data: &SequenceSet,
        lanes: &mut LaneWorkspace,
        scratch: &mut GroupScratch,
        ws: &mut PosteriorWorkspace,
        acc: &mut ExpectedStatistics<E::Stats>,
    ) -> Result<()> {
        let s = self.n_states();
        scratch.lens.clear();
        scratch
            .lens
            .extend(group.clone().map(|k| data.get(k).len()));
        lanes.begin(&scratch.lens);
        let mut loaded = true;
        for (l, k) in group.clone().enumerate() {
            let seq = data.get(k);
            scratch.log_b.resize(seq.len() * s, 0.0);
            if self
                .emission
                .log_density_into(seq, &mut scratch.log_b)
                .is_err()
            {
                loaded = false;
                break;
            }
            lanes.load(l, &scratch.log_b);
        }
        if !loaded {
            for k in group {
                self.accumulate_sequence(k, data, ws, acc)?;
            }
            return Ok(());
        }
        let ok = lanes.run();
        scratch.xi.resize(s * s, 0.0);
        for (l, k) in group.enumerate() {
            if ok[l] {
                let ll = lanes.log_likelihood(l);
                lanes.gamma_into(l, &mut scratch.gamma);
                lanes.xi_into(l, &mut scratch.xi);
                self.add_posteriors(k, data, ll, &scratch.gamma, &scratch.xi, acc)?;
            } else {
                self.accumulate_sequence(k, data, ws, acc)?;
            }
        }
        Ok(())
    }

    /// The statistics of one block of consecutive sequences: groups of up
    /// to eight consecutive sequences of at most `LANE_MAX_FRAMES` frames
    /// through the lane form when the model admits it, the others one by one.
    fn block_statistics(
        &self,
        range: std::ops::Range<usize>,
        data: &SequenceSet,
    ) -> Result<ExpectedStatistics<E::Stats>> {
        let mut acc = self.empty_statistics();
        let mut ws = PosteriorWorkspace::new(self);
        let mut lanes = LaneWorkspace::new(self);
        let mut scratch = GroupScratch::default();
        let mut k = range.start;
        while k < range.end {
            let end = self.group_end(&lanes, data, k, range.end);
            if end - k >= LANE_MIN_GROUP {
                self.accumulate_group(k..end, data, &mut lanes, &mut scratch, &mut ws, &mut acc)?;
                k = end;
            } else {
                self.accumulate_sequence(k, data, &mut ws, &mut acc)?;
                k += 1;
            }
        }
        Ok(acc)
    }

    /// Diagnostics of the E-step's paths (for benchmarks, not a stable
    /// interface): how many sequences the lane form finished, how many it
    /// handed back to the per-sequence path, and the per-sequence path's
    /// forward and backward steps in their fast and general forms. Runs the
    /// E-step's recursions once, on the current thread, without statistics.
    #[doc(hidden)]
    pub fn step_counts(&self, data: &SequenceSet) -> Result<StepCounts> {
        let mut counts = StepCounts::default();
        let mut ws = PosteriorWorkspace::new(self);
        let mut lanes = LaneWorkspace::new(self);
        let mut scratch = GroupScratch::default();
        let s = self.n_states();
        let one = |k: usize, ws: &mut PosteriorWorkspace| -> Result<()> {
            let seq = data.get(k);
            self.emission
                .log_density_into(seq, ws.log_b_for(seq.len()))
                .map_err(|e| HmmError::from(e).in_sequence(k))?;
            ws.run().map_err(|e| e.in_sequence(k))?;
            Ok(())
        };
        for range in blocks(data) {
            let mut k = range.start;
            while k < range.end {
                let end = self.group_end(&lanes, data, k, range.end);
                if end - k < LANE_MIN_GROUP {
                    one(k, &mut ws)?;
                    counts.per_sequence += 1;
                    k += 1;
                    continue;
                }
                scratch.lens.clear();
                scratch.lens.extend((k..end).map(|q| data.get(q).len()));
                lanes.begin(&scratch.lens);
                for (l, q) in (k..end).enumerate() {
                    let seq = data.get(q);
                    scratch.log_b.resize(seq.len() * s, 0.0);
                    self.emission.log_density_into(seq, &mut scratch.log_b)?;
                    lanes.load(l, &scratch.log_b);
                }
                let ok = lanes.run();
                for (l, q) in (k..end).enumerate() {
                    if ok[l] {
                        counts.lanes += 1;
                    } else {
                        counts.lanes_redone += 1;
                        one(q, &mut ws)?;
                    }
                }
                k = end;
            }
        }
        let [ff, fg, bf, bg] = ws.step_counts();
        counts.forward_fast = ff;
        counts.forward_general = fg;
        counts.backward_fast = bf;
        counts.backward_general = bg;
        Ok(counts)
    }

    /// The end of the lane group that starts at sequence `k` (`k` itself
    /// when the model or the sequence does not admit the lane form).
    fn group_end(&self, lanes: &LaneWorkspace, data: &SequenceSet, k: usize, end: usize) -> usize {
        let mut e = k;
        if lanes.usable() {
            while e < end && e - k < LANE_WIDTH && data.get(e).len() <= LANE_MAX_FRAMES {
                e += 1;
            }
        }
        e
    }

    /// The E-step over all sequences, in parallel on the current rayon pool;
    /// bit-identical whatever the number of threads. Data must have passed
    /// [`Hmm::check_sequences`].
    ///
    /// Sequences are grouped into blocks of consecutive sequences that
    /// depend only on the data; every block's statistics are accumulated
    /// sequence by sequence and the blocks are merged in their order, so the
    /// grouping of the work over threads changes no bit. On one thread (or
    /// with one block) the blocks run in place, without the pool.
    pub fn expected_statistics(&self, data: &SequenceSet) -> Result<ExpectedStatistics<E::Stats>> {
        self.e_step(data, false)
    }

    /// [`Hmm::expected_statistics`], on the current thread alone when
    /// `serial` (the same bits: the blocks are merged in order either way).
    fn e_step(&self, data: &SequenceSet, serial: bool) -> Result<ExpectedStatistics<E::Stats>> {
        let ranges = blocks(data);
        let parts: Vec<Result<ExpectedStatistics<E::Stats>>> =
            if serial || ranges.len() == 1 || rayon::current_num_threads() == 1 {
                ranges
                    .into_iter()
                    .map(|range| self.block_statistics(range, data))
                    .collect()
            } else {
                ranges
                    .into_par_iter()
                    .map(|range| self.block_statistics(range, data))
                    .collect()
            };
        let mut parts = parts.into_iter();
        let mut total = parts
            .next()
            .unwrap_or_else(|| Ok(self.empty_statistics()))?;
        for part in parts {
            total.merge(&part?)?;
        }
        Ok(total)
    }

    /// The M-step: new parameters from expected statistics,
    /// `π_i = s_i / Σ_j s_j` ([`start_update`]) and
    /// `a_ij = ξ_ij / Σ_j' ξ_ij'` ([`transition_update`]), then the emission's
    /// M-step. Frozen parts are kept; a transition row with no expected visits
    /// keeps its previous values.
    ///
    /// Errors (naming the vector) when `stats` is shaped for another number of
    /// states, or holds a negative or non-finite count.
    pub fn maximise(
        &self,
        stats: &ExpectedStatistics<E::Stats>,
        update: Update,
        reg: &Regularisation,
    ) -> Result<(Hmm<E>, MStepReport)> {
        let s = self.n_states();
        stats.check_shape(s).map_err(|e| match e {
            HmmError::InvalidParameter { name, reason } => HmmError::InvalidParameter {
                name,
                reason: format!("{reason} for a model with {s} states"),
            },
            e => e,
        })?;
        for (name, v) in [
            ("start statistics", &stats.start),
            ("transition statistics", &stats.transitions),
        ] {
            if let Some(j) = v.iter().position(|x| !(x.is_finite() && *x >= 0.0)) {
                return Err(HmmError::InvalidParameter {
                    name,
                    reason: format!("entry {j} is {}, not a finite non-negative count", v[j]),
                });
            }
        }
        let mut start = self.start.clone();
        let mut transition = self.transition.clone();
        if update.start {
            if let Some(p) = start_update(&stats.start) {
                start = p;
            }
        }
        if update.transition {
            for (i, row) in transition_update(&stats.transitions, s)
                .into_iter()
                .enumerate()
            {
                if let Some(row) = row {
                    transition[i * s..(i + 1) * s].copy_from_slice(&row);
                }
            }
        }
        let mut emission = self.emission.clone();
        let report = if update.emission {
            emission.m_step(&stats.emission, reg)?
        } else {
            MStepReport::default()
        };
        let mut hmm = Hmm {
            start,
            transition,
            emission,
            log_start: Vec::new(),
            log_transition: Vec::new(),
        };
        hmm.normalise();
        Ok((hmm, report))
    }
}

/// Checked settings of Baum-Welch; build with [`BaumWelch::builder`].
///
/// Deserialisation runs [`BaumWelchBuilder::build`]'s checks (and
/// [`Regularisation`]'s), so settings read from a file are refused with the
/// same message as in code (e.g. `restarts = 0`, a NaN tolerance, k-bins
/// smoothing outside `[0, 1]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "BaumWelchRaw")]
pub struct BaumWelch {
    max_iter: usize,
    tol: f64,
    convergence: Convergence,
    regularisation: Regularisation,
    update: Update,
    init: HmmInit,
    restarts: usize,
    seed: u64,
    threads: Option<usize>,
}

/// The serialised form of [`BaumWelch`], before validation.
#[derive(Deserialize)]
struct BaumWelchRaw {
    max_iter: usize,
    tol: f64,
    convergence: Convergence,
    regularisation: Regularisation,
    update: Update,
    init: HmmInit,
    restarts: usize,
    seed: u64,
    threads: Option<usize>,
}

impl TryFrom<BaumWelchRaw> for BaumWelch {
    type Error = HmmError;
    fn try_from(r: BaumWelchRaw) -> Result<Self> {
        BaumWelchBuilder(BaumWelch {
            max_iter: r.max_iter,
            tol: r.tol,
            convergence: r.convergence,
            regularisation: r.regularisation,
            update: r.update,
            init: r.init,
            restarts: r.restarts,
            seed: r.seed,
            threads: r.threads,
        })
        .build()
    }
}

/// Builder of [`BaumWelch`]; [`BaumWelchBuilder::build`] validates once.
#[derive(Debug, Clone)]
pub struct BaumWelchBuilder(BaumWelch);

/// The covariance regularisation of [`BaumWelch::default`] and of
/// `phasekit_gmm::Em::default`: `1e-6` added to every covariance diagonal after
/// each M-step, scikit-learn's default `reg_covar`.
///
/// It keeps a constant or collinear feature (a marker that never moves, a
/// column that is a multiple of another) from making a covariance singular,
/// and is negligible against the variances of data on a unit scale. It is in
/// the data's units squared: on data whose variances are near `1e-6` or below
/// it dominates them (standardise such data, or choose the regularisation).
/// [`Regularisation::none`] gives plain maximum likelihood (hmmlearn's
/// estimates, and the monotone EM of the textbook).
pub fn default_regularisation() -> Regularisation {
    // 1e-6 is finite and non-negative, which is all `add_diagonal` checks.
    Regularisation::add_diagonal(DEFAULT_ADDED_DIAGONAL).unwrap_or_default()
}

/// The amount [`default_regularisation`] adds to every covariance diagonal.
pub const DEFAULT_ADDED_DIAGONAL: f64 = 1e-6;

impl Default for BaumWelch {
    /// 100 iterations, tolerance `1e-4` on the total log-likelihood,
    /// [`default_regularisation`] (`1e-6` added to every covariance diagonal),
    /// everything updated, k-bins initialisation, one run, seed 0.
    fn default() -> Self {
        BaumWelch {
            max_iter: 100,
            tol: 1e-4,
            convergence: Convergence::Total,
            regularisation: default_regularisation(),
            update: Update::default(),
            init: HmmInit::default(),
            restarts: 1,
            seed: 0,
            threads: None,
        }
    }
}

impl BaumWelchBuilder {
    /// At most `n` M-steps.
    pub fn max_iter(mut self, n: usize) -> Self {
        self.0.max_iter = n;
        self
    }
    /// Stop when the gain of the objective between two E-steps (on the
    /// [`Convergence`] scale) is below `tol`; a decrease also stops.
    /// `f64::NEG_INFINITY` disables the test.
    ///
    /// The objective is `log p(X) + log prior` ([`Emission::log_prior`]), the
    /// quantity EM increases: it is `log p(X)` itself when the regularisation
    /// is not a prior (none, or `r·I` added after the M-step), and the
    /// penalised objective under an inverse-Wishart prior or pseudo-counts.
    pub fn tol(mut self, tol: f64) -> Self {
        self.0.tol = tol;
        self
    }
    /// Scale of the convergence test.
    pub fn convergence(mut self, c: Convergence) -> Self {
        self.0.convergence = c;
        self
    }
    /// Regularisation of every emission M-step (and of the initialisation).
    pub fn regularisation(mut self, r: Regularisation) -> Self {
        self.0.regularisation = r;
        self
    }
    /// Which parameters to re-estimate.
    pub fn update(mut self, u: Update) -> Self {
        self.0.update = u;
        self
    }
    /// Initialisation (ignored by [`BaumWelch::fit_from`]).
    pub fn init(mut self, init: HmmInit) -> Self {
        self.0.init = init;
        self
    }
    /// Number of runs from different initialisations; the best final objective wins.
    /// Run `r > 0` uses seed `seed + r`; with k-bins (deterministic) runs `r > 0` start from k-means++.
    pub fn restarts(mut self, n: usize) -> Self {
        self.0.restarts = n;
        self
    }
    /// Seed of every random choice.
    pub fn seed(mut self, seed: u64) -> Self {
        self.0.seed = seed;
        self
    }
    /// Run on a dedicated pool of `n` threads (default: rayon's global pool).
    pub fn threads(mut self, n: usize) -> Self {
        self.0.threads = Some(n);
        self
    }
    /// Validates the settings.
    pub fn build(self) -> Result<BaumWelch> {
        let b = self.0;
        if b.tol.is_nan() {
            return Err(HmmError::InvalidParameter {
                name: "tol",
                reason: "tolerance is NaN".into(),
            });
        }
        if b.restarts == 0 {
            return Err(HmmError::InvalidParameter {
                name: "restarts",
                reason: "at least one run is needed".into(),
            });
        }
        if b.threads == Some(0) {
            return Err(HmmError::InvalidParameter {
                name: "threads",
                reason: "at least one thread is needed".into(),
            });
        }
        if let HmmInit::KBins { smoothing } = b.init {
            if !(0.0..=1.0).contains(&smoothing) {
                return Err(HmmError::InvalidParameter {
                    name: "smoothing",
                    reason: format!("k-bins smoothing must lie in [0, 1], got {smoothing}"),
                });
            }
        }
        Ok(b)
    }
}

/// What a fit did (read-only: made by [`BaumWelch`], new fields may be added).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct HmmFitReport {
    /// Number of M-steps of the returned run.
    pub iterations: usize,
    /// `log p(X)` (summed over sequences) at every E-step of the returned run; the last entry is the returned model's.
    pub log_likelihood: Vec<f64>,
    /// `log p(X) + log prior` at every E-step (equals `log_likelihood` without a prior).
    pub objective: Vec<f64>,
    /// Whether the tolerance test stopped the run (rather than `max_iter`).
    pub converged: bool,
    /// The emission M-step reports of the returned run, one per iteration.
    pub m_steps: Vec<MStepReport>,
    /// Final objective of every run (`None` for a run that failed), in run order.
    pub restarts: Vec<Option<f64>>,
    /// Index of the returned run.
    pub best_restart: usize,
    /// Wall-clock seconds of the whole fit.
    pub fit_seconds: f64,
}

/// A fitted model and its report (made by [`BaumWelch`]).
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct HmmFit<E: Emission> {
    /// The model whose log-likelihood was evaluated last.
    pub model: Hmm<E>,
    /// What the fit did.
    pub report: HmmFitReport,
}

impl BaumWelch {
    /// A builder starting from the defaults.
    pub fn builder() -> BaumWelchBuilder {
        BaumWelchBuilder(BaumWelch::default())
    }

    /// A builder starting from these settings (to change some of them).
    pub fn to_builder(&self) -> BaumWelchBuilder {
        BaumWelchBuilder(self.clone())
    }

    /// The regularisation used.
    pub fn regularisation(&self) -> &Regularisation {
        &self.regularisation
    }

    /// At most this many M-steps.
    pub fn max_iter(&self) -> usize {
        self.max_iter
    }

    /// The convergence tolerance (on the [`BaumWelch::convergence`] scale).
    pub fn tol(&self) -> f64 {
        self.tol
    }

    /// The scale of the convergence test.
    pub fn convergence(&self) -> Convergence {
        self.convergence
    }

    /// Which parameters are re-estimated.
    pub fn update(&self) -> Update {
        self.update
    }

    /// The initialisation.
    pub fn init(&self) -> HmmInit {
        self.init
    }

    /// The number of runs.
    pub fn restarts(&self) -> usize {
        self.restarts
    }

    /// The seed of every random choice.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// The size of the dedicated thread pool (`None`: rayon's global pool).
    pub fn threads(&self) -> Option<usize> {
        self.threads
    }

    fn scale(&self, data: &SequenceSet, ll: f64) -> f64 {
        match self.convergence {
            Convergence::Total => ll,
            Convergence::MeanPerSequence => ll / data.len() as f64,
            Convergence::MeanPerFrame => ll / data.total_frames() as f64,
        }
    }

    /// Runs `f` on the dedicated pool of [`BaumWelch::threads`]; with one
    /// thread, on the calling thread (no pool to start: the E-step then runs
    /// serially, [`BaumWelch::serial`]).
    /// Whether the E-step runs on the calling thread alone (`threads(1)`).
    fn serial(&self) -> bool {
        self.threads == Some(1)
    }

    fn in_pool<T: Send>(&self, f: impl FnOnce() -> Result<T> + Send) -> Result<T> {
        match self.threads {
            None | Some(1) => f(),
            Some(n) => rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| HmmError::ThreadPool(e.to_string()))?
                .install(f),
        }
    }

    /// Initialises from an emission `template` with `S` states (its parameters
    /// are ignored, its structure is kept) and runs Baum-Welch.
    pub fn fit<E: Emission>(&self, template: &E, data: &SequenceSet) -> Result<HmmFit<E>> {
        let clock = Instant::now();
        if data.is_empty() {
            return Err(HmmError::NoData);
        }
        phasekit_emission::check_dim(template.dim(), data.dim())?;
        for (k, seq) in data.iter().enumerate() {
            template
                .check_frames(seq)
                .map_err(|e| HmmError::from(e).in_sequence(k))?;
        }
        let runs = best_of_restarts(
            self.restarts,
            |r| {
                let mut rng = ChaCha8Rng::seed_from_u64(self.seed.wrapping_add(r as u64));
                let init = match (r, self.init) {
                    (r, HmmInit::KBins { .. }) if r > 0 => HmmInit::KMeans,
                    (_, init) => init,
                };
                initialise(template, data, init, &self.regularisation, &mut rng)
                    .and_then(|hmm| self.run(hmm, data))
            },
            |fitted| *fitted.report.objective.last().unwrap_or(&f64::NEG_INFINITY),
        );
        match runs.best {
            Some((mut fitted, r)) => {
                fitted.report.best_restart = r;
                fitted.report.restarts = runs.finals;
                fitted.report.fit_seconds = clock.elapsed().as_secs_f64();
                Ok(fitted)
            }
            None => Err(runs.first_error.unwrap_or(HmmError::NoData)),
        }
    }

    /// Runs Baum-Welch from the given model.
    pub fn fit_from<E: Emission>(&self, initial: Hmm<E>, data: &SequenceSet) -> Result<HmmFit<E>> {
        let clock = Instant::now();
        initial.check_sequences(data)?;
        let mut fitted = self.run(initial, data)?;
        fitted.report.restarts = vec![fitted.report.objective.last().copied()];
        fitted.report.fit_seconds = clock.elapsed().as_secs_f64();
        Ok(fitted)
    }

    fn run<E: Emission>(&self, mut hmm: Hmm<E>, data: &SequenceSet) -> Result<HmmFit<E>> {
        self.in_pool(|| {
            let mut log_likelihood = Vec::new();
            let mut objective = Vec::new();
            let mut m_steps = Vec::new();
            let mut converged = false;
            loop {
                let stats = hmm.e_step(data, self.serial())?;
                let ll = stats.log_likelihood;
                let obj = ll + hmm.emission.log_prior(&self.regularisation);
                // Test the gain of what EM increases: the penalised objective
                // `log p(X) + log prior`. Without a prior `log_prior` is exactly 0,
                // so `obj == ll` bit for bit and the test is the log-likelihood's.
                if let Some(prev) = objective.last() {
                    if self.scale(data, obj) - self.scale(data, *prev) < self.tol {
                        converged = true;
                    }
                }
                log_likelihood.push(ll);
                objective.push(obj);
                if converged || m_steps.len() >= self.max_iter {
                    break;
                }
                let (next, report) = hmm.maximise(&stats, self.update, &self.regularisation)?;
                hmm = next;
                m_steps.push(report);
            }
            Ok(HmmFit {
                model: hmm,
                report: HmmFitReport {
                    iterations: m_steps.len(),
                    log_likelihood,
                    objective,
                    converged,
                    m_steps,
                    restarts: Vec::new(),
                    best_restart: 0,
                    fit_seconds: 0.0,
                },
            })
        })
    }
}
