#!/usr/bin/env python3
"""Time hmmlearn, scikit-learn and dynamax (their current releases) on the
workloads that ``bench_compare run DIR`` wrote (manifest.json + raw f64
files), read phasekit's timings from DIR/phasekit.json, check that every
tool starts from the same log-likelihood and print a table of per-iteration
times and ratios.

Run through ``benches/compare/run.sh`` (its own virtualenv, one core).

dynamax (JAX, float64, CPU): ``GaussianHMM`` initialised with the same
parameters; per-iteration time = median CPU time of one call of the EM
step of its ``fit_em`` (E-step vmapped over the sequences, log prior,
M-step), jitted once, after a first call (compilation excluded). Its
priors (Dirichlet 1.1, a weak NIW) are not phasekit's, so only the first
log-likelihood (before any M-step) is compared; the arithmetic per
iteration is the same. dynamax takes a (sequences, T, D) array without a
mask: workloads with sequences of unequal lengths (NuiSI) run per length
group inside one jitted step (see ``run_dynamax``).

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

from functools import partial

import numpy as np

from hmmlearn import hmm
import hmmlearn
import sklearn
from sklearn.mixture import GaussianMixture

try:
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from dynamax.hidden_markov_model import GaussianHMM as DynamaxGaussianHMM
    import importlib.metadata
    DYNAMAX = importlib.metadata.version("dynamax")
except ImportError:  # dynamax not installed: its columns say so
    DYNAMAX = None

logging.getLogger("hmmlearn").setLevel(logging.ERROR)
warnings.filterwarnings("ignore")

TARGET_LOG = 30.0
TARGET_SCALING = 15.0  # (issue 6; issue 18 sets none for scaling)
TARGET_SKLEARN = 5.0
TARGET_DYNAMAX = 10.0
# Which peers to run (comma-separated; default all): e.g. PEERS=dynamax.
PEERS = set(os.environ.get("PEERS", "hmmlearn,sklearn,dynamax").split(","))


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
    if "hmmlearn" not in PEERS:
        return None
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
                     "max_rel_ll_diff": max(diffs), "final_ll": hist[-1],
                     "first_ll_rel_diff": diffs[0]}
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


def run_dynamax(dirname, w, pk):
    """dynamax float64: CPU seconds of one EM iteration (its own E-step and
    M-step, jitted once, compilation excluded) and its first log-likelihood,
    or None where dynamax cannot run the workload.

    dynamax takes a (sequences, T, D) array and has no mask, so sequences of
    unequal lengths (the NuiSI demonstrations) are run per length group: the
    E-step vmapped over the sequences of each length, the groups' statistics
    concatenated along the sequence axis and given to its M-step, all inside
    one jitted step (one compilation for the whole data set, excluded from
    the time). That is what a dynamax user with such data has to write; the
    arithmetic is the same as with equal lengths."""
    lengths = w["lengths"]
    if DYNAMAX is None or "dynamax" not in PEERS or (w["covariance_type"] != "full" and w["dim"] != 1):
        return None
    s, d = w["n_states"], w["dim"]
    x = load(dirname, w)
    groups = {}
    start = 0
    for t in lengths:
        groups.setdefault(t, []).append(x[start:start + t])
        start += t
    xs_groups = [jnp.array(np.stack(v)) for _, v in sorted(groups.items())]
    p = w["init"]
    model = DynamaxGaussianHMM(s, d)
    params, props = model.initialize(
        initial_probs=jnp.array(p["start"]),
        transition_matrix=jnp.array(p["transmat"]).reshape(s, s),
        emission_means=jnp.array(p["means"]).reshape(s, d),
        emission_covariances=jnp.array(p["covars_full"]).reshape(s, d, d))

    # One iteration exactly as dynamax's fit_em does it (its em_step), jitted once;
    # one vmapped E-step per length group.
    @jax.jit
    def em_step(carry, xs_groups):
        params, m_step_state = carry
        parts = [jax.vmap(partial(model.e_step, params))(xs) for xs in xs_groups]
        batch_stats = jax.tree_util.tree_map(lambda *a: jnp.concatenate(a, axis=0), *[b for b, _ in parts])
        ll = sum(lls.sum() for _, lls in parts)
        lp = model.log_prior(params) + ll
        params, m_step_state = model.m_step(params, props, batch_stats, m_step_state)
        return (params, m_step_state), ll, lp

    carry = (params, model.initialize_m_step_state(params, props))
    carry, first_ll, _ = em_step(carry, xs_groups)  # compiles; the log-likelihood of the initial parameters
    first_ll = float(first_ll)
    state = {"carry": carry}

    def one():
        state["carry"], ll, _ = em_step(state["carry"], xs_groups)
        jax.block_until_ready(ll)
    secs, _ = time_median(one, 5, 50, 2.0)
    return {"per_iter_s": secs, "first_ll": first_ll, "length_groups": len(xs_groups),
            "first_ll_rel_diff": rel(first_ll, pk["ll_history"][0])}


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
    import scipy
    emit(f"hmmlearn {hmmlearn.__version__}, scikit-learn {sklearn.__version__}, numpy {np.__version__}, "
         f"scipy {scipy.__version__}, dynamax {DYNAMAX} (JAX {jax.__version__ if DYNAMAX else '-'}, float64); "
         f"OMP/OPENBLAS/MKL threads = {os.environ.get('OPENBLAS_NUM_THREADS')}, "
         f"RAYON_NUM_THREADS = {os.environ.get('RAYON_NUM_THREADS')}")
    emit(f"single-core dgemm peak (nalgebra 1024x1024): {pkres['peak_gflops']:.1f} GFLOP/s")
    emit()
    emit("### Baum-Welch, per iteration (ms), one thread")
    emit()
    emit("| workload | frames | S | D | phasekit | GFLOP/s | hmmlearn log | × | hmmlearn scaling | × | dynamax f64 | × | rel. Δ first log-lik (hmmlearn / dynamax) | max rel. Δ log-lik (hmmlearn log / scaling) |")
    emit("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    small = []
    gmm = []
    for w in man["workloads"]:
        pk = pk_by[w["name"]]
        if w["kind"] == "gmm":
            if "sklearn" in PEERS:
                gmm.append((w, pk, run_gmm(dirname, w, pk)))
            continue
        r = run_hmm(dirname, w, pk, cap)
        if w["kind"] == "small":
            small.append((w, pk, r))
            continue
        p = pk["per_iter_s"]
        dx = run_dynamax(dirname, w, pk)
        if r:
            lg, sc = r["log"]["per_iter_s"], r["scaling"]["per_iter_s"]
            ok = "" if lg / p >= TARGET_LOG else " (target missed)"
            hcol = f"{fmt_ms(lg)} | **{lg / p:.1f}**{ok} | {fmt_ms(sc)} | **{sc / p:.1f}**"
            hll = f"{r['log']['first_ll_rel_diff']:.1e}"
            hmax = f"{r['log']['max_rel_ll_diff']:.1e} / {r['scaling']['max_rel_ll_diff']:.1e}"
        else:
            hcol, hll, hmax = "not run | – | not run | –", "–", "–"
        if dx:
            dxok = "" if dx["per_iter_s"] / p >= TARGET_DYNAMAX else " (target missed)"
            grp = f" ({dx['length_groups']} length groups)" if dx["length_groups"] > 1 else ""
            dcol = f"{fmt_ms(dx['per_iter_s'])}{grp} | **{dx['per_iter_s'] / p:.1f}**{dxok}"
            dll = f"{dx['first_ll_rel_diff']:.1e}"
        else:
            dcol, dll = "not run | –", "–"
        emit(f"| {w['name']} | {sum(w['lengths'])} | {w['n_states']} | {w['dim']} | {fmt_ms(p)} | "
             f"{pk['gflops']:.1f} | {hcol} | {dcol} | {hll} / {dll} | {hmax} |")
    if small:
        emit()
        emit("### HiddenMarkovModels.jl configuration (50 × 100 frames, 1-D), whole data set (µs)")
        emit()
        emit("| K | op | phasekit | hmmlearn log | × | hmmlearn scaling | × | dynamax f64 | × |")
        emit("|---|---|---|---|---|---|---|---|---|")
        for w, pk, r in small:
            dx = run_dynamax(dirname, w, pk)
            for op, key in (("forward", "forward_s"), ("forward-backward", "forward_backward_s"),
                            ("Viterbi", "viterbi_s"), ("Baum-Welch iteration", "per_iter_s")):
                a = pk[key]
                hh = (f"{r['log'][key] * 1e6:.1f} | {r['log'][key] / a:.1f} | "
                      f"{r['scaling'][key] * 1e6:.1f} | {r['scaling'][key] / a:.1f}") if r else "– | – | – | –"
                dd = f"{dx[key] * 1e6:.1f} | {dx[key] / a:.1f}" if dx and key in dx else "– | –"
                emit(f"| {w['n_states']} | {op} | {a * 1e6:.1f} | {hh} | {dd} |")
        if all(r for _, _, r in small):
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
