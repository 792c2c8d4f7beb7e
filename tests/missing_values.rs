//! Missing values (NaN = "not observed") against slow, obvious versions.
//!
//! * log-densities of incomplete frames against the textbook marginal density
//!   (explicit sub-blocks, `nalgebra` inverse and determinant), for every
//!   emission; complete frames next to incomplete ones bit for bit as before;
//! * one accumulation + M-step against the textbook EM update for Gaussians
//!   with missing data (conditional means and covariances by explicit inverses),
//!   and the expected counts of Poisson and categorical emissions;
//! * HMM likelihood and Viterbi against enumeration of all state paths with
//!   marginal densities; the online filter against the batch forward pass;
//! * Baum-Welch and mixture EM with missing values never decrease the
//!   observed-data objective (they are exact EM);
//! * GMR with missing inputs against the analytic conditional on the observed
//!   inputs; online equals batch;
//! * with 10 % and 30 % of the values removed at random, fitted means and
//!   predictions stay close to the complete-data ones.
//!
//! Every random choice comes from a seeded `ChaCha8Rng`; proptest runs from a
//! fixed seed (override with `PROPTEST_RNG_SEED`).
// The slow versions index several arrays by the same state or dimension, as
// the formulas are written.
#![allow(clippy::needless_range_loop)]

use nalgebra::{DMatrix, DVector};
use phasekit::emission::{
    Categorical, CovarianceType, Emission, Frames, Gaussian, MixtureEmission, Poisson,
    Regularisation, SequenceSet, Shape,
};
use phasekit::gmm::{Em, Gmm, GmmInit};
use phasekit::gmr::{GmmRegression, HmmRegression};
use phasekit::hmm::{BaumWelch, Hmm, HmmInit};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;

fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::with_cases(cases);
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x0b5e_12fe);
    }
    c.failure_persistence = None;
    c
}

const KINDS: [CovarianceType; 4] = [
    CovarianceType::Full,
    CovarianceType::Diagonal,
    CovarianceType::Spherical,
    CovarianceType::Tied,
];

// ---------------------------------------------------------------------------
// Random models and data
// ---------------------------------------------------------------------------

fn random_spd(d: usize, rng: &mut ChaCha8Rng) -> DMatrix<f64> {
    let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-1.0..1.0));
    let m = &a * a.transpose() / d as f64 + DMatrix::identity(d, d) * 0.3;
    (&m + m.transpose()) * 0.5
}

fn random_gaussian(kind: CovarianceType, s: usize, d: usize, rng: &mut ChaCha8Rng) -> Gaussian {
    let means: Vec<f64> = (0..s * d).map(|_| rng.random_range(-2.0..2.0)).collect();
    let covs: Vec<f64> = match kind {
        CovarianceType::Full => (0..s)
            .flat_map(|_| random_spd(d, rng).transpose().as_slice().to_vec())
            .collect(),
        CovarianceType::Tied => random_spd(d, rng).transpose().as_slice().to_vec(),
        CovarianceType::Diagonal => (0..s * d).map(|_| rng.random_range(0.2..2.0)).collect(),
        CovarianceType::Spherical => (0..s).map(|_| rng.random_range(0.2..2.0)).collect(),
    };
    Gaussian::new(kind, d, means, covs).unwrap()
}

/// Sets each value to NaN with probability `p`, and whole frames with probability `p_frame`.
fn knock_out(data: &mut [f64], d: usize, p: f64, p_frame: f64, rng: &mut ChaCha8Rng) {
    for frame in data.chunks_exact_mut(d) {
        if rng.random::<f64>() < p_frame {
            frame.fill(f64::NAN);
            continue;
        }
        for v in frame.iter_mut() {
            if rng.random::<f64>() < p {
                *v = f64::NAN;
            }
        }
    }
}

fn observed(x: &[f64]) -> Vec<usize> {
    (0..x.len()).filter(|&k| !x[k].is_nan()).collect()
}

fn sub(m: &DMatrix<f64>, rows: &[usize], cols: &[usize]) -> DMatrix<f64> {
    DMatrix::from_fn(rows.len(), cols.len(), |r, c| m[(rows[r], cols[c])])
}

/// Textbook `log N(x_o; μ_o, Σ_oo)` with an explicit inverse and determinant; 0 when nothing is observed.
fn textbook_marginal(mean: &[f64], cov: &DMatrix<f64>, x: &[f64]) -> f64 {
    let o = observed(x);
    if o.is_empty() {
        return 0.0;
    }
    let s = sub(cov, &o, &o);
    let diff = DVector::from_iterator(o.len(), o.iter().map(|&k| x[k] - mean[k]));
    let inv = s.clone().try_inverse().unwrap();
    -0.5 * (o.len() as f64 * (2.0 * PI).ln()
        + s.determinant().ln()
        + (diff.transpose() * inv * &diff)[0])
}

/// Textbook conditional of the missing dims: `(x̂, C)` with `x̂` the whole
/// frame, missing values replaced by `μ_m + Σ_mo Σ_oo⁻¹ (x_o − μ_o)`, and `C`
/// the `D × D` matrix holding `Σ_mm − Σ_mo Σ_oo⁻¹ Σ_om` in its `m × m` block.
fn textbook_conditional(mean: &[f64], cov: &DMatrix<f64>, x: &[f64]) -> (Vec<f64>, DMatrix<f64>) {
    let d = x.len();
    let o = observed(x);
    let m: Vec<usize> = (0..d).filter(|&k| x[k].is_nan()).collect();
    let mut xhat = x.to_vec();
    let mut c = DMatrix::zeros(d, d);
    if m.is_empty() {
        return (xhat, c);
    }
    let (s_mm, s_mo) = (sub(cov, &m, &m), sub(cov, &m, &o));
    let (r, cond) = if o.is_empty() {
        (DMatrix::zeros(m.len(), 0), s_mm)
    } else {
        let inv = sub(cov, &o, &o).try_inverse().unwrap();
        let r = &s_mo * inv;
        let cond = &s_mm - &r * s_mo.transpose();
        (r, cond)
    };
    for (a, &k) in m.iter().enumerate() {
        xhat[k] = mean[k]
            + o.iter()
                .enumerate()
                .map(|(b, &j)| r[(a, b)] * (x[j] - mean[j]))
                .sum::<f64>();
        for (b, &j) in m.iter().enumerate() {
            c[(k, j)] = cond[(a, b)];
        }
    }
    (xhat, c)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
}

fn log_sum_exp(v: &[f64]) -> f64 {
    let m = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + v.iter().map(|x| (x - m).exp()).sum::<f64>().ln()
}

// ---------------------------------------------------------------------------
// Log-densities
// ---------------------------------------------------------------------------

proptest! {
    #![proptest_config(config(64))]

    #[test]
    fn gaussian_incomplete_frames_use_the_exact_marginal(
        seed in any::<u64>(), s in 1usize..4, d in 1usize..7, t in 1usize..40, p in 0.0f64..0.9,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        for kind in KINDS {
            let g = random_gaussian(kind, s, d, &mut rng);
            let mut x: Vec<f64> = (0..t * d).map(|_| rng.random_range(-3.0..3.0)).collect();
            knock_out(&mut x, d, p, 0.1, &mut rng);
            let got = g.log_density(Frames::new(&x, d).unwrap()).unwrap();
            for (tt, f) in x.chunks_exact(d).enumerate() {
                for i in 0..s {
                    let want = textbook_marginal(g.mean(i), &g.covariance(i), f);
                    prop_assert!(close(got[tt * s + i], want, 1e-9),
                        "{kind:?} frame {tt} state {i}: {} vs {want} ({f:?})", got[tt * s + i]);
                }
            }
        }
    }

    #[test]
    fn discrete_and_mixture_emissions_marginalise_missing_values(seed in any::<u64>(), t in 1usize..30) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        // Poisson: independent dims, so the marginal is the product over observed dims.
        let rates: Vec<f64> = (0..2 * 3).map(|_| rng.random_range(0.1..5.0)).collect();
        let pois = Poisson::new(3, rates.clone()).unwrap();
        let mut x: Vec<f64> = (0..t * 3).map(|_| rng.random_range(0..8) as f64).collect();
        knock_out(&mut x, 3, 0.4, 0.1, &mut rng);
        let frames = Frames::new(&x, 3).unwrap();
        pois.check_frames(frames).unwrap();
        let got = pois.log_density(frames).unwrap();
        for (tt, f) in x.chunks_exact(3).enumerate() {
            for i in 0..2 {
                let want: f64 = (0..3).filter(|&k| !f[k].is_nan()).map(|k| {
                    let lam = rates[i * 3 + k];
                    f[k] * lam.ln() - lam - libm_lgamma(f[k] + 1.0)
                }).sum();
                prop_assert!(close(got[tt * 2 + i], want, 1e-12));
            }
        }
        // Categorical: a missing symbol has probability 1.
        let probs = vec![0.1, 0.2, 0.7, 0.5, 0.25, 0.25];
        let cat = Categorical::new(3, probs.clone()).unwrap();
        let mut y: Vec<f64> = (0..t).map(|_| rng.random_range(0..3) as f64).collect();
        knock_out(&mut y, 1, 0.4, 0.0, &mut rng);
        let frames = Frames::new(&y, 1).unwrap();
        cat.check_frames(frames).unwrap();
        let got = cat.log_density(frames).unwrap();
        for (tt, v) in y.iter().enumerate() {
            for i in 0..2 {
                let want = if v.is_nan() { 0.0 } else { probs[i * 3 + *v as usize].ln() };
                prop_assert!(close(got[tt * 2 + i], want, 1e-15));
            }
        }
        // Mixture of full Gaussians per state: log Σ_m w_m N(x_o; μ_m,o, Σ_m,oo).
        let comps: Vec<Gaussian> = (0..2).map(|_| random_gaussian(CovarianceType::Full, 3, 4, &mut rng)).collect();
        let weights = vec![0.2, 0.5, 0.3, 0.6, 0.1, 0.3];
        let mix = MixtureEmission::new(weights.clone(), comps.clone()).unwrap();
        let mut z: Vec<f64> = (0..t * 4).map(|_| rng.random_range(-3.0..3.0)).collect();
        knock_out(&mut z, 4, 0.4, 0.1, &mut rng);
        let got = mix.log_density(Frames::new(&z, 4).unwrap()).unwrap();
        for (tt, f) in z.chunks_exact(4).enumerate() {
            for i in 0..2 {
                let terms: Vec<f64> = (0..3).map(|m| weights[i * 3 + m].ln()
                    + textbook_marginal(comps[i].mean(m), &comps[i].covariance(m), f)).collect();
                prop_assert!(close(got[tt * 2 + i], log_sum_exp(&terms), 1e-9));
            }
        }
    }
}

/// `ln Γ(x)` for whole `x ≥ 1`: `ln (x − 1)!`.
fn libm_lgamma(x: f64) -> f64 {
    (1..x as u64).map(|k| (k as f64).ln()).sum()
}

#[test]
fn complete_frames_keep_their_exact_values_next_to_missing_ones() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for kind in KINDS {
        for d in [1, 3, 12, 36] {
            let g = random_gaussian(kind, 5, d, &mut rng);
            let x: Vec<f64> = (0..70 * d).map(|_| rng.random_range(-3.0..3.0)).collect();
            let plain = g.log_density(Frames::new(&x, d).unwrap()).unwrap();
            let mut y = x.clone();
            for t in [0, 17, 18, 40, 69] {
                y[t * d + rng.random_range(0..d)] = f64::NAN;
            }
            let frames = Frames::new(&y, d).unwrap();
            assert!(frames.has_missing());
            let mixed = g.log_density(frames).unwrap();
            for t in 0..70 {
                if y[t * d..(t + 1) * d].iter().any(|v| v.is_nan()) {
                    continue;
                }
                for i in 0..5 {
                    assert_eq!(
                        plain[t * 5 + i].to_bits(),
                        mixed[t * 5 + i].to_bits(),
                        "{kind:?} D={d} frame {t}"
                    );
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------
// Expected sufficient statistics
// ---------------------------------------------------------------------------

proptest! {
    #![proptest_config(config(48))]

    #[test]
    fn gaussian_m_step_is_the_textbook_em_update(
        seed in any::<u64>(), s in 1usize..4, d in 1usize..6, p in 0.1f64..0.6,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let t = 60;
        for kind in KINDS {
            let g = random_gaussian(kind, s, d, &mut rng);
            let mut x: Vec<f64> = (0..t * d).map(|_| rng.random_range(-3.0..3.0)).collect();
            knock_out(&mut x, d, p, 0.05, &mut rng);
            let w: Vec<f64> = (0..t * s).map(|_| rng.random_range(0.0..1.0)).collect();
            let frames = Frames::new(&x, d).unwrap();
            // Split into two blocks merged afterwards: the statistics must combine exactly.
            let mut stats = g.new_stats();
            g.accumulate(frames.slice(0..25), &w[..25 * s], &mut stats).unwrap();
            let mut rest = g.new_stats();
            g.accumulate(frames.slice(25..t), &w[25 * s..], &mut rest).unwrap();
            phasekit::emission::SufficientStatistics::merge(&mut stats, &rest).unwrap();
            let mut fitted = g.clone();
            fitted.m_step(&stats, &Regularisation::none()).unwrap();

            let mut tied_scatter = DMatrix::zeros(d, d);
            let mut tied_n = 0.0;
            for i in 0..s {
                let cov = g.covariance(i);
                let filled: Vec<(Vec<f64>, DMatrix<f64>)> = x
                    .chunks_exact(d)
                    .map(|f| textbook_conditional(g.mean(i), &cov, f))
                    .collect();
                // Frames with nothing observed do not enter the statistics.
                let seen: Vec<bool> = x.chunks_exact(d).map(|f| f.iter().any(|v| !v.is_nan())).collect();
                let wt = |tt: usize| if seen[tt] { w[tt * s + i] } else { 0.0 };
                let n: f64 = (0..t).map(wt).sum();
                let mu: Vec<f64> = (0..d)
                    .map(|k| (0..t).map(|tt| wt(tt) * filled[tt].0[k]).sum::<f64>() / n)
                    .collect();
                let mut scatter = DMatrix::zeros(d, d);
                for (tt, (xh, c)) in filled.iter().enumerate() {
                    let e = DVector::from_iterator(d, xh.iter().zip(&mu).map(|(a, b)| a - b));
                    scatter += (&e * e.transpose() + c) * wt(tt);
                }
                for k in 0..d {
                    prop_assert!(close(fitted.mean(i)[k], mu[k], 1e-9),
                        "{kind:?} state {i} mean {k}: {} vs {}", fitted.mean(i)[k], mu[k]);
                }
                let got = fitted.covariance(i);
                match kind {
                    CovarianceType::Full => {
                        let want = &scatter / n;
                        for (a, b) in got.iter().zip(want.iter()) {
                            prop_assert!(close(*a, *b, 1e-8), "{kind:?}: {a} vs {b}");
                        }
                    }
                    CovarianceType::Diagonal => {
                        for k in 0..d {
                            prop_assert!(close(got[(k, k)], scatter[(k, k)] / n, 1e-8));
                        }
                    }
                    CovarianceType::Spherical => {
                        prop_assert!(close(got[(0, 0)], scatter.trace() / (n * d as f64), 1e-8));
                    }
                    CovarianceType::Tied => {
                        tied_scatter += scatter;
                        tied_n += n;
                    }
                }
            }
            if kind == CovarianceType::Tied {
                let want = tied_scatter / tied_n;
                for (a, b) in fitted.covariance(0).iter().zip(want.iter()) {
                    prop_assert!(close(*a, *b, 1e-8), "tied: {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn discrete_m_steps_use_expected_counts(seed in any::<u64>()) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let t = 50;
        let rates: Vec<f64> = (0..2 * 2).map(|_| rng.random_range(0.5..4.0)).collect();
        let pois = Poisson::new(2, rates.clone()).unwrap();
        let mut x: Vec<f64> = (0..t * 2).map(|_| rng.random_range(0..6) as f64).collect();
        knock_out(&mut x, 2, 0.3, 0.1, &mut rng);
        let w: Vec<f64> = (0..t * 2).map(|_| rng.random_range(0.0..1.0)).collect();
        let mut st = pois.new_stats();
        pois.accumulate(Frames::new(&x, 2).unwrap(), &w, &mut st).unwrap();
        let mut fitted = pois.clone();
        fitted.m_step(&st, &Regularisation::none()).unwrap();
        for i in 0..2 {
            // Frames with no count observed do not enter the statistics.
            let wt = |tt: usize| if x[tt * 2].is_nan() && x[tt * 2 + 1].is_nan() { 0.0 } else { w[tt * 2 + i] };
            let n: f64 = (0..t).map(wt).sum();
            for k in 0..2 {
                let want = (0..t).map(|tt| {
                    let v = x[tt * 2 + k];
                    wt(tt) * if v.is_nan() { rates[i * 2 + k] } else { v }
                }).sum::<f64>() / n;
                prop_assert!(close(fitted.rates()[i * 2 + k], want, 1e-12));
            }
        }
        let probs = vec![0.1, 0.2, 0.7, 0.5, 0.25, 0.25];
        let cat = Categorical::new(3, probs.clone()).unwrap();
        let mut y: Vec<f64> = (0..t).map(|_| rng.random_range(0..3) as f64).collect();
        knock_out(&mut y, 1, 0.3, 0.0, &mut rng);
        let mut st = cat.new_stats();
        cat.accumulate(Frames::new(&y, 1).unwrap(), &w, &mut st).unwrap();
        let mut fitted = cat.clone();
        fitted.m_step(&st, &Regularisation::none()).unwrap();
        for i in 0..2 {
            // A missing symbol does not enter the counts.
            let n: f64 = (0..t).filter(|&tt| !y[tt].is_nan()).map(|tt| w[tt * 2 + i]).sum();
            for j in 0..3 {
                let want = (0..t).filter(|&tt| !y[tt].is_nan()).map(|tt| w[tt * 2 + i] * if y[tt] as usize == j { 1.0 } else { 0.0 }).sum::<f64>() / n;
                prop_assert!(close(fitted.probabilities()[i * 3 + j], want, 1e-12));
            }
        }
    }
}

// ---------------------------------------------------------------------------
// HMM inference against enumeration
// ---------------------------------------------------------------------------

fn random_stochastic(rows: usize, cols: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let mut v: Vec<f64> = (0..rows * cols)
        .map(|_| rng.random_range(0.05..1.0))
        .collect();
    for row in v.chunks_exact_mut(cols) {
        let total: f64 = row.iter().sum();
        row.iter_mut().for_each(|x| *x /= total);
    }
    v
}

proptest! {
    #![proptest_config(config(64))]

    #[test]
    fn hmm_inference_with_missing_values_matches_enumeration(
        seed in any::<u64>(), s in 1usize..4, t in 1usize..6,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let d = 3;
        let g = random_gaussian(CovarianceType::Full, s, d, &mut rng);
        let hmm = Hmm::new(random_stochastic(1, s, &mut rng), random_stochastic(s, s, &mut rng), g.clone()).unwrap();
        let mut x: Vec<f64> = (0..t * d).map(|_| rng.random_range(-3.0..3.0)).collect();
        knock_out(&mut x, d, 0.4, 0.2, &mut rng);
        let frames = Frames::new(&x, d).unwrap();
        let log_b: Vec<Vec<f64>> = x.chunks_exact(d)
            .map(|f| (0..s).map(|i| textbook_marginal(g.mean(i), &g.covariance(i), f)).collect())
            .collect();
        // Enumerate all S^T paths.
        let mut paths = Vec::new();
        let mut best = f64::NEG_INFINITY;
        for code in 0..s.pow(t as u32) {
            let z: Vec<usize> = (0..t).map(|k| code / s.pow(k as u32) % s).collect();
            let mut lp = hmm.start()[z[0]].ln() + log_b[0][z[0]];
            for k in 1..t {
                lp += hmm.transition()[z[k - 1] * s + z[k]].ln() + log_b[k][z[k]];
            }
            best = best.max(lp);
            paths.push(lp);
        }
        let want = log_sum_exp(&paths);
        prop_assert!(close(hmm.log_likelihood(frames).unwrap(), want, 1e-10));
        let post = hmm.posteriors(frames).unwrap();
        for row in post.gamma.chunks_exact(s) {
            prop_assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
        prop_assert!(close(hmm.viterbi(frames).unwrap().log_probability, best, 1e-10));
        // The online filter, frame by frame, equals the batch forward variable.
        let batch = hmm.forward(frames).unwrap();
        let mut online = hmm.filter();
        for (tt, f) in x.chunks_exact(d).enumerate() {
            let h = online.step(f).unwrap();
            for i in 0..s {
                prop_assert!((h[i] - batch.filtered()[tt * s + i]).abs() < 1e-12);
            }
        }
        prop_assert!(close(online.log_likelihood(), want, 1e-10));
    }
}

// ---------------------------------------------------------------------------
// EM with missing values is exact EM: the observed-data objective never decreases
// ---------------------------------------------------------------------------

proptest! {
    #![proptest_config(config(24))]

    #[test]
    fn baum_welch_with_missing_values_never_decreases_its_objective(
        seed in any::<u64>(), s in 2usize..4, d in 2usize..4, p in 0.1f64..0.5,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        for kind in [CovarianceType::Full, CovarianceType::Diagonal, CovarianceType::Tied] {
            let truth = Hmm::new(
                random_stochastic(1, s, &mut rng),
                random_stochastic(s, s, &mut rng),
                random_gaussian(kind, s, d, &mut rng),
            ).unwrap();
            let seqs: Vec<Vec<f64>> = (0..4).map(|_| {
                let (mut x, _) = truth.sample(40, &mut rng).unwrap();
                knock_out(&mut x, d, p, 0.05, &mut rng);
                x
            }).collect();
            let data = SequenceSet::new(&seqs, d).unwrap();
            // A proper inverse-Wishart prior keeps every covariance positive
            // definite; EM then increases the penalised objective monotonically.
            let bw = BaumWelch::builder()
                .regularisation(Regularisation::inverse_wishart(0.05, 0.0).unwrap())
                .init(HmmInit::KMeans)
                .seed(seed)
                .max_iter(12)
                .tol(f64::NEG_INFINITY)
                .build()
                .unwrap();
            let fitted = bw.fit(&Gaussian::standard(kind, Shape { n_states: s, dim: d }).unwrap(), &data).unwrap();
            let obj = &fitted.report.objective;
            prop_assert_eq!(obj.len(), 13);
            for w in obj.windows(2) {
                prop_assert!(w[1] >= w[0] - 1e-9 * w[0].abs(), "{kind:?}: objective fell {} -> {}", w[0], w[1]);
            }
            prop_assert!(fitted.model.emission().means().iter().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn mixture_em_with_missing_values_never_decreases_its_objective(
        seed in any::<u64>(), k in 2usize..4, d in 2usize..5, p in 0.1f64..0.5,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let truth = Gmm::new(random_stochastic(1, k, &mut rng), random_gaussian(CovarianceType::Full, k, d, &mut rng)).unwrap();
        let (mut x, _) = truth.sample(300, &mut rng).unwrap();
        knock_out(&mut x, d, p, 0.05, &mut rng);
        let frames = Frames::new(&x, d).unwrap();
        let em = Em::builder()
            .regularisation(Regularisation::inverse_wishart(0.05, 0.0).unwrap())
            .init(GmmInit::KMeans)
            .seed(seed)
            .max_iter(15)
            .tol(f64::NEG_INFINITY)
            .build()
            .unwrap();
        let fitted = em.fit(&Gaussian::standard(CovarianceType::Full, Shape { n_states: k, dim: d }).unwrap(), frames).unwrap();
        let obj = &fitted.report.objective;
        for w in obj.windows(2) {
            prop_assert!(w[1] >= w[0] - 1e-9 * w[0].abs(), "objective fell {} -> {}", w[0], w[1]);
        }
    }
}

#[test]
fn initialisation_with_missing_values_reaches_the_fixed_assignment_optimum() {
    // k-bins assigns frames to states by time; with missing values the
    // initial emission must be the maximum-likelihood Gaussian of each bin for
    // the observed data, i.e. a fixed point of one more EM step on the same bins.
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let truth = Hmm::new(
        vec![1.0, 0.0, 0.0],
        vec![0.95, 0.05, 0.0, 0.0, 0.95, 0.05, 0.0, 0.0, 1.0],
        random_gaussian(CovarianceType::Full, 3, 4, &mut rng),
    )
    .unwrap();
    let seqs: Vec<Vec<f64>> = (0..5)
        .map(|_| {
            let (mut x, _) = truth.sample(90, &mut rng).unwrap();
            knock_out(&mut x, 4, 0.3, 0.05, &mut rng);
            x
        })
        .collect();
    let data = SequenceSet::new(&seqs, 4).unwrap();
    let bw = BaumWelch::builder()
        .init(HmmInit::KBins { smoothing: 0.01 })
        .max_iter(0)
        .build()
        .unwrap();
    let init = bw
        .fit(
            &Gaussian::standard(
                CovarianceType::Full,
                Shape {
                    n_states: 3,
                    dim: 4,
                },
            )
            .unwrap(),
            &data,
        )
        .unwrap()
        .model;
    let g = init.emission();
    // One more step of EM on the same bins.
    let mut stats = g.new_stats();
    for seq in data.iter() {
        let edges = phasekit::hmm::kbins_edges(seq.len(), 3);
        let mut w = vec![0.0; seq.len() * 3];
        for i in 0..3 {
            for t in edges[i]..edges[i + 1] {
                w[t * 3 + i] = 1.0;
            }
        }
        g.accumulate(seq, &w, &mut stats).unwrap();
    }
    let mut again = g.clone();
    again.m_step(&stats, &Regularisation::none()).unwrap();
    for (a, b) in g.means().iter().zip(again.means()) {
        assert!((a - b).abs() < 1e-5, "means moved: {a} vs {b}");
    }
    for i in 0..3 {
        let diff = (g.covariance(i) - again.covariance(i)).abs().max();
        assert!(diff < 1e-5, "covariance {i} moved by {diff}");
    }
}

// ---------------------------------------------------------------------------
// GMR with missing inputs
// ---------------------------------------------------------------------------

#[test]
fn gmr_with_missing_inputs_is_the_conditional_on_the_observed_inputs() {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let (d, input, output) = (6, [0usize, 1, 2, 3], [4usize, 5]);
    // One component: the prediction is the Gaussian conditional itself.
    let g = random_gaussian(CovarianceType::Full, 1, d, &mut rng);
    let gmm = Gmm::new(vec![1.0], g.clone()).unwrap();
    let gmr = GmmRegression::new(&gmm, &input, &output).unwrap();
    let cov = g.covariance(0);
    let mu = g.mean(0);
    let patterns: [&[usize]; 5] = [&[], &[1], &[0, 3], &[0, 1, 2], &[0, 1, 2, 3]];
    for missing in patterns {
        let mut x: Vec<f64> = (0..4).map(|_| rng.random_range(-2.0..2.0)).collect();
        for &k in missing {
            x[k] = f64::NAN;
        }
        let pred = gmr.predict(Frames::new(&x, 4).unwrap(), true).unwrap();
        let obs: Vec<usize> = (0..4).filter(|k| !missing.contains(k)).collect();
        let (want_mean, want_cov) = if obs.is_empty() {
            (
                DVector::from_iterator(2, output.iter().map(|&k| mu[k])),
                sub(&cov, &output, &output),
            )
        } else {
            let inv = sub(&cov, &obs, &obs).try_inverse().unwrap();
            let r = sub(&cov, &output, &obs) * inv;
            let dx = DVector::from_iterator(obs.len(), obs.iter().map(|&k| x[k] - mu[k]));
            (
                DVector::from_iterator(2, output.iter().map(|&k| mu[k])) + &r * dx,
                sub(&cov, &output, &output) - &r * sub(&cov, &obs, &output),
            )
        };
        for k in 0..2 {
            assert!(close(pred.mean[k], want_mean[k], 1e-10), "{missing:?}");
            for l in 0..2 {
                let got = pred.covariance.as_ref().unwrap()[k * 2 + l];
                assert!(close(got, want_cov[(k, l)], 1e-10), "{missing:?}");
            }
        }
    }
    // Several components: weights are the responsibilities of the observed
    // inputs' marginal, each state conditioned on the observed inputs.
    let g = random_gaussian(CovarianceType::Full, 3, d, &mut rng);
    let pi = [0.3, 0.5, 0.2];
    let gmm = Gmm::new(pi.to_vec(), g.clone()).unwrap();
    let gmr = GmmRegression::new(&gmm, &input, &output).unwrap();
    let x = [0.3, f64::NAN, -1.0, f64::NAN];
    let pred = gmr.predict(Frames::new(&x, 4).unwrap(), false).unwrap();
    let xj = [x[0], x[1], x[2], x[3], f64::NAN, f64::NAN];
    let logs: Vec<f64> = (0..3)
        .map(|k| pi[k].ln() + textbook_marginal(g.mean(k), &g.covariance(k), &xj))
        .collect();
    let lse = log_sum_exp(&logs);
    let mut want = [0.0; 2];
    for k in 0..3 {
        let h = (logs[k] - lse).exp();
        assert!(close(pred.weights[k], h, 1e-10));
        let (filled, _) = textbook_conditional(g.mean(k), &g.covariance(k), &xj);
        want[0] += h * filled[4];
        want[1] += h * filled[5];
    }
    assert!(close(pred.mean[0], want[0], 1e-10) && close(pred.mean[1], want[1], 1e-10));
}

#[test]
fn hmm_gmr_online_with_missing_inputs_equals_batch() {
    let mut rng = ChaCha8Rng::seed_from_u64(22);
    let hmm = Hmm::new(
        random_stochastic(1, 4, &mut rng),
        random_stochastic(4, 4, &mut rng),
        random_gaussian(CovarianceType::Full, 4, 6, &mut rng),
    )
    .unwrap();
    let gmr = HmmRegression::new(&hmm, &[0, 1, 2], &[3, 4, 5]).unwrap();
    let (x, _) = hmm.sample(120, &mut rng).unwrap();
    let mut human: Vec<f64> = x.chunks_exact(6).flat_map(|f| f[..3].to_vec()).collect();
    knock_out(&mut human, 3, 0.3, 0.1, &mut rng);
    let batch = gmr.predict(Frames::new(&human, 3).unwrap(), true).unwrap();
    let mut online = gmr.online();
    for (t, f) in human.chunks_exact(3).enumerate() {
        let m = online.step_with_covariance(f).unwrap().to_vec();
        for k in 0..3 {
            assert!((m[k] - batch.mean[t * 3 + k]).abs() < 1e-10, "frame {t}");
        }
        for (a, b) in online
            .covariance()
            .iter()
            .zip(&batch.covariance.as_ref().unwrap()[t * 9..(t + 1) * 9])
        {
            assert!((a - b).abs() < 1e-10);
        }
    }
    assert!(batch.mean.iter().all(|v| v.is_finite()));
}

// ---------------------------------------------------------------------------
// Accuracy: values removed at random barely move the fit
// ---------------------------------------------------------------------------

/// A 3-state left-right HMM over 2 input and 2 output dims whose outputs depend on the inputs.
fn interaction_truth() -> Hmm<Gaussian> {
    let means = vec![
        0.0, 0.0, 0.0, 1.0, //
        3.0, 1.0, 2.0, -1.0, //
        6.0, -1.0, 4.0, 2.0,
    ];
    let base = DMatrix::from_row_slice(
        4,
        4,
        &[
            0.30, 0.05, 0.15, 0.00, //
            0.05, 0.20, 0.00, 0.08, //
            0.15, 0.00, 0.25, 0.02, //
            0.00, 0.08, 0.02, 0.15,
        ],
    );
    let covs: Vec<f64> = (0..3)
        .flat_map(|k| {
            (&base * (1.0 + 0.3 * k as f64))
                .transpose()
                .as_slice()
                .to_vec()
        })
        .collect();
    Hmm::new(
        vec![1.0, 0.0, 0.0],
        vec![0.97, 0.03, 0.0, 0.0, 0.97, 0.03, 0.0, 0.0, 1.0],
        Gaussian::full(4, means, covs).unwrap(),
    )
    .unwrap()
}

#[test]
fn values_removed_at_random_barely_move_the_fit_and_the_predictions() {
    let truth = interaction_truth();
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let train: Vec<Vec<f64>> = (0..20)
        .map(|_| truth.sample(100, &mut rng).unwrap().0)
        .collect();
    let test: Vec<Vec<f64>> = (0..5)
        .map(|_| truth.sample(100, &mut rng).unwrap().0)
        .collect();
    let bw = BaumWelch::builder()
        .init(HmmInit::KBins { smoothing: 0.01 })
        .regularisation(Regularisation::add_diagonal(1e-3).unwrap())
        .max_iter(100)
        .tol(1e-6)
        .build()
        .unwrap();
    let template = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: 3,
            dim: 4,
        },
    )
    .unwrap();
    let fit = |seqs: &[Vec<f64>]| {
        bw.fit(&template, &SequenceSet::new(seqs, 4).unwrap())
            .unwrap()
            .model
    };
    let mse = |model: &Hmm<Gaussian>, drop_test: f64, rng: &mut ChaCha8Rng| {
        let gmr = HmmRegression::new(model, &[0, 1], &[2, 3]).unwrap();
        let (mut err, mut n) = (0.0, 0.0);
        for seq in &test {
            let mut human: Vec<f64> = seq.chunks_exact(4).flat_map(|f| f[..2].to_vec()).collect();
            knock_out(&mut human, 2, drop_test, 0.0, rng);
            let pred = gmr.predict(Frames::new(&human, 2).unwrap(), false).unwrap();
            for (f, p) in seq.chunks_exact(4).zip(pred.mean.chunks_exact(2)) {
                err += (f[2] - p[0]).powi(2) + (f[3] - p[1]).powi(2);
                n += 1.0;
            }
        }
        err / n
    };
    let complete = fit(&train);
    let base_mse = mse(&complete, 0.0, &mut rng);
    for (frac, mean_tol, mse_ratio) in [(0.1, 0.05, 1.05), (0.3, 0.12, 1.15)] {
        let mut dropped = train.clone();
        for seq in &mut dropped {
            knock_out(seq, 4, frac, 0.0, &mut rng);
        }
        let model = fit(&dropped);
        // Left-right k-bins keeps the state order, so states match by index.
        let err = model
            .emission()
            .means()
            .iter()
            .zip(complete.emission().means())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(err < mean_tol, "{frac}: means moved by {err}");
        let m = mse(&model, 0.0, &mut rng);
        assert!(
            m < base_mse * mse_ratio,
            "{frac}: MSE {m} vs complete {base_mse}"
        );
        // Human frames with missing values at test time still predict.
        let m_missing = mse(&model, frac, &mut rng);
        assert!(m_missing.is_finite() && m_missing < base_mse * (1.0 + 4.0 * frac));
    }
}

#[test]
fn mixture_recovery_with_missing_values() {
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    let truth: Gmm = Gmm::new(
        vec![0.3, 0.3, 0.4],
        Gaussian::full(
            2,
            vec![-4.0, 0.0, 0.0, 4.0, 4.0, 0.0],
            vec![1.0, 0.3, 0.3, 0.5, 0.6, 0.0, 0.0, 0.6, 1.0, -0.4, -0.4, 0.8],
        )
        .unwrap(),
    )
    .unwrap();
    let (mut x, _) = truth.sample(3000, &mut rng).unwrap();
    knock_out(&mut x, 2, 0.3, 0.0, &mut rng);
    let em = Em::builder()
        .seed(2)
        .max_iter(300)
        .tol(1e-8)
        .build()
        .unwrap();
    let fitted = em
        .fit(
            &Gaussian::standard(
                CovarianceType::Full,
                Shape {
                    n_states: 3,
                    dim: 2,
                },
            )
            .unwrap(),
            Frames::new(&x, 2).unwrap(),
        )
        .unwrap()
        .model;
    for k in 0..3 {
        let m = truth.components().mean(k);
        let best = (0..3)
            .map(|j| {
                let f = fitted.components().mean(j);
                ((f[0] - m[0]).powi(2) + (f[1] - m[1]).powi(2)).sqrt()
            })
            .fold(f64::INFINITY, f64::min);
        assert!(
            best < 0.15,
            "component {k}: nearest fitted mean {best} away"
        );
    }
}

#[test]
fn an_added_diagonal_is_not_compounded_by_missing_values() {
    // Σ = S/n + rI after every M-step: the conditional covariance of a missing
    // value must not carry r into the next M-step, or with a fraction f missing
    // the variances settle near s + r/(1 − f) instead of s + r.
    let mut rng = ChaCha8Rng::seed_from_u64(51);
    let truth = Gmm::new(
        vec![1.0],
        Gaussian::full(2, vec![0.0, 0.0], vec![1.0, 0.5, 0.5, 1.0]).unwrap(),
    )
    .unwrap();
    let (complete, _) = truth.sample(20_000, &mut rng).unwrap();
    let mut holes = complete.clone();
    knock_out(&mut holes, 2, 0.3, 0.0, &mut rng);
    let em = Em::builder()
        .regularisation(Regularisation::add_diagonal(0.5).unwrap())
        .max_iter(500)
        .tol(1e-12)
        .build()
        .unwrap();
    let fit = |x: &[f64]| {
        em.fit(
            &Gaussian::standard(
                CovarianceType::Full,
                Shape {
                    n_states: 1,
                    dim: 2,
                },
            )
            .unwrap(),
            Frames::new(x, 2).unwrap(),
        )
        .unwrap()
        .model
        .components()
        .covariance(0)
    };
    let (a, b) = (fit(&complete), fit(&holes));
    for k in 0..2 {
        assert!((a[(k, k)] - 1.5).abs() < 0.05, "complete: {}", a[(k, k)]);
        assert!(
            (b[(k, k)] - a[(k, k)]).abs() < 0.05,
            "30 % missing: variance {} vs complete {}",
            b[(k, k)],
            a[(k, k)]
        );
    }
    assert!((b[(0, 1)] - a[(0, 1)]).abs() < 0.05);
}
