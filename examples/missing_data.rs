//! How much missing data costs: the accuracy table of BENCHMARKS.md ("Missing
//! data", generated interactions).
//!
//!     cargo run --release --example missing_data
//!
//! Generated handshake-like interactions (`phasekit::tsc::synthetic`, metres):
//! 20 training and 10 test demonstrations per seed, features as in the seed
//! paper (both hands' positions and first differences, 12-D). Values are
//! removed at random from the training demonstrations and from the human's
//! side of the test demonstrations, in three ways:
//!
//! * `values`: every position value independently;
//! * `frames`: whole frames (both hands);
//! * `occlusions`: runs of 10 consecutive frames of the human's hand.
//!
//! Velocities are computed after the removal, so a velocity is missing where
//! either of its positions is. Two ways of fitting the same 5-state HMM
//! (temporal k-bins, reg 1e-4 m², tolerance 1e-4 per sequence):
//!
//! * `EM`: phasekit's missing-value EM (marginal densities of the observed
//!   values, expected statistics of the missing ones), prediction from the
//!   observed human values;
//! * `mean-fill`: what one does without it — every missing value replaced by
//!   its training mean, then a plain fit and prediction.
//!
//! Reported per fraction (mean ± std over 5 seeds): the error of the fitted
//! state means (positions, RMS over states and dims, mm) against the fit to
//! the complete data of the same seed, and the MSE of the robot's predicted
//! hand position on the test demonstrations (cm², truth complete).

use phasekit::emission::{CovarianceType, Frames, Gaussian, Regularisation, SequenceSet, Shape};
use phasekit::gmr::HmmRegression;
use phasekit::hmm::{BaumWelch, Convergence, Hmm, HmmInit};
use phasekit::tsc::synthetic;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const STATES: usize = 5;
const HUMAN: [usize; 6] = [0, 1, 2, 3, 4, 5];
const ROBOT: [usize; 6] = [6, 7, 8, 9, 10, 11];

#[derive(Clone, Copy, PartialEq)]
enum Mode {
    Values,
    Frames,
    Occlusions,
}

impl Mode {
    fn name(self) -> &'static str {
        match self {
            Mode::Values => "values",
            Mode::Frames => "frames",
            Mode::Occlusions => "occlusions",
        }
    }
}

/// Removes positions (`T × 6`: human xyz, robot xyz) in place; `human_only`
/// leaves the robot's (the truth of a test demonstration) complete.
fn remove(frames: &mut [f64], mode: Mode, frac: f64, human_only: bool, rng: &mut ChaCha8Rng) {
    let t = frames.len() / 6;
    let width = if human_only { 3 } else { 6 };
    match mode {
        Mode::Values => {
            for f in frames.chunks_exact_mut(6) {
                for v in &mut f[..width] {
                    if rng.random::<f64>() < frac {
                        *v = f64::NAN;
                    }
                }
            }
        }
        Mode::Frames => {
            for f in frames.chunks_exact_mut(6) {
                if rng.random::<f64>() < frac {
                    f[..width].fill(f64::NAN);
                }
            }
        }
        Mode::Occlusions => {
            // Runs of 10 frames of the human's hand, starting with the
            // probability that makes `frac` of the frames occluded.
            let start = frac / (10.0 * (1.0 - frac) + frac);
            let mut left = 0;
            for k in 0..t {
                if left == 0 && rng.random::<f64>() < start {
                    left = 10;
                }
                if left > 0 {
                    frames[k * 6..k * 6 + 3].fill(f64::NAN);
                    left -= 1;
                }
            }
        }
    }
}

/// Positions and first differences, `T × 12`: human x, v, robot x, v (NaN propagates).
fn features(frames: &[f64]) -> Vec<f64> {
    synthetic::with_velocities(&synthetic::Interaction {
        frames: frames.to_vec(),
        phases: Vec::new(),
        boundaries: Vec::new(),
    })
}

fn fit(train: &[Vec<f64>]) -> Hmm<Gaussian> {
    BaumWelch::builder()
        .init(HmmInit::KBins { smoothing: 0.01 })
        .regularisation(Regularisation::add_diagonal(1e-4).expect("valid"))
        .convergence(Convergence::MeanPerSequence)
        .tol(1e-4)
        .max_iter(100)
        .build()
        .expect("valid settings")
        .fit(
            &Gaussian::standard(
                CovarianceType::Full,
                Shape {
                    n_states: STATES,
                    dim: 12,
                },
            )
            .expect("valid"),
            &SequenceSet::new(train, 12).expect("valid data"),
        )
        .expect("the fit converges")
        .model
}

/// Every missing value replaced by the mean of its feature over `train`.
fn mean_filled(seqs: &[Vec<f64>], train: &[Vec<f64>], dims: usize) -> Vec<Vec<f64>> {
    let mut mean = [0.0; 12];
    let mut n = [0.0; 12];
    for f in train.iter().flat_map(|s| s.chunks_exact(12)) {
        for k in 0..12 {
            if !f[k].is_nan() {
                mean[k] += f[k];
                n[k] += 1.0;
            }
        }
    }
    let mean: Vec<f64> = mean.iter().zip(&n).map(|(m, n)| m / n).collect();
    seqs.iter()
        .map(|s| {
            s.chunks_exact(dims)
                .flat_map(|f| {
                    f.iter()
                        .enumerate()
                        .map(|(k, v)| if v.is_nan() { mean[k % 12] } else { *v })
                        .collect::<Vec<_>>()
                })
                .collect()
        })
        .collect()
}

/// RMS difference of the position means (mm), states matched by the best permutation.
fn mean_error(a: &Hmm<Gaussian>, b: &Hmm<Gaussian>) -> f64 {
    let pos = [0usize, 1, 2, 6, 7, 8];
    let cost = |i: usize, j: usize| -> f64 {
        pos.iter()
            .map(|&k| (a.emission().mean(i)[k] - b.emission().mean(j)[k]).powi(2))
            .sum()
    };
    let mut best = f64::INFINITY;
    let mut perm: Vec<usize> = (0..STATES).collect();
    permutations(&mut perm, 0, &mut |p| {
        best = best.min((0..STATES).map(|i| cost(i, p[i])).sum());
    });
    1e3 * (best / (STATES * pos.len()) as f64).sqrt()
}

fn permutations(p: &mut [usize], k: usize, f: &mut impl FnMut(&[usize])) {
    if k == p.len() {
        f(p);
        return;
    }
    for i in k..p.len() {
        p.swap(k, i);
        permutations(p, k + 1, f);
        p.swap(k, i);
    }
}

/// Robot hand MSE (cm²) on the test demonstrations; `human` are their human features (`T × 6`).
fn mse(model: &Hmm<Gaussian>, human: &[Vec<f64>], truth: &[Vec<f64>]) -> f64 {
    let gmr = HmmRegression::new(model, &HUMAN, &ROBOT).expect("valid roles");
    let (mut se, mut n) = (0.0, 0.0);
    for (h, full) in human.iter().zip(truth) {
        let pred = gmr
            .predict(Frames::new(h, 6).expect("valid frames"), false)
            .expect("prediction");
        for (p, f) in pred.mean.chunks_exact(6).zip(full.chunks_exact(6)) {
            se += (0..3)
                .map(|k| (1e2 * (p[k] - f[3 + k])).powi(2))
                .sum::<f64>();
            n += 1.0;
        }
    }
    se / n
}

fn mean_std(v: &[f64]) -> String {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1).max(1) as f64).sqrt();
    format!("{m:.2} ± {s:.2}")
}

fn main() {
    let seeds = 5u64;
    let fracs = [0.0, 0.1, 0.2, 0.3, 0.5];
    println!("| removed | fraction | mean error, EM (mm) | mean error, mean-fill (mm) | MSE, EM (cm²) | MSE, mean-fill (cm²) |");
    println!("|---|---:|---:|---:|---:|---:|");
    for mode in [Mode::Values, Mode::Frames, Mode::Occlusions] {
        for &frac in &fracs {
            let (mut err_em, mut err_fill, mut mse_em, mut mse_fill) =
                (Vec::new(), Vec::new(), Vec::new(), Vec::new());
            for seed in 0..seeds {
                let demos = synthetic::generate(30, 100 + seed);
                let (train_demos, test_demos) = demos.split_at(20);
                let complete: Vec<Vec<f64>> =
                    train_demos.iter().map(|d| features(&d.frames)).collect();
                let truth: Vec<Vec<f64>> = test_demos.iter().map(|d| d.frames.clone()).collect();
                let reference = fit(&complete);
                let mut rng = ChaCha8Rng::seed_from_u64(1000 * seed + (frac * 100.0) as u64);
                let train: Vec<Vec<f64>> = train_demos
                    .iter()
                    .map(|d| {
                        let mut f = d.frames.clone();
                        remove(&mut f, mode, frac, false, &mut rng);
                        features(&f)
                    })
                    .collect();
                let human: Vec<Vec<f64>> = test_demos
                    .iter()
                    .map(|d| {
                        let mut f = d.frames.clone();
                        remove(&mut f, mode, frac, true, &mut rng);
                        features(&f)
                            .chunks_exact(12)
                            .flat_map(|x| x[..6].to_vec())
                            .collect()
                    })
                    .collect();
                let em = fit(&train);
                err_em.push(mean_error(&em, &reference));
                mse_em.push(mse(&em, &human, &truth));
                let filled_train = mean_filled(&train, &train, 12);
                let fill = fit(&filled_train);
                err_fill.push(mean_error(&fill, &reference));
                // The test humans filled with the training means of the human features.
                let human_filled: Vec<Vec<f64>> = mean_filled(
                    &human
                        .iter()
                        .map(|h| {
                            h.chunks_exact(6)
                                .flat_map(|x| {
                                    x.iter().copied().chain([f64::NAN; 6]).collect::<Vec<_>>()
                                })
                                .collect()
                        })
                        .collect::<Vec<Vec<f64>>>(),
                    &train,
                    12,
                )
                .iter()
                .map(|s| s.chunks_exact(12).flat_map(|x| x[..6].to_vec()).collect())
                .collect();
                mse_fill.push(mse(&fill, &human_filled, &truth));
            }
            println!(
                "| {} | {:.0} % | {} | {} | {} | {} |",
                mode.name(),
                frac * 100.0,
                mean_std(&err_em),
                mean_std(&err_fill),
                mean_std(&mse_em),
                mean_std(&mse_fill)
            );
        }
    }
}
