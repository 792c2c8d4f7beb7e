//! Forward–backward and one EM iteration of the HSMM against phasekit's own
//! HMM on the expanded state space (`S · D` states, the state expansion of
//! hmmlearn's HSMM pull request #582), the forward pass as the maximum
//! duration grows, and the online filter's step. One thread.
//!
//! Run with `cargo bench -p phasekit-hsmm --bench hsmm -- --warm-up-time 1 --measurement-time 5`
//! (the tables in `crates/hsmm/BENCHMARKS.md`).

mod workloads;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use phasekit_emission::Regularisation;
use phasekit_hmm::Update;
use phasekit_hsmm::{DurationRegularisation, HsmmUpdate};
use std::hint::black_box;
use workloads::{expanded_hmm, workload, Workload};

/// The expanded HMM costs `O(T (S·D)²)`: above this many states one
/// iteration takes many seconds (`examples/hsmm_compare.rs` times it once).
const EXPANDED_LIMIT: usize = 400;

fn one_thread<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(f)
}

fn sizes() -> Vec<Workload> {
    vec![
        workload(4, 25, 3, 20, 100, 1),
        workload(8, 50, 6, 20, 250, 2),
        workload(8, 100, 6, 20, 250, 3),
    ]
}

fn forward_backward(c: &mut Criterion) {
    let mut group = c.benchmark_group("hsmm_forward_backward");
    group.sample_size(10);
    for w in sizes() {
        group.throughput(Throughput::Elements(w.data.total_frames() as u64));
        group.bench_with_input(BenchmarkId::new("hsmm", &w.name), &w, |b, w| {
            b.iter(|| {
                for seq in w.data.iter() {
                    black_box(w.model.posteriors(black_box(seq)).unwrap());
                }
            })
        });
        if w.n_states * w.max_duration > EXPANDED_LIMIT {
            continue;
        }
        let hmm = expanded_hmm(&w);
        // The same model: the likelihoods agree.
        let (a, b) = (
            w.model.log_likelihood_all(&w.data).unwrap(),
            hmm.log_likelihood_all(&w.data).unwrap(),
        );
        assert!((a - b).abs() < 1e-8 * a.abs(), "{a} vs {b}");
        group.bench_with_input(BenchmarkId::new("expanded_hmm", &w.name), &w, |b, w| {
            b.iter(|| {
                for seq in w.data.iter() {
                    black_box(hmm.posteriors(black_box(seq)).unwrap());
                }
            })
        });
    }
    group.finish();
}

fn em_iteration(c: &mut Criterion) {
    let mut group = c.benchmark_group("hsmm_em_iteration");
    group.sample_size(10);
    let reg = Regularisation::add_diagonal(1e-6).unwrap();
    let dreg = DurationRegularisation::none();
    for w in sizes() {
        group.throughput(Throughput::Elements(w.data.total_frames() as u64));
        group.bench_with_input(BenchmarkId::new("hsmm", &w.name), &w, |b, w| {
            b.iter(|| {
                one_thread(|| {
                    let stats = w.model.expected_statistics(&w.data).unwrap();
                    black_box(
                        w.model
                            .maximise(&stats, HsmmUpdate::default(), &reg, &dreg)
                            .unwrap(),
                    )
                })
            })
        });
        if w.n_states * w.max_duration > EXPANDED_LIMIT {
            continue;
        }
        let hmm = expanded_hmm(&w);
        group.bench_with_input(BenchmarkId::new("expanded_hmm", &w.name), &w, |b, w| {
            b.iter(|| {
                one_thread(|| {
                    let stats = hmm.expected_statistics(&w.data).unwrap();
                    black_box(hmm.maximise(&stats, Update::default(), &reg).unwrap())
                })
            })
        });
    }
    group.finish();
}

fn forward_by_max_duration(c: &mut Criterion) {
    let mut group = c.benchmark_group("hsmm_forward_by_max_duration");
    group.sample_size(10);
    for dm in [25, 50, 100, 200, 400] {
        let w = workload(8, dm, 6, 10, 500, 4);
        group.throughput(Throughput::Elements(w.data.total_frames() as u64));
        group.bench_with_input(BenchmarkId::new("forward", dm), &w, |b, w| {
            b.iter(|| {
                for seq in w.data.iter() {
                    black_box(w.model.log_likelihood(black_box(seq)).unwrap());
                }
            })
        });
        group.bench_with_input(BenchmarkId::new("forward_backward", dm), &w, |b, w| {
            b.iter(|| {
                for seq in w.data.iter() {
                    black_box(w.model.posteriors(black_box(seq)).unwrap());
                }
            })
        });
    }
    group.finish();
}

fn online_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("hsmm_online_step");
    for dm in [50, 100] {
        let w = workload(8, dm, 6, 1, 2000, 5);
        let seq = w.data.get(0);
        let mut filter = w.model.filter();
        let mut t = 0;
        group.bench_function(BenchmarkId::new("filter_step_S8_dim6", dm), |b| {
            b.iter(|| {
                if t == seq.len() {
                    filter.reset();
                    t = 0;
                }
                black_box(filter.step(black_box(seq.frame(t))).unwrap());
                t += 1;
            })
        });
    }
    group.finish();
}

criterion_group!(
    benches,
    forward_backward,
    em_iteration,
    forward_by_max_duration,
    online_step
);
criterion_main!(benches);
