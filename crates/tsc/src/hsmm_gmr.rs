//! The `hsmm` preset: a left-right hidden semi-Markov model (explicit phase
//! durations) on joint frames, predicting by HSMM-GMR
//! ([`phasekit_gmr::HsmmRegression`]: the human-marginal online filter with
//! durations weighs the per-state conditionals of the robot given the human).
//!
//! The emission is any of the HMM presets' ([`EmissionKind`]), fitted by EM
//! together with the durations (`phasekit_hsmm::HsmmEm`): k-bins
//! initialisation, left-right transitions (`i → i + 1`), the last segment
//! right-censored (a demonstration may stop in the middle of its last phase),
//! `reg` added to every covariance after each M-step as for the HMM, and a
//! pseudo-count of `1e-2` on the duration counts.

use crate::emission_choice::{AnyEmission, EmissionKind};
use crate::error::{Result, TscError};
use crate::hmm_settings::HmmSettings;
use phasekit_emission::{Regularisation, SequenceSet};
use phasekit_hsmm::{
    suggested_max_duration, AnyDuration, Censoring, Convergence, DurationRegularisation,
    GaussianDuration, Hsmm, HsmmEm, HsmmFitReport, HsmmInit, NegativeBinomialDuration,
    NonParametricDuration, PoissonDuration, Structure,
};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The family of the per-state duration distributions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DurationFamily {
    /// A free pmf over `1..=D` per state (`non-parametric`).
    NonParametric,
    /// A shifted Poisson (`poisson`).
    Poisson,
    /// A shifted negative binomial (`negative-binomial`).
    NegativeBinomial,
    /// pbdlib's discretised Gaussian (`gaussian`, the default: two
    /// parameters per state, a width independent of the mean).
    #[default]
    Gaussian,
}

impl DurationFamily {
    /// Every family, in the order the help lists them.
    pub const ALL: [DurationFamily; 4] = [
        DurationFamily::Gaussian,
        DurationFamily::Poisson,
        DurationFamily::NegativeBinomial,
        DurationFamily::NonParametric,
    ];

    /// The name [`DurationFamily::from_str`] reads.
    pub fn name(self) -> &'static str {
        match self {
            DurationFamily::NonParametric => "non-parametric",
            DurationFamily::Poisson => "poisson",
            DurationFamily::NegativeBinomial => "negative-binomial",
            DurationFamily::Gaussian => "gaussian",
        }
    }

    /// The initial durations of `n_states` states up to `max_duration` frames
    /// (k-bins then moves them to the bins' lengths).
    pub fn template(self, n_states: usize, max_duration: usize) -> Result<AnyDuration> {
        Ok(match self {
            DurationFamily::NonParametric => {
                NonParametricDuration::uniform(n_states, max_duration)?.into()
            }
            DurationFamily::Poisson => PoissonDuration::template(n_states, max_duration)?.into(),
            DurationFamily::NegativeBinomial => {
                NegativeBinomialDuration::template(n_states, max_duration)?.into()
            }
            DurationFamily::Gaussian => GaussianDuration::template(n_states, max_duration)?.into(),
        })
    }
}

impl fmt::Display for DurationFamily {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for DurationFamily {
    type Err = TscError;
    fn from_str(s: &str) -> Result<Self> {
        DurationFamily::ALL
            .into_iter()
            .find(|d| d.name() == s)
            .ok_or_else(|| TscError::InvalidSetting {
                name: "duration",
                reason: format!(
                    "unknown duration family `{s}`; known: {}",
                    DurationFamily::ALL.map(DurationFamily::name).join(", ")
                ),
            })
    }
}

/// Settings of the `hsmm` preset, validated once by [`HsmmSettingsBuilder::build`]
/// (and on deserialisation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "HsmmSettingsRaw")]
pub struct HsmmSettings {
    /// States, emission, regularisation, iterations, tolerance, runs and seed.
    hmm: HmmSettings,
    duration: DurationFamily,
    /// Longest phase in frames; `None`: [`suggested_max_duration`] of the data.
    max_duration: Option<usize>,
}

#[derive(Deserialize)]
struct HsmmSettingsRaw {
    hmm: HmmSettings,
    #[serde(default)]
    duration: DurationFamily,
    #[serde(default)]
    max_duration: Option<usize>,
}

impl TryFrom<HsmmSettingsRaw> for HsmmSettings {
    type Error = TscError;
    fn try_from(r: HsmmSettingsRaw) -> Result<Self> {
        HsmmSettingsBuilder(HsmmSettings {
            hmm: r.hmm,
            duration: r.duration,
            max_duration: r.max_duration,
        })
        .build()
    }
}

impl Default for HsmmSettings {
    /// The HMM's defaults (4 full-covariance states, `reg = 1e-2`, 40
    /// iterations, tolerance `1e-4`), Gaussian durations, the suggested maximum duration.
    fn default() -> Self {
        HsmmSettings {
            hmm: HmmSettings::default(),
            duration: DurationFamily::default(),
            max_duration: None,
        }
    }
}

/// Builder of [`HsmmSettings`].
#[derive(Debug, Clone)]
pub struct HsmmSettingsBuilder(HsmmSettings);

impl HsmmSettingsBuilder {
    /// The states, emission and EM settings (as for an HMM; no automatic state count).
    pub fn hmm(mut self, hmm: HmmSettings) -> Self {
        self.0.hmm = hmm;
        self
    }
    /// The duration family.
    pub fn duration(mut self, d: DurationFamily) -> Self {
        self.0.duration = d;
        self
    }
    /// The longest phase `D ≥ 1` in frames (`None`: suggested from the data).
    pub fn max_duration(mut self, d: Option<usize>) -> Self {
        self.0.max_duration = d;
        self
    }
    /// Validates the settings.
    pub fn build(self) -> Result<HsmmSettings> {
        let s = self.0;
        if s.hmm.auto_states().is_some() {
            return Err(TscError::InvalidSetting {
                name: "states",
                reason: "the hsmm preset takes a number of states, not an automatic choice".into(),
            });
        }
        if s.max_duration == Some(0) {
            return Err(TscError::InvalidSetting {
                name: "max_duration",
                reason: "a phase lasts at least one frame: give a maximum duration ≥ 1".into(),
            });
        }
        Ok(s)
    }
}

impl HsmmSettings {
    /// A builder from the defaults.
    pub fn builder() -> HsmmSettingsBuilder {
        HsmmSettingsBuilder(HsmmSettings::default())
    }
    /// A builder from these settings.
    pub fn to_builder(&self) -> HsmmSettingsBuilder {
        HsmmSettingsBuilder(self.clone())
    }
    /// States, emission and EM settings.
    pub fn hmm(&self) -> &HmmSettings {
        &self.hmm
    }
    /// The duration family.
    pub fn duration(&self) -> DurationFamily {
        self.duration
    }
    /// The maximum duration given (`None`: suggested from the data).
    pub fn max_duration(&self) -> Option<usize> {
        self.max_duration
    }
    /// The emission of every state.
    pub fn emission(&self) -> EmissionKind {
        self.hmm.emission()
    }

    /// The EM of the preset (see the module documentation).
    pub fn em(&self) -> Result<HsmmEm> {
        let h = &self.hmm;
        Ok(HsmmEm::builder()
            .max_iter(h.max_iter())
            .tol(h.tol())
            .convergence(Convergence::MeanPerSequence)
            .regularisation(Regularisation::add_diagonal(h.reg())?)
            .duration_regularisation(DurationRegularisation::none().with_pseudo_count(1e-2)?)
            .init(HsmmInit::KBins { smoothing: 0.01 })
            .structure(Structure::LeftRight { skip: 0 })
            .censoring(Censoring::RightCensored)
            .restarts(h.restarts())
            .seed(h.seed())
            .build()?)
    }

    /// Fits the HSMM to joint training sequences.
    pub fn fit(&self, data: &SequenceSet) -> Result<(Hsmm<AnyEmission>, HsmmFitReport)> {
        let s = self.hmm.states();
        let d = self
            .max_duration
            .unwrap_or_else(|| suggested_max_duration(data, s));
        let durations = self.duration.template(s, d)?;
        let template = self.hmm.template(s, data.dim())?;
        let fit = self.em()?.fit(&template, &durations, data)?;
        Ok((fit.model, fit.report))
    }
}
