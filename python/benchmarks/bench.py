"""Speed of phasekit's Python API against hmmlearn and scikit-learn, same arrays, same process.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python python/benchmarks/bench.py [--quick]

Every timing is the best of `--repeat` runs (default 3) of CPU seconds of the
process (time.process_time: robust to other processes on a shared machine;
every library runs on one thread) and wall seconds. Writes a Markdown table to
stdout. The same starting parameters go to both libraries and the
log-likelihoods after the fit are checked to agree.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

warnings.simplefilter("ignore")


def timed(f, repeat):
    best = None
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        out = f()
        c, w = time.process_time() - c0, time.perf_counter() - w0
        if best is None or c < best[0]:
            best = (c, w, out)
    return best


def hmm_data(n_frames, S, D, seed=0):
    rng = np.random.default_rng(seed)
    means = rng.normal(scale=3.0, size=(S, D))
    z = np.zeros(n_frames, dtype=int)
    for t in range(1, n_frames):
        z[t] = z[t - 1] if rng.random() < 0.95 else rng.integers(S)
    X = means[z] + rng.normal(size=(n_frames, D))
    lengths = [1000] * (n_frames // 1000)
    start = np.full(S, 1.0 / S)
    trans = np.full((S, S), 0.05 / (S - 1)) + np.eye(S) * (0.95 - 0.05 / (S - 1))
    m0 = means + rng.normal(scale=0.5, size=(S, D))
    c0 = np.tile(np.eye(D), (S, 1, 1))
    return X, lengths, (start, trans, m0, c0)


def set_params(m, p):
    m.startprob_, m.transmat_, m.means_, m.covars_ = p


def bench_hmm(args, rows):
    from hmmlearn import hmm as hl

    from phasekit import hmm as pk

    n, S, D, iters = args.frames, 16, 12, 10
    X, lengths, p = hmm_data(n, S, D)

    def fit(module, **kw):
        m = module.GaussianHMM(S, "full", init_params="", n_iter=iters, tol=-np.inf, **kw)
        set_params(m, p)
        return m.fit(X, lengths)

    pk_c, pk_w, pk_m = timed(lambda: fit(pk), args.repeat)
    # the binding's share: the E-steps alone, called directly on the compiled core
    from phasekit import _core

    data = _core.Sequences(X, lengths)
    start = pk.GaussianHMM(S, "full", init_params="")
    set_params(start, p)
    start._check()
    core = start._to_core()  # the starting model: the same posteriors as the fit's first E-step
    es_c, es_w, _ = timed(lambda: [core.expected_statistics(data, 1) for _ in range(iters)], args.repeat)
    results = {"phasekit": (pk_c, pk_w, pk_m.score(X, lengths))}
    for impl in ("log", "scaling"):
        c, w, m = timed(lambda: fit(hl, implementation=impl), 1)
        results[f"hmmlearn ({impl})"] = (c, w, m.score(X, lengths))
    ll = results["phasekit"][2]
    for name, (c, w, s) in results.items():
        assert abs(s / ll - 1) < 1e-8, (name, s, ll)
    for name, (c, w, s) in results.items():
        rows.append(
            (f"GaussianHMM(16, 'full').fit, {n:.0e} frames, D = 12, 10 iterations", name, c, w, c / iters, pk_c and c / pk_c)
        )
    rows.append(("  of which phasekit's 10 E-steps called directly on the core", "phasekit (core)", es_c, es_w, es_c / iters, None))
    # the command on the same arrays: 1000-frame NPY files (columns c0..c11), no
    # velocities; its CPU time (getrusage of the child) includes reading the
    # files, the k-bins initialisation and one more E-step than the Python fit
    bin_ = args.phasekit_bin
    if bin_ and Path(bin_).is_file():
        import resource

        with tempfile.TemporaryDirectory() as d:
            off = 0
            for k, L in enumerate(lengths):
                np.save(Path(d) / f"train_{k:04d}.npy", X[off : off + L])
                off += L
            best = None
            for _ in range(args.repeat):
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                out = subprocess.run(
                    [bin_, "fit", "--data", d, "--method", "hmm:states=16", "--velocity", "none",
                     "--human", "c0,c1,c2,c3,c4,c5", "--robot", "c6,c7,c8,c9,c10,c11",
                     "--max-iter", str(iters), "--tol", "0", "--threads", "1", "--format", "json"],
                    capture_output=True, text=True, check=True,
                )
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
                rep = json.loads(out.stdout)
                if best is None or cpu < best[0]:
                    best = (cpu, rep)
            cpu, rep = best
            e_steps = len(rep["log_likelihood"])
            rows.append((
                f"the command's fit on the same frames (NPY files, k-bins init, {rep['iterations']} M-steps, {e_steps} E-steps, one thread)",
                "phasekit fit", cpu, rep["fit_seconds"], cpu / e_steps, None,
            ))
    return rows


def bench_gmm(args, rows):
    from sklearn.mixture import GaussianMixture as SK

    from phasekit.mixture import GaussianMixture as PK

    n, K, D, iters = args.frames, 16, 12, 10
    X, _, p = hmm_data(n, K, D, seed=1)
    kw = dict(n_components=K, covariance_type="full", max_iter=iters, tol=0, weights_init=np.full(K, 1 / K), means_init=p[2],
              precisions_init=np.tile(np.eye(D), (K, 1, 1)))
    pk_c, pk_w, pk_m = timed(lambda: PK(**kw).fit(X), args.repeat)
    sk_c, sk_w, sk_m = timed(lambda: SK(**kw).fit(X), args.repeat)
    assert abs(pk_m.lower_bound_ / sk_m.lower_bound_ - 1) < 1e-8
    name = f"GaussianMixture(16, 'full').fit, {n:.0e} frames, D = 12, 10 iterations"
    rows.append((name, "phasekit", pk_c, pk_w, pk_c / iters, 1.0))
    rows.append((name, "scikit-learn", sk_c, sk_w, sk_c / iters, sk_c / pk_c))
    return rows


def bench_online(args, rows):
    from phasekit import InteractionModel

    rng = np.random.default_rng(0)
    demos = []
    for _ in range(8):
        t = np.linspace(0, 1, 150)[:, None]
        h = np.hstack([np.sin(3 * t), np.cos(2 * t), t]) + rng.normal(scale=0.01, size=(150, 3))
        demos.append(np.hstack([h, 0.9 * h + 0.05]))
    for method in ("hmm:states=7", "tsc-hmm"):
        model = InteractionModel(method).fit(demos, human=[0, 1, 2], robot=[3, 4, 5])
        online = model.online()
        frames = [np.ascontiguousarray(d[:, :3][t]) for d in demos for t in range(150)]
        n = 20000
        for label, step in (("step(frame)", online.step), ("step_with_covariance(frame)", online.step_with_covariance)):
            def loop():
                for i in range(n):
                    step(frames[i % len(frames)])
            c, w, _ = timed(loop, args.repeat)
            rows.append((f"online {label}, {method} ({model.n_states} states, 6 human features with velocities, 6 robot)",
                         "phasekit", None, w / n * 1e6, None, None))
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--phasekit-bin", default=str(Path(__file__).resolve().parents[2] / "target" / "release" / "phasekit"))
    args = ap.parse_args()
    rows = []
    bench_hmm(args, rows)
    bench_gmm(args, rows)
    bench_online(args, rows)
    import platform

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; python {sys.version.split()[0]}")
    print()
    print("| workload | library | CPU (s) | wall (s) | CPU per iteration (s) | × phasekit |")
    print("|---|---|---:|---:|---:|---:|")
    for w, lib, c, wall, per, ratio in rows:
        f = lambda v, fmt: "–" if v is None else format(v, fmt)  # noqa: E731
        if "online" in w:
            print(f"| {w} | {lib} | – | {wall:.2f} µs per call | – | – |")
        else:
            print(f"| {w} | {lib} | {f(c, '.3f')} | {f(wall, '.3f')} | {f(per, '.4f')} | {f(ratio, '.1f')} |")


if __name__ == "__main__":
    main()
