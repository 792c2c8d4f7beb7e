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
//! # Example
//!
//! A library of two generated interactions (handshake, wave), each fitted
//! with the paper's HMM, recognises a new wave frame by frame:
//!
//! ```
//! use phasekit_emission::SequenceSet;
//! use phasekit_recognition::{Decision, Library, LibrarySettings, Recogniser, RecogniserSettings};
//! use phasekit_tsc::synthetic::{generate_kind, with_velocities, Kind};
//! use phasekit_tsc::{Method, Preset, PresetOptions, Roles};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // Joint features: the human's hand position and velocity (0..6), the robot's (6..12).
//! let joint = |kind, n, seed| -> Vec<Vec<f64>> {
//!     generate_kind(kind, n, seed).iter().map(with_velocities).collect()
//! };
//! let handshakes = SequenceSet::new(&joint(Kind::Handshake, 6, 1), 12)?;
//! let waves = SequenceSet::new(&joint(Kind::Wave, 6, 1), 12)?;
//! let roles = Roles::new((0..6).collect(), (6..12).collect())?;
//! let method = Method::preset(Preset::Hmm, &PresetOptions::default())?;
//! let (library, _reports) = Library::fit(
//!     &[("handshake", &handshakes, &method), ("wave", &waves, &method)],
//!     None, // each model recognises its own action
//!     &roles,
//!     &LibrarySettings::default(),
//! )?;
//!
//! // A wave the library has not seen, one frame of the human's features at a time.
//! let mut recogniser = Recogniser::new(&library, RecogniserSettings::default())?;
//! let mut decision = Decision::Unknown;
//! for frame in joint(Kind::Wave, 1, 77)[0].chunks_exact(12) {
//!     decision = recogniser.step(&frame[..6])?;
//!     assert_eq!(recogniser.robot().len(), 6); // the robot's predicted features
//! }
//! assert_eq!(decision, Decision::Action(1));
//! assert!(recogniser.posterior()[1] > 0.99); // p(wave | frames so far)
//! # Ok(())
//! # }
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
