//! Named methods (presets) and the options they share.
//!
//! * [`Preset::Hmm`] (`hmm`): the paper's baseline, an HMM on joint frames with HMM-GMR;
//! * [`Preset::Hsmm`] (`hsmm`): a left-right HSMM (explicit phase durations) on joint
//!   frames with HSMM-GMR ([`crate::hsmm_gmr`]);
//! * [`Preset::TscHmm`] (`tsc-hmm`): the paper's TSC-HMM with the default composition
//!   ([`DEFAULT_COMPOSITION`]); `tsc-hmm-union`, `tsc-hmm-frozen`, `tsc-hmm-gated` and
//!   `tsc-hmm-worst` (λ_T trained on the frames the base predicts worst) name the alternatives;
//! * [`Preset::GmmTsc`] (`gmm-tsc`): Krishnan-style TSC over a GMM; its kept transition
//!   clusters join the GMM's components and static GMR predicts;
//! * [`Preset::Gmm`] (`gmm`): static GMR from a GMM;
//! * [`Preset::HmmCv`] and [`Preset::TscHmmCv`] (`hmm-cv`, `tsc-hmm-cv`): the
//!   number of states (and the TSC-HMM's window) chosen by cross-validation.
//!
//! [`Method::preset`] turns a preset and [`PresetOptions`] into a [`Method`]
//! whose every setting is checked.

use crate::emission_choice::EmissionKind;
use crate::error::{Result, TscError};
use crate::hmm_settings::{AutoStates, HmmSettings};
use crate::hsmm_gmr::{DurationFamily, HsmmSettings};
use crate::krishnan::{KrishnanSettings, TimeClustering};
use crate::method::{CrossValidation, GmmSettings, Method};
use crate::reg_units::RegUnits;
use crate::select::Selector;
use crate::tsc_hmm::{Composition, Detector, TscSettings};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The composition used by the `tsc-hmm` preset.
pub const DEFAULT_COMPOSITION: Composition = Composition::Union;

/// Fewest states an automatic choice of states tries (one state has no transitions).
pub const AUTO_MIN_STATES: usize = 2;

/// A named method; parsed from and displayed as its name (`hmm`, `tsc-hmm`, …).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Preset {
    /// `hmm`: an HMM on joint frames, HMM-GMR (the paper's baseline).
    Hmm,
    /// `hsmm`: a left-right HSMM on joint frames, HSMM-GMR.
    Hsmm,
    /// `hmm-cv`: HMMs with `states..=states + tsc_states` states, chosen by 5-fold cross-validation.
    HmmCv,
    /// `tsc-hmm-cv`: those HMMs and the union TSC-HMM with windows 0, 2 and 5, chosen by cross-validation.
    TscHmmCv,
    /// `tsc-hmm`: the paper's TSC-HMM with [`DEFAULT_COMPOSITION`].
    TscHmm,
    /// `tsc-hmm-union`: `λ` and `λ_T` as one HMM, re-trained from that warm start.
    TscHmmUnion,
    /// `tsc-hmm-frozen`: the union with the emissions frozen.
    TscHmmFrozen,
    /// `tsc-hmm-gated`: `λ`'s prediction, replaced by `λ_T`'s where it explains the human better.
    TscHmmGated,
    /// `tsc-hmm-worst`: the union, `λ_T` trained on the 15 % of frames `λ` predicts worst.
    TscHmmWorst,
    /// `gmm-tsc`: Krishnan-style TSC over a GMM, static GMR.
    GmmTsc,
    /// `gmm`: static GMR from a GMM.
    Gmm,
    /// `auto`: the family, states, regularisation and emission chosen by
    /// cross-validation on the training demonstrations ([`crate::auto`]).
    Auto,
}

impl Preset {
    /// Every preset, in the order the help lists them.
    pub const ALL: [Preset; 12] = [
        Preset::Hmm,
        Preset::HmmCv,
        Preset::TscHmmCv,
        Preset::TscHmm,
        Preset::TscHmmUnion,
        Preset::TscHmmFrozen,
        Preset::TscHmmGated,
        Preset::TscHmmWorst,
        Preset::GmmTsc,
        Preset::Gmm,
        Preset::Hsmm,
        Preset::Auto,
    ];

    /// The name [`Preset::from_str`] reads.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Hmm => "hmm",
            Preset::Hsmm => "hsmm",
            Preset::HmmCv => "hmm-cv",
            Preset::TscHmmCv => "tsc-hmm-cv",
            Preset::TscHmm => "tsc-hmm",
            Preset::TscHmmUnion => "tsc-hmm-union",
            Preset::TscHmmFrozen => "tsc-hmm-frozen",
            Preset::TscHmmGated => "tsc-hmm-gated",
            Preset::TscHmmWorst => "tsc-hmm-worst",
            Preset::GmmTsc => "gmm-tsc",
            Preset::Gmm => "gmm",
            Preset::Auto => "auto",
        }
    }

    /// Every preset's name, comma-separated (for help texts and errors).
    pub fn names() -> String {
        Preset::ALL.map(Preset::name).join(", ")
    }

    /// Whether `states=auto` is offered: `hmm`, the TSC-HMM presets (`λ`'s
    /// states) and `gmm-tsc` (the frame mixture); the cross-validated presets
    /// choose their states by cross-validation, and `gmm` has no automatic count.
    pub fn offers_auto_states(self) -> bool {
        !matches!(
            self,
            Preset::HmmCv | Preset::TscHmmCv | Preset::Gmm | Preset::Hsmm | Preset::Auto
        )
    }
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Preset {
    type Err = TscError;
    fn from_str(name: &str) -> Result<Preset> {
        Preset::ALL
            .into_iter()
            .find(|p| p.name() == name)
            .ok_or_else(|| TscError::InvalidSetting {
                name: "method",
                reason: format!("unknown preset `{name}`; known: {}", Preset::names()),
            })
    }
}

/// The options the presets share, validated once by
/// [`PresetOptionsBuilder::build`] (and on deserialisation). A front end
/// fills them from its own inputs (the command line from its flags and
/// `NAME:key=value` settings) and [`Method::preset`] makes the method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "PresetOptionsRaw")]
pub struct PresetOptions {
    states: usize,
    auto_states: bool,
    select: Selector,
    max_states: usize,
    tsc_states: usize,
    window: usize,
    rho: f64,
    time_clusters: usize,
    reg: f64,
    max_iter: usize,
    tol: f64,
    restarts: usize,
    seed: u64,
    #[serde(default, skip_serializing_if = "EmissionKind::is_default")]
    emission: EmissionKind,
    #[serde(default, skip_serializing_if = "is_default_duration")]
    duration: DurationFamily,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    max_duration: Option<usize>,
    #[serde(default, skip_serializing_if = "RegUnits::is_absolute")]
    reg_units: RegUnits,
}

fn is_default_duration(d: &DurationFamily) -> bool {
    *d == DurationFamily::default()
}

/// The serialised form of [`PresetOptions`], before validation.
#[derive(Deserialize)]
struct PresetOptionsRaw {
    states: usize,
    #[serde(default)]
    auto_states: bool,
    #[serde(default)]
    select: Selector,
    #[serde(default = "default_max_states")]
    max_states: usize,
    tsc_states: usize,
    window: usize,
    #[serde(default = "default_rho")]
    rho: f64,
    #[serde(default)]
    time_clusters: usize,
    reg: f64,
    max_iter: usize,
    tol: f64,
    restarts: usize,
    seed: u64,
    #[serde(default)]
    emission: EmissionKind,
    #[serde(default)]
    duration: DurationFamily,
    #[serde(default)]
    max_duration: Option<usize>,
    #[serde(default)]
    reg_units: RegUnits,
}

fn default_max_states() -> usize {
    10
}

fn default_rho() -> f64 {
    0.5
}

impl TryFrom<PresetOptionsRaw> for PresetOptions {
    type Error = TscError;
    fn try_from(r: PresetOptionsRaw) -> Result<Self> {
        PresetOptionsBuilder(PresetOptions {
            states: r.states,
            auto_states: r.auto_states,
            select: r.select,
            max_states: r.max_states,
            tsc_states: r.tsc_states,
            window: r.window,
            rho: r.rho,
            time_clusters: r.time_clusters,
            reg: r.reg,
            max_iter: r.max_iter,
            tol: r.tol,
            restarts: r.restarts,
            seed: r.seed,
            emission: r.emission,
            duration: r.duration,
            max_duration: r.max_duration,
            reg_units: r.reg_units,
        })
        .build()
    }
}

impl Default for PresetOptions {
    /// The paper-compatible values: 4 states, 3 transition states, window ±2, `reg = 1e-2`,
    /// 40 iterations, tolerance `1e-4`, one run, seed 0; automatic choices (when asked
    /// for) by BIC up to 10; `ρ = 0.5`; no time sub-clustering.
    fn default() -> Self {
        PresetOptions {
            states: 4,
            auto_states: false,
            select: Selector::Bic,
            max_states: default_max_states(),
            tsc_states: 3,
            window: 2,
            rho: default_rho(),
            time_clusters: 0,
            reg: 1e-2,
            max_iter: 40,
            tol: 1e-4,
            restarts: 1,
            seed: 0,
            emission: EmissionKind::default(),
            duration: DurationFamily::default(),
            max_duration: None,
            reg_units: RegUnits::Absolute,
        }
    }
}

/// Builder of [`PresetOptions`]; [`PresetOptionsBuilder::build`] validates once.
#[derive(Debug, Clone)]
pub struct PresetOptionsBuilder(PresetOptions);

impl PresetOptionsBuilder {
    /// `n ≥ 1` base states (components for `gmm`), and no automatic choice.
    pub fn states(mut self, n: usize) -> Self {
        self.0.states = n;
        self.0.auto_states = false;
        self
    }
    /// Choose the base states automatically: `hmm` and the TSC-HMM presets
    /// `λ`'s states, `gmm-tsc` the frame mixture (and the GMM it extends), by
    /// [`PresetOptionsBuilder::select`] over `AUTO_MIN_STATES..=max_states`.
    pub fn auto_states(mut self) -> Self {
        self.0.auto_states = true;
        self
    }
    /// How automatic counts are chosen.
    pub fn select(mut self, s: Selector) -> Self {
        self.0.select = s;
        self
    }
    /// Largest count an automatic choice may give (`≥ AUTO_MIN_STATES`; the
    /// data may support fewer, and the fit then says so).
    pub fn max_states(mut self, n: usize) -> Self {
        self.0.max_states = n;
        self
    }
    /// Transition states (TSC-HMM, `≥ 1`) or transition clusters (`gmm-tsc`, 0 = automatic).
    pub fn tsc_states(mut self, n: usize) -> Self {
        self.0.tsc_states = n;
        self
    }
    /// Dilation `±w` of transition frames (TSC-HMM), or frames stacked into
    /// one vector (`gmm-tsc`, `1..=MAX_WINDOW`).
    pub fn window(mut self, w: usize) -> Self {
        self.0.window = w;
        self
    }
    /// `ρ ∈ [0, 1]` of `gmm-tsc`: transition clusters with transitions from
    /// fewer than this fraction of the demonstrations are pruned.
    pub fn rho(mut self, rho: f64) -> Self {
        self.0.rho = rho;
        self
    }
    /// `gmm-tsc`: sub-cluster every kept transition cluster by normalised time
    /// into at most this many sub-clusters (chosen by BIC); 0 = off.
    pub fn time_clusters(mut self, n: usize) -> Self {
        self.0.time_clusters = n;
        self
    }
    /// Covariance regularisation `r ≥ 0`, in the unit of
    /// [`PresetOptionsBuilder::reg_units`] (data units squared by default).
    pub fn reg(mut self, reg: f64) -> Self {
        self.0.reg = reg;
        self
    }
    /// The unit of `reg`: absolute (`r I` added to every covariance, the
    /// paper's; the default) or relative (`r · diag(v)`, `v_j` the variance of
    /// feature `j` over the training frames, 1 for a constant feature; see
    /// [`crate::reg_units`]). Every preset takes it, the cross-validated ones
    /// and `auto` for every candidate.
    pub fn reg_units(mut self, units: RegUnits) -> Self {
        self.0.reg_units = units;
        self
    }
    /// At most `n ≥ 1` EM iterations.
    pub fn max_iter(mut self, n: usize) -> Self {
        self.0.max_iter = n;
        self
    }
    /// Convergence tolerance `≥ 0`.
    pub fn tol(mut self, tol: f64) -> Self {
        self.0.tol = tol;
        self
    }
    /// `n ≥ 1` runs from different initialisations.
    pub fn restarts(mut self, n: usize) -> Self {
        self.0.restarts = n;
        self
    }
    /// Seed of every random choice.
    pub fn seed(mut self, seed: u64) -> Self {
        self.0.seed = seed;
        self
    }
    /// The emission of every HMM state (the HMM presets) or mixture component
    /// (`gmm`, `gmm-tsc`).
    pub fn emission(mut self, emission: EmissionKind) -> Self {
        self.0.emission = emission;
        self
    }
    /// The duration family of `hsmm`.
    pub fn duration(mut self, d: DurationFamily) -> Self {
        self.0.duration = d;
        self
    }
    /// The longest phase of `hsmm` in frames (`None`: suggested from the data).
    pub fn max_duration(mut self, d: Option<usize>) -> Self {
        self.0.max_duration = d;
        self
    }
    /// Validates the options, naming the first bad one (the checks that depend
    /// on the preset, such as a window's range, are [`Method::preset`]'s).
    pub fn build(self) -> Result<PresetOptions> {
        let o = self.0;
        let bad = |name, reason: String| Err(TscError::InvalidSetting { name, reason });
        if o.states == 0 {
            return bad("states", "at least one state is needed".into());
        }
        if o.max_states < AUTO_MIN_STATES {
            return bad(
                "max_states",
                format!(
                    "an automatic choice tries at least {AUTO_MIN_STATES} states, got at most {}",
                    o.max_states
                ),
            );
        }
        if !(0.0..=1.0).contains(&o.rho) {
            return bad(
                "rho",
                format!("the pruning fraction ρ must lie in [0, 1], got {}", o.rho),
            );
        }
        if !(o.reg.is_finite() && o.reg >= 0.0) {
            return bad("reg", format!("must be a finite number ≥ 0, got {}", o.reg));
        }
        if !(o.tol.is_finite() && o.tol >= 0.0) {
            return bad("tol", format!("must be a finite number ≥ 0, got {}", o.tol));
        }
        if o.max_iter == 0 {
            return bad("max_iter", "at least one iteration is needed".into());
        }
        if o.restarts == 0 {
            return bad("restarts", "at least one run is needed".into());
        }
        Ok(o)
    }
}

impl PresetOptions {
    /// A builder starting from [`PresetOptions::default`].
    pub fn builder() -> PresetOptionsBuilder {
        PresetOptionsBuilder(PresetOptions::default())
    }
    /// A builder starting from these options (to change some of them).
    pub fn to_builder(&self) -> PresetOptionsBuilder {
        PresetOptionsBuilder(self.clone())
    }
    /// Base states (components for `gmm`); not used when [`PresetOptions::auto_states`].
    pub fn states(&self) -> usize {
        self.states
    }
    /// Whether the base states are chosen automatically.
    pub fn auto_states(&self) -> bool {
        self.auto_states
    }
    /// How automatic counts are chosen.
    pub fn select(&self) -> Selector {
        self.select
    }
    /// Largest count an automatic choice may give.
    pub fn max_states(&self) -> usize {
        self.max_states
    }
    /// Transition states (TSC-HMM) or transition clusters (`gmm-tsc`, 0 = automatic).
    pub fn tsc_states(&self) -> usize {
        self.tsc_states
    }
    /// Dilation (TSC-HMM) or stacked frames (`gmm-tsc`).
    pub fn window(&self) -> usize {
        self.window
    }
    /// `ρ` of `gmm-tsc`.
    pub fn rho(&self) -> f64 {
        self.rho
    }
    /// Time sub-clusters of `gmm-tsc` (0 = off).
    pub fn time_clusters(&self) -> usize {
        self.time_clusters
    }
    /// Covariance regularisation.
    pub fn reg(&self) -> f64 {
        self.reg
    }
    /// The unit of `reg`.
    pub fn reg_units(&self) -> RegUnits {
        self.reg_units
    }
    /// Maximum iterations.
    pub fn max_iter(&self) -> usize {
        self.max_iter
    }
    /// Tolerance.
    pub fn tol(&self) -> f64 {
        self.tol
    }
    /// Runs.
    pub fn restarts(&self) -> usize {
        self.restarts
    }
    /// Seed.
    pub fn seed(&self) -> u64 {
        self.seed
    }
    /// The emission of every HMM state.
    pub fn emission(&self) -> EmissionKind {
        self.emission
    }
    /// The duration family of `hsmm`.
    pub fn duration(&self) -> DurationFamily {
        self.duration
    }
    /// The longest phase of `hsmm` (`None`: suggested from the data).
    pub fn max_duration(&self) -> Option<usize> {
        self.max_duration
    }
}

impl Method {
    /// The method `preset` names, with the given options; every setting is
    /// checked here, before any fit.
    pub fn preset(preset: Preset, o: &PresetOptions) -> Result<Method> {
        if o.auto_states && !preset.offers_auto_states() {
            return Err(TscError::InvalidSetting {
                name: "states",
                reason: format!(
                    "states=auto is offered for hmm, the tsc-hmm presets (not tsc-hmm-cv) and gmm-tsc, not `{preset}`"
                ),
            });
        }
        let hmm_builder = HmmSettings::builder()
            .states(o.states)
            .reg(o.reg)
            .reg_units(o.reg_units)
            .max_iter(o.max_iter)
            .tol(o.tol)
            .restarts(o.restarts)
            .seed(o.seed)
            .emission(o.emission);
        let hmm = if o.auto_states && preset != Preset::GmmTsc {
            hmm_builder.auto_states(AutoStates::new(AUTO_MIN_STATES, o.max_states, o.select)?)
        } else {
            hmm_builder
        }
        .build()?;
        let tsc = |composition, detector| -> Result<Method> {
            Ok(Method::TscHmm(
                TscSettings::builder()
                    .base(hmm.clone())
                    .tsc_states(o.tsc_states)
                    .window(o.window)
                    .min_run(2)
                    .detector(detector)
                    .composition(composition)
                    .build()?,
            ))
        };
        let gmm = || {
            GmmSettings::builder()
                .components(o.states)
                .reg(o.reg)
                .reg_units(o.reg_units)
                .max_iter(o.max_iter.max(100))
                .tol(1e-3)
                .restarts(o.restarts.max(3))
                .seed(o.seed)
                .emission(o.emission)
                .build()
        };
        let hsmm_only = o.duration != DurationFamily::default() || o.max_duration.is_some();
        if hsmm_only && preset != Preset::Hsmm {
            return Err(TscError::InvalidSetting {
                name: "duration",
                reason: format!("duration and max-duration are settings of hsmm, not `{preset}`"),
            });
        }
        Ok(match preset {
            Preset::Hmm => Method::Hmm(hmm),
            Preset::Hsmm => Method::Hsmm(
                HsmmSettings::builder()
                    .hmm(hmm)
                    .duration(o.duration)
                    .max_duration(o.max_duration)
                    .build()?,
            ),
            Preset::TscHmm => tsc(DEFAULT_COMPOSITION, Detector::Disagreement)?,
            Preset::TscHmmUnion => tsc(Composition::Union, Detector::Disagreement)?,
            Preset::TscHmmFrozen => tsc(Composition::UnionFrozen, Detector::Disagreement)?,
            Preset::TscHmmGated => tsc(Composition::Gated, Detector::Disagreement)?,
            Preset::TscHmmWorst => tsc(
                Composition::Union,
                Detector::WorstPrediction { fraction: 0.15 },
            )?,
            Preset::Gmm => Method::Gmm(gmm()?),
            Preset::Auto => crate::auto::AutoSettings::default().method(o)?,
            Preset::HmmCv | Preset::TscHmmCv => {
                let mut candidates: Vec<(String, Method)> = (o.states..=o.states + o.tsc_states)
                    .map(|s| {
                        Ok((
                            format!("hmm:states={s}"),
                            Method::Hmm(hmm.to_builder().states(s).build()?),
                        ))
                    })
                    .collect::<Result<_>>()?;
                if preset == Preset::TscHmmCv {
                    for w in [0, 2, 5] {
                        let t = o.to_builder().window(w).build()?;
                        candidates.push((
                            format!("tsc-hmm-union:window={w}"),
                            Method::preset(Preset::TscHmmUnion, &t)?,
                        ));
                    }
                }
                Method::CrossValidated(CrossValidation::new(candidates, 5)?)
            }
            Preset::GmmTsc => Method::GmmTsc {
                gmm: gmm()?,
                tsc: KrishnanSettings::builder()
                    .components((!o.auto_states).then_some(o.states))
                    .max_components(o.max_states)
                    .selector(o.select)
                    .window(o.window)
                    .transition_clusters((o.tsc_states > 0).then_some(o.tsc_states))
                    .prune_fraction(o.rho)
                    .time_clusters(if o.time_clusters > 0 {
                        Some(TimeClustering::new(
                            o.time_clusters,
                            TimeClustering::default().reg(),
                        )?)
                    } else {
                        None
                    })
                    .reg(o.reg)
                    .seed(o.seed)
                    .emission(o.emission)
                    .build()?,
            },
        })
    }
}
