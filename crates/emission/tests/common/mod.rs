//! Shared helpers for the emission property tests: random models and the slow,
//! obvious reference formulas the library is checked against.
#![allow(dead_code)]

use nalgebra::{DMatrix, DVector};
use phasekit_emission::{CovarianceType, Gaussian};
use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::f64::consts::PI;

pub const KINDS: [CovarianceType; 4] = [
    CovarianceType::Full,
    CovarianceType::Diagonal,
    CovarianceType::Spherical,
    CovarianceType::Tied,
];

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

pub fn normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    rng.sample(StandardNormal)
}

/// A random symmetric positive-definite matrix `A Aᵀ + ε I`.
pub fn random_pd<R: Rng + ?Sized>(d: usize, eps: f64, rng: &mut R) -> DMatrix<f64> {
    let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-1.0..1.0));
    let m = &a * a.transpose() + DMatrix::identity(d, d) * eps;
    // Exactly symmetric.
    (&m + m.transpose()) * 0.5
}

pub fn row_major(m: &DMatrix<f64>) -> Vec<f64> {
    let mut v = Vec::with_capacity(m.len());
    for r in 0..m.nrows() {
        for c in 0..m.ncols() {
            v.push(m[(r, c)]);
        }
    }
    v
}

/// A random model of the given structure, with the full covariance matrix of
/// every state as the test sees it (built independently of the library).
pub struct RandomGaussian {
    pub model: Gaussian,
    pub means: Vec<DVector<f64>>,
    pub covs: Vec<DMatrix<f64>>,
}

pub fn random_gaussian<R: Rng + ?Sized>(
    kind: CovarianceType,
    s: usize,
    d: usize,
    rng: &mut R,
) -> RandomGaussian {
    let means: Vec<DVector<f64>> = (0..s)
        .map(|_| DVector::from_fn(d, |_, _| rng.random_range(-3.0..3.0)))
        .collect();
    let flat_means: Vec<f64> = means.iter().flat_map(|m| m.iter().copied()).collect();
    let (raw, covs): (Vec<f64>, Vec<DMatrix<f64>>) = match kind {
        CovarianceType::Full => {
            let covs: Vec<_> = (0..s).map(|_| random_pd(d, 0.1, rng)).collect();
            (covs.iter().flat_map(row_major).collect(), covs)
        }
        CovarianceType::Tied => {
            let c = random_pd(d, 0.1, rng);
            (row_major(&c), vec![c; s])
        }
        CovarianceType::Diagonal => {
            let v: Vec<f64> = (0..s * d).map(|_| rng.random_range(0.1..3.0)).collect();
            let covs = (0..s)
                .map(|i| {
                    DMatrix::from_diagonal(&DVector::from_column_slice(&v[i * d..(i + 1) * d]))
                })
                .collect();
            (v, covs)
        }
        CovarianceType::Spherical => {
            let v: Vec<f64> = (0..s).map(|_| rng.random_range(0.1..3.0)).collect();
            let covs = v.iter().map(|x| DMatrix::identity(d, d) * *x).collect();
            (v, covs)
        }
    };
    let model = Gaussian::new(kind, d, flat_means, raw).expect("valid random model");
    RandomGaussian { model, means, covs }
}

/// Textbook `log N(x; μ, Σ) = −½ (D ln 2π + ln det Σ + (x−μ)ᵀ Σ⁻¹ (x−μ))`.
pub fn textbook_log_normal(x: &[f64], mu: &DVector<f64>, cov: &DMatrix<f64>) -> f64 {
    let d = mu.len();
    let diff = DVector::from_column_slice(x) - mu;
    let inv = cov.clone().try_inverse().expect("invertible");
    let maha = (diff.transpose() * inv * &diff)[(0, 0)];
    -0.5 * (d as f64 * (2.0 * PI).ln() + cov.determinant().ln() + maha)
}

/// `|a − b| ≤ tol · max(1, |a|, |b|)`.
pub fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * 1f64.max(a.abs()).max(b.abs())
}

/// `|a − b| ≤ tol · scale`.
pub fn close_to_scale(a: f64, b: f64, tol: f64, scale: f64) -> bool {
    (a - b).abs() <= tol * scale
}

pub fn assert_matrix_close(got: &DMatrix<f64>, want: &DMatrix<f64>, tol: f64, what: &str) {
    assert_eq!(got.shape(), want.shape(), "{what}: shape");
    let scale = want.amax().max(1e-300);
    for r in 0..want.nrows() {
        for c in 0..want.ncols() {
            assert!(
                (got[(r, c)] - want[(r, c)]).abs() <= tol * scale,
                "{what}: entry ({r},{c}) got {} want {} (scale {scale})\ngot = {got}\nwant = {want}",
                got[(r, c)],
                want[(r, c)]
            );
        }
    }
}

/// Numerically stable `ln Σ exp(v)` written out directly for the tests.
pub fn direct_log_sum_exp(v: &[f64]) -> f64 {
    let m = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + v.iter().map(|x| (x - m).exp()).sum::<f64>().ln()
}

/// `ln x! = Σ_{j=2}^{x} ln j`.
pub fn log_factorial(x: u64) -> f64 {
    (2..=x).map(|j| (j as f64).ln()).sum()
}

/// Random frames `T × D` around the given means (row-major).
pub fn random_frames<R: Rng + ?Sized>(t: usize, d: usize, spread: f64, rng: &mut R) -> Vec<f64> {
    (0..t * d).map(|_| spread * normal(rng)).collect()
}

/// Structured projection of a full matrix onto a covariance type's shape.
pub fn project(kind: CovarianceType, m: &DMatrix<f64>) -> DMatrix<f64> {
    let d = m.nrows();
    match kind {
        CovarianceType::Full | CovarianceType::Tied => m.clone(),
        CovarianceType::Diagonal => DMatrix::from_diagonal(&m.diagonal()),
        CovarianceType::Spherical => DMatrix::identity(d, d) * (m.trace() / d as f64),
    }
}
