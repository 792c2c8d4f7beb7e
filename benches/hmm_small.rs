//! HiddenMarkovModels.jl's benchmark configuration (issue 6, workload 3):
//! 50 sequences of 100 frames, 1-D Gaussian emissions, K = 2..10 states:
//! forward, forward-backward, Viterbi over all sequences, and 5 Baum-Welch
//! iterations (one thread).
//!
//! Run with `cargo bench --bench hmm_small -- --warm-up-time 1 --measurement-time 3`.

#[path = "common/mod.rs"]
mod common;

use common::*;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use phasekit::hmm::BaumWelch;
use std::hint::black_box;

fn small(c: &mut Criterion) {
    let workloads: Vec<HmmWorkload> = (2..=10).map(small_workload).collect();
    let mut group = c.benchmark_group("hmm_small_50x100_1d");
    for w in &workloads {
        let k = w.n_states();
        let h = &w.init;
        group.bench_with_input(BenchmarkId::new("forward", k), w, |b, w| {
            b.iter(|| {
                for s in w.data.iter() {
                    black_box(h.log_likelihood(black_box(s)).unwrap());
                }
            })
        });
        group.bench_with_input(BenchmarkId::new("forward_backward", k), w, |b, w| {
            b.iter(|| {
                for s in w.data.iter() {
                    black_box(h.posteriors(black_box(s)).unwrap());
                }
            })
        });
        group.bench_with_input(BenchmarkId::new("viterbi", k), w, |b, w| {
            b.iter(|| {
                for s in w.data.iter() {
                    black_box(h.viterbi(black_box(s)).unwrap());
                }
            })
        });
        let bw = BaumWelch::builder()
            .max_iter(w.n_iter)
            .tol(f64::NEG_INFINITY)
            .threads(1)
            .build()
            .unwrap();
        group.bench_with_input(BenchmarkId::new("baum_welch_5_iter", k), w, |b, w| {
            b.iter(|| black_box(bw.fit_from(w.init.clone(), &w.data).unwrap()))
        });
    }
    group.finish();
}

criterion_group!(benches, small);
criterion_main!(benches);
