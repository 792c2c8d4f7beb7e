//! The per-state route: write ONE state's distribution, get an [`Emission`].
//!
//! A [`StateDistribution`] needs about three operations, as in
//! HiddenMarkovModels.jl (`logdensityof`, `rand`, `fit!`): the log-density of
//! a frame ([`StateDistribution::log_density`]), a draw
//! ([`StateDistribution::sample`]) and a weighted fit from frames and weights
//! given the previous parameters ([`StateDistribution::fit`]). [`PerState`]
//! makes `S` of them an [`Emission`]:
//!
//! * its statistics ([`PerStateStats`]) keep the frames that received weight
//!   and every state's weights; merging appends them in the order given, and
//!   the E-steps of the HMM and the mixture merge their blocks in data order,
//!   so [`StateDistribution::fit`] sees the same frames in the same order for
//!   any number of threads: the fit is bit-identical. The price of not
//!   writing sufficient statistics is memory: a copy of the weighted frames
//!   and `S` weights per frame during an E-step (`T (D + S)` values);
//! * missing values (NaN) work when the distribution offers marginals
//!   ([`StateDistribution::MISSING_VALUES`] and [`StateDistribution::marginal`]):
//!   a frame with NaN is evaluated on the marginal of its observed values
//!   (cached per missing pattern) and [`StateDistribution::fit`] receives the
//!   frames with their NaN, to use the expected statistics of the missing
//!   values; otherwise [`Emission::check_frames`] refuses NaN, naming the
//!   frame and column;
//! * an empty state (total weight below [`Regularisation::min_weight`]) keeps
//!   its parameters and is reported, the others are fitted one by one and
//!   their errors and events are located at their state;
//! * serde: `{"states": [...]}`, each state as its own type serialises, and
//!   checked on reading (at least one state, one dimension for all).
//!
//! The optional capabilities: [`StateDistribution::marginal`] gives
//! [`Marginal`], [`StateConditional`] gives [`Conditional`], and
//! [`ConcatStates`] comes free. See the guide [`crate::guide`] for a complete
//! example and [`crate::StudentT`] for a worked one.

use crate::capability::{check_split, ConcatStates, Conditional, ConditionalSplit, Marginal};
use crate::error::{EmissionError, Result};
use crate::missing::{for_each_run, observed_dims, PatternCache};
use crate::regularisation::{MStepEvent, MStepReport, Regularisation};
use crate::{check_dim, check_len, check_state, Emission, Frames, SufficientStatistics};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::fmt::Debug;

/// One state's distribution over frames of `dim()` values: what a plug-in
/// writes to get an [`Emission`] through [`PerState`].
///
/// Required: [`dim`](Self::dim), [`log_density`](Self::log_density),
/// [`sample`](Self::sample), [`fit`](Self::fit),
/// [`n_parameters`](Self::n_parameters). The rest have defaults.
pub trait StateDistribution: Clone + Debug + Send + Sync {
    /// A name for messages ("Student-t").
    const NAME: &'static str = "plug-in distribution";

    /// True when [`marginal`](Self::marginal) is implemented and
    /// [`fit`](Self::fit) accepts frames with NaN (using the expected
    /// statistics of the missing values): [`PerState`] then evaluates frames
    /// with missing values on the marginal of their observed values. When
    /// false, [`Emission::check_frames`] refuses NaN with the frame and column.
    const MISSING_VALUES: bool = false;

    /// Dimension `D` of a frame.
    fn dim(&self) -> usize;

    /// `log b(x)` of one complete frame `x` (length `D`, no NaN, values that
    /// passed [`check_value`](Self::check_value)); `-inf` outside the support.
    fn log_density(&self, x: &[f64]) -> f64;

    /// `out[t] = log b(x_t)` for a block of complete frames. The default calls
    /// [`log_density`](Self::log_density) frame by frame; override it when
    /// a block can be done faster.
    fn log_density_batch(&self, frames: Frames<'_>, out: &mut [f64]) {
        for (x, o) in frames.iter().zip(out.iter_mut()) {
            *o = self.log_density(x);
        }
    }

    /// Draws one frame into `out` (length `D`).
    fn sample<R: Rng + ?Sized>(&self, rng: &mut R, out: &mut [f64]);

    /// New parameters from weighted frames, given the current ones (`self`):
    /// an M-step, `argmax_θ Σ_t w_t log b(x_t; θ)`, or any step that does not
    /// decrease it (an ECM step for a distribution with latent variables).
    ///
    /// `weights` has one entry per frame, `≥ 0` (some may be 0), with a total
    /// of at least [`Regularisation::min_weight`]. Apply `reg` to covariances
    /// with [`crate::regularised_covariance`]; record what had to be done (a
    /// jitter) in `report` as events of state 0 (the route renumbers them).
    /// Frames may hold NaN only when [`MISSING_VALUES`](Self::MISSING_VALUES)
    /// is true. Errors leave `self` as it was; use
    /// [`EmissionError::plugin`] for the distribution's own.
    fn fit(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        reg: &Regularisation,
        report: &mut MStepReport,
    ) -> Result<Self>;

    /// Number of free parameters (for AIC/BIC).
    fn n_parameters(&self) -> usize;

    /// Checks one observed value of column `column` (the support: whole
    /// numbers for counts, …); the error says why it is refused. Default:
    /// every finite value.
    fn check_value(&self, column: usize, value: f64) -> std::result::Result<(), &'static str> {
        let _ = (column, value);
        Ok(())
    }

    /// Parameters from weighted frames when `self` is a template whose values
    /// mean nothing yet (see [`Emission::initialise`]). The default is
    /// [`fit`](Self::fit), right when the fit does not depend on the current
    /// parameters; a distribution whose fit does (latent weights, components)
    /// starts from something the data decide and iterates.
    fn initialise<R: Rng + ?Sized>(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        reg: &Regularisation,
        report: &mut MStepReport,
        rng: &mut R,
    ) -> Result<Self> {
        let _ = rng;
        self.fit(frames, weights, reg, report)
    }

    /// Log-density of the prior that `reg` implies at the current parameters
    /// (see [`Emission::log_prior`]); 0 by default.
    fn log_prior(&self, reg: &Regularisation) -> f64 {
        let _ = reg;
        0.0
    }

    /// The marginal on `dims` (valid, checked by the caller):
    /// `b(x_dims) = ∫ b(x) dx_rest`. Default: unsupported.
    fn marginal(&self, dims: &[usize]) -> Result<Self> {
        let _ = dims;
        Err(EmissionError::Unsupported(format!(
            "{} offers no marginal (no missing values, no filter on a subset of dimensions)",
            Self::NAME
        )))
    }
}

/// One state's conditional of output dims given input dims (regression),
/// the optional capability that gives [`PerState`] its [`Conditional`].
pub trait StateConditional: StateDistribution {
    /// What is precomputed for one `(input, output)` split of one state.
    type Split: StateSplit;

    /// Precomputes the conditional of `output` given `input` (both valid and
    /// disjoint, checked by the caller).
    fn conditional(&self, input: &[usize], output: &[usize]) -> Result<Self::Split>;
}

/// One state's precomputed conditional; `&mut self` for its own scratch.
/// The input (length `|I|`) is complete; the buffers have been checked.
pub trait StateSplit: Clone + Debug + Send + Sync {
    /// `log b(x_I)`, the state's marginal log-density of the input.
    fn input_log_density(&mut self, input: &[f64]) -> f64;

    /// `E[x_O | x_I]` into `mean` (`|O|`), `Cov[x_O | x_I]` into
    /// `covariance` (`|O| × |O|`, row-major).
    fn predict(&mut self, input: &[f64], mean: &mut [f64], covariance: &mut [f64]) -> Result<()>;
}

/// `S` states, each its own [`StateDistribution`]: an [`Emission`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(
    try_from = "PerStateParams<D>",
    into = "PerStateParams<D>",
    bound = "D: StateDistribution + Serialize + for<'a> Deserialize<'a>"
)]
pub struct PerState<D: StateDistribution> {
    states: Vec<D>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct PerStateParams<D> {
    states: Vec<D>,
}

impl<D: StateDistribution> TryFrom<PerStateParams<D>> for PerState<D> {
    type Error = EmissionError;
    fn try_from(p: PerStateParams<D>) -> Result<Self> {
        PerState::new(p.states)
    }
}

impl<D: StateDistribution> From<PerState<D>> for PerStateParams<D> {
    fn from(p: PerState<D>) -> Self {
        PerStateParams { states: p.states }
    }
}

impl<D: StateDistribution> PerState<D> {
    /// One state per distribution; at least one, all of one dimension `≥ 1`.
    pub fn new(states: Vec<D>) -> Result<Self> {
        let Some(first) = states.first() else {
            return Err(EmissionError::InvalidParameter {
                name: "states",
                reason: "a per-state emission needs at least one state".into(),
            });
        };
        let d = first.dim();
        if d == 0 {
            return Err(EmissionError::InvalidParameter {
                name: "states",
                reason: "a state's dimension must be at least 1".into(),
            });
        }
        if let Some(i) = states.iter().position(|s| s.dim() != d) {
            return Err(EmissionError::InvalidParameter {
                name: "states",
                reason: format!(
                    "state {i} has dimension {}, state 0 has {d}",
                    states[i].dim()
                ),
            });
        }
        Ok(PerState { states })
    }

    /// `n_states` copies of `template` (e.g. a template for an initialisation).
    pub fn repeat(template: D, n_states: usize) -> Result<Self> {
        Self::new(vec![template; n_states])
    }

    /// The distributions, one per state.
    pub fn states(&self) -> &[D] {
        &self.states
    }

    /// The distribution of state `i`, or the error naming it.
    pub fn state(&self, i: usize) -> Result<&D> {
        check_state(i, self.states.len())?;
        Ok(&self.states[i])
    }

    fn locate(&self, e: EmissionError, state: usize) -> EmissionError {
        e.at_state(state, None)
    }

    /// Complete frames: each state's batch into a column, scattered to `out`.
    fn log_density_complete(&self, frames: Frames<'_>, out: &mut [f64], col: &mut Vec<f64>) {
        let s = self.states.len();
        col.clear();
        col.resize(frames.len(), 0.0);
        for (i, st) in self.states.iter().enumerate() {
            st.log_density_batch(frames, col);
            for (row, v) in out.chunks_exact_mut(s).zip(col.iter()) {
                row[i] = *v;
            }
        }
    }
}

/// The statistics of [`PerState`]: the frames that received weight (copied,
/// in data order) and every state's weight of each.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PerStateStats {
    dim: usize,
    /// `T × D` row-major.
    frames: Vec<f64>,
    /// Per state, `T` weights.
    weights: Vec<Vec<f64>>,
}

impl PerStateStats {
    /// Number of frames held.
    pub fn n_frames(&self) -> usize {
        self.frames.len() / self.dim.max(1)
    }

    /// Total weight of each state.
    pub fn state_weights(&self) -> Vec<f64> {
        self.weights.iter().map(|w| w.iter().sum()).collect()
    }
}

impl SufficientStatistics for PerStateStats {
    /// Appends `other`'s frames after `self`'s (merge in data order).
    fn merge(&mut self, other: &Self) -> Result<()> {
        if self.dim != other.dim || self.weights.len() != other.weights.len() {
            return Err(EmissionError::StatsMismatch(format!(
                "per-state statistics of {} states of dimension {} and of {} states of dimension {}",
                self.weights.len(),
                self.dim,
                other.weights.len(),
                other.dim
            )));
        }
        self.frames.extend_from_slice(&other.frames);
        for (a, b) in self.weights.iter_mut().zip(&other.weights) {
            a.extend_from_slice(b);
        }
        Ok(())
    }

    fn total_weight(&self) -> f64 {
        self.weights.iter().flatten().sum()
    }
}

impl<D: StateDistribution> Emission for PerState<D> {
    type Stats = PerStateStats;

    fn n_states(&self) -> usize {
        self.states.len()
    }

    fn dim(&self) -> usize {
        self.states[0].dim()
    }

    fn check_frames(&self, frames: Frames<'_>) -> Result<()> {
        check_dim(self.dim(), frames.dim())?;
        let d = self.dim();
        for (i, v) in frames.as_slice().iter().enumerate() {
            let (t, k) = (i / d, i % d);
            if v.is_nan() {
                if !D::MISSING_VALUES {
                    return Err(EmissionError::InvalidValue {
                        frame: t,
                        column: k,
                        value: *v,
                        reason: "missing value, but this emission has no marginal to evaluate it on (fill or drop missing values)",
                    });
                }
                continue;
            }
            if let Err(reason) = self.states[0].check_value(k, *v) {
                return Err(EmissionError::InvalidValue {
                    frame: t,
                    column: k,
                    value: *v,
                    reason,
                });
            }
        }
        Ok(())
    }

    fn log_density_into(&self, frames: Frames<'_>, out: &mut [f64]) -> Result<()> {
        check_dim(self.dim(), frames.dim())?;
        let s = self.states.len();
        check_len("log-density output buffer", frames.len() * s, out.len())?;
        let mut col = Vec::new();
        if !frames.has_missing() {
            self.log_density_complete(frames, out, &mut col);
            return Ok(());
        }
        let mut marginals: PatternCache<Vec<D>> = PatternCache::new();
        let mut obs = Vec::with_capacity(self.dim());
        let mut xo = Vec::with_capacity(self.dim());
        for_each_run(frames, |range, complete| {
            let rows = &mut out[range.start * s..range.end * s];
            if complete {
                self.log_density_complete(frames.slice(range), rows, &mut col);
                return Ok(());
            }
            let x = frames.frame(range.start);
            observed_dims(x, &mut obs);
            if obs.is_empty() {
                rows.fill(0.0);
                return Ok(());
            }
            let m = marginals.get_or_try_insert(x, || {
                self.states
                    .iter()
                    .enumerate()
                    .map(|(i, st)| st.marginal(&obs).map_err(|e| self.locate(e, i)))
                    .collect::<Result<Vec<D>>>()
            })?;
            xo.clear();
            xo.extend(obs.iter().map(|&k| x[k]));
            for (o, st) in rows.iter_mut().zip(m) {
                *o = st.log_density(&xo);
            }
            Ok(())
        })
    }

    fn new_stats(&self) -> PerStateStats {
        PerStateStats {
            dim: self.dim(),
            frames: Vec::new(),
            weights: vec![Vec::new(); self.states.len()],
        }
    }

    fn accumulate(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut PerStateStats,
    ) -> Result<()> {
        check_dim(self.dim(), frames.dim())?;
        let s = self.states.len();
        check_len("accumulate weights", frames.len() * s, weights.len())?;
        if stats.dim != self.dim() || stats.weights.len() != s {
            return Err(EmissionError::StatsMismatch(
                "statistics shaped for another model".into(),
            ));
        }
        for (x, w) in frames.iter().zip(weights.chunks_exact(s)) {
            // A frame without weight adds nothing; one with nothing observed
            // neither (its density is 1 whatever the parameters).
            if w.iter().all(|v| *v == 0.0) || x.iter().all(|v| v.is_nan()) {
                continue;
            }
            stats.frames.extend_from_slice(x);
            for (col, v) in stats.weights.iter_mut().zip(w) {
                col.push(*v);
            }
        }
        Ok(())
    }

    fn m_step(&mut self, stats: &PerStateStats, reg: &Regularisation) -> Result<MStepReport> {
        let s = self.states.len();
        if stats.dim != self.dim()
            || stats.weights.len() != s
            || stats
                .weights
                .iter()
                .any(|w| w.len() * stats.dim != stats.frames.len())
        {
            return Err(EmissionError::StatsMismatch(
                "statistics shaped for another model".into(),
            ));
        }
        let frames = Frames::new(&stats.frames, stats.dim)?;
        let mut report = MStepReport::added_diagonal(reg);
        let mut next = self.states.clone();
        for (i, (st, w)) in next.iter_mut().zip(&stats.weights).enumerate() {
            let n: f64 = w.iter().sum();
            if n.is_nan() || n < reg.min_weight().max(f64::MIN_POSITIVE) {
                report.events.push(MStepEvent::KeptEmptyState {
                    state: i,
                    component: None,
                    weight: n,
                });
                continue;
            }
            let mut sub = MStepReport::default();
            *st = st
                .fit(frames, w, reg, &mut sub)
                .map_err(|e| self.locate(e, i))?;
            report.absorb_state(i, sub);
        }
        *self = PerState::new(next)?;
        Ok(report)
    }

    fn log_prior(&self, reg: &Regularisation) -> f64 {
        self.states.iter().map(|s| s.log_prior(reg)).sum()
    }

    fn sample_into<R: Rng + ?Sized>(
        &self,
        state: usize,
        rng: &mut R,
        out: &mut [f64],
    ) -> Result<()> {
        check_state(state, self.states.len())?;
        check_len("sample output buffer", self.dim(), out.len())?;
        self.states[state].sample(rng, out);
        Ok(())
    }

    fn n_parameters(&self) -> usize {
        self.states.iter().map(|s| s.n_parameters()).sum()
    }

    /// Every state from the frames it owns: the frames of all parts with a
    /// positive weight for it, through [`StateDistribution::initialise`].
    fn initialise<R: Rng + ?Sized>(
        &self,
        parts: &[(Frames<'_>, &[f64])],
        reg: &Regularisation,
        rng: &mut R,
    ) -> Result<(Self, MStepReport)> {
        let (s, d) = (self.states.len(), self.dim());
        let mut report = MStepReport::added_diagonal(reg);
        let mut next = Vec::with_capacity(s);
        for (i, st) in self.states.iter().enumerate() {
            let (mut xs, mut ws) = (Vec::new(), Vec::new());
            for (frames, w) in parts {
                check_dim(d, frames.dim())?;
                check_len("initialisation weights", frames.len() * s, w.len())?;
                for (x, wt) in frames.iter().zip(w.chunks_exact(s)) {
                    if wt[i] > 0.0 && !x.iter().all(|v| v.is_nan()) {
                        xs.extend_from_slice(x);
                        ws.push(wt[i]);
                    }
                }
            }
            if ws.is_empty() {
                return Err(EmissionError::InvalidParameter {
                    name: "initialisation weights",
                    reason: format!("state {i} received no frame with positive weight"),
                });
            }
            let frames = Frames::new(&xs, d)?;
            let mut sub = MStepReport::default();
            next.push(
                st.initialise(frames, &ws, reg, &mut sub, rng)
                    .map_err(|e| self.locate(e, i))?,
            );
            report.absorb_state(i, sub);
        }
        Ok((PerState::new(next)?, report))
    }
}

impl<D: StateDistribution> Marginal for PerState<D> {
    fn marginal(&self, dims: &[usize]) -> Result<Self> {
        crate::check_dims(dims, self.dim())?;
        let states = self
            .states
            .iter()
            .enumerate()
            .map(|(i, st)| st.marginal(dims).map_err(|e| self.locate(e, i)))
            .collect::<Result<Vec<_>>>()?;
        PerState::new(states)
    }
}

impl<D: StateDistribution> ConcatStates for PerState<D> {
    fn concat_states(&self, other: &Self) -> Result<Self> {
        check_dim(self.dim(), other.dim())?;
        let mut states = self.states.clone();
        states.extend(other.states.iter().cloned());
        PerState::new(states)
    }
}

/// The conditionals of a [`PerState`] emission: one [`StateSplit`] per state.
#[derive(Debug, Clone)]
pub struct PerStateSplit<P> {
    input: Vec<usize>,
    output: Vec<usize>,
    splits: Vec<P>,
}

impl<P: StateSplit> ConditionalSplit for PerStateSplit<P> {
    fn n_states(&self) -> usize {
        self.splits.len()
    }

    fn input_dims(&self) -> &[usize] {
        &self.input
    }

    fn output_dims(&self) -> &[usize] {
        &self.output
    }

    fn input_log_density(&mut self, state: usize, input: &[f64]) -> Result<f64> {
        check_state(state, self.splits.len())?;
        check_len("regression input", self.input.len(), input.len())?;
        Ok(self.splits[state].input_log_density(input))
    }

    fn predict(
        &mut self,
        state: usize,
        input: &[f64],
        mean: &mut [f64],
        covariance: &mut [f64],
    ) -> Result<()> {
        check_state(state, self.splits.len())?;
        let o = self.output.len();
        check_len("regression input", self.input.len(), input.len())?;
        check_len("regression mean", o, mean.len())?;
        check_len("regression covariance", o * o, covariance.len())?;
        self.splits[state]
            .predict(input, mean, covariance)
            .map_err(|e| e.at_state(state, None))
    }
}

impl<D: StateConditional> Conditional for PerState<D> {
    type Split = PerStateSplit<D::Split>;

    fn conditional(&self, input: &[usize], output: &[usize]) -> Result<Self::Split> {
        check_split(input, output, self.dim())?;
        let splits = self
            .states
            .iter()
            .enumerate()
            .map(|(i, st)| st.conditional(input, output).map_err(|e| self.locate(e, i)))
            .collect::<Result<Vec<_>>>()?;
        Ok(PerStateSplit {
            input: input.to_vec(),
            output: output.to_vec(),
            splits,
        })
    }
}
