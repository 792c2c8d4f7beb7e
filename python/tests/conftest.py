"""Shared data generators: small random cases, so that the whole suite runs in seconds."""

import numpy as np
import pytest


def gaussian_sequences(seed, n_states=3, dim=2, lengths=(60, 90, 150)):
    """Sequences from a sticky Gaussian HMM with well separated means."""
    rng = np.random.default_rng(seed)
    means = rng.normal(scale=3.0, size=(n_states, dim))
    out = []
    for n in lengths:
        z = np.zeros(n, dtype=int)
        for t in range(1, n):
            z[t] = z[t - 1] if rng.random() < 0.9 else rng.integers(n_states)
        out.append(means[z] + rng.normal(size=(n, dim)))
    return np.concatenate(out), list(lengths)


def start_params(seed, n_states, dim, kind):
    """Starting parameters shared by hmmlearn and phasekit in the parity tests."""
    rng = np.random.default_rng(seed + 1000)
    startprob = rng.dirichlet(np.ones(n_states))
    transmat = rng.dirichlet(np.ones(n_states) * 2, size=n_states) * 0.4 + np.eye(n_states) * 0.6
    transmat /= transmat.sum(axis=1, keepdims=True)
    means = rng.normal(scale=3.0, size=(n_states, dim))
    if kind == "full":
        a = rng.normal(size=(n_states, dim, dim))
        covars = a @ np.swapaxes(a, 1, 2) + np.eye(dim)
    elif kind == "tied":
        a = rng.normal(size=(dim, dim))
        covars = a @ a.T + np.eye(dim)
    elif kind == "diag":
        covars = rng.uniform(0.5, 2.0, size=(n_states, dim))
    else:
        covars = rng.uniform(0.5, 2.0, size=n_states)
    return startprob, transmat, means, covars


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
