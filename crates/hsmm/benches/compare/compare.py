#!/usr/bin/env python3
"""Time hmmlearn's state-expanded HSMM and pbdlib's HSMM forward variable on
the workloads that ``hsmm_compare run DIR`` wrote (manifest.json + raw f64
files), check that they compute what phasekit computes, and print a table
with phasekit's timings (recorded in the manifest).

Run through ``crates/hsmm/benches/compare/run.sh`` (one thread, its own
virtual environment).

* hmmlearn: the HSMM as a GaussianHMM on ``S · D`` states ``(j, r)``, ``r``
  frames left in the segment (the method of hmmlearn's HSMM pull request
  #582, which runs its forward/backward kernels on that augmented model):
  start ``π_j p_j(r)``, ``(j, r) → (j, r − 1)``, ``(j, 1) → (k, r)`` with
  ``a_jk p_k(r)``, every ``(j, ·)`` emitting ``b_j``. Its likelihood is the
  right-censored HSMM's, checked against phasekit's. Timed: ``score``
  (forward), ``score_samples`` (forward-backward, posteriors) and ``fit``
  with one iteration (one E-step and M-step), ``implementation="log"``.
* pbdlib-python (not on PyPI; used when ``import pbdlib`` works): its HSMM
  forward variable, the loop of ``HSMM.forward_variable`` (``_fwd_init``,
  then ``_fwd_step`` per frame) with its own ``obs_likelihood``; the
  duration table ``Pd`` is pbdlib's own formula with the workload's
  parameters (``N(d − 1; μ − 1, σ²)`` normalised on ``d = 1..D``, checked
  against phasekit's pmf). ``forward_variable`` itself cannot be called on
  NumPy ≥ 1.12 (it sizes arrays with the float ``np.round(4 T / S)``), so
  the loop is called directly with ``nbD = D``. Its filtered marginals are
  compared with phasekit's; pbdlib-python's ``_fwd_step`` starts the next
  segments from ``Trans_Pdᵀ ALPHA[:, 0]`` where pbdlib's MATLAB original
  (``demo_HSMM``) uses ``E = bmx .* ALPHA(:, 1)``, the ending segments
  weighted by the current frame's emission, so the two differ by design of
  that port; the maximum difference is reported.
"""

import json
import logging
import os
import platform
import sys
import time
import warnings

import numpy as np

warnings.filterwarnings("ignore")
logging.getLogger("hmmlearn").setLevel(logging.ERROR)

ALL = os.environ.get("HSMM_COMPARE_ALL") == "1"
MAX_EXPANDED = 400


def load(dirname, w):
    x = np.fromfile(os.path.join(dirname, w["file"]), dtype="<f8")
    return x.reshape(-1, w["dim"])


def time_median(fn, min_reps=1, max_reps=5, budget=3.0):
    """Median process CPU seconds of one call of fn, and its last result."""
    cpu, out = [], None
    start = time.perf_counter()
    while len(cpu) < min_reps or (time.perf_counter() - start < budget and len(cpu) < max_reps):
        c0 = time.process_time()
        out = fn()
        cpu.append(time.process_time() - c0)
    return float(np.median(cpu)), out


def duration_pmf(w):
    """The workload's Gaussian durations, p(d) ∝ exp(−(d − μ)² / 2σ²) on d = 1..D."""
    d = np.arange(1, w["max_duration"] + 1)[None, :]
    mu = np.array(w["duration_means"])[:, None]
    sd = np.array(w["duration_stds"])[:, None]
    lp = -0.5 * ((d - mu) / sd) ** 2
    lp -= lp.max(axis=1, keepdims=True)
    p = np.exp(lp)
    return p / p.sum(axis=1, keepdims=True)


def expanded(w, n_iter):
    from hmmlearn import hmm

    s, dm, dim = w["n_states"], w["max_duration"], w["dim"]
    n = s * dm
    pmf = duration_pmf(w)
    a = np.array(w["transition"]).reshape(s, s)
    start = (np.array(w["start"])[:, None] * pmf).reshape(n)
    trans = np.zeros((n, n))
    for j in range(s):
        for r in range(dm):
            row = j * dm + r
            if r > 0:
                trans[row, row - 1] = 1.0
            else:
                trans[row] = (a[j][:, None] * pmf).reshape(n)
    means = np.repeat(np.array(w["means"]).reshape(s, dim), dm, axis=0)
    covars = np.repeat(np.array(w["variances"]).reshape(s, dim), dm, axis=0)
    m = hmm.GaussianHMM(n_components=n, covariance_type="diag", n_iter=n_iter, tol=-np.inf,
                        init_params="", params="stmc", implementation="log")
    m.startprob_ = start
    m.transmat_ = trans
    m.means_ = means
    m.covars_ = covars
    return m


def run_hmmlearn(w, x, lengths):
    m = expanded(w, 1)
    ll = m.score(x, lengths)
    want = w["phasekit"]["log_likelihood"]
    assert abs(ll - want) <= 1e-7 * abs(want), (ll, want)
    fwd, _ = time_median(lambda: m.score(x, lengths))
    fb, _ = time_median(lambda: m.score_samples(x, lengths))
    em, _ = time_median(lambda: expanded(w, 1).fit(x, lengths))
    return {"log_likelihood": ll, "forward_s": fwd, "forward_backward_s": fb, "em_iteration_s": em}


def run_pbdlib(w, x, lengths):
    import pbdlib

    s, dm, dim = w["n_states"], w["max_duration"], w["dim"]
    model = pbdlib.HSMM(nb_states=s, nb_dim=dim)
    model.mu = np.array(w["means"]).reshape(s, dim)
    model.sigma = np.array([np.diag(v) for v in np.array(w["variances"]).reshape(s, dim)])
    model.init_priors = np.array(w["start"])
    model.Trans_Pd = np.array(w["transition"]).reshape(s, s)
    model.Mu_Pd = np.array(w["duration_means"]) - 1.0
    model.Sigma_Pd = np.array(w["duration_stds"]) ** 2
    pd = np.zeros((s, dm))
    for i in range(s):
        pd[i] = pbdlib.multi_variate_normal(np.arange(dm, dtype=float)[:, None], model.Mu_Pd[i],
                                            np.array([[model.Sigma_Pd[i]]]), log=False)
        pd[i] /= pd[i].sum()
    assert np.allclose(pd, duration_pmf(w), rtol=1e-9, atol=1e-300), "duration parametrisation"
    model.Pd = pd
    seqs = np.split(x, np.cumsum(lengths)[:-1])

    def forward(demo):
        p_obs, _ = model.obs_likelihood(demo)
        h = np.zeros((s, demo.shape[0]))
        bmx, alpha, st, h[:, 0] = model._fwd_init(dm, p_obs[:, 0])
        for t in range(1, demo.shape[0]):
            bmx, alpha, st, h[:, t] = model._fwd_step(bmx, alpha, st, dm, p_obs[:, t])
        return h / np.sum(h, axis=0)

    h0 = forward(seqs[0]).T
    ours = np.array(w["phasekit"]["filtered_first_sequence"]).reshape(-1, s)
    diff = float(np.nanmax(np.abs(h0 - ours)))
    fwd, _ = time_median(lambda: [forward(d) for d in seqs])
    return {"forward_s": fwd, "max_filtered_difference": diff,
            "nan": bool(np.isnan(h0).any())}


def ratio(a, b):
    return "–" if a is None or b is None else f"{a / b:,.0f}×"


def ms(v):
    return "–" if v is None else f"{v * 1e3:,.1f}"


def main():
    out = sys.argv[1]
    manifest = json.load(open(os.path.join(out, "manifest.json")))
    import hmmlearn
    import scipy
    print(f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
          f"hmmlearn {hmmlearn.__version__}")
    try:
        import pbdlib  # noqa: F401
        have_pbdlib = True
        print(f"pbdlib from {os.path.dirname(pbdlib.__file__)}")
    except Exception as e:  # pbdlib is optional
        have_pbdlib = False
        print(f"pbdlib not importable ({type(e).__name__}: {e}): skipped")
    rows = []
    for w in manifest["workloads"]:
        x = load(out, w)
        lengths = w["lengths"]
        n_exp = w["n_states"] * w["max_duration"]
        h = run_hmmlearn(w, x, lengths) if (ALL or n_exp <= MAX_EXPANDED) else None
        p = run_pbdlib(w, x, lengths) if have_pbdlib else None
        rows.append((w, h, p))
        print(w["name"], json.dumps({"hmmlearn": h, "pbdlib": p}))
    print()
    print("| workload (S, D, dim, sequences × frames) | expanded states | phasekit forward (ms) | "
          "pbdlib forward (ms) | phasekit is | phasekit forward–backward (ms) | expanded phasekit HMM (ms) | "
          "hmmlearn expanded (ms) | phasekit is | phasekit EM iteration (ms) | expanded phasekit HMM (ms) | "
          "hmmlearn expanded (ms) | phasekit is |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for w, h, p in rows:
        k = w["phasekit"]
        pf = p["forward_s"] if p else None
        hf = h["forward_backward_s"] if h else None
        he = h["em_iteration_s"] if h else None
        print(f"| {w['name']} | {w['n_states'] * w['max_duration']} | {ms(k['forward_s'])} | {ms(pf)} | "
              f"{ratio(pf, k['forward_s'])} | {ms(k['forward_backward_s'])} | "
              f"{ms(k['expanded_hmm_forward_backward_s'])} | {ms(hf)} | {ratio(hf, k['forward_backward_s'])} | "
              f"{ms(k['em_iteration_s'])} | {ms(k['expanded_hmm_em_iteration_s'])} | {ms(he)} | "
              f"{ratio(he, k['em_iteration_s'])} |")
    if have_pbdlib:
        print()
        for w, _, p in rows:
            print(f"{w['name']}: pbdlib filtered marginals differ from phasekit's by at most "
                  f"{p['max_filtered_difference']:.3g} (NaN: {p['nan']})")
    json.dump([{"workload": w["name"], "hmmlearn": h, "pbdlib": p} for w, h, p in rows],
              open(os.path.join(out, "others.json"), "w"), indent=1)


if __name__ == "__main__":
    main()
