//! Workloads shared by the criterion benches (`benches/*.rs`) and the
//! comparison driver (`examples/bench_compare.rs`), so that both measure
//! exactly the same data and initial parameters. Every random choice is
//! seeded (ChaCha8).
//!
//! 1. `paper_*`: the NuiSI handshake training demonstrations (8 demos,
//!    2,281 frames), p1+p2 shoulder/elbow/wrist positions and their first
//!    differences (D = 36) or the two wrists with velocities (D = 12),
//!    K = 8 and 15 states, temporal k-bins initialisation, 20 iterations.
//! 2. `gen_*`: frames sampled from a random sticky HMM, 100k frames in 400
//!    sequences, 10 iterations, initialised from the perturbed truth.
//! 3. `small_*`: the HiddenMarkovModels.jl benchmark shape, 50 sequences of
//!    100 frames, 1-D Gaussian, K = 2..10.
//! 4. `gmm_*`: frames from a random GMM, initialised from the perturbed truth.
#![allow(dead_code)]

use nalgebra::DMatrix;
use phasekit::emission::{CovarianceType, Emission, Gaussian, Regularisation, SequenceSet, Shape};
use phasekit::gmm::Gmm;
use phasekit::hmm::{initialise, Hmm, HmmInit};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;

/// Where the NuiSI data lie: `$PHASEKIT_NUISI`, else `../shared/data/nuisi`
/// beside the repository (as in CI), else `/work/shared/data/nuisi`.
pub fn nuisi_dir() -> Option<PathBuf> {
    let candidates = [
        std::env::var_os("PHASEKIT_NUISI").map(PathBuf::from),
        Some(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/nuisi")),
        Some(PathBuf::from("/work/shared/data/nuisi")),
    ];
    candidates
        .into_iter()
        .flatten()
        .find(|p| p.join("handshake").is_dir())
}

/// Which columns of the NuiSI handshake demonstrations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Columns {
    /// p1 and p2 shoulder/elbow/wrist xyz (18) and their velocities: D = 36.
    AllJoints,
    /// p1 and p2 wrist xyz (6) and their velocities: D = 12.
    Wrists,
}

/// The NuiSI handshake training demonstrations (`train_*.csv`, in name order),
/// positions followed by their first differences (`v_0 = 0`).
pub fn nuisi_handshake(cols: Columns) -> Option<SequenceSet> {
    let dir = nuisi_dir()?.join("handshake");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("train_") && n.ends_with(".csv"))
        })
        .collect();
    files.sort();
    let pick: Vec<usize> = match cols {
        Columns::AllJoints => (0..18).collect(),
        Columns::Wrists => vec![6, 7, 8, 15, 16, 17],
    };
    let p = pick.len();
    let mut seqs = Vec::new();
    for f in files {
        let text = std::fs::read_to_string(&f).ok()?;
        let rows: Vec<Vec<f64>> = text
            .lines()
            .skip(1)
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                l.split(',')
                    .map(|v| v.trim().parse().expect("number"))
                    .collect()
            })
            .collect();
        let mut seq = Vec::with_capacity(rows.len() * 2 * p);
        for (t, row) in rows.iter().enumerate() {
            seq.extend(pick.iter().map(|&c| row[c]));
            seq.extend(
                pick.iter()
                    .map(|&c| if t == 0 { 0.0 } else { row[c] - rows[t - 1][c] }),
            );
        }
        seqs.push(seq);
    }
    if seqs.is_empty() {
        return None;
    }
    Some(SequenceSet::new(&seqs, 2 * p).expect("finite NuiSI frames"))
}

/// A random symmetric positive-definite `d × d` matrix `A Aᵀ / d + 0.1 I`, row-major.
pub fn random_pd(d: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-1.0..1.0));
    let m = &a * a.transpose() / d as f64 + DMatrix::identity(d, d) * 0.1;
    let m = (&m + m.transpose()) * 0.5;
    (0..d * d).map(|k| m[(k / d, k % d)]).collect()
}

/// `s` full-covariance Gaussians with means uniform in `[-spread, spread]^d`.
pub fn random_gaussian(s: usize, d: usize, spread: f64, rng: &mut ChaCha8Rng) -> Gaussian {
    let means: Vec<f64> = (0..s * d)
        .map(|_| rng.random_range(-spread..spread))
        .collect();
    let covs: Vec<f64> = (0..s).flat_map(|_| random_pd(d, rng)).collect();
    Gaussian::full(d, means, covs).expect("valid Gaussian")
}

/// Start uniform, `a_ii = stay`, the rest uniform.
pub fn sticky(s: usize, stay: f64) -> (Vec<f64>, Vec<f64>) {
    let mut a = vec![(1.0 - stay) / (s - 1).max(1) as f64; s * s];
    for i in 0..s {
        a[i * s + i] = if s == 1 { 1.0 } else { stay };
    }
    (vec![1.0 / s as f64; s], a)
}

/// The same Gaussians with means moved by `U(-shift, shift)` and `inflate·I` added to the covariances.
pub fn perturbed(g: &Gaussian, shift: f64, inflate: f64, rng: &mut ChaCha8Rng) -> Gaussian {
    let d = g.dim();
    let means: Vec<f64> = g
        .means()
        .iter()
        .map(|m| m + rng.random_range(-shift..shift))
        .collect();
    let covs: Vec<f64> = g
        .covariances_raw()
        .iter()
        .enumerate()
        .map(|(k, c)| {
            if (k % (d * d)).is_multiple_of(d + 1) {
                c + inflate
            } else {
                *c
            }
        })
        .collect();
    Gaussian::full(d, means, covs).expect("valid Gaussian")
}

/// A Baum-Welch workload: data, initial model, regularisation and iterations.
#[derive(Clone)]
pub struct HmmWorkload {
    pub name: String,
    pub data: SequenceSet,
    pub init: Hmm<Gaussian>,
    /// Inverse-Wishart scale `ψ` (prior `IW(ψ I, ν = 0)`): hmmlearn's
    /// `covars_prior = ψ I`, `covars_weight = 2D + 1` gives the same M-step.
    pub iw_scale: f64,
    pub n_iter: usize,
}

impl HmmWorkload {
    /// `IW(ψ I, 0)`, or plain maximum likelihood when `ψ = 0`.
    pub fn reg(&self) -> Regularisation {
        if self.iw_scale > 0.0 {
            Regularisation::inverse_wishart(self.iw_scale, 0.0).expect("valid prior")
        } else {
            Regularisation::none()
        }
    }
    pub fn n_states(&self) -> usize {
        self.init.n_states()
    }
    pub fn dim(&self) -> usize {
        self.init.dim()
    }
}

/// Workload 1: NuiSI handshake, temporal k-bins (ε = 0.01) initialisation, 20 iterations.
pub fn paper_workload(cols: Columns, k: usize) -> Option<HmmWorkload> {
    let data = nuisi_handshake(cols)?;
    let d = data.dim();
    let iw_scale = 1e-6;
    let reg = Regularisation::inverse_wishart(iw_scale, 0.0).expect("valid prior");
    let template = Gaussian::standard(
        CovarianceType::Full,
        Shape {
            n_states: k,
            dim: d,
        },
    )
    .expect("template");
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let init = initialise(
        &template,
        &data,
        HmmInit::KBins { smoothing: 0.01 },
        &reg,
        &mut rng,
    )
    .expect("k-bins initialisation");
    Some(HmmWorkload {
        name: format!("paper_D{d}_K{k}"),
        data,
        init,
        iw_scale,
        n_iter: 20,
    })
}

/// All four paper workloads (empty when the NuiSI data are absent).
pub fn paper_workloads() -> Vec<HmmWorkload> {
    [
        (Columns::AllJoints, 8),
        (Columns::AllJoints, 15),
        (Columns::Wrists, 8),
        (Columns::Wrists, 15),
    ]
    .into_iter()
    .filter_map(|(c, k)| paper_workload(c, k))
    .collect()
}

/// `n_seq` sequences of `frames / n_seq` frames sampled from a random sticky
/// (`a_ii = 0.95`) `s`-state, `d`-dim full-covariance HMM; the initial model is
/// the truth with perturbed means and covariances, `a_ii = 0.7` and a uniform start.
pub fn generated_workload(
    s: usize,
    d: usize,
    frames: usize,
    n_seq: usize,
    seed: u64,
) -> HmmWorkload {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let truth_emission = random_gaussian(s, d, 2.0, &mut rng);
    let (start, a) = sticky(s, 0.95);
    let truth = Hmm::new(start, a, truth_emission.clone()).expect("valid HMM");
    let len = frames / n_seq;
    let seqs: Vec<Vec<f64>> = (0..n_seq)
        .map(|_| truth.sample(len, &mut rng).expect("sampling").0)
        .collect();
    let data = SequenceSet::new(&seqs, d).expect("finite frames");
    let (start, a) = sticky(s, 0.7);
    let init =
        Hmm::new(start, a, perturbed(&truth_emission, 0.5, 0.5, &mut rng)).expect("valid HMM");
    HmmWorkload {
        name: format!("gen_S{s}_D{d}_{}k", frames / 1000),
        data,
        init,
        iw_scale: 1e-3,
        n_iter: 10,
    }
}

/// Workload 2: (S=16, D=12) and (S=8, D=36), 100k frames in 400 sequences.
pub fn generated_workloads() -> Vec<HmmWorkload> {
    vec![
        generated_workload(16, 12, 100_000, 400, 16),
        generated_workload(8, 36, 100_000, 400, 8),
    ]
}

/// Workload 3 (HiddenMarkovModels.jl's benchmark shape): `k` states, 1-D
/// Gaussian emissions (means `0..k` plus noise, unit variance), random start
/// and transition rows; 50 sequences of 100 frames sampled from it; the
/// initial model for Baum-Welch is a perturbed copy. 5 iterations.
pub fn small_workload(k: usize) -> HmmWorkload {
    let mut rng = ChaCha8Rng::seed_from_u64(100 + k as u64);
    let random_dist = |rng: &mut ChaCha8Rng, n: usize| -> Vec<f64> {
        let raw: Vec<f64> = (0..n).map(|_| rng.random_range(0.1..1.0)).collect();
        let total: f64 = raw.iter().sum();
        raw.iter().map(|v| v / total).collect()
    };
    let start = random_dist(&mut rng, k);
    let a: Vec<f64> = (0..k).flat_map(|_| random_dist(&mut rng, k)).collect();
    let means: Vec<f64> = (0..k)
        .map(|i| i as f64 + rng.random_range(-0.2..0.2))
        .collect();
    let truth = Hmm::new(
        start,
        a,
        Gaussian::diagonal(1, means.clone(), vec![1.0; k]).unwrap(),
    )
    .expect("valid HMM");
    let seqs: Vec<Vec<f64>> = (0..50)
        .map(|_| truth.sample(100, &mut rng).expect("sampling").0)
        .collect();
    let data = SequenceSet::new(&seqs, 1).expect("finite frames");
    let start = random_dist(&mut rng, k);
    let a: Vec<f64> = (0..k).flat_map(|_| random_dist(&mut rng, k)).collect();
    let means: Vec<f64> = means
        .iter()
        .map(|m| m + rng.random_range(-0.3..0.3))
        .collect();
    let vars: Vec<f64> = (0..k).map(|_| rng.random_range(0.7..1.5)).collect();
    let init = Hmm::new(start, a, Gaussian::diagonal(1, means, vars).unwrap()).expect("valid HMM");
    HmmWorkload {
        name: format!("small_K{k}"),
        data,
        init,
        iw_scale: 0.0,
        n_iter: 5,
    }
}

/// A mixture EM workload.
#[derive(Clone)]
pub struct GmmWorkload {
    pub name: String,
    /// `N × D` row-major.
    pub data: Vec<f64>,
    pub dim: usize,
    pub init: Gmm,
    /// scikit-learn's `reg_covar`: `Regularisation::add_diagonal`.
    pub reg_covar: f64,
    pub n_iter: usize,
}

/// Workload 4: `n` frames from a random `k`-component, `d`-dim full GMM; the
/// initial mixture is the perturbed truth with uniform weights; 10 iterations.
pub fn gmm_workload(k: usize, d: usize, n: usize, seed: u64) -> GmmWorkload {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let truth_c = random_gaussian(k, d, 2.0, &mut rng);
    let raw: Vec<f64> = (0..k).map(|_| rng.random_range(0.5..1.5)).collect();
    let total: f64 = raw.iter().sum();
    let truth = Gmm::new(raw.iter().map(|w| w / total).collect(), truth_c.clone()).unwrap();
    let (data, _) = truth.sample(n, &mut rng).expect("sampling");
    let init = Gmm::new(
        vec![1.0 / k as f64; k],
        perturbed(&truth_c, 0.5, 0.5, &mut rng),
    )
    .unwrap();
    GmmWorkload {
        name: format!("gmm_K{k}_D{d}_{}k", n / 1000),
        data,
        dim: d,
        init,
        reg_covar: 1e-6,
        n_iter: 10,
    }
}

/// Workload 4's two shapes.
pub fn gmm_workloads() -> Vec<GmmWorkload> {
    vec![
        gmm_workload(8, 12, 100_000, 412),
        gmm_workload(8, 36, 100_000, 436),
    ]
}

/// Useful floating-point operations of one Baum-Welch iteration (E-step and
/// M-step) with `s` full-covariance Gaussian states of dimension `d` over
/// `t` frames in `n_seq` sequences:
///
/// * log-density, per frame and state: `x − μ` (D), `W (x − μ)` with the
///   packed triangle `W = L⁻¹` (D(D+1)), the squared norm (2D): `D² + 4D`;
/// * statistics, per frame and state: `x − c` (D), `γ (x − c)` (D), the sum
///   (D), the lower triangle of `γ (x − c)(x − c)ᵀ` (D(D+1)): `D² + 5D`;
/// * forward-backward, per frame: prediction, backward message and ξ, `7 S²`
///   (the `S` exponentials of each pass are not counted);
/// * M-step, per state: scatter, Cholesky and triangular inverse, about `D³`.
pub fn bw_iteration_flops(t: usize, s: usize, d: usize) -> f64 {
    let (t, s, d) = (t as f64, s as f64, d as f64);
    t * s * (2.0 * d * d + 9.0 * d) + 7.0 * t * s * s + s * d * d * d
}

/// Useful flops of one GMM EM iteration (same terms, no transitions).
pub fn em_iteration_flops(n: usize, k: usize, d: usize) -> f64 {
    let (n, k, d) = (n as f64, k as f64, d as f64);
    n * k * (2.0 * d * d + 9.0 * d) + k * d * d * d
}

/// CPU time consumed so far by this process (all its threads), in seconds
/// (`CLOCK_PROCESS_CPUTIME_ID`). Unlike wall time it does not count the time
/// other processes hold the CPU, which on a shared two-core machine makes
/// timings far more reproducible.
pub fn process_cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid timespec to write into.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}
