"""Gaussian mixture regression against the textbook conditional formulas."""

import numpy as np
import pytest

from conftest import gaussian_sequences
from phasekit import hmm
from phasekit.gmr import GMR
from phasekit.mixture import GaussianMixture


def conditional(mean, cov, i, o, x):
    Sii = cov[np.ix_(i, i)]
    Soi = cov[np.ix_(o, i)]
    m = mean[o] + Soi @ np.linalg.solve(Sii, x - mean[i])
    C = cov[np.ix_(o, o)] - Soi @ np.linalg.solve(Sii, Soi.T)
    return m, C


def gauss(x, m, C):
    d = x - m
    return np.exp(-0.5 * d @ np.linalg.solve(C, d)) / np.sqrt(np.linalg.det(2 * np.pi * C))


def test_static_gmr_matches_the_formula():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(400, 4)) @ rng.normal(size=(4, 4)) + rng.integers(0, 3, size=(400, 1)) * 3
    g = GaussianMixture(3, random_state=0).fit(X)
    i, o = [0, 2], [1, 3]
    gmr = GMR(g, i, o)
    Xi = X[:20][:, i]
    p = gmr.predict(Xi)
    for t in range(20):
        w = np.array([g.weights_[k] * gauss(Xi[t], g.means_[k][i], g.covariances_[k][np.ix_(i, i)]) for k in range(3)])
        w /= w.sum()
        parts = [conditional(g.means_[k], g.covariances_[k], i, o, Xi[t]) for k in range(3)]
        mean = sum(w[k] * parts[k][0] for k in range(3))
        cov = sum(w[k] * (parts[k][1] + np.outer(parts[k][0], parts[k][0])) for k in range(3)) - np.outer(mean, mean)
        np.testing.assert_allclose(p.mean[t], mean, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(p.covariance[t], cov, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(p.weights[t], w, rtol=1e-9, atol=1e-14)


def test_hmm_gmr_online_equals_batch_and_uses_filtered_weights():
    X, lengths = gaussian_sequences(1, dim=4, lengths=(300,))
    m = hmm.GaussianHMM(3, "full", random_state=0, n_iter=10).fit(X, lengths)
    gmr = GMR(m, [0, 1], [2, 3])
    p = gmr.predict(X[:, :2])
    online = gmr.online()
    for t in range(50):
        mean, cov = online.step_with_covariance(X[t, :2])
        np.testing.assert_array_equal(mean, p.mean[t])
        np.testing.assert_array_equal(cov, p.covariance[t])
    # the weights are the forward (filtered) probabilities of the input marginal
    sub = hmm.GaussianHMM(3, "full", init_params="")
    sub.startprob_, sub.transmat_ = m.startprob_, m.transmat_
    sub.means_, sub.covars_ = m.means_[:, :2], m.covars_[:, :2, :2]
    for t in (0, 10, 49):
        _, post = sub.score_samples(X[: t + 1, :2])
        np.testing.assert_allclose(p.weights[t], post[-1], rtol=1e-8, atol=1e-12)


def test_gmr_accepts_sklearn_and_hmmlearn_models():
    sk = pytest.importorskip("sklearn.mixture")
    hl = pytest.importorskip("hmmlearn.hmm")
    rng = np.random.default_rng(2)
    X = rng.normal(size=(200, 3))
    g = sk.GaussianMixture(2, covariance_type="diag", random_state=0).fit(X)
    assert GMR(g, [0], [1, 2]).predict(X[:5, :1]).mean.shape == (5, 2)
    h = hl.GaussianHMM(2, "diag", random_state=0, n_iter=3).fit(X)
    assert GMR(h, [0, 1], [2]).predict(X[:5, :2]).mean.shape == (5, 1)
    with pytest.raises(ValueError, match="out of range"):
        GMR(g, [0], [5])
    with pytest.raises(ValueError, match="repeated|disjoint|both|overlap|dimension"):
        GMR(g, [0], [0])
