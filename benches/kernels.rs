//! Emission hot paths of the E-step (issue 6) and the single-core peak.
//!
//! * `log_density`: `log N(x_t; μ_i, Σ_i)` of one 250-frame sequence for every
//!   state (full covariance), for (S=8, D=36) and (S=16, D=12);
//! * `accumulate`: the weighted statistics `Σ_t γ_t(i) (x_t − c_i)(x_t − c_i)ᵀ`
//!   of the same sequence;
//! * `peak_dgemm_1024`: nalgebra `DMatrix` 1024×1024 product (matrixmultiply,
//!   one thread), the reference for the achieved GFLOP/s in BENCHMARKS.md.
//!
//! Run with `cargo bench --bench kernels -- --warm-up-time 1 --measurement-time 3`.

#[path = "common/mod.rs"]
mod common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use nalgebra::DMatrix;
use phasekit::emission::{Emission, Frames};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

fn emission(c: &mut Criterion) {
    for (s, d) in [(8usize, 36usize), (16, 12)] {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let g = common::random_gaussian(s, d, 2.0, &mut rng);
        let t = 250;
        let x: Vec<f64> = (0..t * d).map(|_| rng.random_range(-3.0..3.0)).collect();
        let frames = Frames::new(&x, d).unwrap();
        let gamma: Vec<f64> = {
            let raw: Vec<f64> = (0..t * s).map(|_| rng.random_range(0.0..1.0)).collect();
            raw.chunks_exact(s)
                .flat_map(|r| {
                    let z: f64 = r.iter().sum();
                    r.iter().map(move |v| v / z).collect::<Vec<_>>()
                })
                .collect()
        };
        let mut group = c.benchmark_group(format!("emission_S{s}_D{d}_T{t}"));
        group.throughput(Throughput::Elements(t as u64));
        let mut out = vec![0.0; t * s];
        group.bench_function("log_density", |b| {
            b.iter(|| g.log_density_into(black_box(frames), &mut out).unwrap())
        });
        let mut stats = g.new_stats();
        group.bench_function("accumulate", |b| {
            b.iter(|| g.accumulate(black_box(frames), &gamma, &mut stats).unwrap())
        });
        group.finish();
    }
}

fn peak(c: &mut Criterion) {
    let n = 1024;
    let a = DMatrix::<f64>::from_fn(n, n, |r, c| ((r * 7 + c * 13) % 17) as f64 / 17.0 - 0.5);
    let b = DMatrix::<f64>::from_fn(n, n, |r, c| ((r * 5 + c * 3) % 11) as f64 / 11.0 - 0.5);
    let mut out = DMatrix::<f64>::zeros(n, n);
    let mut group = c.benchmark_group("peak");
    group.sample_size(10);
    group.throughput(Throughput::Elements(2 * (n as u64).pow(3)));
    group.bench_function("dgemm_1024", |bch| {
        bch.iter(|| a.mul_to(black_box(&b), &mut out))
    });
    group.finish();
}

criterion_group!(benches, emission, peak);
criterion_main!(benches);
