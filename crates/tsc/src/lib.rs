//! Transition state clustering, built from small parts so that every method is a composition.
//!
//! The parts:
//! * [`detect`]: labellers (GMM, HMM Viterbi, HMM filtered argmax on all dims or a
//!   marginal) and transition detectors (label changes, disagreement of two
//!   labellings, dilation by ±w, runs);
//! * [`hmm_settings`]: the settings of one HMM fit, with the automatic choice of
//!   its number of states;
//! * [`tsc_hmm`]: the seed paper's TSC-HMM (Hahne et al., HRI'24, Algorithm 1)
//!   and the compositions of a base HMM with a transition HMM (union with
//!   warm-started or frozen emissions, likelihood gate);
//! * [`krishnan`]: Krishnan-style TSC over a GMM (IJRR 2017), with pruning and
//!   automatic component counts, optional time sub-clustering and
//!   per-demonstration segmentations;
//! * [`select`]: automatic choice of component and state counts (BIC, G-means),
//!   bounded by what the data support.
//!
//! The methods built from them:
//! * [`preset`]: the named methods ([`Preset`]: `hmm`, `tsc-hmm`, `gmm-tsc`, `gmm`, …)
//!   and the options they share ([`PresetOptions`]);
//! * [`method`]: a [`Method`] with all its settings, and fitting it;
//! * [`model`]: the fitted [`Model`], its [`Predictor`] and its [`Segmentation`];
//! * [`predictor`]: batch and online prediction of the robot from the human;
//! * [`cross_validation`]: the criterion of the `-cv` presets;
//! * [`summary`]: what a fit did ([`FitSummary`]).
//!
//! Every settings type is a validated builder (`X::builder()…build()?`,
//! `x.to_builder()` to change one), also validated when deserialised; errors
//! name the parameter (the builder method), see [`TscError::describe`].
//!
//! # Example
//!
//! Fit the paper's TSC-HMM to generated handshakes, predict the robot's hand
//! from the human's frame by frame, and segment a demonstration:
//!
//! ```
//! use phasekit_emission::{Frames, SequenceSet};
//! use phasekit_tsc::synthetic::generate;
//! use phasekit_tsc::{human_frames, Method, Preset, PresetOptions, Roles};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // Six demonstrations: human hand xyz (dims 0..3), robot hand xyz (3..6).
//! let demos = generate(6, 1);
//! let frames: Vec<&[f64]> = demos.iter().map(|d| &d.frames[..]).collect();
//! let train = SequenceSet::new(&frames, 6)?;
//! let roles = Roles::new(vec![0, 1, 2], vec![3, 4, 5])?;
//!
//! let options = PresetOptions::builder().window(2).build()?;
//! let method = Method::preset("tsc-hmm".parse::<Preset>()?, &options)?;
//! let (model, summary) = method.fit(&train, &roles)?;
//! assert_eq!(model.n_states(), 7); // 4 base states and 3 transition states
//! assert!(summary.transition_segments.unwrap() > 0);
//!
//! // Online prediction: one human frame in, one robot frame out.
//! let test = &generate(1, 99)[0];
//! let seq = Frames::new(&test.frames, 6)?;
//! let mut online = model.predictor(&roles)?.online();
//! for human in human_frames(seq, &roles)?.chunks_exact(3) {
//!     let robot = online.step(human, false)?;
//!     assert_eq!(robot.len(), 3);
//! }
//!
//! // Segmentation by the states of the model that predicts (the union's 7),
//! // with the base HMM's 4 beside them.
//! let seg = model.segment(seq, &roles)?;
//! assert!(seg.labels.iter().all(|&s| s < 7));
//! assert!(seg.base_labels.unwrap().iter().all(|&s| s < 4));
//! # Ok(())
//! # }
//! ```

#![warn(missing_docs)]

pub mod auto;
pub mod cross_validation;
pub mod detect;
pub mod emission_choice;
pub mod error;
pub mod hmm_settings;
pub mod hsmm_gmr;
pub mod krishnan;
pub mod method;
pub mod model;
pub mod predictor;
pub mod preset;
pub mod reg_units;
pub mod roles;
pub mod segmentation;
pub mod select;
pub mod summary;
pub mod synthetic;
pub mod tsc_hmm;

pub use auto::{AutoSettings, AutoSettingsBuilder, Grid};
pub use cross_validation::{cross_validate, CvRow, FoldPlan, Halving};
pub use emission_choice::{AnyEmission, AnySplit, AnyStats, EmissionKind, StateMoments};
pub use error::{NoTransitionCause, ParameterNamer, Result, TscError};
pub use hmm_settings::{AutoStates, AutoStatesReport, HmmSettings, HmmSettingsBuilder};
pub use hsmm_gmr::{DurationFamily, HsmmSettings, HsmmSettingsBuilder};
pub use krishnan::{
    KrishnanReport, KrishnanSettings, KrishnanSettingsBuilder, KrishnanTsc, TimeClustering,
};
pub use method::{
    Calibration, CrossValidation, GmmSettings, GmmSettingsBuilder, Method, Selection,
};
pub use model::{EnsembleMember, Model};
pub use predictor::{human_frames, OnlinePredictor, Predictor};
pub use preset::{
    Preset, PresetOptions, PresetOptionsBuilder, AUTO_MIN_STATES, DEFAULT_COMPOSITION,
};
pub use reg_units::{feature_variances, position_scales, scale_data, scale_model, RegUnits};
pub use roles::Roles;
pub use segmentation::Segmentation;
pub use select::{AutoCount, GMeansStates, Selector};
pub use summary::{CovarianceCalibration, FitStop, FitSummary};
pub use tsc_hmm::{Composition, Detector, TscHmm, TscReport, TscSettings, TscSettingsBuilder};
