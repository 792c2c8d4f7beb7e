//! One GMM EM iteration (E-step and M-step), one thread (issue 6, workload 4):
//! 100k frames from a random 8-component GMM, D = 12 and D = 36, full
//! covariances, `reg_covar = 1e-6` (scikit-learn's default).
//!
//! Run with `cargo bench --bench gmm_em -- --warm-up-time 1 --measurement-time 3`.

#[path = "common/mod.rs"]
mod common;

use common::*;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use phasekit::emission::{Frames, Regularisation};
use std::hint::black_box;

fn em(c: &mut Criterion) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("thread pool");
    let mut group = c.benchmark_group("gmm_em_iteration");
    group.sample_size(10);
    for w in gmm_workloads() {
        let frames = Frames::new(&w.data, w.dim).unwrap();
        let reg = Regularisation::add_diagonal(w.reg_covar).unwrap();
        group.throughput(Throughput::Elements(frames.len() as u64));
        group.bench_function(&w.name, |b| {
            b.iter(|| {
                pool.install(|| {
                    let stats = w.init.expected_statistics(black_box(frames)).unwrap();
                    black_box(w.init.maximise(&stats, &reg).unwrap())
                })
            })
        });
    }
    group.finish();
}

criterion_group!(benches, em);
criterion_main!(benches);
