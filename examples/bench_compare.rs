//! Speed measurements of phasekit for the comparison with hmmlearn and
//! scikit-learn (`benches/compare/run.sh` drives it; see BENCHMARKS.md).
//!
//! ```text
//! bench_compare run DIR [FILTER]  write every workload's data and initial parameters
//!                                 to DIR (manifest.json + raw little-endian f64 files),
//!                                 time phasekit on them single-threaded and write
//!                                 DIR/phasekit.json (only workloads whose name
//!                                 contains FILTER, if given)
//! bench_compare peak              single-core dgemm peak (nalgebra 1024×1024)
//! bench_compare scaling FRAMES    one Baum-Welch iteration, S=8, D=12, sequences of
//!                                 250 frames: time and peak resident memory
//! bench_compare threads [REPS]    workload 2 on 1 and on 2 threads: time per
//!                                 iteration, log-likelihoods and a parameter hash
//! bench_compare breakdown [FILTER] [fitted]
//!                                 where one Baum-Welch iteration spends its time
//!                                 (forward-backward = E-step − log-densities − statistics),
//!                                 at the initial model or (`fitted`) at the fitted one
//! bench_compare steps NAME...     which path the E-step's recursions take (lane form,
//!                                 per-sequence fast and general steps), at the initial
//!                                 and at the fitted model
//! bench_compare fit NAME [REPS]   REPS whole fits of one workload, one thread (for profilers)
//! bench_compare kernels           CPU time of the emission hot paths on one sequence
//! ```
//!
//! Every timing runs on one thread unless said (`BaumWelch::threads(1)`,
//! `Em::threads(1)`); per-iteration times are medians over repetitions.

#[path = "../benches/common/mod.rs"]
mod common;

use common::*;
use nalgebra::DMatrix;
use phasekit::emission::{Frames, Gaussian, Regularisation, SequenceSet};
use phasekit::gmm::Em;
use phasekit::hmm::{BaumWelch, Hmm, Update};
use serde_json::{json, Value};
use std::hint::black_box;
use std::io::Write;
use std::path::Path;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Runs `f` at least `min_reps` times and until `budget` seconds have passed
/// (at most `max_reps`); returns the median wall seconds and the median CPU
/// seconds (whole process) of one call, and the count.
fn time_median(
    min_reps: usize,
    max_reps: usize,
    budget: f64,
    mut f: impl FnMut(),
) -> (f64, f64, usize) {
    let clock = Instant::now();
    let mut wall = Vec::new();
    let mut cpu = Vec::new();
    while wall.len() < min_reps || (clock.elapsed().as_secs_f64() < budget && wall.len() < max_reps)
    {
        let t0 = Instant::now();
        let c0 = process_cpu_seconds();
        f();
        cpu.push(process_cpu_seconds() - c0);
        wall.push(t0.elapsed().as_secs_f64());
    }
    let n = wall.len();
    (median(wall), median(cpu), n)
}

fn write_f64(path: &Path, data: &[f64]) {
    let mut bytes = Vec::with_capacity(data.len() * 8);
    for v in data {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, bytes).expect("write data file");
}

fn fnv1a(values: impl IntoIterator<Item = f64>) -> String {
    let mut h: u64 = 0xcbf29ce484222325;
    for v in values {
        for b in v.to_bits().to_le_bytes() {
            h ^= b as u64;
            h = h.wrapping_mul(0x100000001b3);
        }
    }
    format!("{h:016x}")
}

fn hmm_hash(h: &Hmm<Gaussian>) -> String {
    let e = h.emission();
    fnv1a(
        h.start()
            .iter()
            .chain(h.transition())
            .chain(e.means())
            .chain(e.covariances_raw())
            .copied(),
    )
}

fn hmm_params_json(h: &Hmm<Gaussian>) -> Value {
    let e = h.emission();
    let s = h.n_states();
    let d = h.dim();
    let covs: Vec<f64> = (0..s)
        .flat_map(|i| {
            e.covariance(i)
                .transpose()
                .iter()
                .copied()
                .collect::<Vec<_>>()
        })
        .collect();
    json!({
        "start": h.start(),
        "transmat": h.transition(),
        "means": e.means(),
        "covars_full": covs,
        "n_states": s,
        "dim": d,
    })
}

fn fit_hmm(w: &HmmWorkload, threads: usize) -> phasekit::hmm::HmmFit<Gaussian> {
    BaumWelch::builder()
        .max_iter(w.n_iter)
        .tol(f64::NEG_INFINITY)
        .regularisation(w.reg())
        .threads(threads)
        .build()
        .expect("settings")
        .fit_from(w.init.clone(), &w.data)
        .expect("Baum-Welch")
}

fn run_hmm(w: &HmmWorkload, dir: &Path, budget: f64) -> (Value, Value) {
    let file = format!("{}.f64", w.name);
    write_f64(&dir.join(&file), w.data.all_frames().as_slice());
    let lengths: Vec<usize> = w.data.lengths().collect();
    let manifest = json!({
        "name": w.name, "kind": if w.name.starts_with("small") { "small" } else { "hmm" },
        "file": file, "lengths": lengths, "dim": w.dim(), "n_states": w.n_states(),
        "n_iter": w.n_iter,
        "covariance_type": if w.dim() == 1 { "diag" } else { "full" },
        "iw_scale": w.iw_scale,
        "init": hmm_params_json(&w.init),
    });
    let mut last = None;
    let (fit_s, fit_cpu, reps) = time_median(1, 7, budget, || last = Some(fit_hmm(w, 1)));
    let fitted = last.unwrap();
    // fit_from runs n_iter M-steps and n_iter + 1 E-steps (the last one scores the
    // returned model); dividing by n_iter charges that extra E-step to phasekit.
    let per_iter = fit_cpu / w.n_iter as f64;
    let t = w.data.total_frames();
    let flops = bw_iteration_flops(t, w.n_states(), w.dim());
    let mut res = json!({
        "name": w.name,
        "fit_seconds": fit_s,
        "fit_cpu_seconds": fit_cpu,
        "per_iter_s": per_iter,
        "per_iter_wall_s": fit_s / w.n_iter as f64,
        "reps": reps,
        "ll_history": fitted.report.log_likelihood,
        "flops_per_iter": flops,
        "gflops": flops / per_iter / 1e9,
        "param_hash": hmm_hash(&fitted.model),
    });
    if w.name.starts_with("small") {
        let seqs: Vec<Frames<'_>> = w.data.iter().collect();
        let h = &w.init;
        let (_, fwd, _) = time_median(5, 2000, budget / 4.0, || {
            for s in &seqs {
                black_box(h.log_likelihood(*s).unwrap());
            }
        });
        let (_, fb, _) = time_median(5, 2000, budget / 4.0, || {
            for s in &seqs {
                black_box(h.posteriors(*s).unwrap());
            }
        });
        let (_, vit, _) = time_median(5, 2000, budget / 4.0, || {
            for s in &seqs {
                black_box(h.viterbi(*s).unwrap());
            }
        });
        let ll: f64 = seqs.iter().map(|s| h.log_likelihood(*s).unwrap()).sum();
        let vlp: f64 = seqs
            .iter()
            .map(|s| h.viterbi(*s).unwrap().log_probability)
            .sum();
        res["forward_s"] = json!(fwd);
        res["forward_backward_s"] = json!(fb);
        res["viterbi_s"] = json!(vit);
        res["init_ll"] = json!(ll);
        res["viterbi_logprob"] = json!(vlp);
    }
    (manifest, res)
}

fn run_gmm(w: &GmmWorkload, dir: &Path, budget: f64) -> (Value, Value) {
    let file = format!("{}.f64", w.name);
    write_f64(&dir.join(&file), &w.data);
    let c = w.init.components();
    let k = w.init.n_components();
    let covs: Vec<f64> = (0..k)
        .flat_map(|i| {
            c.covariance(i)
                .transpose()
                .iter()
                .copied()
                .collect::<Vec<_>>()
        })
        .collect();
    let n = w.data.len() / w.dim;
    let manifest = json!({
        "name": w.name, "kind": "gmm", "file": file, "dim": w.dim, "n_samples": n,
        "n_components": k, "n_iter": w.n_iter, "reg_covar": w.reg_covar,
        "init": {"weights": w.init.weights(), "means": c.means(), "covars_full": covs},
    });
    let frames = Frames::new(&w.data, w.dim).unwrap();
    let em = Em::builder()
        .max_iter(w.n_iter)
        .tol(f64::NEG_INFINITY)
        .regularisation(Regularisation::add_diagonal(w.reg_covar).unwrap())
        .threads(1)
        .build()
        .unwrap();
    let mut last = None;
    let (fit_s, fit_cpu, reps) = time_median(1, 7, budget, || {
        last = Some(em.fit_from(w.init.clone(), frames).unwrap())
    });
    let fitted = last.unwrap();
    let per_iter = fit_cpu / w.n_iter as f64;
    let flops = em_iteration_flops(n, k, w.dim);
    let res = json!({
        "name": w.name, "fit_seconds": fit_s, "fit_cpu_seconds": fit_cpu, "per_iter_s": per_iter,
        "per_iter_wall_s": fit_s / w.n_iter as f64, "reps": reps,
        "ll_history": fitted.report.log_likelihood,
        "flops_per_iter": flops, "gflops": flops / per_iter / 1e9,
    });
    (manifest, res)
}

fn peak() -> f64 {
    let n = 1024;
    let a = DMatrix::<f64>::from_fn(n, n, |r, c| ((r * 7 + c * 13) % 17) as f64 / 17.0 - 0.5);
    let b = DMatrix::<f64>::from_fn(n, n, |r, c| ((r * 5 + c * 3) % 11) as f64 / 11.0 - 0.5);
    let mut c = DMatrix::<f64>::zeros(n, n);
    let mut best = f64::INFINITY;
    for _ in 0..6 {
        let t0 = Instant::now();
        a.mul_to(&b, &mut c);
        best = best.min(t0.elapsed().as_secs_f64());
        black_box(&c);
    }
    2.0 * (n as f64).powi(3) / best / 1e9
}

fn status_kb(field: &str) -> u64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    s.lines()
        .find(|l| l.starts_with(field))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

fn one_iteration(
    hmm: &Hmm<Gaussian>,
    data: &SequenceSet,
    reg: &Regularisation,
) -> (f64, Hmm<Gaussian>) {
    let stats = hmm.expected_statistics(data).expect("E-step");
    let (next, _) = hmm
        .maximise(&stats, Update::default(), reg)
        .expect("M-step");
    (stats.log_likelihood, next)
}

fn scaling(frames: usize) {
    let w = generated_workload(8, 12, frames, (frames / 250).max(1), 7);
    let data_mib = (w.data.total_frames() * w.dim() * 8) as f64 / 1048576.0;
    // Give the generator's freed memory back to the system, then reset the
    // peak-RSS counter so that it covers the iteration only.
    // SAFETY: malloc_trim only releases free heap memory.
    unsafe { libc::malloc_trim(0) };
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let rss_before = status_kb("VmRSS:");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let reg = w.reg();
    let t0 = Instant::now();
    let (ll, next) = pool.install(|| one_iteration(&w.init, &w.data, &reg));
    let secs = t0.elapsed().as_secs_f64();
    black_box(next);
    let hwm = status_kb("VmHWM:");
    println!(
        "{{\"frames\": {}, \"seconds\": {secs:.6}, \"ns_per_frame\": {:.2}, \"data_mib\": {data_mib:.1}, \"rss_before_mib\": {:.1}, \"peak_rss_mib\": {:.1}, \"log_likelihood\": {ll}}}",
        w.data.total_frames(),
        secs * 1e9 / w.data.total_frames() as f64,
        rss_before as f64 / 1024.0,
        hwm as f64 / 1024.0
    );
}

fn threads(reps: usize) {
    for w in generated_workloads() {
        let mut out = Vec::new();
        for n in [1usize, 2] {
            let mut last = None;
            let mut times = Vec::new();
            let mut cpus = Vec::new();
            for _ in 0..reps {
                let t0 = Instant::now();
                let c0 = process_cpu_seconds();
                last = Some(fit_hmm(&w, n));
                cpus.push((process_cpu_seconds() - c0) / w.n_iter as f64);
                times.push(t0.elapsed().as_secs_f64() / w.n_iter as f64);
            }
            let f = last.unwrap();
            let ll = f.report.log_likelihood.clone();
            out.push((n, median(times), median(cpus), ll, hmm_hash(&f.model)));
        }
        let identical = out[0]
            .3
            .iter()
            .zip(&out[1].3)
            .all(|(a, b)| a.to_bits() == b.to_bits())
            && out[0].4 == out[1].4;
        for (n, t, c, ll, hash) in &out {
            println!(
                "{:<16} threads={n} per_iter={t:.4}s (cpu {c:.4}s, {:.2} cores busy) final_ll={:.17e} param_hash={hash}",
                w.name,
                c / t,
                ll.last().unwrap()
            );
        }
        println!(
            "{:<16} speed-up(2 vs 1)={:.2}x bit-identical={identical}",
            w.name,
            out[0].1 / out[1].1
        );
    }
}

fn breakdown(filter: &str, fitted: bool) {
    use phasekit::emission::Emission;
    let mut ws: Vec<HmmWorkload> = Vec::new();
    for (c, k) in [
        (Columns::AllJoints, 8),
        (Columns::AllJoints, 15),
        (Columns::Wrists, 8),
        (Columns::Wrists, 15),
    ] {
        if let Some(w) = paper_workload(c, k) {
            ws.push(w);
        }
    }
    if "gen".contains(filter) || filter.starts_with("gen") {
        ws.extend(generated_workloads());
    }
    if filter.starts_with("small") {
        ws.extend((2..=10).map(small_workload));
    }
    println!("| workload | log-densities | forward-backward | statistics | M-step | sum (ms) | forward-backward share |");
    println!("|---|---|---|---|---|---|---|");
    for w in ws.iter().filter(|w| w.name.contains(filter)) {
        let model = fitted.then(|| fit_hmm(w, 1).model);
        let h = model.as_ref().unwrap_or(&w.init);
        let e = h.emission();
        let best = |f: &mut dyn FnMut()| -> f64 {
            (0..5)
                .map(|_| {
                    let c0 = process_cpu_seconds();
                    f();
                    process_cpu_seconds() - c0
                })
                .fold(f64::INFINITY, f64::min)
                * 1e3
        };
        let ld = best(&mut || {
            for s in w.data.iter() {
                black_box(e.log_density(s).unwrap());
            }
        });
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        // The E-step as Baum-Welch runs it (lane form where it applies):
        // log-densities, forward-backward and statistics.
        let estep = best(&mut || {
            black_box(pool.install(|| h.expected_statistics(&w.data).unwrap()));
        });
        let gammas: Vec<Vec<f64>> = w
            .data
            .iter()
            .map(|s| h.posteriors(s).unwrap().gamma)
            .collect();
        let acc = best(&mut || {
            let mut st = e.new_stats();
            for (s, g) in w.data.iter().zip(&gammas) {
                e.accumulate(s, g, &mut st).unwrap();
            }
            black_box(st);
        });
        let stats = pool.install(|| h.expected_statistics(&w.data).unwrap());
        let reg = w.reg();
        let m = best(&mut || {
            black_box(h.maximise(&stats, Update::default(), &reg).unwrap());
        });
        let fb = estep - ld - acc;
        let total = estep + m;
        println!(
            "| {} | {ld:.2} | {fb:.2} | {acc:.2} | {m:.2} | {total:.2} | {:.0}% |",
            w.name,
            100.0 * fb / total
        );
    }
}

/// CPU nanoseconds of one online HMM-GMR step (the model of `benches/gmr.rs`:
/// 7 states, 12-D joint, 6 inputs, 6 outputs), best of 20 batches of 100k steps.
fn online() {
    use phasekit::gmr::HmmRegression;
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let (s, d, n_in) = (7, 12, 6);
    let emission = random_gaussian(s, d, 2.0, &mut rng);
    let mut transition = vec![0.1 / (s - 1) as f64; s * s];
    for i in 0..s {
        transition[i * s + i] = 0.9;
    }
    let mut start = vec![0.0; s];
    start[0] = 1.0;
    let hmm = Hmm::new(start, transition, emission).unwrap();
    let input: Vec<usize> = (0..n_in).collect();
    let output: Vec<usize> = (n_in..d).collect();
    let gmr = HmmRegression::new(&hmm, &input, &output).unwrap();
    let (joint, _) = hmm.sample(1000, &mut rng).unwrap();
    let xs: Vec<f64> = joint
        .chunks_exact(d)
        .flat_map(|f| f[..n_in].to_vec())
        .collect();
    for with_cov in [false, true] {
        let mut online = gmr.online();
        let mut t = 0;
        let best = (0..20)
            .map(|_| {
                let c0 = process_cpu_seconds();
                for _ in 0..100_000 {
                    if t == 1000 {
                        t = 0;
                        online.reset();
                    }
                    let x = &xs[t * n_in..(t + 1) * n_in];
                    let y = if with_cov {
                        online.step_with_covariance(x)
                    } else {
                        online.step(x)
                    };
                    black_box(y.unwrap()[0]);
                    t += 1;
                }
                (process_cpu_seconds() - c0) / 100_000.0 * 1e9
            })
            .fold(f64::INFINITY, f64::min);
        println!(
            "online step ({}): {best:.0} ns",
            if with_cov {
                "mean and covariance"
            } else {
                "mean"
            }
        );
    }
}

/// CPU microseconds per call of the emission hot paths on one 250-frame sequence.
fn kernels() {
    use phasekit::emission::Emission;
    use rand::{Rng, SeedableRng};
    {
        // The slice exp of the recursions: S values at a time.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        for n in [7usize, 16, 1000] {
            let x: Vec<f64> = (0..1000 * n)
                .map(|_| rng.random_range(-40.0..0.0))
                .collect();
            let mut v = x.clone();
            let best = (0..15)
                .map(|_| {
                    v.copy_from_slice(&x);
                    let c0 = process_cpu_seconds();
                    for c in v.chunks_exact_mut(n) {
                        phasekit::emission::linalg::exp_in_place(black_box(c));
                    }
                    (process_cpu_seconds() - c0) / (1000 * n) as f64 * 1e9
                })
                .fold(f64::INFINITY, f64::min);
            println!("exp_in_place on slices of {n:<4}: {best:6.2} ns per value");
        }
    }
    for (s, d) in [(8usize, 36usize), (16, 12), (8, 12)] {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let g = random_gaussian(s, d, 2.0, &mut rng);
        let t = 250;
        let x: Vec<f64> = (0..t * d).map(|_| rng.random_range(-3.0..3.0)).collect();
        let frames = Frames::new(&x, d).unwrap();
        let gamma: Vec<f64> = (0..t * s)
            .map(|_| rng.random_range(0.0..1.0) / s as f64)
            .collect();
        let mut out = vec![0.0; t * s];
        // Best of 15 batches of 40 calls, in CPU time.
        let cpu = |f: &mut dyn FnMut()| {
            f();
            (0..15)
                .map(|_| {
                    let c0 = process_cpu_seconds();
                    for _ in 0..40 {
                        f();
                    }
                    (process_cpu_seconds() - c0) / 40.0 * 1e6
                })
                .fold(f64::INFINITY, f64::min)
        };
        let ld = cpu(&mut || g.log_density_into(black_box(frames), &mut out).unwrap());
        let mut stats = g.new_stats();
        let acc = cpu(&mut || g.accumulate(black_box(frames), &gamma, &mut stats).unwrap());
        let fl = (t * s * (d * (d + 1) / 2)) as f64 * 2.0;
        println!(
            "S={s:<2} D={d:<2} T={t}: log_density {ld:8.1} us ({:5.1} GFLOP/s)  accumulate {acc:8.1} us ({:5.1} GFLOP/s)",
            fl / ld / 1e3,
            fl / acc / 1e3
        );
    }
}

/// The workload of that name (`paper_*`, `gen_*`, `small_K*`), or `None`.
fn workload_by_name(name: &str) -> Option<HmmWorkload> {
    if let Some(k) = name.strip_prefix("small_K") {
        return Some(small_workload(k.parse().ok()?));
    }
    if let Some(rest) = name.strip_prefix("gen_S") {
        // gen_S{s}_D{d}_{k}k: any generated shape (sequences of 250 frames, seed s).
        let parts: Vec<&str> = rest.split('_').collect();
        if let [s, d, k] = parts[..] {
            if let (Ok(s), Some(Ok(d)), Some(Ok(k))) = (
                s.parse::<usize>(),
                d.strip_prefix('D').map(str::parse::<usize>),
                k.strip_suffix('k').map(str::parse::<usize>),
            ) {
                if !(k == 100 && (s == 16 && d == 12 || s == 8 && d == 36)) {
                    return Some(generated_workload(s, d, k * 1000, k * 4, s as u64));
                }
            }
        }
    }
    match name {
        "gen_S16_D12_100k" => Some(generated_workload(16, 12, 100_000, 400, 16)),
        "gen_S8_D36_100k" => Some(generated_workload(8, 36, 100_000, 400, 8)),
        "paper_D36_K8" => paper_workload(Columns::AllJoints, 8),
        "paper_D36_K15" => paper_workload(Columns::AllJoints, 15),
        "paper_D12_K8" => paper_workload(Columns::Wrists, 8),
        "paper_D12_K15" => paper_workload(Columns::Wrists, 15),
        _ => None,
    }
}

/// `REPS` whole fits of one workload on one thread, for profilers
/// (`valgrind --tool=callgrind`, `perf record`): prints the CPU time of each
/// and the final log-likelihood.
fn fit_only(name: &str, reps: usize) {
    let w = workload_by_name(name).expect("unknown workload");
    for _ in 0..reps {
        let c0 = process_cpu_seconds();
        let f = fit_hmm(&w, 1);
        let cpu = process_cpu_seconds() - c0;
        println!(
            "{name} fit {:.3} ms CPU ({} iterations) final_ll={:.17e} param_hash={}",
            cpu * 1e3,
            w.n_iter,
            f.report.log_likelihood.last().unwrap(),
            hmm_hash(&f.model)
        );
    }
}

/// A workload built only when its name passes the filter.
type LazyWorkload = Box<dyn Fn() -> Option<HmmWorkload>>;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    match args.get(1).map(String::as_str) {
        Some("peak") => println!("peak_gflops {:.2}", peak()),
        Some("kernels") => kernels(),
        Some("online") => online(),
        Some("breakdown") => breakdown(
            args.get(2).map(String::as_str).unwrap_or(""),
            args.get(3).is_some_and(|a| a == "fitted"),
        ),
        Some("scaling") => scaling(args.get(2).and_then(|v| v.parse().ok()).expect("FRAMES")),
        Some("threads") => threads(args.get(2).and_then(|v| v.parse().ok()).unwrap_or(3)),
        Some("steps") => {
            for name in args[2..].iter() {
                let w = workload_by_name(name).expect("unknown workload");
                let c = w.init.step_counts(&w.data).expect("E-step");
                println!("{name} (initial model): {c:?}");
                let fitted = fit_hmm(&w, 1).model;
                let c = fitted.step_counts(&w.data).expect("E-step");
                println!("{name} (after {} iterations): {c:?}", w.n_iter);
                let zeros = fitted.transition().iter().filter(|a| **a == 0.0).count();
                let tiny = fitted
                    .transition()
                    .iter()
                    .filter(|a| **a > 0.0 && **a < 1e-290)
                    .count();
                let start_zeros = fitted.start().iter().filter(|p| **p < 1e-290).count();
                println!(
                    "{name} (after {} iterations): a_ij = 0: {zeros}, 0 < a_ij < 1e-290: {tiny} of {}; π_i < 1e-290: {start_zeros} of {}",
                    w.n_iter,
                    fitted.transition().len(),
                    fitted.n_states()
                );
            }
        }
        Some("fit") => fit_only(
            args.get(2).map(String::as_str).expect("NAME"),
            args.get(3).and_then(|v| v.parse().ok()).unwrap_or(1),
        ),
        Some("run") => {
            let dir = Path::new(args.get(2).expect("DIR"));
            let filter = args.get(3).cloned().unwrap_or_default();
            std::fs::create_dir_all(dir).expect("create DIR");
            let budget: f64 = std::env::var("PHASEKIT_BENCH_BUDGET")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(3.0);
            let peak_gflops = peak();
            eprintln!("dgemm 1024 peak: {peak_gflops:.2} GFLOP/s");
            let mut manifest = Vec::new();
            let mut results = Vec::new();
            // Workloads are built lazily, so that a FILTER skips the generation of the others.
            let mut hmm_w: Vec<(String, LazyWorkload)> = Vec::new();
            for (c, dd) in [(Columns::AllJoints, 36), (Columns::Wrists, 12)] {
                for k in [8, 15] {
                    hmm_w.push((
                        format!("paper_D{dd}_K{k}"),
                        Box::new(move || paper_workload(c, k)),
                    ));
                }
            }
            hmm_w.push((
                "gen_S16_D12_100k".into(),
                Box::new(|| Some(generated_workload(16, 12, 100_000, 400, 16))),
            ));
            hmm_w.push((
                "gen_S8_D36_100k".into(),
                Box::new(|| Some(generated_workload(8, 36, 100_000, 400, 8))),
            ));
            for k in 2..=10 {
                hmm_w.push((
                    format!("small_K{k}"),
                    Box::new(move || Some(small_workload(k))),
                ));
            }
            for (name, make) in hmm_w.iter().filter(|(n, _)| n.contains(&filter)) {
                let Some(w) = make() else {
                    eprintln!("{name}: data not found, skipped");
                    continue;
                };
                assert_eq!(&w.name, name);
                let (m, r) = run_hmm(&w, dir, budget);
                eprintln!(
                    "{:<18} {:>9.3} ms/iter  {:>6.2} GFLOP/s  ll {:.10e}",
                    w.name,
                    r["per_iter_s"].as_f64().unwrap() * 1e3,
                    r["gflops"].as_f64().unwrap(),
                    r["ll_history"]
                        .as_array()
                        .unwrap()
                        .last()
                        .unwrap()
                        .as_f64()
                        .unwrap()
                );
                manifest.push(m);
                results.push(r);
            }
            let gmm_w: Vec<(String, Box<dyn Fn() -> GmmWorkload>)> = vec![
                (
                    "gmm_K8_D12_100k".into(),
                    Box::new(|| gmm_workload(8, 12, 100_000, 412)),
                ),
                (
                    "gmm_K8_D36_100k".into(),
                    Box::new(|| gmm_workload(8, 36, 100_000, 436)),
                ),
            ];
            for (_, make) in gmm_w.iter().filter(|(n, _)| n.contains(&filter)) {
                let w = make();
                let (m, r) = run_gmm(&w, dir, budget);
                eprintln!(
                    "{:<18} {:>9.3} ms/iter  {:>6.2} GFLOP/s",
                    w.name,
                    r["per_iter_s"].as_f64().unwrap() * 1e3,
                    r["gflops"].as_f64().unwrap()
                );
                manifest.push(m);
                results.push(r);
            }
            let m = json!({"workloads": manifest});
            std::fs::write(
                dir.join("manifest.json"),
                serde_json::to_string(&m).unwrap(),
            )
            .unwrap();
            let r = json!({"peak_gflops": peak_gflops, "results": results});
            let mut f = std::fs::File::create(dir.join("phasekit.json")).unwrap();
            f.write_all(serde_json::to_string_pretty(&r).unwrap().as_bytes())
                .unwrap();
        }
        _ => {
            eprintln!(
                "usage: bench_compare run DIR [FILTER] | peak | scaling FRAMES | threads [REPS]"
            );
            std::process::exit(2);
        }
    }
}
