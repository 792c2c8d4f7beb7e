#!/usr/bin/env python3
"""Time hmmlearn 0.3.3 and scikit-learn 1.5.2 on the workloads that
``bench_compare run DIR`` wrote (manifest.json + raw f64 files), read
phasekit's timings from DIR/phasekit.json, check that the log-likelihoods
agree and print a table of per-iteration times and ratios.

Run through ``benches/compare/run.sh`` (pinned virtualenv, one thread).

Conventions (identical on both sides):
* hmmlearn GaussianHMM, ``init_params=""``, ``params="stmc"``, ``tol=-inf``,
  ``startprob_prior = transmat_prior = 1``, ``means_weight = 0`` and
  ``covars_prior = ψ I``, ``covars_weight = 2D + 1``: exactly phasekit's
  inverse-Wishart MAP step ``Σ = (S + ψ I) / (n + D + 1)``
  (``ψ = 0``: maximum likelihood).
* Per-iteration time = fit time / n_iter. hmmlearn's fit does n_iter E- and
  M-steps; phasekit's ``fit_from`` does one more E-step (it scores the
  returned model), which is charged to phasekit.
* scikit-learn GaussianMixture with ``weights_init``, ``means_init``,
  ``precisions_init`` (inverse of the initial covariances), ``tol=0``,
  ``reg_covar`` = phasekit's ``add_diagonal``, ``init_params="random_from_data"``
  (the cheapest; the supplied parameters override it). Its fit, like
  phasekit's ``fit_from``, does n_iter M-steps and n_iter + 1 E-steps.
"""

import json
import os
import sys
import time
import warnings
import logging

import numpy as np

from hmmlearn import hmm
import hmmlearn
import sklearn
from sklearn.mixture import GaussianMixture

logging.getLogger("hmmlearn").setLevel(logging.ERROR)
warnings.filterwarnings("ignore")

TARGET_LOG = 30.0
TARGET_SCALING = 15.0
TARGET_SKLEARN = 5.0


def load(dirname, w):
    x = np.fromfile(os.path.join(dirname, w["file"]), dtype="<f8")
    return x.reshape(-1, w["dim"])


def time_median(fn, min_reps=1, max_reps=5, budget=3.0):
    """Median process CPU seconds (and wall seconds) of one call of fn, and its last result."""
    cpu, wall, out = [], [], None
    start = time.perf_counter()
    while len(cpu) < min_reps or (time.perf_counter() - start < budget and len(cpu) < max_reps):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    return float(np.median(cpu)), out


def hmm_model(w, implementation, n_iter):
    s, d = w["n_states"], w["dim"]
    p = w["init"]
    ct = w["covariance_type"]
    psi = w["iw_scale"]
    kw = dict(n_components=s, covariance_type=ct, n_iter=n_iter, tol=-np.inf,
              init_params="", params="stmc", implementation=implementation,
              startprob_prior=1.0, transmat_prior=1.0, means_prior=0.0, means_weight=0.0)
    if ct == "full":
        kw["covars_prior"] = np.broadcast_to(psi * np.eye(d), (s, d, d)).copy()
        kw["covars_weight"] = 2 * d + 1
    else:  # diag, 1-D small workloads: maximum likelihood (ψ = 0)
        assert psi == 0.0
        kw["covars_prior"] = 0.0
        kw["covars_weight"] = 1.0
    m = hmm.GaussianHMM(**kw)
    m.startprob_ = np.array(p["start"])
    m.transmat_ = np.array(p["transmat"]).reshape(s, s)
    m.means_ = np.array(p["means"]).reshape(s, d)
    covs = np.array(p["covars_full"]).reshape(s, d, d)
    m.covars_ = covs if ct == "full" else np.array([np.diag(c) for c in covs])
    return m


def rel(a, b):
    return abs(a - b) / max(abs(b), 1e-300)


def run_hmm(dirname, w, pk, cap):
    x = load(dirname, w)
    lengths = np.array(w["lengths"])
    n_iter = w["n_iter"]
    n_run = min(n_iter, cap) if cap else n_iter
    out = {}
    for impl in ("log", "scaling"):
        budget = 3.0 if w["kind"] == "small" else 0.0
        def fit():
            m = hmm_model(w, impl, n_run)
            m.fit(x, lengths)
            return m
        secs, m = time_median(fit, budget=budget)
        hist = list(m.monitor_.history)
        diffs = [rel(a, b) for a, b in zip(pk["ll_history"], hist)]
        out[impl] = {"per_iter_s": secs / n_run, "n_iter_run": n_run,
                     "max_rel_ll_diff": max(diffs), "final_ll": hist[-1]}
        if w["kind"] == "small":
            m0 = hmm_model(w, impl, 1)
            m0.n_features = 1
            f_s, ll = time_median(lambda: m0.score(x, lengths), 5, 200, 1.0)
            fb_s, _ = time_median(lambda: m0.predict_proba(x, lengths), 5, 200, 1.0)
            v_s, (vlp, _) = time_median(lambda: m0.decode(x, lengths, algorithm="viterbi"), 5, 200, 1.0)
            out[impl].update({"forward_s": f_s, "forward_backward_s": fb_s, "viterbi_s": v_s,
                              "init_ll_rel_diff": rel(pk["init_ll"], ll),
                              "viterbi_rel_diff": rel(pk["viterbi_logprob"], vlp)})
    return out


def run_gmm(dirname, w, pk):
    x = load(dirname, w)
    k, d, n_iter = w["n_components"], w["dim"], w["n_iter"]
    p = w["init"]
    covs = np.array(p["covars_full"]).reshape(k, d, d)
    precs = np.array([np.linalg.inv(c) for c in covs])
    precs = 0.5 * (precs + precs.transpose(0, 2, 1))

    def fit():
        g = GaussianMixture(n_components=k, covariance_type="full", tol=0.0, max_iter=n_iter,
                            n_init=1, reg_covar=w["reg_covar"], init_params="random_from_data",
                            weights_init=np.array(p["weights"]),
                            means_init=np.array(p["means"]).reshape(k, d),
                            precisions_init=precs, random_state=0)
        g.fit(x)
        return g
    secs, g = time_median(fit, budget=3.0)
    n = x.shape[0]
    # lower_bound_ is the mean log-likelihood of the last E-step, i.e. under the
    # parameters after n_iter - 1 M-steps: phasekit's ll_history[n_iter - 1] / N.
    d_ll = rel(pk["ll_history"][n_iter - 1] / n, g.lower_bound_)
    return {"per_iter_s": secs / n_iter, "max_rel_ll_diff": d_ll, "n_iter_run": n_iter}


def fmt_ms(s):
    return f"{s * 1e3:.3f}" if s < 10 else f"{s:.1f} s"


def main():
    dirname = sys.argv[1]
    cap = int(os.environ.get("PHASEKIT_COMPARE_HMMLEARN_ITERS", "0"))
    man = json.load(open(os.path.join(dirname, "manifest.json")))
    pkres = json.load(open(os.path.join(dirname, "phasekit.json")))
    pk_by = {r["name"]: r for r in pkres["results"]}
    lines = []
    emit = lambda s="": (print(s, flush=True), lines.append(s))
    emit(f"hmmlearn {hmmlearn.__version__}, scikit-learn {sklearn.__version__}, numpy {np.__version__}; "
         f"OMP/OPENBLAS/MKL threads = {os.environ.get('OPENBLAS_NUM_THREADS')}, "
         f"RAYON_NUM_THREADS = {os.environ.get('RAYON_NUM_THREADS')}")
    emit(f"single-core dgemm peak (nalgebra 1024x1024): {pkres['peak_gflops']:.1f} GFLOP/s")
    emit()
    emit("### Baum-Welch, per iteration (ms), one thread")
    emit()
    emit("| workload | frames | S | D | phasekit | GFLOP/s | hmmlearn log | × | hmmlearn scaling | × | max rel. Δ log-lik (log / scaling) |")
    emit("|---|---|---|---|---|---|---|---|---|---|---|")
    small = []
    gmm = []
    for w in man["workloads"]:
        pk = pk_by[w["name"]]
        if w["kind"] == "gmm":
            gmm.append((w, pk, run_gmm(dirname, w, pk)))
            continue
        r = run_hmm(dirname, w, pk, cap)
        if w["kind"] == "small":
            small.append((w, pk, r))
            continue
        p = pk["per_iter_s"]
        lg, sc = r["log"]["per_iter_s"], r["scaling"]["per_iter_s"]
        ok = "" if lg / p >= TARGET_LOG and sc / p >= TARGET_SCALING else " (target missed)"
        emit(f"| {w['name']} | {sum(w['lengths'])} | {w['n_states']} | {w['dim']} | {fmt_ms(p)} | "
             f"{pk['gflops']:.1f} | {fmt_ms(lg)} | **{lg / p:.1f}**{ok} | {fmt_ms(sc)} | **{sc / p:.1f}** | "
             f"{r['log']['max_rel_ll_diff']:.1e} / {r['scaling']['max_rel_ll_diff']:.1e} |")
    if small:
        emit()
        emit("### HiddenMarkovModels.jl configuration (50 × 100 frames, 1-D), whole data set (µs)")
        emit()
        emit("| K | op | phasekit | hmmlearn log | × | hmmlearn scaling | × |")
        emit("|---|---|---|---|---|---|---|")
        for w, pk, r in small:
            for op, key in (("forward", "forward_s"), ("forward-backward", "forward_backward_s"),
                            ("Viterbi", "viterbi_s"), ("Baum-Welch iteration", "per_iter_s")):
                a, b, c = pk[key], r["log"][key], r["scaling"][key]
                emit(f"| {w['n_states']} | {op} | {a * 1e6:.1f} | {b * 1e6:.1f} | {b / a:.1f} | {c * 1e6:.1f} | {c / a:.1f} |")
        worst = max(max(r["log"]["max_rel_ll_diff"], r["scaling"]["max_rel_ll_diff"],
                        r["log"]["init_ll_rel_diff"], r["log"]["viterbi_rel_diff"]) for _, _, r in small)
        emit()
        emit(f"largest relative difference of a log-likelihood / Viterbi log-probability: {worst:.1e}")
    if gmm:
        emit()
        emit("### GMM EM vs scikit-learn GaussianMixture, per iteration (ms), one thread")
        emit()
        emit("| workload | N | K | D | phasekit | GFLOP/s | sklearn | × | rel. Δ lower bound |")
        emit("|---|---|---|---|---|---|---|---|---|")
        for w, pk, r in gmm:
            p, s = pk["per_iter_s"], r["per_iter_s"]
            ok = "" if s / p >= TARGET_SKLEARN else " (target missed)"
            emit(f"| {w['name']} | {w['n_samples']} | {w['n_components']} | {w['dim']} | {fmt_ms(p)} | "
                 f"{pk['gflops']:.1f} | {fmt_ms(s)} | **{s / p:.1f}**{ok} | {r['max_rel_ll_diff']:.1e} |")
    with open(os.path.join(dirname, "table.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
