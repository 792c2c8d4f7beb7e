//! EM for HSMMs over many sequences, with a parallel, deterministic E-step.
//!
//! E-step: for every sequence the state posteriors `γ`, the expected
//! segment starts at frame 0, the expected transitions between segments, the
//! expected counts of complete durations `η_i(d)` and of right-censored last
//! segments, and the emission statistics `Σ_t γ_t(i) φ(x_t)`. Sequences are
//! grouped into blocks of consecutive sequences that depend only on the data
//! (never on the number of threads); blocks run in parallel and their
//! statistics are merged in block order, so the result is bit-identical for
//! any thread count.
//!
//! M-step: `π_i ∝ Σ_k σ^k_0(i)`, `a_ij ∝ Σ ξ(i, j)` (zeros stay zero, the
//! diagonal is zero), the durations by [`Duration::m_step`] from
//! `c_i(d) = η_i(d) + p_i(d) Σ_{d' ≤ d} κ_i(d') / P(D_i ≥ d')` (a
//! censored last segment of `d'` frames, weight `κ_i(d')`, is a visit of
//! unknown length `≥ d'`: EM counts it at every `d ≥ d'` with its
//! conditional probability under the current durations), and the emission's
//! own M-step with its regularisation.

use crate::duration::{Duration, DurationRegularisation, DurationReport};
use crate::error::{invalid, HsmmError, Result};
use crate::inference::{SegmentCounts, Workspace};
use crate::init::{initialise, HsmmInit, InitSettings, Structure};
use crate::model::{Censoring, Hsmm, Tables};
use phasekit_emission::restarts::best_of_restarts;
use phasekit_emission::{Emission, MStepReport, Regularisation, SequenceSet, SufficientStatistics};
pub use phasekit_hmm::Convergence;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Frames per E-step block: blocks are consecutive sequences holding at least this many frames.
const BLOCK_FRAMES: usize = 4096;

/// Which parameters the M-step re-estimates (the others stay frozen).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct HsmmUpdate {
    /// Re-estimate the initial distribution `π`.
    pub start: bool,
    /// Re-estimate the transitions between segments `A`.
    pub transition: bool,
    /// Re-estimate the durations.
    pub durations: bool,
    /// Re-estimate the emissions.
    pub emission: bool,
}

impl Default for HsmmUpdate {
    fn default() -> Self {
        HsmmUpdate {
            start: true,
            transition: true,
            durations: true,
            emission: true,
        }
    }
}

/// Expected sufficient statistics of an E-step over a set of sequences.
#[derive(Debug, Clone)]
pub struct HsmmStatistics<S> {
    /// `Σ_k log p(x^k)`.
    pub log_likelihood: f64,
    /// `Σ_k p(the first segment is i | x^k)`.
    pub start: Vec<f64>,
    /// Expected transitions between segments, `S × S`.
    pub transitions: Vec<f64>,
    /// Expected complete segments per state and duration, `S × D`.
    pub durations: Vec<f64>,
    /// Expected right-censored last segments per state and observed length, `S × D`.
    pub censored: Vec<f64>,
    /// Emission statistics.
    pub emission: S,
    /// Number of sequences.
    pub n_sequences: usize,
    /// Number of frames.
    pub n_frames: usize,
}

impl<S: SufficientStatistics> HsmmStatistics<S> {
    fn check_shape(&self, s: usize, dm: usize) -> Result<()> {
        for (name, v, n) in [
            ("start statistics", &self.start, s),
            ("transition statistics", &self.transitions, s * s),
            ("duration statistics", &self.durations, s * dm),
            ("censored duration statistics", &self.censored, s * dm),
        ] {
            if v.len() != n {
                return Err(invalid(name, format!("{} entries, expected {n}", v.len())));
            }
        }
        Ok(())
    }

    /// Adds `other` (statistics of other sequences under the same model).
    /// Errors, leaving `self` unchanged, when the shapes differ.
    pub fn merge(&mut self, other: &Self) -> Result<()> {
        let s = self.start.len();
        let dm = self.durations.len().checked_div(s).unwrap_or(0);
        self.check_shape(s, dm)?;
        other.check_shape(s, dm).map_err(|e| match e {
            HsmmError::InvalidParameter { name, reason } => HsmmError::InvalidParameter {
                name,
                reason: format!("cannot merge statistics of another model: {reason}"),
            },
            e => e,
        })?;
        self.emission.merge(&other.emission)?;
        self.log_likelihood += other.log_likelihood;
        for (a, b) in [
            (&mut self.start, &other.start),
            (&mut self.transitions, &other.transitions),
            (&mut self.durations, &other.durations),
            (&mut self.censored, &other.censored),
        ] {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
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

/// The complete-duration counts for the M-step: `η` plus the censored
/// segments spread over the durations they may have had.
fn imputed_counts(
    tables: &Tables,
    s: usize,
    dm: usize,
    complete: &[f64],
    censored: &[f64],
) -> Vec<f64> {
    let mut counts = complete.to_vec();
    for i in 0..s {
        let base = i * dm;
        let mut acc = 0.0;
        for d in 0..dm {
            let c = censored[base + d];
            let ls = tables.log_survival[base + d];
            if c > 0.0 && ls > f64::NEG_INFINITY {
                acc += (c.ln() - ls).exp();
            }
            let lp = tables.log_pmf[base + d];
            if acc > 0.0 && lp > f64::NEG_INFINITY {
                counts[base + d] += acc * lp.exp();
            }
        }
    }
    counts
}

impl<E: Emission, D: Duration> Hsmm<E, D> {
    fn empty_statistics(&self) -> HsmmStatistics<E::Stats> {
        let (s, dm) = (self.n_states(), self.max_duration());
        HsmmStatistics {
            log_likelihood: 0.0,
            start: vec![0.0; s],
            transitions: vec![0.0; s * s],
            durations: vec![0.0; s * dm],
            censored: vec![0.0; s * dm],
            emission: self.emission.new_stats(),
            n_sequences: 0,
            n_frames: 0,
        }
    }

    fn accumulate_sequence(
        &self,
        k: usize,
        data: &SequenceSet,
        ws: &mut Workspace,
        counts: &mut SegmentCounts,
        acc: &mut HsmmStatistics<E::Stats>,
    ) -> Result<()> {
        let seq = data.get(k);
        self.fill_log_b(seq, ws).map_err(|e| e.in_sequence(k))?;
        let (ll, lambda) = self.forward_ws(ws).map_err(|e| e.in_sequence(k))?;
        self.backward_ws(ws, lambda, counts, None);
        acc.log_likelihood += ll;
        acc.n_sequences += 1;
        acc.n_frames += seq.len();
        self.emission
            .accumulate(seq, &ws.gamma, &mut acc.emission)
            .map_err(|e| HsmmError::from(e).in_sequence(k))
    }

    /// The E-step over all sequences, in parallel on the current rayon pool;
    /// bit-identical whatever the number of threads. Data must have passed
    /// [`Hsmm::check_sequences`].
    pub fn expected_statistics(&self, data: &SequenceSet) -> Result<HsmmStatistics<E::Stats>> {
        let (s, dm) = (self.n_states(), self.max_duration());
        let parts: Vec<Result<HsmmStatistics<E::Stats>>> = blocks(data)
            .into_par_iter()
            .map(|range| {
                let mut acc = self.empty_statistics();
                let mut counts = SegmentCounts::zeros(s, dm);
                let mut ws = Workspace::default();
                for k in range {
                    self.accumulate_sequence(k, data, &mut ws, &mut counts, &mut acc)?;
                }
                acc.start = counts.start;
                acc.transitions = counts.transitions;
                acc.durations = counts.durations;
                acc.censored = counts.censored;
                Ok(acc)
            })
            .collect();
        let mut total = self.empty_statistics();
        for part in parts {
            total.merge(&part?)?;
        }
        Ok(total)
    }

    /// The M-step: new parameters from expected statistics (see the module
    /// documentation). Frozen parts are kept; a transition row with no
    /// expected transitions, and a state with no expected duration count,
    /// keep their previous values.
    ///
    /// Errors (naming the vector) when `stats` is shaped for another model or
    /// holds a negative or non-finite count.
    pub fn maximise(
        &self,
        stats: &HsmmStatistics<E::Stats>,
        update: HsmmUpdate,
        reg: &Regularisation,
        duration_reg: &DurationRegularisation,
    ) -> Result<(Hsmm<E, D>, MStepReport, DurationReport)> {
        let (s, dm) = (self.n_states(), self.max_duration());
        stats.check_shape(s, dm).map_err(|e| match e {
            HsmmError::InvalidParameter { name, reason } => HsmmError::InvalidParameter {
                name,
                reason: format!("{reason} for a model with {s} states and max_duration {dm}"),
            },
            e => e,
        })?;
        for (name, v) in [
            ("start statistics", &stats.start),
            ("transition statistics", &stats.transitions),
            ("duration statistics", &stats.durations),
            ("censored duration statistics", &stats.censored),
        ] {
            if let Some(j) = v.iter().position(|x| !(x.is_finite() && *x >= 0.0)) {
                return Err(invalid(
                    name,
                    format!("entry {j} is {}, not a finite non-negative count", v[j]),
                ));
            }
        }
        let mut start = self.start.clone();
        let mut transition = self.transition.clone();
        if update.start {
            let total: f64 = stats.start.iter().sum();
            if total > 0.0 {
                start = stats.start.iter().map(|v| v / total).collect();
            }
        }
        if update.transition {
            for i in 0..s {
                let row = &stats.transitions[i * s..(i + 1) * s];
                let total: f64 = row.iter().sum();
                if total > 0.0 {
                    for j in 0..s {
                        // a_ii = 0 by definition (its expected count is 0 too).
                        transition[i * s + j] = if i == j { 0.0 } else { row[j] / total };
                    }
                }
            }
        }
        let mut durations = self.durations.clone();
        let duration_report = if update.durations {
            let counts = imputed_counts(&self.tables, s, dm, &stats.durations, &stats.censored);
            durations.m_step(&counts, duration_reg)?
        } else {
            DurationReport::default()
        };
        let mut emission = self.emission.clone();
        let report = if update.emission {
            emission.m_step(&stats.emission, reg)?
        } else {
            MStepReport::default()
        };
        let mut hsmm = Hsmm {
            start,
            transition,
            durations,
            emission,
            censoring: self.censoring,
            tables: Tables::default(),
        };
        hsmm.refresh()?;
        Ok((hsmm, report, duration_report))
    }
}

/// Checked settings of HSMM EM; build with [`HsmmEm::builder`].
///
/// Deserialisation runs [`HsmmEmBuilder::build`]'s checks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "HsmmEmRaw")]
pub struct HsmmEm {
    max_iter: usize,
    tol: f64,
    convergence: Convergence,
    regularisation: Regularisation,
    duration_regularisation: DurationRegularisation,
    update: HsmmUpdate,
    init: HsmmInit,
    structure: Structure,
    censoring: Censoring,
    restarts: usize,
    seed: u64,
    threads: Option<usize>,
}

#[derive(Deserialize)]
struct HsmmEmRaw {
    max_iter: usize,
    tol: f64,
    convergence: Convergence,
    regularisation: Regularisation,
    duration_regularisation: DurationRegularisation,
    update: HsmmUpdate,
    init: HsmmInit,
    structure: Structure,
    censoring: Censoring,
    restarts: usize,
    seed: u64,
    threads: Option<usize>,
}

impl TryFrom<HsmmEmRaw> for HsmmEm {
    type Error = HsmmError;
    fn try_from(r: HsmmEmRaw) -> Result<Self> {
        HsmmEmBuilder(HsmmEm {
            max_iter: r.max_iter,
            tol: r.tol,
            convergence: r.convergence,
            regularisation: r.regularisation,
            duration_regularisation: r.duration_regularisation,
            update: r.update,
            init: r.init,
            structure: r.structure,
            censoring: r.censoring,
            restarts: r.restarts,
            seed: r.seed,
            threads: r.threads,
        })
        .build()
    }
}

impl Default for HsmmEm {
    /// 100 iterations, tolerance `1e-4` on the total log-likelihood, no
    /// regularisation, everything updated, k-bins initialisation, ergodic,
    /// right-censored, one run, seed 0.
    fn default() -> Self {
        HsmmEm {
            max_iter: 100,
            tol: 1e-4,
            convergence: Convergence::Total,
            regularisation: Regularisation::default(),
            duration_regularisation: DurationRegularisation::default(),
            update: HsmmUpdate::default(),
            init: HsmmInit::default(),
            structure: Structure::default(),
            censoring: Censoring::default(),
            restarts: 1,
            seed: 0,
            threads: None,
        }
    }
}

/// Builder of [`HsmmEm`]; [`HsmmEmBuilder::build`] validates once.
#[derive(Debug, Clone)]
pub struct HsmmEmBuilder(HsmmEm);

impl HsmmEmBuilder {
    /// At most `n` M-steps.
    pub fn max_iter(mut self, n: usize) -> Self {
        self.0.max_iter = n;
        self
    }
    /// Stop when the gain of `log p(X) + log prior` between two E-steps (on
    /// the [`Convergence`] scale) is below `tol`; a decrease also stops.
    /// `f64::NEG_INFINITY` disables the test.
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
    /// Regularisation of every duration M-step (and of the initialisation).
    pub fn duration_regularisation(mut self, r: DurationRegularisation) -> Self {
        self.0.duration_regularisation = r;
        self
    }
    /// Which parameters to re-estimate.
    pub fn update(mut self, u: HsmmUpdate) -> Self {
        self.0.update = u;
        self
    }
    /// Initialisation (ignored by [`HsmmEm::fit_from`]).
    pub fn init(mut self, init: HsmmInit) -> Self {
        self.0.init = init;
        self
    }
    /// Allowed transitions at initialisation (EM keeps the forbidden ones at zero).
    pub fn structure(mut self, structure: Structure) -> Self {
        self.0.structure = structure;
        self
    }
    /// How the last segment of every sequence is scored (ignored by [`HsmmEm::fit_from`]).
    pub fn censoring(mut self, censoring: Censoring) -> Self {
        self.0.censoring = censoring;
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
    pub fn build(self) -> Result<HsmmEm> {
        let b = self.0;
        if b.tol.is_nan() {
            return Err(invalid("tol", "tolerance is NaN"));
        }
        if b.restarts == 0 {
            return Err(invalid("restarts", "at least one run is needed"));
        }
        if b.threads == Some(0) {
            return Err(invalid("threads", "at least one thread is needed"));
        }
        if let HsmmInit::KBins { smoothing } = b.init {
            if !(0.0..=1.0).contains(&smoothing) {
                return Err(invalid(
                    "smoothing",
                    format!("k-bins smoothing must lie in [0, 1], got {smoothing}"),
                ));
            }
        }
        Ok(b)
    }
}

/// What a fit did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct HsmmFitReport {
    /// Number of M-steps of the returned run.
    pub iterations: usize,
    /// `log p(X)` at every E-step of the returned run; the last entry is the returned model's.
    pub log_likelihood: Vec<f64>,
    /// `log p(X) + log prior` at every E-step (equals `log_likelihood` without a prior).
    pub objective: Vec<f64>,
    /// Whether the tolerance test stopped the run (rather than `max_iter`).
    pub converged: bool,
    /// The emission M-step reports of the returned run, one per iteration.
    pub m_steps: Vec<MStepReport>,
    /// The duration M-step reports of the returned run, one per iteration.
    pub duration_steps: Vec<DurationReport>,
    /// Final objective of every run (`None` for a run that failed), in run order.
    pub restarts: Vec<Option<f64>>,
    /// Index of the returned run.
    pub best_restart: usize,
    /// Wall-clock seconds of the whole fit.
    pub fit_seconds: f64,
}

/// A fitted model and its report.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct HsmmFit<E: Emission, D: Duration> {
    /// The model whose log-likelihood was evaluated last.
    pub model: Hsmm<E, D>,
    /// What the fit did.
    pub report: HsmmFitReport,
}

impl HsmmEm {
    /// A builder starting from the defaults.
    pub fn builder() -> HsmmEmBuilder {
        HsmmEmBuilder(HsmmEm::default())
    }

    /// The emission regularisation used.
    pub fn regularisation(&self) -> &Regularisation {
        &self.regularisation
    }

    /// The duration regularisation used.
    pub fn duration_regularisation(&self) -> &DurationRegularisation {
        &self.duration_regularisation
    }

    fn scale(&self, data: &SequenceSet, ll: f64) -> f64 {
        match self.convergence {
            Convergence::Total => ll,
            Convergence::MeanPerSequence => ll / data.len() as f64,
            Convergence::MeanPerFrame => ll / data.total_frames() as f64,
        }
    }

    fn in_pool<T: Send>(&self, f: impl FnOnce() -> Result<T> + Send) -> Result<T> {
        match self.threads {
            None => f(),
            Some(n) => rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| HsmmError::ThreadPool(e.to_string()))?
                .install(f),
        }
    }

    /// Initialises from an emission template and a duration template with
    /// `S` states (their parameter values are ignored; their structure, the
    /// duration family and the maximum duration are kept) and runs EM.
    pub fn fit<E: Emission, D: Duration>(
        &self,
        emission: &E,
        durations: &D,
        data: &SequenceSet,
    ) -> Result<HsmmFit<E, D>> {
        let clock = Instant::now();
        if data.is_empty() {
            return Err(HsmmError::NoData);
        }
        phasekit_emission::check_dim(emission.dim(), data.dim())?;
        for (k, seq) in data.iter().enumerate() {
            emission
                .check_frames(seq)
                .map_err(|e| HsmmError::from(e).in_sequence(k))?;
        }
        let settings = InitSettings {
            init: self.init,
            structure: self.structure,
            censoring: self.censoring,
            regularisation: &self.regularisation,
            duration_regularisation: &self.duration_regularisation,
        };
        let runs = best_of_restarts(
            self.restarts,
            |r| {
                let mut rng = ChaCha8Rng::seed_from_u64(self.seed.wrapping_add(r as u64));
                let init = match (r, self.init) {
                    (r, HsmmInit::KBins { .. }) if r > 0 => HsmmInit::KMeans,
                    (_, init) => init,
                };
                initialise(
                    emission,
                    durations,
                    data,
                    InitSettings { init, ..settings },
                    &mut rng,
                )
                .and_then(|m| self.run(m, data))
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
            None => Err(runs.first_error.unwrap_or(HsmmError::NoData)),
        }
    }

    /// Runs EM from the given model.
    pub fn fit_from<E: Emission, D: Duration>(
        &self,
        initial: Hsmm<E, D>,
        data: &SequenceSet,
    ) -> Result<HsmmFit<E, D>> {
        let clock = Instant::now();
        initial.check_sequences(data)?;
        let mut fitted = self.run(initial, data)?;
        fitted.report.restarts = vec![fitted.report.objective.last().copied()];
        fitted.report.fit_seconds = clock.elapsed().as_secs_f64();
        Ok(fitted)
    }

    fn run<E: Emission, D: Duration>(
        &self,
        mut model: Hsmm<E, D>,
        data: &SequenceSet,
    ) -> Result<HsmmFit<E, D>> {
        self.in_pool(|| {
            let mut log_likelihood = Vec::new();
            let mut objective = Vec::new();
            let mut m_steps = Vec::new();
            let mut duration_steps = Vec::new();
            let mut converged = false;
            loop {
                let stats = model.expected_statistics(data)?;
                let ll = stats.log_likelihood;
                let obj = ll
                    + model.emission.log_prior(&self.regularisation)
                    + model.durations.log_prior(&self.duration_regularisation);
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
                let (next, report, duration_report) = model.maximise(
                    &stats,
                    self.update,
                    &self.regularisation,
                    &self.duration_regularisation,
                )?;
                model = next;
                m_steps.push(report);
                duration_steps.push(duration_report);
            }
            Ok(HsmmFit {
                model,
                report: HsmmFitReport {
                    iterations: m_steps.len(),
                    log_likelihood,
                    objective,
                    converged,
                    m_steps,
                    duration_steps,
                    restarts: Vec::new(),
                    best_restart: 0,
                    fit_seconds: 0.0,
                },
            })
        })
    }
}
