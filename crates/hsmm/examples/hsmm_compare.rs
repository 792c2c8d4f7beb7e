//! Speed of phasekit's HSMM for the comparison with pbdlib and with the
//! state-expanded HMM of hmmlearn's HSMM pull request #582
//! (`crates/hsmm/benches/compare/run.sh` drives it; see `crates/hsmm/BENCHMARKS.md`).
//!
//! ```text
//! hsmm_compare run DIR [FILTER]   write every workload's model and data to DIR
//!                                 (manifest.json + raw little-endian f64 files),
//!                                 time phasekit on them on one thread and write
//!                                 DIR/phasekit.json (workloads whose name contains FILTER)
//! ```
//!
//! Timed (median CPU seconds of the process over repetitions): the forward
//! pass, forward–backward (posteriors), one EM iteration (E-step + M-step of
//! durations, transitions and emissions) over all sequences, the online
//! filter per frame, and phasekit's own HMM on the expanded state space
//! (`S · D` states) for the same forward–backward and EM iteration.

#[path = "../benches/workloads/mod.rs"]
mod workloads;

use phasekit_emission::Regularisation;
use phasekit_hmm::Update;
use phasekit_hsmm::{DurationRegularisation, HsmmUpdate};
use serde_json::{json, Value};
use std::hint::black_box;
use std::path::Path;
use std::time::Instant;
use workloads::{expanded_hmm, workload, Workload};

fn process_cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid timespec to write into.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Median CPU seconds of one call of `f` (at least 3 calls, then until
/// `budget` wall seconds have passed, at most 50).
fn time_cpu(budget: f64, mut f: impl FnMut()) -> f64 {
    let clock = Instant::now();
    let mut cpu = Vec::new();
    while cpu.len() < 3 || (clock.elapsed().as_secs_f64() < budget && cpu.len() < 50) {
        let c0 = process_cpu_seconds();
        f();
        cpu.push(process_cpu_seconds() - c0);
    }
    median(cpu)
}

fn one_thread<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(f)
}

fn write_f64(path: &Path, data: &[f64]) {
    let mut bytes = Vec::with_capacity(data.len() * 8);
    for v in data {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, bytes).expect("write data file");
}

fn workloads() -> Vec<Workload> {
    vec![
        workload(4, 25, 3, 20, 100, 1),
        workload(8, 50, 6, 20, 250, 2),
        workload(8, 100, 6, 20, 250, 3),
        // The NuiSI paper setting's shape: 8 demonstrations of ~280 frames,
        // 7 states, D = 12, pbdlib's nbD = round(4 T / S) = 160.
        workload(7, 160, 12, 8, 280, 4),
    ]
}

fn run(w: &Workload, dir: &Path, expanded: bool) -> Value {
    let file = format!("{}.f64", w.name);
    write_f64(&dir.join(&file), w.data.all_frames().as_slice());
    let reg = Regularisation::add_diagonal(1e-6).unwrap();
    let dreg = DurationRegularisation::none();
    let ll = w.model.log_likelihood_all(&w.data).unwrap();
    let first = w.model.forward(w.data.get(0)).unwrap();
    let frames = w.data.total_frames() as f64;
    let budget = 3.0;
    let forward = time_cpu(budget, || {
        for seq in w.data.iter() {
            black_box(w.model.log_likelihood(seq).unwrap());
        }
    });
    let forward_backward = time_cpu(budget, || {
        for seq in w.data.iter() {
            black_box(w.model.posteriors(seq).unwrap());
        }
    });
    let em = time_cpu(budget, || {
        one_thread(|| {
            let stats = w.model.expected_statistics(&w.data).unwrap();
            black_box(
                w.model
                    .maximise(&stats, HsmmUpdate::default(), &reg, &dreg)
                    .unwrap(),
            );
        })
    });
    let viterbi = time_cpu(budget, || {
        for seq in w.data.iter() {
            black_box(w.model.viterbi(seq).unwrap());
        }
    });
    let mut filter = w.model.filter();
    let seq0 = w.data.get(0);
    let online = time_cpu(budget, || {
        filter.reset();
        for t in 0..seq0.len() {
            black_box(filter.step(seq0.frame(t)).unwrap());
        }
    }) / seq0.len() as f64;
    let (mut hmm_fb, mut hmm_em, mut hmm_ll) = (None, None, None);
    if expanded {
        let hmm = expanded_hmm(w);
        hmm_ll = Some(hmm.log_likelihood_all(&w.data).unwrap());
        hmm_fb = Some(time_cpu(budget, || {
            for seq in w.data.iter() {
                black_box(hmm.posteriors(seq).unwrap());
            }
        }));
        hmm_em = Some(time_cpu(budget, || {
            one_thread(|| {
                let stats = hmm.expected_statistics(&w.data).unwrap();
                black_box(hmm.maximise(&stats, Update::default(), &reg).unwrap());
            })
        }));
    }
    println!(
        "{:<28} forward {:>8.2} ms  forward-backward {:>8.2} ms  EM iteration {:>8.2} ms  viterbi {:>8.2} ms  online {:>6.2} µs/frame  ({:.2} µs/frame forward-backward){}",
        w.name,
        forward * 1e3,
        forward_backward * 1e3,
        em * 1e3,
        viterbi * 1e3,
        online * 1e6,
        forward_backward / frames * 1e6,
        match (hmm_fb, hmm_em) {
            (Some(a), Some(b)) => format!(
                "  | expanded HMM ({} states): forward-backward {:.1} ms, EM {:.1} ms",
                w.n_states * w.max_duration,
                a * 1e3,
                b * 1e3
            ),
            _ => String::new(),
        }
    );
    json!({
        "name": w.name,
        "file": file,
        "n_states": w.n_states,
        "max_duration": w.max_duration,
        "dim": w.dim,
        "lengths": w.data.lengths().collect::<Vec<_>>(),
        "start": w.model.start(),
        "transition": w.model.transition(),
        "duration_means": w.duration_means,
        "duration_stds": w.duration_stds,
        "means": w.means,
        "variances": w.variances,
        "phasekit": {
            "log_likelihood": ll,
            "filtered_first_sequence": first.filtered(),
            "forward_s": forward,
            "forward_backward_s": forward_backward,
            "em_iteration_s": em,
            "viterbi_s": viterbi,
            "online_step_s": online,
            "expanded_hmm_log_likelihood": hmm_ll,
            "expanded_hmm_forward_backward_s": hmm_fb,
            "expanded_hmm_em_iteration_s": hmm_em,
        }
    })
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 || args[1] != "run" {
        eprintln!("usage: hsmm_compare run DIR [FILTER]");
        std::process::exit(2);
    }
    let dir = Path::new(&args[2]);
    std::fs::create_dir_all(dir).expect("output folder");
    let filter = args.get(3).cloned().unwrap_or_default();
    let mut out = Vec::new();
    for w in workloads() {
        if !w.name.contains(&filter) {
            continue;
        }
        // The expanded HMM has S·D states and costs O(T (S·D)²): skip the largest.
        let expanded =
            w.n_states * w.max_duration <= 800 && std::env::var_os("HSMM_NO_EXPANDED").is_none();
        out.push(run(&w, dir, expanded));
    }
    std::fs::write(
        dir.join("manifest.json"),
        serde_json::to_string_pretty(&json!({ "workloads": out })).unwrap(),
    )
    .expect("write manifest");
}
