"""Frames per second of phasekit.dask.fit on a LocalCluster, against the in-process fit.

    python python/benchmarks/bench_dask.py [--frames 1e6 1e7] [--iterations 3]

A GaussianHMM(8, "full") over D = 6 features, sequences of 1000 frames
generated on the workers (the data never pass through the client), 1 and 2
worker processes of one thread each; the in-process fit (one thread) on the
same sequences is the baseline. Prints a Markdown table.
"""

import argparse
import time

import numpy as np

S, D, L = 8, 6, 1000


def make_sequence(k):
    rng = np.random.default_rng(k)
    means = np.random.default_rng(0).normal(scale=3.0, size=(S, D))
    z = np.repeat(rng.integers(S, size=L // 50), 50)
    return means[z] + rng.normal(size=(L, D))


def model(iterations):
    from phasekit import hmm

    rng = np.random.default_rng(1)
    m = hmm.GaussianHMM(S, "full", init_params="", n_iter=iterations, tol=-np.inf)
    m.startprob_ = np.full(S, 1 / S)
    m.transmat_ = np.full((S, S), 0.02 / (S - 1)) + np.eye(S) * (0.98 - 0.02 / (S - 1))
    m.means_ = np.random.default_rng(0).normal(scale=3.0, size=(S, D)) + rng.normal(scale=0.3, size=(S, D))
    m.covars_ = np.tile(np.eye(D), (S, 1, 1))
    return m


def main():
    import dask.bag as db
    from distributed import Client, LocalCluster, wait

    from phasekit import dask as pkdask

    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=float, nargs="+", default=[1e6, 1e7])
    ap.add_argument("--iterations", type=int, default=3)
    args = ap.parse_args()
    rows = []
    for frames in args.frames:
        n_seq = int(frames) // L
        # in process
        seqs = [make_sequence(k) for k in range(n_seq)]
        X = np.concatenate(seqs)
        del seqs
        m = model(args.iterations)
        t0 = time.perf_counter()
        m.fit(X, [L] * n_seq)
        local = (time.perf_counter() - t0) / args.iterations
        ll = m.monitor_.history[-1]
        del X
        rows.append((n_seq * L, "in process, 1 thread", local, n_seq * L / local, 0.0))
        for workers in (1, 2):
            with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, Client(cluster) as client:
                bag = db.from_sequence(range(n_seq), npartitions=max(8, 4 * workers)).map(make_sequence).persist()
                wait(bag)  # the data are generated in the workers before the clock starts
                client.run(lambda: __import__("phasekit"))  # and phasekit is imported there
                m2 = model(args.iterations)
                t0 = time.perf_counter()
                pkdask.fit(m2, bag, init_frames=0, persist=False)
                per = (time.perf_counter() - t0) / args.iterations
                assert abs(m2.monitor_.history[-1] / ll - 1) < 1e-9
                rows.append((n_seq * L, f"Dask LocalCluster, {workers} worker process{'es' if workers > 1 else ''} × 1 thread", per, n_seq * L / per, per - local))
    print("| frames | where | wall per iteration (s) | frames/s | overhead per iteration vs in process (s) |")
    print("|---:|---|---:|---:|---:|")
    for f, where, per, fps, over in rows:
        print(f"| {f:.0e} | {where} | {per:.3f} | {fps:.3g} | {over:+.3f} |")


if __name__ == "__main__":
    main()
