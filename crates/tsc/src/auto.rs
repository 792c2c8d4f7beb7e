//! The `auto` preset: a predictor that tunes itself.
//!
//! `auto` chooses among model families (the HMM, the TSC-HMM union, static
//! GMR from a GMM), numbers of states, regularisations and emissions by
//! cross-validated prediction error of the robot from the human on the
//! training demonstrations only (folds of whole demonstrations, shuffled by
//! the options' seed), with early abandoning of hopeless candidates by
//! successive halving ([`Halving::default`]: every candidate on 2 folds, the
//! best third, at least 3, on to all folds), then refits the best five on
//! all training demonstrations and predicts with their mean
//! ([`crate::Selection::Mean`], [`DEFAULT_ENSEMBLE`]; `ensemble=1` refits the
//! winner alone). See [`crate::cross_validation`] for the criterion, the folds
//! and the rule; the fit's summary carries the whole table
//! ([`crate::FitSummary::cv_table`], the mean's own held-out row last) and the
//! choice ([`crate::FitSummary::chosen`]).
//!
//! **Unit-free candidates by default.** The default grid ([`Grid::UnitFree`],
//! [`unit_free_grid`]) gives every candidate's `reg` as a fraction of a
//! variance of the data (`reg-pos`: each position's; `reg-rel`: each
//! feature's), so every candidate fits the same model in metres, millimetres
//! or z-scores. The choice is by the squared error summed over the scored
//! dims in the user's units: the data's, the same under a change of unit
//! common to them (m → mm); on z-scored data the roles carry the deviations
//! as error units ([`crate::Roles::with_error_units`]; the command's
//! `--standardise` sets them), since z-scoring gives each dim its own scale
//! and would otherwise reweight the dims in that sum and change which
//! candidates are averaged. With them `auto` on z-scores predicts what it
//! predicts in metres (tested; on NuiSI the same MSE per seed to 2e-9). The grid of the paper's unit
//! (`grid=default`, `reg` in m² on NuiSI) is kept by name.
//!
//! **Why a mean.** Cross-validation on six to eight demonstrations ranks
//! close candidates by noise: the winner changes with the training subset
//! and whichever unit-free grid chooses one candidate loses to the 7-state
//! HMM on some action. The mean of the best few is never worse than their
//! average error on the held-out frames (Jensen) and in practice better than
//! the best alone (ABLATION.md, "A unit-free mean of the best candidates").
//!
//! Every candidate is a plain method specification, `NAME:key=value,...`, the
//! same the command line reads (`hmm:states=7,reg=1e-3`), made on top of the
//! options `auto` was given (seed, iterations, tolerance, runs, emission and the
//! unit of `reg` pass through; the grid's keys override; a grid's `reg=` sets
//! the amount in that unit, so `auto:reg-units=relative` makes every
//! candidate's `reg` a fraction of each feature's variance): a new candidate is one line of
//! [`DEFAULT_GRID`] or [`SMALL_GRID`], and its family is its preset's name.
//!
//! **Calibrated uncertainty.** The winner's predictive covariance is then
//! given the shape of its held-out errors as far as held-out likelihood asks
//! for it, and sized so that a new demonstration's frames fall inside its
//! 95 % regions at 95 % in expectation, with how hard a demonstration is
//! measured on the folds' held-out demonstrations ([`Calibration::Predictive`];
//! training demonstrations only; see [`crate::cross_validation`]): the bands
//! are the data's, not the regulariser's. The added covariance, the factor
//! and the coverage/NLPD before and after are in the summary
//! ([`crate::FitSummary::covariance_calibration`]). The calibration is fitted
//! on the scored dims (the robot's positions, from the command); the other
//! robot dims' covariance is multiplied by the same factor, nothing added, and
//! is not calibrated.
//!
//! Keys (`auto:key=value`, [`AutoSettings::set`]):
//! `grid=unit-free|small|default|relative|positions|mixed`, `folds=K` (`K ≥ 2`, clamped
//! to the number of demonstrations), `families=hmm+tsc-hmm` (a `+`-separated
//! subset of the grid's families), `halving=on|off`, `ensemble=K` (the mean
//! of the best `K`, 5 by default; 1: the best alone), `choose=best|one-se`
//! (one candidate: `best` is `ensemble=1`; `one-se` with `ensemble=K > 1` is
//! refused) ([`crate::Selection`]), `calibrate=on|predictive|demonstrations|frames|off`
//! (`on` = `predictive`, the default; `demonstrations` widens the pooled
//! factor by what leaving each held-out demonstration out misses; `frames`
//! pools the held-out frames). The mean is calibrated on its own held-out
//! frames (the members' held-out predictions combined as the mean predicts).
//!
//! Not done: warm starts across folds (an HMM fitted on folds `A ∪ B` started
//! from the one fitted on `A` is a different fit, so the choice would depend
//! on the rung order; no warm start here is exact, so none is used).
//!
//! ```
//! use phasekit_tsc::{AutoSettings, Grid, Selection};
//! let s = AutoSettings::default();
//! assert_eq!((s.grid(), s.selection()), (Grid::UnitFree, Selection::Mean(5)));
//! let one = AutoSettings::set(AutoSettings::builder(), "ensemble", "1")?.build()?;
//! assert_eq!(one.selection(), Selection::Best);
//! # Ok::<(), phasekit_tsc::TscError>(())
//! ```

use crate::cross_validation::Halving;
use crate::emission_choice::EmissionKind;
use crate::error::{Result, TscError};
use crate::method::{Calibration, CrossValidation, Method, Selection};
use crate::preset::{Preset, PresetOptions, PresetOptionsBuilder};
use crate::reg_units::RegUnits;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The default grid: 23 candidates over the HMM (states × regularisation),
/// the TSC-HMM union, the left-right HSMM, Student-t emissions and static GMR
/// (Gaussian and Student-t components: ABLATION.md, "the static mixtures").
pub const DEFAULT_GRID: &[&str] = &[
    "hmm:states=5,reg=1e-2",
    "hmm:states=5,reg=1e-3",
    "hmm:states=7,reg=1e-2",
    "hmm:states=7,reg=3e-3",
    "hmm:states=7,reg=1e-3",
    "hmm:states=10,reg=1e-2",
    "hmm:states=10,reg=3e-3",
    "hmm:states=10,reg=1e-3",
    "hmm:states=13,reg=1e-3",
    "hmm:states=7,reg=1e-3,emission=student-t",
    "tsc-hmm:states=4,reg=1e-2",
    "tsc-hmm:states=4,reg=1e-3",
    "tsc-hmm:states=7,reg=1e-2",
    "tsc-hmm:states=7,reg=1e-3",
    "tsc-hmm:states=4,reg=1e-3,emission=student-t",
    "hsmm:states=4,reg=1e-2",
    "hsmm:states=4,reg=1e-3",
    "gmm:states=5,reg=1e-2",
    "gmm:states=10,reg=1e-2",
    "gmm:states=10,reg=1e-3",
    "gmm:states=15,reg=1e-3",
    "gmm:states=5,reg=1e-2,emission=student-t",
    "gmm:states=10,reg=1e-3,emission=student-t",
];

/// The default grid in units of the data: every candidate's `reg` a fraction
/// of each feature's variance (`reg-rel`), 0.3, 0.1 and 0.03 where the
/// default grid has 1e-2, 3e-3 and 1e-3 m² (those values over a hand
/// position's typical variance on NuiSI, 0.03 m²), for data in any unit.
pub const RELATIVE_GRID: &[&str] = &[
    "hmm:states=5,reg-rel=0.3",
    "hmm:states=5,reg-rel=0.03",
    "hmm:states=7,reg-rel=0.3",
    "hmm:states=7,reg-rel=0.1",
    "hmm:states=7,reg-rel=0.03",
    "hmm:states=10,reg-rel=0.3",
    "hmm:states=10,reg-rel=0.1",
    "hmm:states=10,reg-rel=0.03",
    "hmm:states=13,reg-rel=0.03",
    "hmm:states=7,reg-rel=0.03,emission=student-t",
    "tsc-hmm:states=4,reg-rel=0.3",
    "tsc-hmm:states=4,reg-rel=0.03",
    "tsc-hmm:states=7,reg-rel=0.3",
    "tsc-hmm:states=7,reg-rel=0.03",
    "tsc-hmm:states=4,reg-rel=0.03,emission=student-t",
    "hsmm:states=4,reg-rel=0.3",
    "hsmm:states=4,reg-rel=0.03",
    "gmm:states=5,reg-rel=0.3",
    "gmm:states=10,reg-rel=0.3",
    "gmm:states=10,reg-rel=0.03",
    "gmm:states=15,reg-rel=0.03",
    "gmm:states=5,reg-rel=0.3,emission=student-t",
    "gmm:states=10,reg-rel=0.03,emission=student-t",
];

/// The default grid in units of the positions: every candidate's `reg` a
/// fraction of each feature's position's variance (`reg-pos`,
/// [`RegUnits::Positions`]: a velocity regularised by as much as its
/// position, as the paper's absolute `reg` does on data in one unit), 0.3,
/// 0.1 and 0.03 where the default grid has 1e-2, 3e-3 and 1e-3 m². Every
/// candidate fits the same model whatever the unit of each feature; the
/// choice is the same under a unit common to the scored dims (m → mm), and
/// under a scale of each when the roles carry it as error units (z-scores:
/// see [`unit_free_grid`]).
pub const POSITIONS_GRID: &[&str] = &[
    "hmm:states=5,reg-pos=0.3",
    "hmm:states=5,reg-pos=0.03",
    "hmm:states=7,reg-pos=0.3",
    "hmm:states=7,reg-pos=0.1",
    "hmm:states=7,reg-pos=0.03",
    "hmm:states=10,reg-pos=0.3",
    "hmm:states=10,reg-pos=0.1",
    "hmm:states=10,reg-pos=0.03",
    "hmm:states=13,reg-pos=0.03",
    "hmm:states=7,reg-pos=0.03,emission=student-t",
    "tsc-hmm:states=4,reg-pos=0.3",
    "tsc-hmm:states=4,reg-pos=0.03",
    "tsc-hmm:states=7,reg-pos=0.3",
    "tsc-hmm:states=7,reg-pos=0.03",
    "tsc-hmm:states=4,reg-pos=0.03,emission=student-t",
    "hsmm:states=4,reg-pos=0.3",
    "hsmm:states=4,reg-pos=0.03",
    "gmm:states=5,reg-pos=0.3",
    "gmm:states=10,reg-pos=0.3",
    "gmm:states=10,reg-pos=0.03",
    "gmm:states=15,reg-pos=0.03",
    "gmm:states=5,reg-pos=0.3,emission=student-t",
    "gmm:states=10,reg-pos=0.03,emission=student-t",
];

/// The six candidates that [`Grid::Mixed`] adds to [`POSITIONS_GRID`]: they
/// keep the velocities (`reg-rel`: a fraction of each feature's own
/// variance), unit-free too.
pub const KEEP_VELOCITIES: &[&str] = &[
    "hmm:states=7,reg-rel=0.1",
    "hmm:states=10,reg-rel=0.1",
    "tsc-hmm:states=4,reg-rel=0.1",
    "hsmm:states=4,reg-rel=0.03",
    "hsmm:states=4,reg-rel=0.1",
    "gmm:states=10,reg-rel=0.1",
];

/// The unit-free grid, `auto`'s default: [`POSITIONS_GRID`] and
/// [`RELATIVE_GRID`] together (46 candidates), every `reg` a fraction of a
/// variance of the data, so that every candidate fits the same model in any
/// unit (metres, millimetres, z-scores). The choice among them ranks by the
/// held-out error in the user's units ([`crate::Roles::with_error_units`]:
/// the command sets them when it z-scores), so it is the same in every unit
/// too. Choosing one of them lost to the 7-state HMM on one action in one
/// unit system; with the mean of the top five ([`crate::Selection::Mean`])
/// that loss is gone against the metres baselines and down to 4.5 % against
/// the z-scored ones (ABLATION.md, "A unit-free mean of the best
/// candidates").
pub fn unit_free_grid() -> Vec<&'static str> {
    [POSITIONS_GRID, RELATIVE_GRID].concat()
}

/// The size of `auto`'s default mean ([`crate::Selection::Mean`]).
pub const DEFAULT_ENSEMBLE: usize = 5;

/// The small grid: 9 candidates, every family with its most useful settings.
pub const SMALL_GRID: &[&str] = &[
    "hmm:states=5,reg=1e-2",
    "hmm:states=7,reg=1e-2",
    "hmm:states=7,reg=1e-3",
    "hmm:states=10,reg=1e-2",
    "hmm:states=10,reg=1e-3",
    "tsc-hmm:states=4,reg=1e-2",
    "tsc-hmm:states=4,reg=1e-3",
    "gmm:states=8,reg=1e-2",
    "gmm:states=8,reg=1e-3",
];

/// Which list of candidates `auto` searches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Grid {
    /// [`SMALL_GRID`].
    Small,
    /// [`DEFAULT_GRID`] (`reg` in the data's units: m² on NuiSI).
    Default,
    /// [`RELATIVE_GRID`].
    Relative,
    /// [`POSITIONS_GRID`].
    Positions,
    /// [`POSITIONS_GRID`] and [`KEEP_VELOCITIES`].
    Mixed,
    /// [`unit_free_grid`]: [`POSITIONS_GRID`] and [`RELATIVE_GRID`].
    #[default]
    #[serde(rename = "unit-free")]
    UnitFree,
}

impl Grid {
    /// The candidates' specifications.
    pub fn specs(self) -> Vec<&'static str> {
        match self {
            Grid::Small => SMALL_GRID.to_vec(),
            Grid::Default => DEFAULT_GRID.to_vec(),
            Grid::Relative => RELATIVE_GRID.to_vec(),
            Grid::Positions => POSITIONS_GRID.to_vec(),
            Grid::Mixed => [POSITIONS_GRID, KEEP_VELOCITIES].concat(),
            Grid::UnitFree => unit_free_grid(),
        }
    }
}

impl fmt::Display for Grid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Grid::Small => "small",
            Grid::Default => "default",
            Grid::Relative => "relative",
            Grid::Positions => "positions",
            Grid::Mixed => "mixed",
            Grid::UnitFree => "unit-free",
        })
    }
}

impl FromStr for Grid {
    type Err = TscError;
    fn from_str(s: &str) -> Result<Grid> {
        match s {
            "small" => Ok(Grid::Small),
            "default" => Ok(Grid::Default),
            "relative" => Ok(Grid::Relative),
            "positions" => Ok(Grid::Positions),
            "mixed" => Ok(Grid::Mixed),
            "unit-free" => Ok(Grid::UnitFree),
            _ => Err(TscError::InvalidSetting {
                name: "grid",
                reason: format!(
                    "unknown grid `{s}`; known: unit-free, small, default, relative, positions, mixed"
                ),
            }),
        }
    }
}

/// The settings of `auto`, validated once by [`AutoSettingsBuilder::build`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AutoSettings {
    grid: Grid,
    folds: usize,
    families: Option<Vec<String>>,
    halving: bool,
    /// Settings written before calibration existed read as
    /// [`Calibration::Demonstrations`] (the default rule when the field
    /// became a name): their model files carry no calibration, so they
    /// predict as they did; those written when it was a flag read `true` as
    /// the rule of the time, [`Calibration::Frames`].
    #[serde(default = "default_calibration")]
    calibrate: Calibration,
    /// How the winner is chosen, or the mean of how many (not written when
    /// [`Selection::Best`], which settings written before the mean read as).
    #[serde(default, skip_serializing_if = "Selection::is_best")]
    choose: Selection,
}

fn default_calibration() -> Calibration {
    Calibration::Demonstrations
}

impl Default for AutoSettings {
    /// The unit-free grid, 5 folds, every family, halving on, the mean of
    /// the best [`DEFAULT_ENSEMBLE`], calibration for a new demonstration
    /// ([`Calibration::Predictive`]).
    fn default() -> Self {
        AutoSettings {
            grid: Grid::UnitFree,
            folds: 5,
            families: None,
            halving: true,
            calibrate: Calibration::Predictive,
            choose: Selection::Mean(DEFAULT_ENSEMBLE),
        }
    }
}

/// Builder of [`AutoSettings`]; [`AutoSettingsBuilder::build`] validates once.
#[derive(Debug, Clone)]
pub struct AutoSettingsBuilder(AutoSettings, ChoiceKeys);

/// Which of the keys that set the choice were given (`choose`, `ensemble`):
/// `choose=one-se` picks one candidate, `ensemble=K > 1` averages `K`, so
/// both together are refused rather than one silently ignored.
#[derive(Debug, Clone, Copy, Default)]
struct ChoiceKeys {
    /// `choose=best` or `choose=one-se`, if given.
    one: Option<Selection>,
    ensemble: Option<usize>,
}

impl AutoSettingsBuilder {
    /// Which grid.
    pub fn grid(mut self, grid: Grid) -> Self {
        self.0.grid = grid;
        self
    }
    /// `K ≥ 2` folds (clamped to the number of demonstrations when fitting).
    pub fn folds(mut self, k: usize) -> Self {
        self.0.folds = k;
        self
    }
    /// Only the candidates of these families (preset names: `hmm`, `tsc-hmm`, `gmm`).
    pub fn families<S: Into<String>>(mut self, families: impl IntoIterator<Item = S>) -> Self {
        self.0.families = Some(families.into_iter().map(Into::into).collect());
        self
    }
    /// Early abandoning by successive halving (on by default).
    pub fn halving(mut self, on: bool) -> Self {
        self.0.halving = on;
        self
    }
    /// How the winner's predictive covariance is calibrated on the folds
    /// ([`Calibration::Predictive`] by default).
    pub fn calibrate(mut self, rule: Calibration) -> Self {
        self.0.calibrate = rule;
        self
    }
    /// How the winner is chosen, or the mean of how many
    /// ([`Selection::Mean`] of [`DEFAULT_ENSEMBLE`] by default).
    pub fn choose(mut self, rule: Selection) -> Self {
        self.0.choose = rule;
        self
    }
    /// The mean of the best `k` (`ensemble=K`; `K = 1`: the best alone).
    pub fn ensemble(mut self, k: usize) -> Self {
        self.1.ensemble = Some(k);
        self.0.choose = if k == 1 {
            Selection::Best
        } else {
            Selection::Mean(k)
        };
        self
    }
    /// Validates the settings: at least 2 folds, every family one of the grid's.
    pub fn build(self) -> Result<AutoSettings> {
        if let (Some(one), Some(k)) = (self.1.one, self.1.ensemble) {
            if k > 1 {
                return Err(TscError::InvalidSetting {
                    name: "choose",
                    reason: format!(
                        "choose={one} picks one candidate and ensemble={k} averages {k}: give one of them"
                    ),
                });
            }
        }
        let mut s = self.0;
        if let Some(one) = self.1.one {
            s.choose = one;
        }
        if s.choose == Selection::Mean(0) {
            return Err(TscError::InvalidSetting {
                name: "ensemble",
                reason: "the mean of 0 candidates: K must be at least 1".into(),
            });
        }
        if s.folds < 2 {
            return Err(TscError::InvalidSetting {
                name: "folds",
                reason: format!("cross-validation needs at least 2 folds, got {}", s.folds),
            });
        }
        if let Some(fams) = &s.families {
            let known = families_of(&s.grid.specs());
            if fams.is_empty() {
                return Err(TscError::InvalidSetting {
                    name: "families",
                    reason: format!("no family given; known: {}", known.join("+")),
                });
            }
            for f in fams {
                if !known.contains(&f.as_str()) {
                    return Err(TscError::InvalidSetting {
                        name: "families",
                        reason: format!(
                            "`{f}` is not a family of the {} grid; known: {}",
                            s.grid,
                            known.join(", ")
                        ),
                    });
                }
            }
        }
        Ok(s)
    }
}

/// The families (preset names) of a grid, in order of first appearance.
fn families_of(specs: &[&'static str]) -> Vec<&'static str> {
    let mut out: Vec<&'static str> = Vec::new();
    for s in specs {
        let name = s.split_once(':').map_or(*s, |(n, _)| n);
        if !out.contains(&name) {
            out.push(name);
        }
    }
    out
}

impl AutoSettings {
    /// A builder starting from [`AutoSettings::default`].
    pub fn builder() -> AutoSettingsBuilder {
        AutoSettingsBuilder(AutoSettings::default(), ChoiceKeys::default())
    }
    /// A builder starting from these settings.
    pub fn to_builder(&self) -> AutoSettingsBuilder {
        AutoSettingsBuilder(self.clone(), ChoiceKeys::default())
    }
    /// Which grid.
    pub fn grid(&self) -> Grid {
        self.grid
    }
    /// Folds.
    pub fn folds(&self) -> usize {
        self.folds
    }
    /// The families searched (`None`: all of the grid's).
    pub fn families(&self) -> Option<&[String]> {
        self.families.as_deref()
    }
    /// Whether hopeless candidates are abandoned early.
    pub fn halving(&self) -> bool {
        self.halving
    }
    /// How the winner's predictive covariance is calibrated on the folds.
    pub fn calibration(&self) -> Calibration {
        self.calibrate
    }
    /// How the winner is chosen.
    pub fn selection(&self) -> Selection {
        self.choose
    }

    /// Whether `key` is one of `auto`'s own keys (`grid`, `folds`, `families`,
    /// `halving`, `calibrate`, `choose`, `ensemble`).
    pub fn is_key(key: &str) -> bool {
        matches!(
            key,
            "grid" | "folds" | "families" | "halving" | "calibrate" | "choose" | "ensemble"
        )
    }

    /// Sets one `auto:key=value` setting on a builder; errors name the key.
    pub fn set(b: AutoSettingsBuilder, key: &str, value: &str) -> Result<AutoSettingsBuilder> {
        let bad = |name, reason: String| TscError::InvalidSetting { name, reason };
        Ok(match key {
            "grid" => b.grid(value.parse()?),
            "folds" => {
                b.folds(value.parse().map_err(|e| {
                    bad("folds", format!("`{value}` is not a number of folds: {e}"))
                })?)
            }
            "families" => b.families(value.split('+').map(str::trim)),
            "halving" => match value {
                "on" => b.halving(true),
                "off" => b.halving(false),
                _ => return Err(bad("halving", format!("expected on or off, got `{value}`"))),
            },
            "choose" => match value {
                "best" | "one-se" => {
                    let one = if value == "best" {
                        Selection::Best
                    } else {
                        Selection::OneStandardError
                    };
                    let mut b = b.choose(one);
                    b.1.one = Some(one);
                    b
                }
                _ => {
                    return Err(bad(
                        "choose",
                        format!("expected best or one-se, got `{value}`"),
                    ))
                }
            },
            "ensemble" => b.ensemble(value.parse().map_err(|e| {
                bad(
                    "ensemble",
                    format!("`{value}` is not a number of candidates to average: {e}"),
                )
            })?),
            "calibrate" => match value {
                "on" | "predictive" => b.calibrate(Calibration::Predictive),
                "demonstrations" => b.calibrate(Calibration::Demonstrations),
                "frames" => b.calibrate(Calibration::Frames),
                "off" => b.calibrate(Calibration::Off),
                _ => {
                    return Err(bad(
                        "calibrate",
                        format!(
                            "expected on (= predictive), predictive, demonstrations, frames or off, got `{value}`"
                        ),
                    ))
                }
            },
            _ => {
                return Err(bad(
                    "method",
                    format!(
                    "unknown key `{key}` of auto; known: grid, folds, families, halving, calibrate, choose, ensemble"
                ),
                ))
            }
        })
    }

    /// The candidates, labelled by their specification, made on top of `base`.
    pub fn candidates(&self, base: &PresetOptions) -> Result<Vec<(String, Method)>> {
        let specs: Vec<&str> = self
            .grid
            .specs()
            .iter()
            .copied()
            .filter(|s| {
                let name = s.split_once(':').map_or(*s, |(n, _)| n);
                self.families
                    .as_ref()
                    .is_none_or(|f| f.iter().any(|x| x == name))
            })
            .collect();
        specs
            .into_iter()
            .map(|s| Ok((s.to_string(), method_of_spec(s, base)?)))
            .collect()
    }

    /// The method: a cross-validated choice among [`AutoSettings::candidates`],
    /// folds shuffled by `base`'s seed, with [`Halving::default`] when on.
    pub fn method(&self, base: &PresetOptions) -> Result<Method> {
        let cv = CrossValidation::new(self.candidates(base)?, self.folds)?
            .with_fold_seed(base.seed())
            .with_calibration(self.calibrate)
            .with_selection(self.choose);
        Ok(Method::CrossValidated(if self.halving {
            cv.with_halving(Halving::default())
        } else {
            cv
        }))
    }
}

/// The method of a specification `NAME[:key=value,...]` on top of `base`.
/// Keys: `states`, `tsc-states`, `window`, `reg`, `reg-units`
/// (`absolute`|`relative`|`positions`), `reg-rel` (`reg-rel=R` is
/// `reg=R,reg-units=relative`), `reg-pos` (`reg=R,reg-units=positions`),
/// `emission`, `max-iter`, `restarts`. `reg=` sets the amount only: its unit is
/// `base`'s (`auto:reg-units=relative` makes every candidate's `reg` relative).
pub fn method_of_spec(spec: &str, base: &PresetOptions) -> Result<Method> {
    let (name, rest) = spec.split_once(':').unwrap_or((spec, ""));
    let preset: Preset = name.parse()?;
    let mut o = base.to_builder();
    for kv in rest.split(',').filter(|s| !s.is_empty()) {
        let (k, v) = kv.split_once('=').ok_or_else(|| TscError::InvalidSetting {
            name: "method",
            reason: format!("`{kv}` in `{spec}` is not key=value"),
        })?;
        o = apply_setting(o, k, v).map_err(|reason| TscError::InvalidSetting {
            name: "method",
            reason: format!("`{kv}` in `{spec}`: {reason}"),
        })?;
    }
    Method::preset(preset, &o.build()?)
}

/// One `key=value` of a specification.
fn apply_setting(
    o: PresetOptionsBuilder,
    k: &str,
    v: &str,
) -> std::result::Result<PresetOptionsBuilder, String> {
    let num = |v: &str| v.parse::<usize>().map_err(|e| e.to_string());
    Ok(match k {
        "states" => o.states(num(v)?),
        "tsc-states" => o.tsc_states(num(v)?),
        "window" => o.window(num(v)?),
        "max-iter" => o.max_iter(num(v)?),
        "restarts" => o.restarts(num(v)?),
        "reg" => o.reg(v.parse::<f64>().map_err(|e| e.to_string())?),
        "reg-units" => o.reg_units(v.parse::<RegUnits>().map_err(|e| e.to_string())?),
        "reg-rel" => o
            .reg(v.parse::<f64>().map_err(|e| e.to_string())?)
            .reg_units(RegUnits::Relative),
        "reg-pos" => o
            .reg(v.parse::<f64>().map_err(|e| e.to_string())?)
            .reg_units(RegUnits::Positions),
        "emission" => o.emission(v.parse::<EmissionKind>().map_err(|e| e.to_string())?),
        other => return Err(format!("unknown key `{other}`")),
    })
}
