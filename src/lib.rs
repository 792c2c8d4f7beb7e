//! phasekit: learning interactions from demonstrations with probabilistic models.
//!
//! Segment a two-person (or person–robot) interaction into phases, and
//! predict the robot's motion from the human's as it happens. This facade
//! re-exports the member crates, lowest layer first:
//!
//! * [`emission`]: the `Emission` trait and its distributions (Gaussian with
//!   full, diagonal, spherical or tied covariances, Student-t, categorical,
//!   Poisson, mixtures), frames with missing values, regularisation;
//! * [`hmm`]: hidden Markov models over any emission (forward-backward,
//!   Viterbi, online filter, Baum-Welch, state selection by BIC);
//! * [`hsmm`]: hidden semi-Markov models (explicit state durations) over any
//!   emission: forward-backward, Viterbi, online filter, EM;
//! * [`gmm`]: mixture models by EM over any emission (BIC, G-means);
//! * [`gmr`]: Gaussian mixture regression from a GMM or an HMM, batch and
//!   online;
//! * [`tsc`]: transition state clustering (the TSC-HMM of Hahne et al.,
//!   HRI'24, and Krishnan-style TSC) as compositions of the above, and the
//!   named methods (presets) the `phasekit` command runs.
//!
//! `ARCHITECTURE.md` at the repository's root says which crate owns which
//! formula and how to add an emission, a composition or a command.
//!
//! # Example
//!
//! Fit the paper's HMM to generated two-person interactions and predict the
//! robot's hand from the human's, one frame at a time, as a controller would:
//!
//! ```
//! use phasekit::emission::{CovarianceType, Gaussian, Regularisation, SequenceSet, Shape};
//! use phasekit::gmr::HmmRegression;
//! use phasekit::hmm::{BaumWelch, Convergence, HmmInit};
//! use phasekit::tsc::synthetic;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // 12-D joint frames: the human's hand position and velocity (dims 0..6), the robot's (6..12).
//! let demos: Vec<Vec<f64>> = synthetic::generate(8, 0)
//!     .iter()
//!     .map(synthetic::with_velocities)
//!     .collect();
//! let data = SequenceSet::new(&demos[..7], 12)?;
//!
//! // The paper-compatible protocol: k-bins, (10 cm)² on the diagonal, at most 40 M-steps.
//! let bw = BaumWelch::builder()
//!     .max_iter(40)
//!     .tol(1e-4)
//!     .convergence(Convergence::MeanPerSequence)
//!     .regularisation(Regularisation::add_diagonal(1e-2)?)
//!     .init(HmmInit::KBins { smoothing: 0.01 })
//!     .build()?;
//! let shape = Shape { n_states: 4, dim: 12 };
//! let fitted = bw.fit(&Gaussian::standard(CovarianceType::Full, shape)?, &data)?;
//!
//! // HMM-GMR: the robot's dims given the human's, frame by frame.
//! let gmr = HmmRegression::new(&fitted.model, &[0, 1, 2, 3, 4, 5], &[6, 7, 8, 9, 10, 11])?;
//! let mut online = gmr.online();
//! for frame in demos[7].chunks_exact(12) {
//!     let robot = online.step(&frame[..6])?; // the robot's hand position and velocity
//!     assert!(robot.iter().all(|v| v.is_finite()));
//! }
//! # Ok(())
//! # }
//! ```

pub use phasekit_emission as emission;
pub use phasekit_gmm as gmm;
pub use phasekit_gmr as gmr;
pub use phasekit_hmm as hmm;
pub use phasekit_hsmm as hsmm;
pub use phasekit_tsc as tsc;
