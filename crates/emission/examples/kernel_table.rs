//! The Gaussian's emission kernels in ns per frame·state, GFLOP/s and share
//! of the single-core peak, as a markdown table (the figures of
//! `crates/emission/BENCHMARKS-kernels.md`).
//!
//! ```text
//! cargo run --release -p phasekit-emission --example kernel_table            # the whole grid
//! cargo run --release -p phasekit-emission --example kernel_table -- quick   # S = 8, 16 × D = 12, 36
//! cargo run --release -p phasekit-emission --example kernel_table -- peak    # the peak alone
//! cargo run --release -p phasekit-emission --example kernel_table -- sizes full 10 2 8 3   # chosen (S, D)
//! # one kernel, a fixed number of calls (for `valgrind --tool=callgrind`):
//! cargo run --release -p phasekit-emission --example kernel_table -- call log_density full 8 36 soft 200
//! ```
//!
//! Timing: every figure is the fastest of many repetitions (each a batch of
//! calls lasting about 0.2 ms) over at least 0.3 s: on a loaded, shared
//! machine the minimum is the time of the code, the rest is other processes.
//! `PHASEKIT_SIMD=portable|avx2|avx512` caps the instruction set the kernels
//! use (see the crate's `gaussian` module).

#[path = "../benches/common/mod.rs"]
mod common;

use common::*;
use phasekit_emission::{CovarianceType, Emission, Frames, Gaussian};
use std::hint::black_box;
use std::time::{Duration, Instant};

/// Fastest time of one call of `f`, in seconds.
fn fastest(mut f: impl FnMut()) -> f64 {
    // Calls per batch, so that a batch lasts about 0.2 ms.
    let t0 = Instant::now();
    f();
    let one = t0.elapsed().as_secs_f64().max(1e-8);
    let batch = ((2e-4 / one).ceil() as usize).max(1);
    let mut best = f64::INFINITY;
    let start = Instant::now();
    let mut reps = 0;
    while reps < 30 || start.elapsed() < Duration::from_millis(300) {
        let t = Instant::now();
        for _ in 0..batch {
            f();
        }
        best = best.min(t.elapsed().as_secs_f64() / batch as f64);
        reps += 1;
        if reps > 100_000 {
            break;
        }
    }
    best
}

/// The measured single-core peak (GFLOP/s) of the widest instruction set.
fn peak() -> (String, f64) {
    #[cfg(target_arch = "x86_64")]
    {
        let k = 256;
        let (a, b, mut c) = peak::panels(k);
        if std::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked above); panels sized by `panels`.
            let t = fastest(|| unsafe { peak::avx512(&a, &b, k, &mut c) });
            return ("AVX-512".into(), peak::flops("avx512", k) / t * 1e-9);
        }
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            // SAFETY: the CPU supports AVX2 and FMA (checked above).
            let t = fastest(|| unsafe { peak::avx2(&a, &b, k, &mut c) });
            return ("AVX2".into(), peak::flops("avx2", k) / t * 1e-9);
        }
    }
    ("none measured".into(), f64::NAN)
}

fn peak_both() {
    #[cfg(target_arch = "x86_64")]
    {
        let k = 256;
        let (a, b, mut c) = peak::panels(k);
        if std::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked above).
            let t = fastest(|| unsafe { peak::avx512(&a, &b, k, &mut c) });
            println!(
                "peak AVX-512 (8 × 24 dgemm micro-kernel): {:.1} GFLOP/s",
                peak::flops("avx512", k) / t * 1e-9
            );
        }
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            // SAFETY: the CPU supports AVX2 and FMA (checked above).
            let t = fastest(|| unsafe { peak::avx2(&a, &b, k, &mut c) });
            println!(
                "peak AVX2 (6 × 8 dgemm micro-kernel): {:.1} GFLOP/s",
                peak::flops("avx2", k) / t * 1e-9
            );
        }
        black_box(&c);
    }
}

fn kind_of(name: &str) -> CovarianceType {
    match name {
        "full" => CovarianceType::Full,
        "tied" => CovarianceType::Tied,
        "diag" => CovarianceType::Diagonal,
        "spherical" => CovarianceType::Spherical,
        _ => panic!("kind: full, tied, diag or spherical"),
    }
}

struct Case {
    g: Gaussian,
    x: Vec<f64>,
    gamma: Vec<f64>,
    out: Vec<f64>,
}

fn case(kind: CovarianceType, s: usize, d: usize, soft: bool) -> Case {
    let seed = (s * 100 + d) as u64;
    Case {
        g: random_gaussian(kind, s, d, seed),
        x: random_frames(FRAMES, d, seed + 1),
        gamma: posteriors(FRAMES, s, soft, seed + 2),
        out: vec![0.0; FRAMES * s],
    }
}

fn run_log_density(c: &mut Case) {
    let frames = Frames::new(&c.x, c.g.dim()).unwrap();
    c.g.log_density_into(black_box(frames), &mut c.out).unwrap();
}

fn run_accumulate(c: &mut Case, stats: &mut phasekit_emission::GaussianStats) {
    let frames = Frames::new(&c.x, c.g.dim()).unwrap();
    c.g.accumulate(black_box(frames), &c.gamma, stats).unwrap();
}

fn table(sizes: &[(usize, usize)], kinds: &[&str]) {
    let (isa, peak) = peak();
    println!("single-core peak ({isa} dgemm micro-kernel): {peak:.1} GFLOP/s; {FRAMES} frames per call\n");
    println!("| kernel | covariance | S | D | weights ≠ 0 | ns per frame·state | GFLOP/s | share of peak |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    for kernel in ["log_density", "accumulate soft", "accumulate sparse"] {
        for kind in kinds {
            for &(s, d) in sizes {
                let soft = kernel != "accumulate sparse";
                let mut c = case(kind_of(kind), s, d, soft);
                let (t, flops) = if kernel == "log_density" {
                    (fastest(|| run_log_density(&mut c)), log_density_flops(d))
                } else {
                    let mut stats = c.g.new_stats();
                    (
                        fastest(|| run_accumulate(&mut c, &mut stats)),
                        statistics_flops(d),
                    )
                };
                // The statistics cost what the non-zero weights cost: time
                // and flops per weighted frame·state.
                let nnz = if kernel == "log_density" {
                    FRAMES * s
                } else {
                    c.gamma.iter().filter(|w| **w != 0.0).count()
                };
                let per = t / nnz as f64;
                let gflops = flops / per * 1e-9;
                println!(
                    "| {kernel} | {kind} | {s} | {d} | {:.0} % | {:.2} | {gflops:.1} | {:.0} % |",
                    100.0 * nnz as f64 / (FRAMES * s) as f64,
                    per * 1e9,
                    100.0 * gflops / peak
                );
            }
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        None | Some("grid") => {
            let mut sizes = Vec::new();
            for s in [4, 8, 16] {
                for d in [2, 3, 6, 12, 24, 36] {
                    sizes.push((s, d));
                }
            }
            table(&sizes, &["full", "tied"]);
        }
        Some("quick") => table(&[(8, 12), (16, 12), (8, 36), (16, 36)], &["full"]),
        Some("sizes") => {
            // sizes KIND S D [S D ...]
            let sizes: Vec<(usize, usize)> = args[2..]
                .chunks_exact(2)
                .map(|p| (p[0].parse().unwrap(), p[1].parse().unwrap()))
                .collect();
            table(&sizes, &[args[1].as_str()]);
        }
        Some("peak") => peak_both(),
        Some("call") => {
            // call KERNEL KIND S D soft|sparse REPS
            let kernel = args[1].as_str();
            let kind = kind_of(&args[2]);
            let s: usize = args[3].parse().unwrap();
            let d: usize = args[4].parse().unwrap();
            let soft = args[5] == "soft";
            let reps: usize = args[6].parse().unwrap();
            let mut c = case(kind, s, d, soft);
            let mut stats = c.g.new_stats();
            for _ in 0..reps {
                match kernel {
                    "log_density" => run_log_density(&mut c),
                    "accumulate" => run_accumulate(&mut c, &mut stats),
                    _ => panic!("kernel: log_density or accumulate"),
                }
            }
            black_box((&c.out, &stats));
        }
        Some(other) => panic!("unknown mode {other}: grid, quick, sizes, peak or call"),
    }
}
