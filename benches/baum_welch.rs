//! One Baum-Welch iteration (E-step and M-step), one thread (issue 6).
//!
//! * workload 1: the NuiSI handshake demonstrations (skipped when the data
//!   are absent), D = 36 and D = 12, K = 8 and 15;
//! * workload 2: 100k generated frames in 400 sequences, (S=16, D=12) and
//!   (S=8, D=36).
//!
//! Run with `cargo bench --bench baum_welch -- --warm-up-time 1 --measurement-time 3`.
//! The workloads are those of `examples/bench_compare.rs` (benches/common).

#[path = "common/mod.rs"]
mod common;

use common::*;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use phasekit::hmm::Update;
use std::hint::black_box;

fn one_iteration(c: &mut Criterion, group_name: &str, workloads: Vec<HmmWorkload>) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("thread pool");
    let mut group = c.benchmark_group(group_name);
    group.sample_size(10);
    for w in workloads {
        let reg = w.reg();
        group.throughput(Throughput::Elements(w.data.total_frames() as u64));
        group.bench_function(&w.name, |b| {
            b.iter(|| {
                pool.install(|| {
                    let stats = w.init.expected_statistics(black_box(&w.data)).unwrap();
                    black_box(w.init.maximise(&stats, Update::default(), &reg).unwrap())
                })
            })
        });
    }
    group.finish();
}

fn paper(c: &mut Criterion) {
    let w = paper_workloads();
    if w.is_empty() {
        eprintln!("NuiSI data not found (set PHASEKIT_NUISI): workload 1 skipped");
        return;
    }
    one_iteration(c, "bw_iteration_paper", w);
}

fn generated(c: &mut Criterion) {
    one_iteration(c, "bw_iteration_generated", generated_workloads());
}

criterion_group!(benches, paper, generated);
criterion_main!(benches);
