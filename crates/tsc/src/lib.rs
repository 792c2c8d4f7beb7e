//! Transition state clustering, built from small parts so that every method is a composition.
//!
//! * [`detect`]: labellers (GMM, HMM Viterbi, HMM filtered argmax on all dims or a
//!   marginal) and transition detectors (label changes, disagreement of two
//!   labellings, dilation by ±w, runs);
//! * [`tsc_hmm`]: the seed paper's HMM and TSC-HMM (Hahne et al., HRI'24,
//!   Algorithm 1) and the compositions of a base HMM with a transition HMM
//!   (union with warm-started or frozen emissions, likelihood gate);
//! * [`krishnan`]: Krishnan-style TSC over a GMM (IJRR 2017), with pruning and
//!   automatic component counts, optional time sub-clustering and
//!   per-demonstration segmentations;
//! * [`select`]: automatic choice of component and state counts (BIC, G-means);
//! * [`preset`]: named methods (`hmm`, `tsc-hmm`, `gmm-tsc`, `gmm`, …), fitted
//!   models with serde, batch and online predictors, and segmentations.

#![warn(missing_docs)]

pub mod detect;
pub mod error;
pub mod krishnan;
pub mod preset;
pub mod select;
pub mod synthetic;
pub mod tsc_hmm;

pub use error::{Result, TscError};
pub use krishnan::{KrishnanSettings, KrishnanTsc, Segmentation, TimeClustering};
pub use preset::{
    FitStop, FitSummary, GmmSettings, Method, Model, OnlinePredictor, Predictor, PresetOptions,
    DEFAULT_COMPOSITION, PRESETS,
};
pub use select::Selector;
pub use tsc_hmm::{Composition, Detector, HmmSettings, Roles, TscHmm, TscReport, TscSettings};
