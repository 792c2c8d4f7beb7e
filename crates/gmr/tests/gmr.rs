//! Gaussian mixture regression against slow, obvious versions.
//!
//! * [`Conditional`] and [`Regression`] equal the analytic conditional
//!   `N(μ_o + Σ_oi Σ_ii⁻¹ (x − μ_i), Σ_oo − Σ_oi Σ_ii⁻¹ Σ_io)` computed here with
//!   `nalgebra` inverses, for random positive-definite covariances (all four
//!   covariance structures) and random disjoint, permuted input/output dims;
//! * with one component, GMR on a GMM fitted by EM is ordinary least squares
//!   (mean) and its residual covariance (covariance), to 1e-8;
//! * the GMR mean and covariance of a 3-component mixture with a 1-D input and
//!   a 1- or 2-D output match Monte-Carlo estimates: (a) sampling the
//!   predictive mixture from analytic weights and conditionals (200 000 draws,
//!   5 standard errors), (b) rejection sampling of the joint near the input
//!   (looser, stated tolerance for the window bias);
//! * static GMR weights are the responsibilities of the input marginal, HMM-GMR
//!   weights are the forward variable of the input marginal, both computed
//!   here independently;
//! * online HMM-GMR frame by frame equals the batch prediction (1e-12);
//! * invalid dims give `GmrError::InvalidDims`, a singular input block gives
//!   `SingularInput { state }`, bad frames give errors and no panic.
//!
//! Every random draw comes from a seeded `ChaCha8Rng`; proptest runs from a
//! fixed seed unless `PROPTEST_RNG_SEED` is set.

use nalgebra::{DMatrix, DVector};
use phasekit_emission::{CovarianceType, Frames, Gaussian, Regularisation, Shape};
use phasekit_gmm::{Em, Gmm};
use phasekit_gmr::{check_io, Conditional, GmmRegression, GmrError, HmmRegression, Regression};
use phasekit_hmm::Hmm;
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::f64::consts::PI;

fn config(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig::with_cases(cases);
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x0906_0a11);
    }
    c.failure_persistence = None;
    c
}

fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

/// A random symmetric positive-definite matrix `A Aᵀ + eps·I`.
fn random_pd(d: usize, eps: f64, rng: &mut ChaCha8Rng) -> DMatrix<f64> {
    let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-1.0..1.0));
    let m = &a * a.transpose() + DMatrix::identity(d, d) * eps;
    (&m + m.transpose()) * 0.5
}

fn row_major(m: &DMatrix<f64>) -> Vec<f64> {
    (0..m.nrows())
        .flat_map(|r| (0..m.ncols()).map(move |c| m[(r, c)]))
        .collect()
}

fn sub(m: &DMatrix<f64>, rows: &[usize], cols: &[usize]) -> DMatrix<f64> {
    DMatrix::from_fn(rows.len(), cols.len(), |r, c| m[(rows[r], cols[c])])
}

fn pick(v: &[f64], idx: &[usize]) -> DVector<f64> {
    DVector::from_iterator(idx.len(), idx.iter().map(|&i| v[i]))
}

/// `|got − want| ≤ tol·(1 + |want|)` element-wise.
fn assert_close(what: &str, got: &[f64], want: &[f64], tol: f64) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g - w).abs() <= tol * (1.0 + w.abs()),
            "{what}[{i}]: got {g:e}, want {w:e}, diff {:e}",
            (g - w).abs()
        );
    }
}

/// The analytic conditional of `N(mean, cov)`, with explicit inverses.
struct Analytic {
    /// `Σ_oi Σ_ii⁻¹`.
    regression: DMatrix<f64>,
    mean_in: DVector<f64>,
    mean_out: DVector<f64>,
    /// `Σ_oo − Σ_oi Σ_ii⁻¹ Σ_io`.
    covariance: DMatrix<f64>,
}

impl Analytic {
    fn new(mean: &[f64], cov: &DMatrix<f64>, input: &[usize], output: &[usize]) -> Self {
        let inv = sub(cov, input, input)
            .try_inverse()
            .expect("invertible input block");
        let regression = sub(cov, output, input) * inv;
        let covariance = sub(cov, output, output) - &regression * sub(cov, input, output);
        Analytic {
            regression,
            mean_in: pick(mean, input),
            mean_out: pick(mean, output),
            covariance,
        }
    }

    fn mean(&self, x_in: &[f64]) -> DVector<f64> {
        &self.mean_out + &self.regression * (DVector::from_column_slice(x_in) - &self.mean_in)
    }
}

/// `log N(x; μ, Σ)` with an explicit inverse and determinant.
fn log_normal(x: &[f64], mean: &DVector<f64>, cov: &DMatrix<f64>) -> f64 {
    let d = x.len() as f64;
    let diff = DVector::from_column_slice(x) - mean;
    let inv = cov.clone().try_inverse().expect("invertible covariance");
    let maha = (diff.transpose() * inv * &diff)[(0, 0)];
    -0.5 * (d * (2.0 * PI).ln() + cov.determinant().ln() + maha)
}

/// Weights `h_k ∝ π_k N(x_in; μ_k^i, Σ_k^ii)`.
fn input_weights(
    weights: &[f64],
    means: &[Vec<f64>],
    covs: &[DMatrix<f64>],
    input: &[usize],
    x_in: &[f64],
) -> Vec<f64> {
    let logs: Vec<f64> = (0..weights.len())
        .map(|k| {
            weights[k].ln()
                + log_normal(x_in, &pick(&means[k], input), &sub(&covs[k], input, input))
        })
        .collect();
    let m = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let e: Vec<f64> = logs.iter().map(|l| (l - m).exp()).collect();
    let total: f64 = e.iter().sum();
    e.iter().map(|v| v / total).collect()
}

/// `Σ_k h_k m_k` and `Σ_k h_k (C_k + (m_k − m)(m_k − m)ᵀ)`, row-major.
fn mix(h: &[f64], parts: &[Analytic], x_in: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let o = parts[0].mean_out.len();
    let means: Vec<DVector<f64>> = parts.iter().map(|p| p.mean(x_in)).collect();
    let mut mean = DVector::zeros(o);
    for (hk, mk) in h.iter().zip(&means) {
        mean += mk * *hk;
    }
    let mut cov = DMatrix::zeros(o, o);
    for ((hk, mk), p) in h.iter().zip(&means).zip(parts) {
        let dm = mk - &mean;
        cov += (&p.covariance + &dm * dm.transpose()) * *hk;
    }
    (mean.as_slice().to_vec(), row_major(&cov))
}

/// Random disjoint, non-empty input and output dims of `0..d`, in random order.
fn random_io(d: usize, rng: &mut ChaCha8Rng) -> (Vec<usize>, Vec<usize>) {
    let mut dims: Vec<usize> = (0..d).collect();
    dims.shuffle(rng);
    let n_in = rng.random_range(1..d);
    let n_out = rng.random_range(1..=d - n_in);
    (dims[..n_in].to_vec(), dims[n_in..n_in + n_out].to_vec())
}

// ---------------------------------------------------------------------------
// Conditionals
// ---------------------------------------------------------------------------

proptest! {
    #![proptest_config(config(96))]

    #[test]
    fn conditional_equals_the_analytic_conditional(seed in any::<u64>(), d in 2usize..=7) {
        let mut r = rng(seed);
        let cov = random_pd(d, 0.3, &mut r);
        let mean: Vec<f64> = (0..d).map(|_| r.random_range(-5.0..5.0)).collect();
        let (input, output) = random_io(d, &mut r);
        let c = Conditional::new(&mean, &cov, &input, &output, 0).unwrap();
        let a = Analytic::new(&mean, &cov, &input, &output);
        prop_assert_eq!(c.n_in(), input.len());
        prop_assert_eq!(c.n_out(), output.len());
        assert_close("regression", c.regression(), &row_major(&a.regression), 1e-10);
        assert_close("covariance", c.covariance(), &row_major(&a.covariance), 1e-10);
        for _ in 0..5 {
            let x: Vec<f64> = (0..input.len()).map(|_| r.random_range(-8.0..8.0)).collect();
            let mut got = vec![f64::NAN; output.len()];
            c.mean_into(&x, &mut got).unwrap();
            assert_close("mean", &got, a.mean(&x).as_slice(), 1e-10);
        }
        // Conditioning on everything but the outputs, with the outputs listed
        // in another order, permutes the result accordingly.
        let mut rev = output.clone();
        rev.reverse();
        let c_rev = Conditional::new(&mean, &cov, &input, &rev, 0).unwrap();
        let o = output.len();
        for rr in 0..o {
            for qq in 0..o {
                let want = c.covariance()[(o - 1 - rr) * o + (o - 1 - qq)];
                prop_assert!((c_rev.covariance()[rr * o + qq] - want).abs() <= 1e-12 * (1.0 + want.abs()));
            }
        }
    }

    #[test]
    fn regression_conditions_every_state_of_every_structure(
        seed in any::<u64>(),
        kind in 0usize..4,
        k in 1usize..=3,
        d in 2usize..=5,
    ) {
        let kind = [CovarianceType::Full, CovarianceType::Diagonal, CovarianceType::Spherical, CovarianceType::Tied][kind];
        let mut r = rng(seed);
        let means: Vec<Vec<f64>> = (0..k).map(|_| (0..d).map(|_| r.random_range(-3.0..3.0)).collect()).collect();
        // The full covariance of every state, built independently of the library.
        let (raw, covs): (Vec<f64>, Vec<DMatrix<f64>>) = match kind {
            CovarianceType::Full => {
                let covs: Vec<DMatrix<f64>> = (0..k).map(|_| random_pd(d, 0.3, &mut r)).collect();
                (covs.iter().flat_map(row_major).collect(), covs)
            }
            CovarianceType::Tied => {
                let c = random_pd(d, 0.3, &mut r);
                (row_major(&c), vec![c; k])
            }
            CovarianceType::Diagonal => {
                let v: Vec<f64> = (0..k * d).map(|_| r.random_range(0.2..3.0)).collect();
                let covs = v.chunks(d).map(|c| DMatrix::from_diagonal(&DVector::from_column_slice(c))).collect();
                (v, covs)
            }
            CovarianceType::Spherical => {
                let v: Vec<f64> = (0..k).map(|_| r.random_range(0.2..3.0)).collect();
                let covs = v.iter().map(|s| DMatrix::identity(d, d) * *s).collect();
                (v, covs)
            }
        };
        let joint = Gaussian::new(kind, d, means.concat(), raw).unwrap();
        let (input, output) = random_io(d, &mut r);
        let reg = Regression::new(&joint, &input, &output).unwrap();
        prop_assert_eq!(reg.n_states(), k);
        prop_assert_eq!(reg.input(), &input[..]);
        prop_assert_eq!(reg.output(), &output[..]);
        let x: Vec<f64> = (0..input.len()).map(|_| r.random_range(-4.0..4.0)).collect();
        for (state, c) in reg.conditionals().iter().enumerate() {
            let a = Analytic::new(&means[state], &covs[state], &input, &output);
            assert_close("regression", c.regression(), &row_major(&a.regression), 1e-10);
            assert_close("covariance", c.covariance(), &row_major(&a.covariance), 1e-10);
            let mut got = vec![0.0; output.len()];
            c.mean_into(&x, &mut got).unwrap();
            assert_close("mean", &got, a.mean(&x).as_slice(), 1e-10);
        }
    }
}

// ---------------------------------------------------------------------------
// One component: least squares
// ---------------------------------------------------------------------------

#[test]
fn one_component_gmr_is_least_squares() {
    let mut r = rng(5);
    let n = 500;
    let a = DMatrix::from_row_slice(2, 3, &[1.5, -0.7, 0.3, 0.2, 2.0, -1.1]);
    let b = DVector::from_column_slice(&[0.5, -3.0]);
    // Joint frames in the order [y0, x0, x1, y1, x2]: inputs 1, 2, 4 and outputs 0, 3.
    let (input, output) = ([1, 2, 4], [0, 3]);
    let mut xs = DMatrix::zeros(n, 3);
    let mut ys = DMatrix::zeros(n, 2);
    let mut joint = Vec::with_capacity(5 * n);
    for t in 0..n {
        let x = DVector::from_fn(3, |_, _| r.random_range(-2.0..3.0));
        let noise = DVector::from_fn(2, |i, _| if i == 0 { 0.3 } else { 0.8 } * normal(&mut r));
        let y = &a * &x + &b + noise;
        xs.set_row(t, &x.transpose());
        ys.set_row(t, &y.transpose());
        joint.extend_from_slice(&[y[0], x[0], x[1], y[1], x[2]]);
    }
    let frames = Frames::new(&joint, 5).unwrap();
    let fitted = Em::builder()
        .regularisation(Regularisation::none())
        .build()
        .unwrap()
        .fit(
            &Gaussian::standard(
                CovarianceType::Full,
                Shape {
                    n_states: 1,
                    dim: 5,
                },
            )
            .unwrap(),
            frames,
        )
        .unwrap();
    let gmr = GmmRegression::new(&fitted.model, &input, &output).unwrap();

    // Ordinary least squares with an intercept, by QR of the design matrix.
    let mut design = DMatrix::from_element(n, 4, 1.0);
    design.view_mut((0, 1), (n, 3)).copy_from(&xs);
    let qr = design.clone().qr();
    let beta = qr
        .r()
        .solve_upper_triangular(&(qr.q().transpose() * &ys))
        .unwrap(); // 4 × 2
    let residuals = &ys - &design * &beta;
    let residual_cov = residuals.transpose() * &residuals / n as f64;

    let queries: Vec<f64> = (0..20 * 3).map(|_| r.random_range(-3.0..4.0)).collect();
    let pred = gmr
        .predict(Frames::new(&queries, 3).unwrap(), true)
        .unwrap();
    assert_eq!(pred.n_out, 2);
    assert!(pred.weights.iter().all(|w| *w == 1.0));
    let cov = pred.covariance.as_ref().unwrap();
    for (t, q) in queries.chunks(3).enumerate() {
        let row = DMatrix::from_row_slice(1, 4, &[1.0, q[0], q[1], q[2]]);
        let want = &row * &beta;
        assert_close(
            &format!("mean at query {t}"),
            &pred.mean[2 * t..2 * t + 2],
            want.as_slice(),
            1e-8,
        );
        assert_close(
            &format!("covariance at query {t}"),
            &cov[4 * t..4 * t + 4],
            &row_major(&residual_cov),
            1e-8,
        );
    }
    // The fit is not trivial: it recovers A and b up to the noise.
    assert!((beta.view((1, 0), (3, 2)).transpose() - &a).abs().max() < 0.2);
}

// ---------------------------------------------------------------------------
// Monte Carlo
// ---------------------------------------------------------------------------

/// A 3-component joint mixture over `1 + n_out` dims; the input is dim 1 when
/// `n_out = 2` (outputs listed as `[2, 0]`) and dim 0 when `n_out = 1`.
struct McMixture {
    weights: Vec<f64>,
    means: Vec<Vec<f64>>,
    covs: Vec<DMatrix<f64>>,
    input: Vec<usize>,
    output: Vec<usize>,
}

fn mc_mixture(n_out: usize) -> McMixture {
    let mut r = rng(40 + n_out as u64);
    let d = 1 + n_out;
    let (input, output) = if n_out == 2 {
        (vec![1], vec![2, 0])
    } else {
        (vec![0], vec![1])
    };
    let x_means = [-1.0, 0.5, 2.0];
    let means = (0..3)
        .map(|k| {
            let mut m: Vec<f64> = (0..d).map(|_| r.random_range(-3.0..3.0)).collect();
            m[input[0]] = x_means[k];
            m
        })
        .collect();
    // Unit input variance for every component, so that x0 = 0.8 sees all three.
    let covs = (0..3)
        .map(|_| {
            let mut c = random_pd(d, 0.2, &mut r);
            let s = 1.0 / c[(input[0], input[0])].sqrt();
            c.row_mut(input[0]).scale_mut(s);
            c.column_mut(input[0]).scale_mut(s);
            c
        })
        .collect();
    McMixture {
        weights: vec![0.3, 0.45, 0.25],
        means,
        covs,
        input,
        output,
    }
}

impl McMixture {
    fn gmm(&self) -> Gmm {
        let d = self.means[0].len();
        let covs: Vec<f64> = self.covs.iter().flat_map(row_major).collect();
        Gmm::new(
            self.weights.clone(),
            Gaussian::full(d, self.means.concat(), covs).unwrap(),
        )
        .unwrap()
    }
}

/// Sample mean and covariance of `samples` (`n × o`), and the standard errors
/// of every entry: `√(S_rr / n)` for the mean and the standard deviation of
/// `(y_r − ȳ_r)(y_q − ȳ_q)` over `√n` for the covariance.
fn moments(samples: &[f64], o: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
    let n = samples.len() / o;
    let nf = n as f64;
    let mut mean = vec![0.0; o];
    for y in samples.chunks(o) {
        for (m, v) in mean.iter_mut().zip(y) {
            *m += v / nf;
        }
    }
    let mut cov = vec![0.0; o * o];
    let mut sq = vec![0.0; o * o];
    for y in samples.chunks(o) {
        for r in 0..o {
            for q in 0..o {
                let p = (y[r] - mean[r]) * (y[q] - mean[q]);
                cov[r * o + q] += p;
                sq[r * o + q] += p * p;
            }
        }
    }
    let cov: Vec<f64> = cov.iter().map(|c| c / nf).collect();
    let se_mean = (0..o).map(|r| (cov[r * o + r] / nf).sqrt()).collect();
    let se_cov = sq
        .iter()
        .zip(&cov)
        .map(|(s, c)| ((s / nf - c * c) / nf).sqrt())
        .collect();
    (mean, cov, se_mean, se_cov)
}

fn assert_within(what: &str, got: &[f64], want: &[f64], tol: &[f64]) {
    for i in 0..got.len() {
        assert!(
            (got[i] - want[i]).abs() <= tol[i],
            "{what}[{i}]: GMR {} vs Monte Carlo {} (tol {})",
            want[i],
            got[i],
            tol[i]
        );
    }
}

#[test]
fn gmr_moments_match_monte_carlo_of_the_predictive_mixture() {
    let x0 = 0.8;
    for n_out in [1, 2] {
        let mc = mc_mixture(n_out);
        let gmr = GmmRegression::new(&mc.gmm(), &mc.input, &mc.output).unwrap();
        let pred = gmr.predict(Frames::new(&[x0], 1).unwrap(), true).unwrap();
        // Analytic weights and conditionals, independent of the library.
        let h = input_weights(&mc.weights, &mc.means, &mc.covs, &mc.input, &[x0]);
        assert!(
            h.iter().all(|v| *v > 0.05),
            "x0 should see every component: {h:?}"
        );
        assert_close("weights", &pred.weights, &h, 1e-12);
        let parts: Vec<Analytic> = (0..3)
            .map(|k| Analytic::new(&mc.means[k], &mc.covs[k], &mc.input, &mc.output))
            .collect();
        let chols: Vec<DMatrix<f64>> = parts
            .iter()
            .map(|p| p.covariance.clone().cholesky().unwrap().unpack())
            .collect();
        let means: Vec<DVector<f64>> = parts.iter().map(|p| p.mean(&[x0])).collect();

        let n = 200_000;
        let mut r = rng(77 + n_out as u64);
        let mut samples = Vec::with_capacity(n * n_out);
        for _ in 0..n {
            let u: f64 = r.random();
            let k = if u < h[0] {
                0
            } else if u < h[0] + h[1] {
                1
            } else {
                2
            };
            let z = DVector::from_fn(n_out, |_, _| normal(&mut r));
            samples.extend((&means[k] + &chols[k] * z).iter());
        }
        let (mean, cov, se_mean, se_cov) = moments(&samples, n_out);
        let five = |se: Vec<f64>| se.iter().map(|s| 5.0 * s).collect::<Vec<_>>();
        assert_within(
            &format!("{n_out}-D output: mean"),
            &mean,
            &pred.mean,
            &five(se_mean),
        );
        assert_within(
            &format!("{n_out}-D output: covariance"),
            &cov,
            pred.covariance.as_ref().unwrap(),
            &five(se_cov),
        );
    }
}

#[test]
fn gmr_moments_match_rejection_sampling_of_the_joint() {
    let x0 = 0.8;
    let eps = 0.02;
    for n_out in [1, 2] {
        let mc = mc_mixture(n_out);
        let d = 1 + n_out;
        let gmr = GmmRegression::new(&mc.gmm(), &mc.input, &mc.output).unwrap();
        let pred = gmr.predict(Frames::new(&[x0], 1).unwrap(), true).unwrap();
        let chols: Vec<DMatrix<f64>> = mc
            .covs
            .iter()
            .map(|c| c.clone().cholesky().unwrap().unpack())
            .collect();
        let mut r = rng(91 + n_out as u64);
        let target = 20_000;
        let mut kept = Vec::with_capacity(target * n_out);
        let mut draws = 0usize;
        while kept.len() < target * n_out {
            draws += 1;
            assert!(draws < 20_000_000, "acceptance rate too low");
            let u: f64 = r.random();
            let k = if u < mc.weights[0] {
                0
            } else if u < mc.weights[0] + mc.weights[1] {
                1
            } else {
                2
            };
            let z = DVector::from_fn(d, |_, _| normal(&mut r));
            let x = DVector::from_column_slice(&mc.means[k]) + &chols[k] * z;
            if (x[mc.input[0]] - x0).abs() < eps {
                kept.extend(mc.output.iter().map(|&o| x[o]));
            }
        }
        let (mean, cov, se_mean, se_cov) = moments(&kept, n_out);
        // 5 standard errors plus an allowance for the window: conditioning on
        // |x − x0| < ε instead of x = x0 biases the moments by O(ε²) (≈ 1e-3 here).
        let tol = |se: Vec<f64>| se.iter().map(|s| 5.0 * s + 0.01).collect::<Vec<_>>();
        assert_within(
            &format!("{n_out}-D output: mean"),
            &mean,
            &pred.mean,
            &tol(se_mean),
        );
        assert_within(
            &format!("{n_out}-D output: covariance"),
            &cov,
            pred.covariance.as_ref().unwrap(),
            &tol(se_cov),
        );
    }
}

// ---------------------------------------------------------------------------
// Weights: static and HMM
// ---------------------------------------------------------------------------

#[test]
fn static_gmr_weights_are_input_marginal_responsibilities() {
    let mut r = rng(12);
    let (d, k) = (4, 3);
    let weights = vec![0.2, 0.5, 0.3];
    let means: Vec<Vec<f64>> = (0..k)
        .map(|_| (0..d).map(|_| r.random_range(-2.0..2.0)).collect())
        .collect();
    let covs: Vec<DMatrix<f64>> = (0..k).map(|_| random_pd(d, 0.3, &mut r)).collect();
    let gmm = Gmm::new(
        weights.clone(),
        Gaussian::full(d, means.concat(), covs.iter().flat_map(row_major).collect()).unwrap(),
    )
    .unwrap();
    let (input, output) = ([2, 0], [3, 1]);
    let gmr = GmmRegression::new(&gmm, &input, &output).unwrap();
    let queries: Vec<f64> = (0..50 * 2).map(|_| r.random_range(-3.0..3.0)).collect();
    let pred = gmr
        .predict(Frames::new(&queries, 2).unwrap(), true)
        .unwrap();
    let parts: Vec<Analytic> = (0..k)
        .map(|j| Analytic::new(&means[j], &covs[j], &input, &output))
        .collect();
    let cov = pred.covariance.as_ref().unwrap();
    for (t, x) in queries.chunks(2).enumerate() {
        let h = input_weights(&weights, &means, &covs, &input, x);
        assert_close(
            &format!("weights at {t}"),
            &pred.weights[k * t..k * (t + 1)],
            &h,
            1e-10,
        );
        let (m, c) = mix(&h, &parts, x);
        assert_close(
            &format!("mean at {t}"),
            &pred.mean[2 * t..2 * t + 2],
            &m,
            1e-9,
        );
        assert_close(
            &format!("covariance at {t}"),
            &cov[4 * t..4 * t + 4],
            &c,
            1e-9,
        );
    }
    // Without the covariance, the same means.
    let mean_only = gmr
        .predict(Frames::new(&queries, 2).unwrap(), false)
        .unwrap();
    assert!(mean_only.covariance.is_none());
    assert_eq!(mean_only.mean, pred.mean);
}

struct JointHmm {
    hmm: Hmm<Gaussian>,
    start: Vec<f64>,
    transition: Vec<f64>,
    means: Vec<Vec<f64>>,
    covs: Vec<DMatrix<f64>>,
}

/// 4 states over 5 joint dims, sticky transitions.
fn joint_hmm(seed: u64) -> JointHmm {
    let mut r = rng(seed);
    let (s, d) = (4, 5);
    let means: Vec<Vec<f64>> = (0..s)
        .map(|_| (0..d).map(|_| r.random_range(-3.0..3.0)).collect())
        .collect();
    let covs: Vec<DMatrix<f64>> = (0..s).map(|_| random_pd(d, 0.3, &mut r)).collect();
    let start = vec![0.4, 0.3, 0.2, 0.1];
    let mut transition = vec![0.0; s * s];
    for i in 0..s {
        for j in 0..s {
            transition[i * s + j] = if i == j { 0.85 } else { 0.05 };
        }
    }
    let emission =
        Gaussian::full(d, means.concat(), covs.iter().flat_map(row_major).collect()).unwrap();
    JointHmm {
        hmm: Hmm::new(start.clone(), transition.clone(), emission).unwrap(),
        start,
        transition,
        means,
        covs,
    }
}

const HMM_INPUT: [usize; 3] = [3, 0, 2];
const HMM_OUTPUT: [usize; 2] = [4, 1];

/// A sampled joint sequence restricted to the input dims (in `HMM_INPUT` order).
fn input_sequence(j: &JointHmm, len: usize, seed: u64) -> Vec<f64> {
    let (joint, _) = j.hmm.sample(len, &mut rng(seed)).unwrap();
    joint
        .chunks(5)
        .flat_map(|f| HMM_INPUT.iter().map(move |&i| f[i]))
        .collect()
}

#[test]
fn hmm_gmr_weights_are_the_input_forward_variable() {
    let j = joint_hmm(21);
    let s = 4;
    let xs = input_sequence(&j, 120, 22);
    let gmr = HmmRegression::new(&j.hmm, &HMM_INPUT, &HMM_OUTPUT).unwrap();
    let pred = gmr.predict(Frames::new(&xs, 3).unwrap(), true).unwrap();
    let parts: Vec<Analytic> = (0..s)
        .map(|k| Analytic::new(&j.means[k], &j.covs[k], &HMM_INPUT, &HMM_OUTPUT))
        .collect();
    // Forward filter on the input marginal, with explicit densities.
    let mut h = vec![0.0; s];
    let cov = pred.covariance.as_ref().unwrap();
    for (t, x) in xs.chunks(3).enumerate() {
        let pred_state: Vec<f64> = if t == 0 {
            j.start.clone()
        } else {
            (0..s)
                .map(|b| (0..s).map(|a| h[a] * j.transition[a * s + b]).sum())
                .collect()
        };
        let logs: Vec<f64> = (0..s)
            .map(|k| {
                pred_state[k].ln()
                    + log_normal(
                        x,
                        &pick(&j.means[k], &HMM_INPUT),
                        &sub(&j.covs[k], &HMM_INPUT, &HMM_INPUT),
                    )
            })
            .collect();
        let m = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let e: Vec<f64> = logs.iter().map(|l| (l - m).exp()).collect();
        let total: f64 = e.iter().sum();
        h = e.iter().map(|v| v / total).collect();
        assert_close(
            &format!("forward variable at {t}"),
            &pred.weights[s * t..s * (t + 1)],
            &h,
            1e-9,
        );
        let (mm, cc) = mix(&h, &parts, x);
        assert_close(
            &format!("mean at {t}"),
            &pred.mean[2 * t..2 * t + 2],
            &mm,
            1e-8,
        );
        assert_close(
            &format!("covariance at {t}"),
            &cov[4 * t..4 * t + 4],
            &cc,
            1e-8,
        );
    }
}

#[test]
fn online_hmm_gmr_equals_the_batch_prediction() {
    let j = joint_hmm(31);
    let s = 4;
    let xs = input_sequence(&j, 300, 32);
    let gmr = HmmRegression::new(&j.hmm, &HMM_INPUT, &HMM_OUTPUT).unwrap();
    assert_eq!(gmr.input_model().dim(), 3);
    let batch = gmr.predict(Frames::new(&xs, 3).unwrap(), true).unwrap();
    let batch_cov = batch.covariance.as_ref().unwrap();
    let mut online = gmr.online();
    // Before the first frame the belief is the initial distribution (of the
    // input-marginal HMM, whose construction renormalises π again: within an ulp).
    assert_eq!(online.belief(), gmr.input_model().start());
    assert_close("initial belief", online.belief(), &j.start, 1e-15);
    let mut mean_only = gmr.online();
    for pass in 0..2 {
        for (t, x) in xs.chunks(3).enumerate() {
            let mean = online.step_with_covariance(x).unwrap().to_vec();
            assert_close(
                &format!("pass {pass}, mean at {t}"),
                &mean,
                &batch.mean[2 * t..2 * t + 2],
                1e-12,
            );
            assert_close(
                &format!("pass {pass}, covariance at {t}"),
                online.covariance(),
                &batch_cov[4 * t..4 * t + 4],
                1e-12,
            );
            assert_close(
                &format!("pass {pass}, belief at {t}"),
                online.belief(),
                &batch.weights[s * t..s * (t + 1)],
                1e-12,
            );
            let m = mean_only.step(x).unwrap();
            assert_close(
                &format!("pass {pass}, mean-only step at {t}"),
                m,
                &batch.mean[2 * t..2 * t + 2],
                1e-12,
            );
        }
        // A new demonstration starts from scratch.
        online.reset();
        mean_only.reset();
        assert_eq!(online.belief(), gmr.input_model().start());
    }
}

// ---------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------

#[test]
fn invalid_dims_are_refused() {
    let j = joint_hmm(41);
    let gmm = Gmm::new(vec![0.25; 4], j.hmm.emission().clone()).unwrap();
    let mean = j.means[0].clone();
    let cov = j.covs[0].clone();
    let cases: [(&[usize], &[usize], &str); 8] = [
        (&[0, 1], &[1, 2], "dimension 1 is both input and output"),
        (&[0, 5], &[1], "input"),
        (&[0], &[7], "output"),
        (&[], &[1], "input"),
        (&[0], &[], "output"),
        (&[0, 0], &[1], "input"),
        (&[2], &[3, 3], "output"),
        (&[0, 1, 2, 3, 4], &[4], "both input and output"),
    ];
    for (input, output, needle) in cases {
        let errors = [
            check_io(input, output, 5).unwrap_err(),
            Conditional::new(&mean, &cov, input, output, 0).unwrap_err(),
            Regression::new(j.hmm.emission(), input, output).unwrap_err(),
            GmmRegression::new(&gmm, input, output).unwrap_err(),
            HmmRegression::new(&j.hmm, input, output).unwrap_err(),
        ];
        for e in errors {
            match &e {
                GmrError::InvalidDims(msg) => {
                    assert!(msg.contains(needle), "{input:?} / {output:?}: {msg}")
                }
                other => panic!("{input:?} / {output:?}: expected InvalidDims, got {other:?}"),
            }
        }
    }
}

#[test]
fn singular_input_block_names_the_state() {
    // x1 = 2·x0 exactly: the input block {0, 1} is singular, the output dim 2 is fine.
    let cov = DMatrix::from_row_slice(3, 3, &[1.0, 2.0, 0.3, 2.0, 4.0, 0.6, 0.3, 0.6, 1.0]);
    for state in [0, 5] {
        let err = Conditional::new(&[0.0, 0.0, 0.0], &cov, &[0, 1], &[2], state).unwrap_err();
        assert_eq!(err, GmrError::SingularInput { state });
        assert!(err.to_string().contains(&format!("state {state}")));
    }
    // An indefinite input block is refused the same way.
    let cov = DMatrix::from_row_slice(3, 3, &[1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0]);
    assert_eq!(
        Conditional::new(&[0.0; 3], &cov, &[1, 0], &[2], 2).unwrap_err(),
        GmrError::SingularInput { state: 2 }
    );
    // Conditioning on a single dimension of zero variance.
    let cov = DMatrix::from_row_slice(2, 2, &[0.0, 0.0, 0.0, 1.0]);
    assert_eq!(
        Conditional::new(&[0.0; 2], &cov, &[0], &[1], 3).unwrap_err(),
        GmrError::SingularInput { state: 3 }
    );
}

#[test]
fn bad_frames_are_errors_not_panics() {
    let j = joint_hmm(51);
    let gmm = Gmm::new(vec![0.25; 4], j.hmm.emission().clone()).unwrap();
    let static_gmr = GmmRegression::new(&gmm, &HMM_INPUT, &HMM_OUTPUT).unwrap();
    let hmm_gmr = HmmRegression::new(&j.hmm, &HMM_INPUT, &HMM_OUTPUT).unwrap();
    // Frames with 2 values instead of the 3 inputs.
    let two = Frames::new(&[0.0, 1.0, 2.0, 3.0], 2).unwrap();
    assert!(static_gmr.predict(two, true).is_err());
    assert!(hmm_gmr.predict(two, true).is_err());
    let mut online = hmm_gmr.online();
    online.step(&[0.0, 1.0, 2.0]).unwrap();
    let belief = online.belief().to_vec();
    for bad in [
        &[0.0, 1.0][..],
        &[0.0, 1.0, 2.0, 3.0],
        &[0.0, f64::NEG_INFINITY, 1.0],
        &[f64::INFINITY, 0.0, 0.0],
        &[],
    ] {
        assert!(online.step(bad).is_err(), "{bad:?}");
        assert!(online.step_with_covariance(bad).is_err(), "{bad:?}");
        assert_eq!(
            online.belief(),
            &belief[..],
            "a refused frame must leave the belief unchanged"
        );
    }
    // The filter goes on after refused frames.
    assert!(online.step(&[0.5, 0.5, 0.5]).is_ok());
    // A conditional refuses buffers of the wrong length instead of truncating.
    let c = &hmm_gmr.regression().conditionals()[0];
    let mut out = vec![0.0; c.n_out()];
    assert!(c.mean_into(&[0.0; 2], &mut out).is_err());
    assert!(c.mean_into(&vec![0.0; c.n_in()], &mut [0.0; 1]).is_err());
    assert!(c.mean_into(&vec![0.0; c.n_in()], &mut out).is_ok());
}

#[test]
fn mix_into_checks_its_buffers() {
    let j = joint_hmm(61);
    let reg = Regression::new(j.hmm.emission(), &HMM_INPUT, &HMM_OUTPUT).unwrap();
    let (k, o) = (reg.n_states(), reg.n_out());
    let x = [0.1, -0.2, 0.3];
    let h = [0.1, 0.2, 0.3, 0.4];
    let parts: Vec<Analytic> = (0..k)
        .map(|s| Analytic::new(&j.means[s], &j.covs[s], &HMM_INPUT, &HMM_OUTPUT))
        .collect();
    let (want_mean, want_cov) = mix(&h, &parts, &x);
    let mut mean = vec![0.0; o];
    let mut cov = vec![0.0; o * o];
    let mut scratch = vec![0.0; k * o];
    reg.mix_into(&x, &h, &mut mean, Some(&mut cov), &mut scratch)
        .unwrap();
    assert_close("mean", &mean, &want_mean, 1e-10);
    assert_close("covariance", &cov, &want_cov, 1e-10);
    // Every buffer of the wrong length is refused (no panic, no silent truncation).
    let ok = |v: usize| vec![0.0; v];
    assert!(reg
        .mix_into(
            &x[..2],
            &h,
            &mut ok(o),
            Some(&mut ok(o * o)),
            &mut ok(k * o)
        )
        .is_err());
    assert!(reg
        .mix_into(
            &x,
            &h[..3],
            &mut ok(o),
            Some(&mut ok(o * o)),
            &mut ok(k * o)
        )
        .is_err());
    assert!(reg
        .mix_into(&x, &h, &mut ok(o - 1), Some(&mut ok(o * o)), &mut ok(k * o))
        .is_err());
    assert!(reg
        .mix_into(&x, &h, &mut ok(o), Some(&mut ok(o * o - 1)), &mut ok(k * o))
        .is_err());
    assert!(reg
        .mix_into(&x, &h, &mut ok(o), None, &mut ok(k * o - 1))
        .is_err());
    assert!(reg
        .mix_into(&x, &h, &mut ok(o + 1), None, &mut ok(k * o))
        .is_err());
}

#[test]
fn conditional_refuses_a_covariance_of_the_wrong_shape() {
    let mean = [0.0, 1.0, 2.0];
    for cov in [
        DMatrix::identity(2, 2),
        DMatrix::identity(4, 4),
        DMatrix::from_element(3, 2, 0.5),
    ] {
        let err = Conditional::new(&mean, &cov, &[0], &[2], 1).unwrap_err();
        assert!(!matches!(err, GmrError::SingularInput { .. }), "{err:?}");
    }
    let mut cov = DMatrix::identity(3, 3);
    cov[(2, 2)] = f64::NAN;
    assert!(Conditional::new(&mean, &cov, &[0], &[2], 1).is_err());
    assert!(Conditional::new(
        &[0.0, f64::INFINITY, 0.0],
        &DMatrix::identity(3, 3),
        &[0],
        &[1],
        1
    )
    .is_err());
}
