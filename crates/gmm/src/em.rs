//! Expectation-maximisation for mixtures.
//!
//! E-step: `r_tk = π_k c_k(x_t) / Σ_j π_j c_j(x_t)`, accumulated into
//! `N_k = Σ_t r_tk` and the components' weighted statistics. Frames are cut into
//! fixed chunks (independent of the thread count), processed in parallel and
//! merged in chunk order, so results are bit-identical for any number of threads.
//! M-step: `π_k = N_k / N` and the components' own M-step with the regularisation.

use crate::error::{GmmError, Result};
use crate::model::{normalise_log_row, Gmm};
use phasekit_emission::kmeans::{kmeans, Seeding};
use phasekit_emission::restarts::best_of_restarts;
use phasekit_emission::{Emission, Frames, MStepReport, Regularisation, SufficientStatistics};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Frames per E-step chunk.
const CHUNK_FRAMES: usize = 4096;

/// How EM starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum GmmInit {
    /// k-means++ seeding and Lloyd iterations; components from the hard clusters.
    KMeans,
    /// Random soft responsibilities.
    Random,
}

/// Expected statistics of a mixture E-step.
///
/// The fields are public so that statistics computed elsewhere can be
/// combined and maximised ([`Gmm::maximise`]).
#[derive(Debug, Clone)]
pub struct MixtureStatistics<S> {
    /// `Σ_t log p(x_t)`.
    pub log_likelihood: f64,
    /// `N_k = Σ_t r_tk`.
    pub counts: Vec<f64>,
    /// Component statistics weighted by the responsibilities.
    pub components: S,
    /// Number of frames.
    pub n_frames: usize,
}

/// Turns a row of joint log-densities `log π_k + log c_k(x_t)` into
/// responsibilities and returns `log p(x_t)`: one exponential per component
/// (`e_k = exp(v_k − max)`, `r_k = e_k / Σ e`) and one logarithm, instead of
/// the log-sum-exp followed by a second pass of exponentials. Rows whose
/// maximum is not finite go through [`normalise_log_row`].
#[inline]
fn responsibilities_in_place(row: &mut [f64]) -> f64 {
    let m = row.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !m.is_finite() {
        return normalise_log_row(row);
    }
    let mut total = 0.0;
    for v in row.iter_mut() {
        *v = (*v - m).exp();
        total += *v;
    }
    let inv = 1.0 / total;
    for v in row.iter_mut() {
        *v *= inv;
    }
    m + total.ln()
}

impl<E: Emission> Gmm<E> {
    fn accumulate_chunk(&self, frames: Frames<'_>) -> Result<MixtureStatistics<E::Stats>> {
        let k = self.n_components();
        let mut r = vec![0.0; frames.len() * k];
        self.joint_log_into(frames, &mut r)?;
        let mut ll = 0.0;
        let mut counts = vec![0.0; k];
        for row in r.chunks_exact_mut(k) {
            ll += responsibilities_in_place(row);
            for (c, v) in counts.iter_mut().zip(row.iter()) {
                *c += v;
            }
        }
        let mut components = self.components.new_stats();
        self.components.accumulate(frames, &r, &mut components)?;
        Ok(MixtureStatistics {
            log_likelihood: ll,
            counts,
            components,
            n_frames: frames.len(),
        })
    }

    /// The E-step over all frames, parallel over fixed chunks, bit-identical for any thread count.
    pub fn expected_statistics(&self, frames: Frames<'_>) -> Result<MixtureStatistics<E::Stats>> {
        let n = frames.len();
        let chunks: Vec<_> = (0..n.div_ceil(CHUNK_FRAMES))
            .map(|c| c * CHUNK_FRAMES..((c + 1) * CHUNK_FRAMES).min(n))
            .collect();
        let parts: Vec<Result<MixtureStatistics<E::Stats>>> = chunks
            .into_par_iter()
            .map(|range| self.accumulate_chunk(frames.slice(range)))
            .collect();
        let mut total = MixtureStatistics {
            log_likelihood: 0.0,
            counts: vec![0.0; self.n_components()],
            components: self.components.new_stats(),
            n_frames: 0,
        };
        for part in parts {
            let part = part?;
            total.log_likelihood += part.log_likelihood;
            for (a, b) in total.counts.iter_mut().zip(&part.counts) {
                *a += b;
            }
            total.components.merge(&part.components)?;
            total.n_frames += part.n_frames;
        }
        Ok(total)
    }

    /// The M-step: `π_k = N_k / N` (plus the pseudo-count of `reg`) and the components' M-step.
    pub fn maximise(
        &self,
        stats: &MixtureStatistics<E::Stats>,
        reg: &Regularisation,
    ) -> Result<(Self, MStepReport)> {
        let a = reg.pseudo_count();
        let k = self.n_components();
        let n: f64 = stats.counts.iter().sum();
        let weights: Vec<f64> = stats
            .counts
            .iter()
            .map(|c| (c + a) / (n + a * k as f64))
            .collect();
        let mut components = self.components.clone();
        let report = components.m_step(&stats.components, reg)?;
        Ok((Gmm::new(weights, components)?, report))
    }

    /// `log prior` of the weights (Dirichlet pseudo-counts) and the components.
    fn log_prior(&self, reg: &Regularisation) -> f64 {
        let a = reg.pseudo_count();
        let w = if a > 0.0 {
            a * self.log_weights.iter().sum::<f64>()
        } else {
            0.0
        };
        w + self.components.log_prior(reg)
    }
}

/// Checked EM settings; build with [`Em::builder`].
///
/// Deserialisation runs [`EmBuilder::build`]'s checks (and
/// [`Regularisation`]'s), so settings read from a file are refused with the
/// same message as in code (e.g. `restarts = 0`, a NaN tolerance).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "EmRaw")]
pub struct Em {
    max_iter: usize,
    tol: f64,
    regularisation: Regularisation,
    init: GmmInit,
    restarts: usize,
    seed: u64,
    threads: Option<usize>,
}

/// The serialised form of [`Em`], before validation.
#[derive(Deserialize)]
struct EmRaw {
    max_iter: usize,
    tol: f64,
    regularisation: Regularisation,
    init: GmmInit,
    restarts: usize,
    seed: u64,
    threads: Option<usize>,
}

impl TryFrom<EmRaw> for Em {
    type Error = GmmError;
    fn try_from(r: EmRaw) -> Result<Self> {
        EmBuilder(Em {
            max_iter: r.max_iter,
            tol: r.tol,
            regularisation: r.regularisation,
            init: r.init,
            restarts: r.restarts,
            seed: r.seed,
            threads: r.threads,
        })
        .build()
    }
}

/// The covariance regularisation of [`Em::default`]: `1e-6` added to every
/// covariance diagonal after each M-step, scikit-learn's default `reg_covar`
/// (and the same as `phasekit_hmm::default_regularisation`).
///
/// It keeps a constant or collinear feature from making a covariance
/// singular and is negligible against the variances of data on a unit scale.
/// It is in the data's units squared: on data whose variances are near `1e-6`
/// or below it dominates them (standardise such data, or choose the
/// regularisation). [`Regularisation::none`] gives plain maximum likelihood
/// (the monotone EM of the textbook).
pub fn default_regularisation() -> Regularisation {
    // 1e-6 is finite and non-negative, which is all `add_diagonal` checks.
    Regularisation::add_diagonal(DEFAULT_ADDED_DIAGONAL).unwrap_or_default()
}

/// The amount [`default_regularisation`] adds to every covariance diagonal.
pub const DEFAULT_ADDED_DIAGONAL: f64 = 1e-6;

impl Default for Em {
    /// 100 iterations, tolerance `1e-3` on the mean log-likelihood per frame,
    /// `1e-6` added to every covariance diagonal ([`default_regularisation`];
    /// all three are scikit-learn's defaults), k-means++ initialisation, one
    /// run, seed 0.
    fn default() -> Self {
        Em {
            max_iter: 100,
            tol: 1e-3,
            regularisation: default_regularisation(),
            init: GmmInit::KMeans,
            restarts: 1,
            seed: 0,
            threads: None,
        }
    }
}

/// Builder of [`Em`].
#[derive(Debug, Clone)]
pub struct EmBuilder(Em);

impl EmBuilder {
    /// At most `n` M-steps.
    pub fn max_iter(mut self, n: usize) -> Self {
        self.0.max_iter = n;
        self
    }
    /// Stop when the gain of the objective per frame between two E-steps is
    /// below `tol` (a decrease also stops); `f64::NEG_INFINITY` disables the test.
    ///
    /// The objective is `log p(X) + log prior`, what EM increases: the
    /// log-likelihood itself unless the regularisation is a prior
    /// (inverse-Wishart covariances, pseudo-counts on the weights).
    pub fn tol(mut self, tol: f64) -> Self {
        self.0.tol = tol;
        self
    }
    /// Regularisation of every M-step and of the initialisation.
    pub fn regularisation(mut self, r: Regularisation) -> Self {
        self.0.regularisation = r;
        self
    }
    /// Initialisation.
    pub fn init(mut self, init: GmmInit) -> Self {
        self.0.init = init;
        self
    }
    /// Number of runs (run `r` uses seed `seed + r`); the best final objective wins.
    pub fn restarts(mut self, n: usize) -> Self {
        self.0.restarts = n;
        self
    }
    /// Seed of every random choice.
    pub fn seed(mut self, seed: u64) -> Self {
        self.0.seed = seed;
        self
    }
    /// Run on a dedicated pool of `n` threads.
    pub fn threads(mut self, n: usize) -> Self {
        self.0.threads = Some(n);
        self
    }
    /// Validates the settings.
    pub fn build(self) -> Result<Em> {
        let e = self.0;
        let bad = |name, reason: &str| {
            Err(GmmError::InvalidParameter {
                name,
                reason: reason.into(),
            })
        };
        if e.tol.is_nan() {
            return bad("tol", "tolerance is NaN");
        }
        if e.restarts == 0 {
            return bad("restarts", "at least one run is needed");
        }
        if e.threads == Some(0) {
            return bad("threads", "at least one thread is needed");
        }
        Ok(e)
    }
}

/// What a mixture fit did (read-only: made by [`Em`], new fields may be added).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct GmmFitReport {
    /// M-steps of the returned run.
    pub iterations: usize,
    /// `Σ_t log p(x_t)` at every E-step of the returned run (the last one is the returned model's).
    pub log_likelihood: Vec<f64>,
    /// `log p(X) + log prior` at every E-step.
    pub objective: Vec<f64>,
    /// Whether the tolerance stopped the run.
    pub converged: bool,
    /// Component M-step reports, one per iteration.
    pub m_steps: Vec<MStepReport>,
    /// Final objective of every run (`None` if it failed).
    pub restarts: Vec<Option<f64>>,
    /// Index of the returned run.
    pub best_restart: usize,
    /// Wall-clock seconds.
    pub fit_seconds: f64,
}

/// A fitted mixture and its report (made by [`Em`]).
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct GmmFit<E: Emission> {
    /// The model whose log-likelihood was evaluated last.
    pub model: Gmm<E>,
    /// What the fit did.
    pub report: GmmFitReport,
}

impl Em {
    /// A builder starting from the defaults.
    pub fn builder() -> EmBuilder {
        EmBuilder(Em::default())
    }

    /// A builder starting from these settings (to change some of them).
    pub fn to_builder(&self) -> EmBuilder {
        EmBuilder(self.clone())
    }

    /// The regularisation of every M-step and of the initialisation.
    pub fn regularisation(&self) -> &Regularisation {
        &self.regularisation
    }

    /// At most this many M-steps.
    pub fn max_iter(&self) -> usize {
        self.max_iter
    }

    /// The convergence tolerance on the objective's gain per frame.
    pub fn tol(&self) -> f64 {
        self.tol
    }

    /// The initialisation.
    pub fn init(&self) -> GmmInit {
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

    /// Initial mixture from an emission template with `K` states.
    pub fn initialise<E: Emission, R: Rng + ?Sized>(
        &self,
        template: &E,
        frames: Frames<'_>,
        init: GmmInit,
        rng: &mut R,
    ) -> Result<Gmm<E>> {
        let k = template.n_states();
        let n = frames.len();
        if n < k {
            return Err(GmmError::TooFewFrames(format!(
                "{n} frames cannot initialise {k} components"
            )));
        }
        let mut r = vec![0.0; n * k];
        match init {
            GmmInit::KMeans => {
                let km = kmeans(frames, k, Seeding::PlusPlus, 100, rng)?;
                for (t, l) in km.labels.iter().enumerate() {
                    r[t * k + l] = 1.0;
                }
            }
            GmmInit::Random => {
                for row in r.chunks_exact_mut(k) {
                    row.iter_mut().for_each(|v| *v = rng.random::<f64>() + 1e-3);
                    let total: f64 = row.iter().sum();
                    row.iter_mut().for_each(|v| *v /= total);
                }
            }
        }
        let mut counts = vec![0.0; k];
        for row in r.chunks_exact(k) {
            for (c, v) in counts.iter_mut().zip(row) {
                *c += v;
            }
        }
        let (components, _) = template.initialise(&[(frames, &r)], &self.regularisation, rng)?;
        let weights = counts.iter().map(|c| c / n as f64).collect();
        Gmm::new(weights, components)
    }

    fn in_pool<T: Send>(&self, f: impl FnOnce() -> Result<T> + Send) -> Result<T> {
        match self.threads {
            None => f(),
            Some(n) => rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| GmmError::ThreadPool(e.to_string()))?
                .install(f),
        }
    }

    /// Fits a mixture with the structure of `template` (its `K` states become
    /// the components; its parameters are ignored).
    pub fn fit<E: Emission>(&self, template: &E, frames: Frames<'_>) -> Result<GmmFit<E>> {
        let clock = Instant::now();
        if frames.is_empty() {
            return Err(GmmError::TooFewFrames("no frames given".into()));
        }
        template.check_frames(frames)?;
        let runs = best_of_restarts(
            self.restarts,
            |r| {
                let mut rng = ChaCha8Rng::seed_from_u64(self.seed.wrapping_add(r as u64));
                self.initialise(template, frames, self.init, &mut rng)
                    .and_then(|m| self.run(m, frames))
            },
            |fitted| *fitted.report.objective.last().unwrap_or(&f64::NEG_INFINITY),
        );
        let mut fitted = match (runs.best, runs.first_error) {
            (Some((mut b, r)), _) => {
                b.report.best_restart = r;
                b
            }
            (None, Some(e)) => return Err(e),
            (None, None) => return Err(GmmError::TooFewFrames("no run was made".into())),
        };
        fitted.report.restarts = runs.finals;
        fitted.report.fit_seconds = clock.elapsed().as_secs_f64();
        Ok(fitted)
    }

    /// Runs EM from the given mixture.
    pub fn fit_from<E: Emission>(&self, initial: Gmm<E>, frames: Frames<'_>) -> Result<GmmFit<E>> {
        let clock = Instant::now();
        initial.check_frames(frames)?;
        let mut fitted = self.run(initial, frames)?;
        fitted.report.restarts = vec![fitted.report.objective.last().copied()];
        fitted.report.fit_seconds = clock.elapsed().as_secs_f64();
        Ok(fitted)
    }

    fn run<E: Emission>(&self, mut model: Gmm<E>, frames: Frames<'_>) -> Result<GmmFit<E>> {
        let n = frames.len() as f64;
        self.in_pool(|| {
            let mut log_likelihood: Vec<f64> = Vec::new();
            let mut objective = Vec::new();
            let mut m_steps = Vec::new();
            let mut converged = false;
            loop {
                let stats = model.expected_statistics(frames)?;
                let ll = stats.log_likelihood;
                let obj = ll + model.log_prior(&self.regularisation);
                // Test the gain of what EM increases, `log p(X) + log prior`;
                // without a prior `log_prior` is exactly 0 and this is the
                // log-likelihood's gain, bit for bit.
                if let Some(prev) = objective.last() {
                    converged = (obj - prev) / n < self.tol;
                }
                log_likelihood.push(ll);
                objective.push(obj);
                if converged || m_steps.len() >= self.max_iter {
                    break;
                }
                let (next, report) = model.maximise(&stats, &self.regularisation)?;
                model = next;
                m_steps.push(report);
            }
            Ok(GmmFit {
                model,
                report: GmmFitReport {
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
