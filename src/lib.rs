//! phasekit: learning interactions from demonstrations with probabilistic models.
//!
//! This facade re-exports the member crates:
//! [`emission`] (pluggable emission distributions), [`hmm`] (hidden Markov models),
//! [`hsmm`] (hidden semi-Markov models), [`gmm`] (Gaussian mixtures), [`gmr`] (Gaussian mixture regression) and
//! [`tsc`] (transition state clustering).

pub use phasekit_emission as emission;
pub use phasekit_gmm as gmm;
pub use phasekit_gmr as gmr;
pub use phasekit_hmm as hmm;
pub use phasekit_hsmm as hsmm;
pub use phasekit_tsc as tsc;
