//! The settings of one HMM fit (the paper-compatible protocol by default) and
//! the automatic choice of its number of states.

use crate::emission_choice::{AnyEmission, EmissionKind};
use crate::error::{Result, TscError};
use crate::reg_units::RegUnits;
use crate::select::{check_range, fit_gmeans_states, gmeans_count, Selector};
use phasekit_emission::{CovarianceType, Emission, Regularisation, SequenceSet};
use phasekit_hmm::{
    max_supported_states, select_states_bic, BaumWelch, Convergence, Hmm, HmmError, HmmFitReport,
    HmmInit, StateLimit,
};
use serde::{Deserialize, Serialize};
use std::ops::RangeInclusive;

/// An automatic choice of the number of HMM states in `min..=max`: by BIC, the
/// count whose HMM, fitted by the same Baum-Welch settings, has the lowest
/// `BIC(S) = −2 log p(O | λ̂_S) + p_S log N` (`p_S` free parameters, `N` frames;
/// `phasekit_hmm::select_states_bic`); by G-means, the number of Gaussian
/// clusters G-means finds in the pooled frames (`phasekit_gmm::gmeans`).
///
/// `max` is lowered to what the data support (`phasekit_hmm::max_supported_states`)
/// when the fit runs, and the fit's report says so.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "AutoStatesRaw")]
pub struct AutoStates {
    min: usize,
    max: usize,
    selector: Selector,
}

/// The serialised form of [`AutoStates`], before validation.
#[derive(Deserialize)]
struct AutoStatesRaw {
    min: usize,
    max: usize,
    #[serde(default)]
    selector: Selector,
}

impl TryFrom<AutoStatesRaw> for AutoStates {
    type Error = TscError;
    fn try_from(r: AutoStatesRaw) -> Result<Self> {
        AutoStates::new(r.min, r.max, r.selector)
    }
}

impl AutoStates {
    /// The counts `min..=max` (`1 ≤ min ≤ max`), chosen by `selector`.
    pub fn new(min: usize, max: usize, selector: Selector) -> Result<Self> {
        check_range("max_states", &(min..=max))?;
        Ok(AutoStates { min, max, selector })
    }

    /// BIC over `min..=max` states.
    pub fn bic(min: usize, max: usize) -> Result<Self> {
        Self::new(min, max, Selector::Bic)
    }

    /// Fewest states tried.
    pub fn min(&self) -> usize {
        self.min
    }

    /// Most states tried (before the limits of the data).
    pub fn max(&self) -> usize {
        self.max
    }

    /// How the count is chosen.
    pub fn selector(&self) -> Selector {
        self.selector
    }
}

/// Settings of one HMM fit with full-covariance Gaussian emissions or another
/// [`EmissionKind`]; [`HmmSettings::paper`] is the paper-compatible protocol.
///
/// Validated once, by [`HmmSettingsBuilder::build`] (and on deserialisation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "HmmSettingsRaw")]
pub struct HmmSettings {
    states: usize,
    reg: f64,
    max_iter: usize,
    tol: f64,
    restarts: usize,
    seed: u64,
    covariance: CovarianceType,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    auto_states: Option<AutoStates>,
    /// Written only when not the default (files stay as they were for full
    /// Gaussians); a file without it has Gaussian states of `covariance`.
    #[serde(default, skip_serializing_if = "EmissionKind::is_default")]
    emission: EmissionKind,
    /// The unit of `reg` (written only when relative: files without it are absolute).
    #[serde(default, skip_serializing_if = "RegUnits::is_absolute")]
    reg_units: RegUnits,
}

/// The serialised form of [`HmmSettings`], before validation (the field names
/// of model files written since version 1).
#[derive(Deserialize)]
struct HmmSettingsRaw {
    states: usize,
    reg: f64,
    max_iter: usize,
    tol: f64,
    restarts: usize,
    seed: u64,
    covariance: CovarianceType,
    #[serde(default)]
    auto_states: Option<AutoStates>,
    #[serde(default)]
    emission: Option<EmissionKind>,
    #[serde(default)]
    reg_units: RegUnits,
}

impl TryFrom<HmmSettingsRaw> for HmmSettings {
    type Error = TscError;
    fn try_from(r: HmmSettingsRaw) -> Result<Self> {
        HmmSettingsBuilder(HmmSettings {
            states: r.states,
            reg: r.reg,
            max_iter: r.max_iter,
            tol: r.tol,
            restarts: r.restarts,
            seed: r.seed,
            covariance: r.covariance,
            auto_states: r.auto_states,
            emission: r.emission.unwrap_or(EmissionKind::Gaussian(r.covariance)),
            reg_units: r.reg_units,
        })
        .build()
    }
}

impl Default for HmmSettings {
    /// The paper-compatible setting with 4 states ([`HmmSettings::paper`]).
    fn default() -> Self {
        HmmSettings {
            states: 4,
            reg: 1e-2,
            max_iter: 40,
            tol: 1e-4,
            restarts: 1,
            seed: 0,
            covariance: CovarianceType::Full,
            auto_states: None,
            emission: EmissionKind::Gaussian(CovarianceType::Full),
            reg_units: RegUnits::Absolute,
        }
    }
}

/// Builder of [`HmmSettings`]; [`HmmSettingsBuilder::build`] validates once.
#[derive(Debug, Clone)]
pub struct HmmSettingsBuilder(HmmSettings);

impl HmmSettingsBuilder {
    /// `states ≥ 1` states (and no automatic choice).
    pub fn states(mut self, states: usize) -> Self {
        self.0.states = states;
        self.0.auto_states = None;
        self
    }
    /// Choose the number of states automatically (the fixed `states` is then not used).
    pub fn auto_states(mut self, auto: AutoStates) -> Self {
        self.0.auto_states = Some(auto);
        self
    }
    /// `r ≥ 0` added to every covariance diagonal at initialisation and after
    /// every M-step, in the data's units squared (`1e-2` on data in metres is (10 cm)²).
    pub fn reg(mut self, reg: f64) -> Self {
        self.0.reg = reg;
        self
    }
    /// The unit of `reg` ([`RegUnits::Relative`]: `reg · diag(v)`, `v` the
    /// features' variances over the training frames). Applied by
    /// [`crate::Method::fit`], which fits on the features divided by their
    /// standard deviations and maps the model back ([`crate::reg_units`]);
    /// [`HmmSettings::fit_selected`] itself always adds `reg` as it is.
    pub fn reg_units(mut self, units: RegUnits) -> Self {
        self.0.reg_units = units;
        self
    }
    /// At most `n ≥ 1` M-steps.
    pub fn max_iter(mut self, n: usize) -> Self {
        self.0.max_iter = n;
        self
    }
    /// Stop when the gain of the mean log-likelihood per sequence is below `tol ≥ 0`.
    pub fn tol(mut self, tol: f64) -> Self {
        self.0.tol = tol;
        self
    }
    /// `n ≥ 1` runs from different initialisations (the first from k-bins, then k-means++).
    pub fn restarts(mut self, n: usize) -> Self {
        self.0.restarts = n;
        self
    }
    /// Seed of the random initialisations.
    pub fn seed(mut self, seed: u64) -> Self {
        self.0.seed = seed;
        self
    }
    /// Covariance structure of Gaussian emissions (the emission becomes
    /// `EmissionKind::Gaussian(covariance)`).
    pub fn covariance(mut self, covariance: CovarianceType) -> Self {
        self.0.covariance = covariance;
        self.0.emission = EmissionKind::Gaussian(covariance);
        self
    }
    /// The emission of every state (a Gaussian choice also sets the
    /// covariance structure; the others have full covariances or scales).
    pub fn emission(mut self, emission: EmissionKind) -> Self {
        self.0.emission = emission;
        self.0.covariance = emission.covariance().unwrap_or(CovarianceType::Full);
        self
    }
    /// Validates the settings, naming the first bad one.
    pub fn build(self) -> Result<HmmSettings> {
        let s = self.0;
        let bad = |name, reason: String| Err(TscError::InvalidSetting { name, reason });
        if s.auto_states.is_none() && s.states == 0 {
            return bad("states", "at least one state is needed".into());
        }
        if !(s.reg.is_finite() && s.reg >= 0.0) {
            return bad("reg", format!("must be a finite number ≥ 0, got {}", s.reg));
        }
        if !(s.tol.is_finite() && s.tol >= 0.0) {
            return bad("tol", format!("must be a finite number ≥ 0, got {}", s.tol));
        }
        if s.max_iter == 0 {
            return bad("max_iter", "at least one iteration is needed".into());
        }
        if s.restarts == 0 {
            return bad("restarts", "at least one run is needed".into());
        }
        if let Some(c) = s.emission.covariance() {
            if c != s.covariance {
                return bad(
                    "emission",
                    format!(
                        "the emission is {} but the covariance structure {:?}",
                        s.emission, s.covariance
                    ),
                );
            }
        }
        Ok(s)
    }
}

/// How the number of states was chosen automatically, for the fit's report.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct AutoStatesReport {
    /// How.
    pub selector: Selector,
    /// The number of states chosen.
    pub best: usize,
    /// The candidates (after the limits of the data).
    pub range: RangeInclusive<usize>,
    /// `(S, BIC(S))` of every candidate fitted (G-means: of the one fitted).
    pub scores: Vec<(usize, f64)>,
    /// `(S, why)` for every BIC candidate that could not be fitted.
    pub failures: Vec<(usize, HmmError)>,
    /// `(asked, why)` when the data support fewer states than the `max` asked for.
    pub lowered: Option<(usize, StateLimit)>,
    /// G-means' own count, when it is below the range and was raised to its lower end.
    pub raised_from: Option<usize>,
}

impl AutoStatesReport {
    /// One line: `states=5 (BIC)`, with what bounded or moved the choice appended.
    pub fn summary(&self) -> String {
        let how = match self.selector {
            Selector::Bic => "BIC",
            Selector::GMeans => "G-means",
        };
        let mut s = format!("states={} ({how}", self.best);
        if let Some(found) = self.raised_from {
            s.push_str(&format!(
                "; it found {found} cluster{}, raised to the fewest states tried",
                if found == 1 { "" } else { "s" }
            ));
        }
        if let Some((asked, limit)) = &self.lowered {
            s.push_str(&format!(
                "; at most {} states of the {asked} asked for: {limit}",
                self.range.end()
            ));
        }
        s.push(')');
        s
    }
}

impl HmmSettings {
    /// A builder starting from [`HmmSettings::default`] (the paper's, 4 states).
    pub fn builder() -> HmmSettingsBuilder {
        HmmSettingsBuilder(HmmSettings::default())
    }

    /// A builder starting from these settings (to change some of them).
    pub fn to_builder(&self) -> HmmSettingsBuilder {
        HmmSettingsBuilder(self.clone())
    }

    /// The paper-compatible setting: `states ≥ 1` full-covariance states,
    /// `reg = 1e-2`, 40 iterations, tolerance `1e-4` on the mean log-likelihood
    /// per sequence, one k-bins run.
    pub fn paper(states: usize) -> Result<Self> {
        Self::builder().states(states).build()
    }

    /// Number of states (not used when [`HmmSettings::auto_states`] is set).
    pub fn states(&self) -> usize {
        self.states
    }
    /// The covariance regularisation `r` (see [`HmmSettingsBuilder::reg`]).
    pub fn reg(&self) -> f64 {
        self.reg
    }
    /// The unit of `reg` (see [`HmmSettingsBuilder::reg_units`]).
    pub fn reg_units(&self) -> RegUnits {
        self.reg_units
    }
    /// At most this many M-steps.
    pub fn max_iter(&self) -> usize {
        self.max_iter
    }
    /// Tolerance on the gain of the mean log-likelihood per sequence.
    pub fn tol(&self) -> f64 {
        self.tol
    }
    /// Runs from different initialisations.
    pub fn restarts(&self) -> usize {
        self.restarts
    }
    /// Seed of the random initialisations.
    pub fn seed(&self) -> u64 {
        self.seed
    }
    /// Covariance structure of the emissions (of Gaussian emissions; full
    /// for the others).
    pub fn covariance(&self) -> CovarianceType {
        self.covariance
    }
    /// The emission of every state.
    pub fn emission(&self) -> EmissionKind {
        self.emission
    }
    /// The automatic choice of the number of states, if any.
    pub fn auto_states(&self) -> Option<AutoStates> {
        self.auto_states
    }
    /// The fewest states a fit with these settings has (`states`, or the
    /// automatic range's lower end): every demonstration needs that many frames.
    pub fn min_states(&self) -> usize {
        self.auto_states.map_or(self.states, |a| a.min)
    }

    /// The Baum-Welch settings: temporal k-bins with `ε = 0.01`, `reg` added
    /// after every M-step, the tolerance on the mean log-likelihood per sequence.
    pub fn baum_welch(&self) -> Result<BaumWelch> {
        Ok(BaumWelch::builder()
            .max_iter(self.max_iter)
            .tol(self.tol)
            .convergence(Convergence::MeanPerSequence)
            .regularisation(Regularisation::add_diagonal(self.reg)?)
            .init(HmmInit::KBins { smoothing: 0.01 })
            .restarts(self.restarts)
            .seed(self.seed)
            .build()?)
    }

    /// The emission structure with `n_states` states of dimension `dim`.
    pub fn template(&self, n_states: usize, dim: usize) -> phasekit_emission::Result<AnyEmission> {
        self.emission.template(n_states, dim)
    }

    /// Fits an HMM with these settings to `data` (choosing the number of
    /// states first when [`HmmSettings::auto_states`] is set).
    pub fn fit(&self, data: &SequenceSet) -> Result<(Hmm<AnyEmission>, HmmFitReport)> {
        let (hmm, report, _) = self.fit_selected(data)?;
        Ok((hmm, report))
    }

    /// [`HmmSettings::fit`] for any emission: `template(S, D)` makes the
    /// emission of `S` states of dimension `D` every fit starts from (the
    /// settings' own emission choice is then not used).
    pub fn fit_with<E: Emission>(
        &self,
        data: &SequenceSet,
        template: &impl Fn(usize, usize) -> phasekit_emission::Result<E>,
    ) -> Result<(Hmm<E>, HmmFitReport)> {
        let (hmm, report, _) = self.fit_selected_with(data, template)?;
        Ok((hmm, report))
    }

    /// Fits an HMM with these settings to `data`; with `auto_states`, first
    /// chooses the number of states and reports how.
    ///
    /// The candidates stop at what the data support
    /// (`phasekit_hmm::max_supported_states`: the shortest demonstration, and
    /// no more free parameters than frames), and the report says when that
    /// lowered the range. A G-means count above the range is refused
    /// ([`TscError::GMeansAboveRange`]); one below it is raised to its lower end.
    pub fn fit_selected(
        &self,
        data: &SequenceSet,
    ) -> Result<(Hmm<AnyEmission>, HmmFitReport, Option<AutoStatesReport>)> {
        self.fit_selected_with(data, &|n, d| self.template(n, d))
    }

    /// [`HmmSettings::fit_selected`] for any emission (see [`HmmSettings::fit_with`]).
    pub fn fit_selected_with<E: Emission>(
        &self,
        data: &SequenceSet,
        template: &impl Fn(usize, usize) -> phasekit_emission::Result<E>,
    ) -> Result<(Hmm<E>, HmmFitReport, Option<AutoStatesReport>)> {
        let bw = self.baum_welch()?;
        let dim = data.dim();
        let template = |k| template(k, dim);
        let Some(auto) = self.auto_states else {
            let fitted = bw.fit(&template(self.states)?, data)?;
            return Ok((fitted.model, fitted.report, None));
        };
        let (supported, limit) = max_supported_states(template, data)?;
        let hi = auto.max.min(supported).max(1);
        let lo = auto.min.min(hi);
        let lowered = (hi < auto.max).then_some((auto.max, limit));
        match auto.selector {
            Selector::Bic => {
                let sel = select_states_bic(&bw, template, data, lo..=hi)?;
                // Refitting the chosen count repeats the selection's fit exactly
                // (same initialisation and seed), so the model is the one scored.
                let fitted = bw.fit(&template(sel.best)?, data)?;
                Ok((
                    fitted.model,
                    fitted.report,
                    Some(AutoStatesReport {
                        selector: auto.selector,
                        best: sel.best,
                        range: lo..=hi,
                        scores: sel.scores,
                        failures: sel.failures,
                        lowered,
                        raised_from: None,
                    }),
                ))
            }
            Selector::GMeans => {
                let clusters = gmeans_count(
                    data.all_frames(),
                    hi,
                    "HMM states",
                    lowered.map(|(asked, limit)| (asked, limit.to_string())),
                )?;
                let found = clusters.k;
                let g = fit_gmeans_states(&bw, template, data, clusters, lo..=hi)?;
                Ok((
                    g.fitted.model,
                    g.fitted.report,
                    Some(AutoStatesReport {
                        selector: auto.selector,
                        best: g.best,
                        range: lo..=hi,
                        scores: vec![(g.best, g.bic)],
                        failures: Vec::new(),
                        lowered,
                        raised_from: (found < lo).then_some(found),
                    }),
                ))
            }
        }
    }
}
