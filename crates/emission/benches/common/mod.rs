//! Workloads and the single-core peak shared by the Gaussian kernel bench
//! (`benches/gaussian_kernels.rs`) and the table tool
//! (`examples/kernel_table.rs`): every random choice is seeded, so both
//! measure the same data.
#![allow(dead_code)]

use nalgebra::DMatrix;
use phasekit_emission::{CovarianceType, Gaussian};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Frames per call: one sequence of the generated Baum-Welch workloads.
pub const FRAMES: usize = 250;

/// Floating-point operations of one frame·state of the log-density,
/// `x − μ`, `W (x − μ)` with the packed `W = L⁻¹`, `‖·‖²`: `D² + 4D` (the
/// count of the repository's `bw_iteration_flops`).
pub fn log_density_flops(d: usize) -> f64 {
    (d * d + 4 * d) as f64
}

/// Floating-point operations of one frame·state of the statistics,
/// `x − c`, `γ (x − c)`, `Σ`, the lower triangle of `γ (x − c)(x − c)ᵀ`:
/// `D² + 5D` (as `bw_iteration_flops`).
pub fn statistics_flops(d: usize) -> f64 {
    (d * d + 5 * d) as f64
}

/// A random symmetric positive definite `d × d` matrix (row-major).
pub fn random_pd(d: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-1.0..1.0));
    let m = &a * a.transpose() / d as f64 + DMatrix::identity(d, d) * 0.3;
    (0..d * d)
        .map(|k| 0.5 * (m[(k / d, k % d)] + m[(k % d, k / d)]))
        .collect()
}

/// `s` states of dimension `d`, means in `U(−2, 2)`.
pub fn random_gaussian(kind: CovarianceType, s: usize, d: usize, seed: u64) -> Gaussian {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let means: Vec<f64> = (0..s * d).map(|_| rng.random_range(-2.0..2.0)).collect();
    let n_cov = if kind == CovarianceType::Tied { 1 } else { s };
    let covs: Vec<f64> = (0..n_cov).flat_map(|_| random_pd(d, &mut rng)).collect();
    Gaussian::new(kind, d, means, covs).expect("valid Gaussian")
}

/// `t` frames in `U(−3, 3)^d`.
pub fn random_frames(t: usize, d: usize, seed: u64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..t * d).map(|_| rng.random_range(-3.0..3.0)).collect()
}

/// Posteriors of `t` frames over `s` states (`T × S`, rows summing to 1).
///
/// `soft`: every weight positive (uniform draws, normalised), the heaviest
/// case for the statistics. Otherwise sticky and nearly hard, as the
/// posteriors of a well-separated HMM: the frames walk through the states in
/// runs of 25, and each frame gives weight to its own state and (near a
/// change) to the next one; every other weight is exactly zero.
pub fn posteriors(t: usize, s: usize, soft: bool, seed: u64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut g = vec![0.0; t * s];
    for (tt, row) in g.chunks_exact_mut(s).enumerate() {
        if soft {
            for v in row.iter_mut() {
                *v = rng.random_range(0.01..1.0);
            }
        } else {
            let i = (tt / 25) % s;
            let into_run = tt % 25;
            if into_run >= 20 {
                let p = rng.random_range(0.0..1.0);
                row[i] = p;
                row[(i + 1) % s] = 1.0 - p;
            } else {
                row[i] = 1.0;
            }
        }
        let z: f64 = row.iter().sum();
        for v in row.iter_mut() {
            *v /= z;
        }
    }
    g
}

/// The single-core peak: a dgemm micro-kernel `C += A B` with `C` held in
/// registers (`8 × 24` doubles in 24 AVX-512 registers, or `6 × 8` in 12
/// AVX2 registers), `A` and `B` panels of `K = 256` in L1, one broadcast of
/// `A` per 3 (2) fused multiply-adds: the inner loop of every BLAS dgemm, so
/// the rate no dense kernel on this core can beat.
pub mod peak {
    /// Flops of one call of [`avx512`] or [`avx2`] on the given panel depth.
    pub fn flops(isa: &str, k: usize) -> f64 {
        match isa {
            "avx512" => (2 * k * 8 * 24) as f64,
            _ => (2 * k * 6 * 8) as f64,
        }
    }

    /// `C[8 × 24] += A[8 × K] B[K × 24]` (`a` is `K × 8`, `b` is `K × 24`).
    ///
    /// # Safety
    /// The CPU must support AVX-512F; `a.len() ≥ 8k`, `b.len() ≥ 24k`, `c.len() ≥ 192`.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2,fma")]
    pub unsafe fn avx512(a: &[f64], b: &[f64], k: usize, c: &mut [f64]) {
        use std::arch::x86_64::*;
        assert!(a.len() >= 8 * k && b.len() >= 24 * k && c.len() >= 192);
        let mut acc = [[_mm512_setzero_pd(); 3]; 8];
        for (u, row) in acc.iter_mut().enumerate() {
            for (v, r) in row.iter_mut().enumerate() {
                *r = _mm512_loadu_pd(c.as_ptr().add(u * 24 + v * 8));
            }
        }
        for p in 0..k {
            let b0 = _mm512_loadu_pd(b.as_ptr().add(p * 24));
            let b1 = _mm512_loadu_pd(b.as_ptr().add(p * 24 + 8));
            let b2 = _mm512_loadu_pd(b.as_ptr().add(p * 24 + 16));
            for (u, row) in acc.iter_mut().enumerate() {
                let av = _mm512_set1_pd(*a.get_unchecked(p * 8 + u));
                row[0] = _mm512_fmadd_pd(av, b0, row[0]);
                row[1] = _mm512_fmadd_pd(av, b1, row[1]);
                row[2] = _mm512_fmadd_pd(av, b2, row[2]);
            }
        }
        for (u, row) in acc.iter().enumerate() {
            for (v, r) in row.iter().enumerate() {
                _mm512_storeu_pd(c.as_mut_ptr().add(u * 24 + v * 8), *r);
            }
        }
    }

    /// `C[6 × 8] += A[6 × K] B[K × 8]` (`a` is `K × 6`, `b` is `K × 8`).
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA; `a.len() ≥ 6k`, `b.len() ≥ 8k`, `c.len() ≥ 48`.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn avx2(a: &[f64], b: &[f64], k: usize, c: &mut [f64]) {
        use std::arch::x86_64::*;
        assert!(a.len() >= 6 * k && b.len() >= 8 * k && c.len() >= 48);
        let mut acc = [[_mm256_setzero_pd(); 2]; 6];
        for (u, row) in acc.iter_mut().enumerate() {
            for (v, r) in row.iter_mut().enumerate() {
                *r = _mm256_loadu_pd(c.as_ptr().add(u * 8 + v * 4));
            }
        }
        for p in 0..k {
            let b0 = _mm256_loadu_pd(b.as_ptr().add(p * 8));
            let b1 = _mm256_loadu_pd(b.as_ptr().add(p * 8 + 4));
            for (u, row) in acc.iter_mut().enumerate() {
                let av = _mm256_set1_pd(*a.get_unchecked(p * 6 + u));
                row[0] = _mm256_fmadd_pd(av, b0, row[0]);
                row[1] = _mm256_fmadd_pd(av, b1, row[1]);
            }
        }
        for (u, row) in acc.iter().enumerate() {
            for (v, r) in row.iter().enumerate() {
                _mm256_storeu_pd(c.as_mut_ptr().add(u * 8 + v * 4), *r);
            }
        }
    }

    /// Panels for the peak kernels (`K = 256`): `(a, b, c)`.
    pub fn panels(k: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let a = (0..8 * k).map(|i| (i % 7) as f64 * 1e-3).collect();
        let b = (0..24 * k).map(|i| (i % 5) as f64 * 1e-3).collect();
        (a, b, vec![0.0; 192])
    }
}
