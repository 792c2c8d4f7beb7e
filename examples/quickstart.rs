//! The README's library example as a whole program: fit the paper's HMM to
//! generated two-person interactions, then predict the robot's hand from the
//! human's, frame by frame, as a controller would.
//!
//!     cargo run --release --example quickstart

use phasekit::emission::{CovarianceType, Gaussian, Regularisation, SequenceSet, Shape};
use phasekit::gmr::HmmRegression;
use phasekit::hmm::{BaumWelch, Convergence, HmmInit};
use phasekit::tsc::synthetic;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // 12-D joint frames: human hand x, y, z and velocity (dims 0..6), robot's (6..12).
    let demos: Vec<Vec<f64>> = synthetic::generate(12, 0)
        .iter()
        .map(synthetic::with_velocities)
        .collect();
    let data = SequenceSet::new(&demos[..10], 12)?;
    let bw = BaumWelch::builder()
        .max_iter(40)
        .tol(1e-4)
        .convergence(Convergence::MeanPerSequence)
        .regularisation(Regularisation::add_diagonal(1e-2)?)
        .init(HmmInit::KBins { smoothing: 0.01 })
        .build()?;
    let fitted = bw.fit(
        &Gaussian::standard(
            CovarianceType::Full,
            Shape {
                n_states: 4,
                dim: 12,
            },
        )?,
        &data,
    )?;
    println!(
        "fitted 4 states in {} EM iterations, log-likelihood {:.1}",
        fitted.report.iterations,
        fitted.report.log_likelihood.last().unwrap_or(&f64::NAN)
    );
    let gmr = HmmRegression::new(&fitted.model, &[0, 1, 2, 3, 4, 5], &[6, 7, 8, 9, 10, 11])?;
    let mut online = gmr.online();
    let (mut se, mut n) = (0.0, 0.0);
    for frame in demos[11].chunks_exact(12) {
        let human_frame = &frame[..6];
        let robot = online.step(human_frame)?; // the robot's predicted hand and velocity
        se += (0..3)
            .map(|k| (100.0 * (robot[k] - frame[6 + k])).powi(2))
            .sum::<f64>();
        n += 1.0;
    }
    println!(
        "online prediction of a new demonstration: MSE {:.2} cm² over {n} frames",
        se / n
    );
    Ok(())
}
