//! phasekit: learning interactions from demonstrations with probabilistic models.
//!
//! This facade re-exports the member crates:
//! [`emission`] (pluggable emission distributions), [`hmm`] (hidden Markov models),
//! [`gmm`] (Gaussian mixtures), [`gmr`] (Gaussian mixture regression),
//! [`tsc`] (transition state clustering) and [`recognition`] (which interaction
//! is happening: a library of interactions, online recognition, streams).

pub use phasekit_emission as emission;
pub use phasekit_gmm as gmm;
pub use phasekit_gmr as gmr;
pub use phasekit_hmm as hmm;
pub use phasekit_recognition as recognition;
pub use phasekit_tsc as tsc;
