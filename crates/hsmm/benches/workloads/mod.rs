//! HSMM workloads shared by the criterion bench (`benches/hsmm.rs`) and the
//! comparison driver (`examples/hsmm_compare.rs`), so that both measure the
//! same data and parameters. Every random choice is seeded (ChaCha8).
//!
//! A workload is an ergodic HSMM with `S` states (transitions random with a
//! zero diagonal, uniform start), pbdlib's Gaussian durations (means in
//! `[D/5, D/2]`, standard deviation a quarter of the mean), diagonal
//! Gaussian emissions, right-censored, and sequences sampled from it.
#![allow(dead_code)]

use phasekit_emission::Gaussian;
use phasekit_hmm::Hmm;
use phasekit_hsmm::{AnyDuration, Duration, GaussianDuration, Hsmm};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One workload: the model (also EM's starting point) and its data.
pub struct Workload {
    pub name: String,
    pub n_states: usize,
    pub max_duration: usize,
    pub dim: usize,
    pub model: Hsmm<Gaussian, AnyDuration>,
    pub data: phasekit_emission::SequenceSet,
    /// Emission parameters (`S × dim` each), for rebuilding the model elsewhere.
    pub means: Vec<f64>,
    pub variances: Vec<f64>,
    pub duration_means: Vec<f64>,
    pub duration_stds: Vec<f64>,
}

/// A workload of `n_seq` sequences of `len` frames.
pub fn workload(s: usize, dm: usize, dim: usize, n_seq: usize, len: usize, seed: u64) -> Workload {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut transition = vec![0.0; s * s];
    for i in 0..s {
        let mut total = 0.0;
        for j in 0..s {
            if j != i {
                let v = rng.random_range(0.2..1.0);
                transition[i * s + j] = v;
                total += v;
            }
        }
        for j in 0..s {
            transition[i * s + j] /= total;
        }
    }
    if s == 1 {
        transition[0] = 0.0;
    }
    let duration_means: Vec<f64> = (0..s)
        .map(|_| rng.random_range(dm as f64 / 5.0..=dm as f64 / 2.0))
        .collect();
    let duration_stds: Vec<f64> = duration_means.iter().map(|m| m / 4.0).collect();
    let means: Vec<f64> = (0..s * dim).map(|_| rng.random_range(-3.0..3.0)).collect();
    let variances: Vec<f64> = (0..s * dim).map(|_| rng.random_range(0.5..1.5)).collect();
    let model = Hsmm::new(
        vec![1.0 / s as f64; s],
        transition,
        GaussianDuration::new(dm, duration_means.clone(), duration_stds.clone())
            .unwrap()
            .into(),
        Gaussian::diagonal(dim, means.clone(), variances.clone()).unwrap(),
    )
    .unwrap();
    let seqs: Vec<Vec<f64>> = (0..n_seq)
        .map(|_| model.sample(len, &mut rng).unwrap().0)
        .collect();
    let data = phasekit_emission::SequenceSet::new(&seqs, dim).unwrap();
    Workload {
        name: format!("S{s}_D{dm}_dim{dim}_{n_seq}x{len}"),
        n_states: s,
        max_duration: dm,
        dim,
        model,
        data,
        means,
        variances,
        duration_means,
        duration_stds,
    }
}

/// The HMM with `S · D` states that is the same model (the state expansion
/// of hmmlearn's HSMM pull request #582): state `(j, r)`, `r = 1..=D` frames
/// left in the segment, index `j·D + r − 1`; `(j, r) → (j, r − 1)` for
/// `r > 1` and `(j, 1) → (k, r)` with `a_jk p_k(r)`; start `π_j p_j(r)`;
/// every `(j, ·)` emits with `b_j`. Its likelihood is the right-censored HSMM's.
pub fn expanded_hmm(w: &Workload) -> Hmm<Gaussian> {
    let (s, dm, dim) = (w.n_states, w.max_duration, w.dim);
    let n = s * dm;
    let mut pmf = vec![0.0; s * dm];
    for i in 0..s {
        let mut lp = vec![0.0; dm];
        w.model.durations().log_pmf_into(i, &mut lp).unwrap();
        for (p, l) in pmf[i * dm..(i + 1) * dm].iter_mut().zip(&lp) {
            *p = l.exp();
        }
    }
    let a = w.model.transition();
    let mut start = vec![0.0; n];
    let mut transition = vec![0.0; n * n];
    for j in 0..s {
        for r in 0..dm {
            let row = j * dm + r;
            start[row] = w.model.start()[j] * pmf[j * dm + r];
            if r > 0 {
                transition[row * n + row - 1] = 1.0;
            } else {
                for k in 0..s {
                    for r2 in 0..dm {
                        transition[row * n + k * dm + r2] = a[j * s + k] * pmf[k * dm + r2];
                    }
                }
            }
        }
    }
    let mut means = Vec::with_capacity(n * dim);
    let mut variances = Vec::with_capacity(n * dim);
    for j in 0..s {
        for _ in 0..dm {
            means.extend_from_slice(&w.means[j * dim..(j + 1) * dim]);
            variances.extend_from_slice(&w.variances[j * dim..(j + 1) * dim]);
        }
    }
    Hmm::new(
        start,
        transition,
        Gaussian::diagonal(dim, means, variances).unwrap(),
    )
    .unwrap()
}
