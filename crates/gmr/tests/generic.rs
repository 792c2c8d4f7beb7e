//! GMR over any emission with conditionals (`phasekit_emission::Conditional`).
//!
//! * Gaussian states: the regression uses the emission's own conditional;
//!   it equals the reference [`Conditional`] of this crate to the last bit, for
//!   every covariance structure, with every input, some or none missing (the
//!   numbers of every earlier release).
//! * Student-t states and mixtures of Gaussians per state: the predicted
//!   mean and covariance against Monte-Carlo conditioning of samples drawn
//!   from the joint emission itself (frames whose input falls in a narrow
//!   window around the input).
//! * Online = batch, bit for bit, for both; a missing input equals the
//!   regression on the observed inputs only.

use phasekit_emission::rand::SeedableRng;
use phasekit_emission::{
    CovarianceType, Emission, Frames, Gaussian, MixtureEmission, PerState, StudentT, StudentTDof,
};
use phasekit_gmr::{Conditional, HmmRegression, Regression};
use phasekit_hmm::Hmm;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

fn random_spd(d: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let a: Vec<f64> = (0..d * d).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut s = vec![0.0; d * d];
    for r in 0..d {
        for c in 0..d {
            s[r * d + c] = (0..d).map(|k| a[r * d + k] * a[c * d + k]).sum::<f64>()
                + if r == c { 0.5 } else { 0.0 };
        }
    }
    s
}

fn gaussian(kind: CovarianceType, s: usize, d: usize, rng: &mut ChaCha8Rng) -> Gaussian {
    let means: Vec<f64> = (0..s * d).map(|_| rng.random_range(-2.0..2.0)).collect();
    let covs = match kind {
        CovarianceType::Full => (0..s).flat_map(|_| random_spd(d, rng)).collect(),
        CovarianceType::Tied => random_spd(d, rng),
        CovarianceType::Diagonal => (0..s * d).map(|_| rng.random_range(0.2..2.0)).collect(),
        CovarianceType::Spherical => (0..s).map(|_| rng.random_range(0.2..2.0)).collect(),
    };
    Gaussian::new(kind, d, means, covs).unwrap()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn gaussian_regression_is_bit_identical_to_the_reference_conditional() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let (s, d) = (3, 6);
    let (input, output) = ([4usize, 0, 2, 5], [3usize, 1]);
    for kind in [
        CovarianceType::Full,
        CovarianceType::Diagonal,
        CovarianceType::Spherical,
        CovarianceType::Tied,
    ] {
        let g = gaussian(kind, s, d, &mut rng);
        let reg = Regression::new(&g, &input, &output).unwrap();
        let o = output.len();
        for pattern in 0..16u32 {
            let x: Vec<f64> = (0..input.len())
                .map(|k| {
                    if pattern & (1 << k) != 0 {
                        f64::NAN
                    } else {
                        rng.random_range(-3.0..3.0)
                    }
                })
                .collect();
            let observed: Vec<usize> = (0..input.len()).filter(|&k| !x[k].is_nan()).collect();
            let dims: Vec<usize> = observed.iter().map(|&k| input[k]).collect();
            let values: Vec<f64> = observed.iter().map(|&k| x[k]).collect();
            for state in 0..s {
                let reference = if dims.is_empty() {
                    Conditional::unconditional(g.mean(state), &g.covariance(state), &output)
                } else {
                    Conditional::new(g.mean(state), &g.covariance(state), &dims, &output, state)
                }
                .unwrap();
                let mut want = vec![0.0; o];
                reference.mean_into(&values, &mut want).unwrap();
                // One-hot weights: the mixture is the state's conditional exactly.
                let mut h = vec![0.0; s];
                h[state] = 1.0;
                let (mut mean, mut cov, mut scratch) =
                    (vec![0.0; o], vec![0.0; o * o], vec![0.0; s * o]);
                reg.mix_into(&x, &h, &mut mean, Some(&mut cov), &mut scratch)
                    .unwrap();
                assert_eq!(
                    bits(&mean),
                    bits(&want),
                    "{kind:?} state {state} pattern {pattern:b}"
                );
                assert_eq!(
                    bits(&cov),
                    bits(reference.covariance()),
                    "{kind:?} state {state} pattern {pattern:b}"
                );
            }
        }
        // The reference conditionals the regression reports are the same.
        for (state, c) in reg.conditionals().iter().enumerate() {
            let r = Conditional::new(g.mean(state), &g.covariance(state), &input, &output, state)
                .unwrap();
            assert_eq!(c, &r);
        }
    }
}

/// Mean and covariance (row-major) of the output dims of the samples whose
/// input dim 0 lies within `half` of `x0`, from `n` draws of state 0 of `e`.
fn monte_carlo<E: Emission>(
    e: &E,
    x0: f64,
    half: f64,
    n: usize,
    seed: u64,
) -> (Vec<f64>, Vec<f64>, usize) {
    let d = e.dim();
    let o = d - 1;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut x = vec![0.0; d];
    let (mut sum, mut sq, mut kept) = (vec![0.0; o], vec![0.0; o * o], 0usize);
    for _ in 0..n {
        e.sample_into(0, &mut rng, &mut x).unwrap();
        if (x[0] - x0).abs() > half {
            continue;
        }
        kept += 1;
        for r in 0..o {
            sum[r] += x[1 + r];
            for c in 0..o {
                sq[r * o + c] += x[1 + r] * x[1 + c];
            }
        }
    }
    let k = kept as f64;
    let mean: Vec<f64> = sum.iter().map(|v| v / k).collect();
    let cov = (0..o * o)
        .map(|i| sq[i] / k - mean[i / o] * mean[i % o])
        .collect();
    (mean, cov, kept)
}

/// The regression's prediction for state 0 at input `x0` (dim 0), outputs 1..D.
fn predicted<E: phasekit_emission::Conditional>(e: &E, x0: f64) -> (Vec<f64>, Vec<f64>) {
    let d = e.dim();
    let output: Vec<usize> = (1..d).collect();
    let reg = Regression::new(e, &[0], &output).unwrap();
    let (s, o) = (e.n_states(), d - 1);
    let mut h = vec![0.0; s];
    h[0] = 1.0;
    let (mut mean, mut cov, mut scratch) = (vec![0.0; o], vec![0.0; o * o], vec![0.0; s * o]);
    reg.mix_into(&[x0], &h, &mut mean, Some(&mut cov), &mut scratch)
        .unwrap();
    (mean, cov)
}

fn assert_monte_carlo<E: phasekit_emission::Conditional>(what: &str, e: &E, x0: f64, n: usize) {
    let (mean, cov) = predicted(e, x0);
    // A window of ±0.1 around the input: its bias on the moments is of order
    // 0.1²/3 of their curvature in the input, far below the tolerance.
    let (mc_mean, mc_cov, kept) = monte_carlo(e, x0, 0.1, n, 11);
    assert!(kept > 20_000, "{what}: only {kept} samples near the input");
    let o = mean.len();
    for r in 0..o {
        // Standard error of a mean: sqrt(var / kept); allow 5 of them.
        let se = (cov[r * o + r] / kept as f64).sqrt();
        assert!(
            (mean[r] - mc_mean[r]).abs() < 5.0 * se,
            "{what}: mean {r} predicted {} vs Monte-Carlo {} (se {se})",
            mean[r],
            mc_mean[r]
        );
    }
    for i in 0..o * o {
        let (a, b) = (cov[i], mc_cov[i]);
        let scale = (cov[(i / o) * o + i / o] * cov[(i % o) * o + i % o]).sqrt();
        assert!(
            (a - b).abs() < 0.05 * scale,
            "{what}: covariance entry {i} predicted {a} vs Monte-Carlo {b}"
        );
    }
}

#[test]
fn student_t_regression_matches_monte_carlo_conditioning() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let scale = random_spd(3, &mut rng);
    let t = StudentT::new(vec![0.5, -1.0, 2.0], scale, 4.0, StudentTDof::Fixed).unwrap();
    let e = PerState::new(vec![t]).unwrap();
    // An input away from the location: the covariance grows with δ, (ν + δ)/(ν + 1 − 2).
    let x0 = 0.5 + 1.5 * e.states()[0].scale()[0].sqrt();
    assert_monte_carlo("student-t", &e, x0, 2_000_000);
    // Not the Gaussian answer: the conditional covariance is larger than Σ_OO − R Σ_IO
    // by the factor (ν + δ)/(ν + |I| − 2) = (4 + 2.25)/3.
    let g = Gaussian::full(
        3,
        e.states()[0].mean().to_vec(),
        e.states()[0].scale().to_vec(),
    )
    .unwrap();
    let (_, cov_t) = predicted(&e, x0);
    let (_, cov_g) = predicted(&g, x0);
    let ratio = cov_t[0] / cov_g[0];
    assert!((ratio - 6.25 / 3.0).abs() < 1e-9, "{ratio}");
}

#[test]
fn mixture_regression_matches_monte_carlo_conditioning() {
    // One state, two well-separated Gaussians with opposite slopes: the
    // conditional is bimodal away from the crossing, and its moments mix both.
    let comps = Gaussian::full(
        3,
        vec![0.0, 0.0, 1.0, 1.0, 2.0, -1.0],
        vec![
            1.0, 0.8, 0.1, 0.8, 1.0, 0.0, 0.1, 0.0, 0.5, //
            1.0, -0.6, 0.0, -0.6, 1.0, 0.2, 0.0, 0.2, 0.7,
        ],
    )
    .unwrap();
    let e = MixtureEmission::new(vec![0.3, 0.7], vec![comps]).unwrap();
    assert_monte_carlo("mixture", &e, 0.6, 2_000_000);
}

fn student_t_hmm(seed: u64) -> Hmm<PerState<StudentT>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let states = (0..3)
        .map(|i| {
            let mean = vec![i as f64, -(i as f64), 0.5 * i as f64, 1.0];
            StudentT::new(
                mean,
                random_spd(4, &mut rng),
                3.0 + i as f64,
                StudentTDof::Fixed,
            )
            .unwrap()
        })
        .collect();
    Hmm::new(
        vec![0.5, 0.3, 0.2],
        vec![0.8, 0.15, 0.05, 0.1, 0.8, 0.1, 0.05, 0.15, 0.8],
        PerState::new(states).unwrap(),
    )
    .unwrap()
}

fn mixture_hmm(seed: u64) -> Hmm<MixtureEmission<Gaussian>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let comps: Vec<Gaussian> = (0..3)
        .map(|_| gaussian(CovarianceType::Full, 2, 4, &mut rng))
        .collect();
    Hmm::new(
        vec![0.5, 0.3, 0.2],
        vec![0.8, 0.15, 0.05, 0.1, 0.8, 0.1, 0.05, 0.15, 0.8],
        MixtureEmission::new(vec![0.4, 0.6, 0.5, 0.5, 0.9, 0.1], comps).unwrap(),
    )
    .unwrap()
}

fn check_online_equals_batch<E>(what: &str, hmm: &Hmm<E>)
where
    E: phasekit_emission::Conditional + phasekit_emission::Marginal,
{
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let (frames, _) = hmm.sample(120, &mut rng).unwrap();
    let (input, output) = ([0usize, 2], [1usize, 3]);
    let mut human: Vec<f64> = frames
        .chunks_exact(4)
        .flat_map(|f| input.iter().map(move |&k| f[k]))
        .collect();
    // Some missing values, one frame with nothing observed.
    for t in (7..120).step_by(13) {
        human[2 * t + t % 2] = f64::NAN;
    }
    human[2 * 50] = f64::NAN;
    human[2 * 50 + 1] = f64::NAN;
    let gmr = HmmRegression::new(hmm, &input, &output).unwrap();
    let batch = gmr.predict(Frames::new(&human, 2).unwrap(), true).unwrap();
    let mut online = gmr.online();
    for (t, x) in human.chunks_exact(2).enumerate() {
        let m = online.step_with_covariance(x).unwrap().to_vec();
        assert_eq!(
            bits(&m),
            bits(&batch.mean[2 * t..2 * t + 2]),
            "{what}: frame {t}"
        );
        let c = batch.covariance.as_ref().unwrap();
        assert_eq!(
            bits(online.covariance()),
            bits(&c[4 * t..4 * t + 4]),
            "{what}: frame {t}"
        );
    }
    assert!(batch.mean.iter().all(|v| v.is_finite()), "{what}");
}

#[test]
fn online_equals_batch_for_student_t_and_mixture_states() {
    check_online_equals_batch("student-t", &student_t_hmm(1));
    check_online_equals_batch("mixture", &mixture_hmm(2));
}

#[test]
fn a_missing_input_is_the_regression_on_the_observed_inputs() {
    let hmm = student_t_hmm(4);
    let e = hmm.emission();
    let full = Regression::new(e, &[0, 2], &[1, 3]).unwrap();
    let observed = Regression::new(e, &[2], &[1, 3]).unwrap();
    let h = [0.2, 0.5, 0.3];
    let (mut a, mut ca, mut b, mut cb, mut scratch) = (
        vec![0.0; 2],
        vec![0.0; 4],
        vec![0.0; 2],
        vec![0.0; 4],
        vec![0.0; 6],
    );
    full.mix_into(&[f64::NAN, 0.7], &h, &mut a, Some(&mut ca), &mut scratch)
        .unwrap();
    observed
        .mix_into(&[0.7], &h, &mut b, Some(&mut cb), &mut scratch)
        .unwrap();
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(bits(&ca), bits(&cb));
}
