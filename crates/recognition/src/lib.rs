//! Which interaction is the human starting? A library of interactions,
//! online recognition, rejection of unknown motions, and continuous streams.
//!
//! The paper's prediction assumes an oracle that tells the robot which
//! interaction is happening. This crate removes it:
//!
//! * [`library`]: a [`Library`] holds one fitted model per action (any method
//!   of `phasekit_tsc`, by name), the prior `p(a)`, a rest state and calibrated
//!   rejection thresholds; serialisable and checked when built or read;
//! * [`recogniser`]: online recognition with one filter per action,
//!   `p(a | o¹_{1:t}) ∝ p(a) · p(o¹_{1:t} | λ_a)` from the normalisers of the
//!   human-marginal forward filters the prediction already runs; the robot's
//!   prediction from the most probable action's GMR or the posterior-weighted
//!   mixture (moment-matched covariance); the rest pose while a motion is rejected;
//! * [`rejection`]: unknown motions rejected by a likelihood-per-frame test or
//!   Lee & Kim's threshold model, thresholds calibrated on held-out training
//!   demonstrations;
//! * [`composed`]: the library as one composed HMM (every action's states and
//!   a rest state, transitions from each action's end into rest and from rest
//!   into each action's start) for continuous streams;
//! * [`metrics`] and [`experiment`]: how it is scored, and the experiment of
//!   `phasekit evaluate --task recognition`.
//!
//! Everything the crate needs from the methods' models goes through [`parts`].
//!
//! ```no_run
//! use phasekit_recognition::{Library, LibrarySettings, Recogniser, RecogniserSettings};
//! # fn demo(handshakes: &phasekit_emission::SequenceSet, waves: &phasekit_emission::SequenceSet,
//! #         method: &phasekit_tsc::Method, roles: &phasekit_tsc::Roles, frame: &[f64])
//! #         -> phasekit_recognition::Result<()> {
//! let (library, _reports) = Library::fit(
//!     &[("handshake", handshakes, method), ("wave", waves, method)],
//!     None,                                          // each model recognises its action
//!     roles,
//!     &LibrarySettings::default(),
//! )?;
//! let mut recogniser = Recogniser::new(&library, RecogniserSettings::default())?;
//! let decision = recogniser.step(frame)?;            // the human's features of one frame
//! let p = recogniser.posterior();                    // p(a | frames so far), per action
//! let robot = recogniser.robot();                    // the robot's predicted features
//! # let _ = (decision, p, robot); Ok(()) }
//! ```

#![warn(missing_docs)]

pub mod composed;
pub mod error;
pub mod experiment;
pub mod library;
pub mod metrics;
pub mod parts;
pub mod recogniser;
pub mod rejection;

pub use composed::{ComposedHmm, ComposedRecogniser};
pub use error::{RecognitionError, Result};
pub use library::{
    Calibration, FittedAction, Library, LibraryAction, LibraryParams, LibrarySettings, Prior,
    RestState, MIN_ACTIONS,
};
pub use recogniser::{
    action_posterior, mix_predictions, AutoReset, Decision, PredictionMode, Recogniser,
    RecogniserSettings,
};
pub use rejection::{threshold_hmm, Rejection};
