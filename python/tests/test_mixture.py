"""Live parity with scikit-learn's GaussianMixture, and its estimator checks."""

import warnings

import numpy as np
import pytest

sk_mixture = pytest.importorskip("sklearn.mixture")

from phasekit.mixture import GaussianMixture  # noqa: E402

KINDS = ["full", "diag", "spherical", "tied"]


def data(seed, k=3, d=3, n=200):
    rng = np.random.default_rng(seed)
    centres = rng.normal(scale=4.0, size=(k, d))
    return np.concatenate([c + rng.normal(size=(n, d)) for c in centres])


def inits(seed, kind, k=3, d=3):
    rng = np.random.default_rng(seed + 100)
    w = rng.dirichlet(np.ones(k) * 5)
    m = rng.normal(scale=4.0, size=(k, d))
    p = {
        "full": np.tile(np.eye(d), (k, 1, 1)) * rng.uniform(0.5, 2, size=(k, 1, 1)),
        "diag": rng.uniform(0.5, 2, size=(k, d)),
        "spherical": rng.uniform(0.5, 2, size=k),
        "tied": np.eye(d) * 1.3,
    }[kind]
    return dict(weights_init=w, means_init=m, precisions_init=p)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("max_iter", [1, 10, 200])
def test_parity_with_sklearn(kind, seed, max_iter):
    X = data(seed)
    kw = dict(n_components=3, covariance_type=kind, max_iter=max_iter, reg_covar=1e-4, **inits(seed, kind))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = sk_mixture.GaussianMixture(**kw).fit(X)
        ours = GaussianMixture(**kw).fit(X)
    assert ours.n_iter_ == ref.n_iter_
    assert ours.converged_ == ref.converged_
    assert ours.lower_bound_ == pytest.approx(ref.lower_bound_, rel=1e-8)
    for name in ("weights_", "means_", "covariances_", "precisions_", "precisions_cholesky_"):
        # scikit-learn's diagonal variances come from raw moments (E[x²] − μ²), which
        r = getattr(ref, name)
        # lose digits to cancellation (8.5e-7 relative on a component holding
        # 2e-5 of a frame, test_centred_variances_are_the_accurate_ones);
        # phasekit's are centred. The log-likelihoods agree to 1e-8.
        np.testing.assert_allclose(getattr(ours, name), r, rtol=2e-6, atol=1e-9 * np.abs(r).max(), err_msg=name)
        assert getattr(ours, name).shape == getattr(ref, name).shape
    np.testing.assert_allclose(ours.score_samples(X), ref.score_samples(X), rtol=1e-8)
    np.testing.assert_allclose(ours.predict_proba(X), ref.predict_proba(X), atol=1e-7)
    np.testing.assert_array_equal(ours.predict(X), ref.predict(X))
    assert ours.bic(X) == pytest.approx(ref.bic(X), rel=1e-9)
    assert ours.aic(X) == pytest.approx(ref.aic(X), rel=1e-9)
    assert ours.score(X) == pytest.approx(ref.score(X), rel=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_sample_is_sklearns(kind):
    X = data(3)
    kw = dict(n_components=3, covariance_type=kind, max_iter=5, random_state=4, **inits(3, kind))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = sk_mixture.GaussianMixture(**kw).fit(X)
        ours = GaussianMixture(**kw).fit(X)
    Xa, ya = ref.sample(40)
    Xb, yb = ours.sample(40)
    np.testing.assert_array_equal(ya, yb)
    np.testing.assert_allclose(Xa, Xb, rtol=1e-6)


@pytest.mark.parametrize("init", ["random", "random_from_data"])
def test_random_initialisations_are_sklearns(init):
    """The random initialisations draw scikit-learn's NumPy random numbers: same fit."""
    X = data(5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = sk_mixture.GaussianMixture(3, random_state=0, init_params=init, n_init=2, max_iter=30).fit(X)
        ours = GaussianMixture(3, random_state=0, init_params=init, n_init=2, max_iter=30).fit(X)
    assert ours.lower_bound_ == pytest.approx(ref.lower_bound_, rel=1e-8)
    assert ours.n_iter_ == ref.n_iter_
    np.testing.assert_allclose(ours.means_, ref.means_, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("init", ["kmeans", "k-means++"])
def test_kmeans_initialisations_find_the_clusters(init):
    X = data(5)
    ref = sk_mixture.GaussianMixture(3, random_state=0, init_params=init, n_init=3).fit(X)
    ours = GaussianMixture(3, random_state=0, init_params=init, n_init=3).fit(X)
    assert ours.converged_
    assert ours.score(X) > ref.score(X) - 1e-6 * abs(ref.score(X))
    again = GaussianMixture(3, random_state=0, init_params=init, n_init=3).fit(X)
    np.testing.assert_array_equal(again.means_, ours.means_)  # same seed, same numbers


def test_warm_start_continues():
    X = data(6)
    g = GaussianMixture(3, max_iter=2, warm_start=True, random_state=0, tol=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        g.fit(X)
        lb = g.lower_bound_
        g.fit(X)
    assert g.lower_bound_ >= lb


def test_check_estimator():
    from sklearn.utils.estimator_checks import check_estimator

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_estimator(GaussianMixture(n_components=2, max_iter=50))


def test_centred_variances_are_the_accurate_ones():
    """Where phasekit and scikit-learn differ beyond 1e-8 (a nearly empty
    component), phasekit's M-step is the one that agrees with an
    extended-precision M-step from the same responsibilities."""
    X = data(2)
    kw = dict(n_components=3, covariance_type="diag", max_iter=1, reg_covar=1e-4, **inits(2, "diag"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = sk_mixture.GaussianMixture(**kw).fit(X)
        ours = GaussianMixture(**kw).fit(X)
        g = sk_mixture.GaussianMixture(**kw)
        g._check_parameters(X)
        g._initialize_parameters(X, np.random.RandomState(0))
        _, log_resp = g._e_step(X)
    r = np.exp(log_resp).astype(np.longdouble)
    XL = X.astype(np.longdouble)
    nk = r.sum(0) + 10 * np.finfo(float).eps
    mu = (r.T @ XL) / nk[:, None]
    var = np.stack([(r[:, k][:, None] * (XL - mu[k]) ** 2).sum(0) / nk[k] for k in range(3)]) + 1e-4
    err = lambda c: float(np.abs((c - var) / var).max())  # noqa: E731
    assert err(ours.covariances_) < 1e-10
    assert err(ref.covariances_) > 1e-7
