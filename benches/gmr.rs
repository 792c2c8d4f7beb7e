//! GMR benchmarks (issue 3).
//!
//! * `online_step`: one frame of online HMM-GMR (forward filter on the 6 input
//!   dims + mixing the conditionals of the 6 output dims) for a 7-state HMM
//!   with 12-D joint full covariances: mean only, with the predictive
//!   covariance, and the filter alone for comparison;
//! * `static_gmr`: GMR over 10^5 frames with a 7-component, 12-D full-covariance
//!   GMM (6 inputs, 6 outputs), mean only and with covariance.
//!
//! Run with `cargo bench --bench gmr -- --warm-up-time 1 --measurement-time 3`.
//! Every random choice is seeded.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use nalgebra::DMatrix;
use phasekit::emission::{Frames, Gaussian};
use phasekit::gmm::Gmm;
use phasekit::gmr::{GmmRegression, HmmRegression};
use phasekit::hmm::Hmm;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

const STATES: usize = 7;
const N_IN: usize = 6;
const N_OUT: usize = 6;
const DIM: usize = N_IN + N_OUT;

/// A random symmetric positive-definite `d × d` matrix `A Aᵀ / d + 0.1 I`, row-major.
fn random_pd(d: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-1.0..1.0));
    let m = &a * a.transpose() / d as f64 + DMatrix::identity(d, d) * 0.1;
    let m = (&m + m.transpose()) * 0.5;
    (0..d)
        .flat_map(|r| (0..d).map(move |c| (r, c)))
        .map(|(r, c)| m[(r, c)])
        .collect()
}

/// `STATES` 12-D Gaussians with random means and random full covariances.
fn joint_emission(rng: &mut ChaCha8Rng) -> Gaussian {
    let means: Vec<f64> = (0..STATES * DIM)
        .map(|_| rng.random_range(-2.0..2.0))
        .collect();
    let covs: Vec<f64> = (0..STATES).flat_map(|_| random_pd(DIM, rng)).collect();
    Gaussian::full(DIM, means, covs).expect("valid joint emission")
}

/// A left-to-right-ish HMM: stay 0.9, otherwise move uniformly.
fn joint_hmm(rng: &mut ChaCha8Rng) -> Hmm<Gaussian> {
    let mut transition = vec![0.1 / (STATES - 1) as f64; STATES * STATES];
    for i in 0..STATES {
        transition[i * STATES + i] = 0.9;
    }
    let mut start = vec![0.0; STATES];
    start[0] = 1.0;
    Hmm::new(start, transition, joint_emission(rng)).expect("valid HMM")
}

fn input_dims() -> Vec<usize> {
    (0..N_IN).collect()
}

fn output_dims() -> Vec<usize> {
    (N_IN..DIM).collect()
}

/// The input columns of `len` frames sampled from `hmm`.
fn input_frames(hmm: &Hmm<Gaussian>, len: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let (joint, _) = hmm.sample(len, rng).expect("sampling");
    joint
        .chunks_exact(DIM)
        .flat_map(|f| f[..N_IN].iter().copied())
        .collect()
}

fn online_step(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let hmm = joint_hmm(&mut rng);
    let gmr = HmmRegression::new(&hmm, &input_dims(), &output_dims()).expect("regression");
    let seq_len = 1000;
    let xs = input_frames(&hmm, seq_len, &mut rng);
    let mut group = c.benchmark_group("online_step_7states_6in_6out");
    group.throughput(Throughput::Elements(1));

    let mut online = gmr.online();
    let mut t = 0;
    group.bench_function("mean", |b| {
        b.iter(|| {
            if t == seq_len {
                t = 0;
                online.reset();
            }
            let y = online
                .step(black_box(&xs[t * N_IN..(t + 1) * N_IN]))
                .expect("step");
            t += 1;
            black_box(y[0])
        })
    });

    let mut online = gmr.online();
    let mut t = 0;
    group.bench_function("mean_and_covariance", |b| {
        b.iter(|| {
            if t == seq_len {
                t = 0;
                online.reset();
            }
            let y = online
                .step_with_covariance(black_box(&xs[t * N_IN..(t + 1) * N_IN]))
                .expect("step");
            t += 1;
            black_box(y[0])
        })
    });

    let mut filter = gmr.input_model().filter();
    let mut t = 0;
    group.bench_function("filter_only", |b| {
        b.iter(|| {
            if t == seq_len {
                t = 0;
                filter.reset();
            }
            let h = filter
                .step(black_box(&xs[t * N_IN..(t + 1) * N_IN]))
                .expect("step");
            t += 1;
            black_box(h[0])
        })
    });
    group.finish();
}

fn static_gmr(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let weights: Vec<f64> = {
        let raw: Vec<f64> = (0..STATES).map(|_| rng.random_range(0.5..1.5)).collect();
        let total: f64 = raw.iter().sum();
        raw.iter().map(|w| w / total).collect()
    };
    let gmm = Gmm::new(weights, joint_emission(&mut rng)).expect("valid GMM");
    let gmr = GmmRegression::new(&gmm, &input_dims(), &output_dims()).expect("regression");
    let n = 100_000;
    let (joint, _) = gmm.sample(n, &mut rng).expect("sampling");
    let xs: Vec<f64> = joint
        .chunks_exact(DIM)
        .flat_map(|f| f[..N_IN].iter().copied())
        .collect();
    let frames = Frames::new(&xs, N_IN).expect("finite frames");

    let mut group = c.benchmark_group("static_gmr_1e5_frames_7comp_6in_6out");
    group.sample_size(10);
    group.throughput(Throughput::Elements(n as u64));
    group.bench_function("mean", |b| {
        b.iter_batched(
            || (),
            |_| black_box(gmr.predict(black_box(frames), false).expect("predict")),
            BatchSize::PerIteration,
        )
    });
    group.bench_function("mean_and_covariance", |b| {
        b.iter_batched(
            || (),
            |_| black_box(gmr.predict(black_box(frames), true).expect("predict")),
            BatchSize::PerIteration,
        )
    });
    group.finish();
}

criterion_group!(benches, online_step, static_gmr);
criterion_main!(benches);
