//! The Gaussian's emission kernels (issue 18): batch log-densities and the
//! weighted accumulation of the sufficient statistics, full and tied
//! covariance, `S ∈ {4, 8, 16}`, `D ∈ {2, 12, 36}`, one call on 250 frames
//! (one sequence of the generated Baum-Welch workloads); and the single-core
//! peak they are compared with (a dgemm micro-kernel, `benches/common`).
//!
//! ```text
//! cargo bench -p phasekit-emission --bench gaussian_kernels -- --warm-up-time 1 --measurement-time 2
//! ```
//!
//! Throughput is in frame·states per second (criterion's "elements"); the
//! table tool `examples/kernel_table.rs` turns the same work into ns per
//! frame·state, GFLOP/s and share of the peak.

mod common;

use common::*;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use phasekit_emission::{CovarianceType, Emission, Frames};
use std::hint::black_box;

const SIZES: [(usize, usize); 9] = [
    (4, 2),
    (8, 2),
    (16, 2),
    (4, 12),
    (8, 12),
    (16, 12),
    (4, 36),
    (8, 36),
    (16, 36),
];

fn kinds() -> [(CovarianceType, &'static str); 2] {
    [
        (CovarianceType::Full, "full"),
        (CovarianceType::Tied, "tied"),
    ]
}

fn log_density(c: &mut Criterion) {
    for (kind, name) in kinds() {
        let mut group = c.benchmark_group(format!("log_density_{name}"));
        for (s, d) in SIZES {
            let seed = (s * 100 + d) as u64;
            let g = random_gaussian(kind, s, d, seed);
            let x = random_frames(FRAMES, d, seed + 1);
            let frames = Frames::new(&x, d).unwrap();
            let mut out = vec![0.0; FRAMES * s];
            group.throughput(Throughput::Elements((FRAMES * s) as u64));
            group.bench_function(BenchmarkId::from_parameter(format!("S{s}_D{d}")), |b| {
                b.iter(|| g.log_density_into(black_box(frames), &mut out).unwrap())
            });
        }
        group.finish();
    }
}

fn accumulate(c: &mut Criterion) {
    for (kind, name) in kinds() {
        for soft in [true, false] {
            let label = if soft { "soft" } else { "sparse" };
            let mut group = c.benchmark_group(format!("accumulate_{label}_{name}"));
            for (s, d) in SIZES {
                let seed = (s * 100 + d) as u64;
                let g = random_gaussian(kind, s, d, seed);
                let x = random_frames(FRAMES, d, seed + 1);
                let frames = Frames::new(&x, d).unwrap();
                let gamma = posteriors(FRAMES, s, soft, seed + 2);
                let mut stats = g.new_stats();
                group.throughput(Throughput::Elements((FRAMES * s) as u64));
                group.bench_function(BenchmarkId::from_parameter(format!("S{s}_D{d}")), |b| {
                    b.iter(|| g.accumulate(black_box(frames), &gamma, &mut stats).unwrap())
                });
            }
            group.finish();
        }
    }
}

fn peak(c: &mut Criterion) {
    #[cfg(target_arch = "x86_64")]
    {
        let k = 256;
        let (a, b, mut out) = peak::panels(k);
        let mut group = c.benchmark_group("peak");
        if std::is_x86_feature_detected!("avx512f") {
            group.throughput(Throughput::Elements(peak::flops("avx512", k) as u64));
            group.bench_function("dgemm_microkernel_avx512", |bch| {
                // SAFETY: the CPU supports AVX-512F (checked above); panels sized by `panels`.
                bch.iter(|| unsafe { peak::avx512(black_box(&a), &b, k, &mut out) })
            });
        }
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            group.throughput(Throughput::Elements(peak::flops("avx2", k) as u64));
            group.bench_function("dgemm_microkernel_avx2", |bch| {
                // SAFETY: the CPU supports AVX2 and FMA (checked above).
                bch.iter(|| unsafe { peak::avx2(black_box(&a), &b, k, &mut out) })
            });
        }
        group.finish();
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = c;
}

criterion_group!(benches, log_density, accumulate, peak);
criterion_main!(benches);
