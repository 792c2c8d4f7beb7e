"""Live parity with hmmlearn 0.3.3: same starting parameters, same fit, same numbers."""

import warnings

import numpy as np
import pytest

hmmlearn_hmm = pytest.importorskip("hmmlearn.hmm")

from conftest import gaussian_sequences, start_params  # noqa: E402
from phasekit import hmm  # noqa: E402

KINDS = ["full", "diag", "spherical", "tied"]
SEEDS = [0, 1, 2]


def rel(a, b):
    return abs(a - b) / max(abs(a), abs(b), 1e-300)


def pair(cls_name, setup, **kwargs):
    out = []
    for module in (hmmlearn_hmm, hmm):
        m = getattr(module, cls_name)(**kwargs)
        setup(m)
        out.append(m)
    return out


def fit_both(models, X, lengths):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for m in models:
            m.fit(X, lengths)


def assert_same_fit(ref, ours, X, lengths, rtol=1e-8):
    assert rel(ref.score(X, lengths), ours.score(X, lengths)) < rtol
    np.testing.assert_array_equal(ref.predict(X, lengths), ours.predict(X, lengths))
    assert list(ref.monitor_.history) == pytest.approx(list(ours.monitor_.history), rel=rtol)
    assert ref.monitor_.converged == ours.monitor_.converged
    assert ref.monitor_.iter == ours.monitor_.iter
    np.testing.assert_allclose(ref.startprob_, ours.startprob_, rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(ref.transmat_, ours.transmat_, rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(ref.predict_proba(X, lengths), ours.predict_proba(X, lengths), atol=1e-8)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", SEEDS)
def test_gaussian_fit_score_predict(kind, seed):
    X, lengths = gaussian_sequences(seed)
    s, t, m, c = start_params(seed, 3, 2, kind)

    def setup(model):
        model.startprob_, model.transmat_, model.means_, model.covars_ = s, t, m, c

    ref, ours = pair("GaussianHMM", setup, n_components=3, covariance_type=kind, init_params="", n_iter=10, tol=1e-6)
    fit_both([ref, ours], X, lengths)
    assert_same_fit(ref, ours, X, lengths)
    np.testing.assert_allclose(ref.means_, ours.means_, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(ref.covars_, ours.covars_, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(ref._covars_, ours._covars_, rtol=1e-8, atol=1e-10)
    assert ref.covars_.shape == ours.covars_.shape and ref._covars_.shape == ours._covars_.shape
    assert rel(ref.aic(X, lengths), ours.aic(X, lengths)) < 1e-8
    assert rel(ref.bic(X, lengths), ours.bic(X, lengths)) < 1e-8
    lp_ref, path_ref = ref.decode(X, lengths, algorithm="map")
    lp, path = ours.decode(X, lengths, algorithm="map")
    np.testing.assert_array_equal(path_ref, path)
    assert rel(lp_ref, lp) < 1e-8
    lp_ref, _ = ref.decode(X, lengths)
    lp, _ = ours.decode(X, lengths)
    assert rel(lp_ref, lp) < 1e-8
    np.testing.assert_allclose(ref._compute_log_likelihood(X), ours._compute_log_likelihood(X), rtol=1e-9)
    np.testing.assert_allclose(ref.get_stationary_distribution(), ours.get_stationary_distribution(), rtol=1e-8)


@pytest.mark.parametrize("kind", KINDS)
def test_gaussian_priors_and_partial_params(kind):
    """Non-default priors and a subset of the parameters re-estimated."""
    X, lengths = gaussian_sequences(7, lengths=(80, 120))
    s, t, m, c = start_params(7, 3, 2, kind)
    for params, extra in [
        ("stmc", dict(means_prior=0.5, means_weight=2.0, covars_prior=0.3, covars_weight=4.0, startprob_prior=2.0, transmat_prior=3.0)),
        ("mc", {}),
        ("st", {}),
        ("smc", dict(covars_prior=0.0, covars_weight=0.0)),
    ]:
        def setup(model):
            model.startprob_, model.transmat_, model.means_, model.covars_ = s, t, m, c

        ref, ours = pair("GaussianHMM", setup, n_components=3, covariance_type=kind, init_params="", params=params, n_iter=6, tol=-np.inf, **extra)
        fit_both([ref, ours], X, lengths)
        assert_same_fit(ref, ours, X, lengths)
        np.testing.assert_allclose(ref._covars_, ours._covars_, rtol=1e-8, atol=1e-10)


def test_structural_zeros_are_kept():
    """A left-right chain stays left-right (hmmlearn keeps zeros of startprob_ and transmat_)."""
    X, lengths = gaussian_sequences(3, lengths=(100, 100))
    trans = np.array([[0.9, 0.1, 0.0], [0.0, 0.9, 0.1], [0.0, 0.0, 1.0]])
    s, _, m, c = start_params(3, 3, 2, "diag")

    def setup(model):
        model.startprob_, model.transmat_, model.means_, model.covars_ = np.array([1.0, 0, 0]), trans, m, c

    ref, ours = pair("GaussianHMM", setup, n_components=3, init_params="", n_iter=8)
    fit_both([ref, ours], X, lengths)
    assert_same_fit(ref, ours, X, lengths)
    assert ours.transmat_[1, 0] == 0 and ours.transmat_[2, 1] == 0 and ours.startprob_[1] == 0


@pytest.mark.parametrize("seed", SEEDS)
def test_categorical(seed):
    rng = np.random.default_rng(seed)
    X = rng.integers(0, 5, size=(400, 1))
    lengths = [150, 250]
    s, t, _, _ = start_params(seed, 3, 1, "diag")
    e = rng.dirichlet(np.ones(5), size=3)

    def setup(model):
        model.startprob_, model.transmat_, model.emissionprob_ = s, t, e

    ref, ours = pair("CategoricalHMM", setup, n_components=3, init_params="", n_iter=10, emissionprob_prior=1.5)
    fit_both([ref, ours], X, lengths)
    assert_same_fit(ref, ours, X, lengths)
    np.testing.assert_allclose(ref.emissionprob_, ours.emissionprob_, rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("seed", SEEDS)
def test_poisson(seed):
    rng = np.random.default_rng(seed)
    X = np.concatenate([rng.poisson(lam, size=(100, 3)) for lam in (1.0, 4.0, 9.0)])
    lengths = [120, 180]
    s, t, _, _ = start_params(seed, 3, 3, "diag")
    lam = rng.uniform(0.5, 10, size=(3, 3))

    def setup(model):
        model.startprob_, model.transmat_, model.lambdas_ = s, t, lam

    ref, ours = pair("PoissonHMM", setup, n_components=3, init_params="", n_iter=10, lambdas_prior=0.5, lambdas_weight=0.1)
    fit_both([ref, ours], X, lengths)
    assert_same_fit(ref, ours, X, lengths)
    np.testing.assert_allclose(ref.lambdas_, ours.lambdas_, rtol=1e-8)


def gmmhmm_case(seed, kind, degenerate=False):
    """Sequences from a sticky HMM whose states are two-component mixtures, and
    starting parameters near the truth (``degenerate``: a random start that
    lets a component collapse)."""
    rng = np.random.default_rng(seed + 50)
    S, M, D = 3, 2, 2
    centres = rng.normal(scale=4.0, size=(S, D))
    offsets = np.array([[-1.5, 0.0], [1.5, 0.0]])
    true_means = centres[:, None, :] + offsets[None]
    X, lengths = gaussian_sequences(seed, lengths=(150, 150))
    if degenerate:
        rng = np.random.default_rng(seed + 50)
        means = rng.normal(scale=3.0, size=(S, M, D))
    else:
        lengths = [200, 200]
        parts = []
        for n in lengths:
            z = np.zeros(n, dtype=int)
            for t in range(1, n):
                z[t] = z[t - 1] if rng.random() < 0.9 else rng.integers(S)
            k = rng.integers(M, size=n)
            parts.append(true_means[z, k] + 0.5 * rng.normal(size=(n, D)))
        X = np.concatenate(parts)
        means = true_means + 0.3 * rng.normal(size=(S, M, D))
    s, t, _, _ = start_params(seed, S, D, "diag")
    covars = {
        "diag": rng.uniform(0.5, 2, size=(S, M, D)),
        "spherical": rng.uniform(0.5, 2, size=(S, M)),
        "full": np.tile(np.eye(D), (S, M, 1, 1)) * rng.uniform(0.5, 2, size=(S, M, 1, 1)),
        "tied": np.tile(np.eye(D), (S, 1, 1)) * rng.uniform(0.5, 2, size=(S, 1, 1)),
    }[kind]

    def setup(model):
        model.startprob_, model.transmat_ = s, t
        model.weights_ = np.full((S, M), 1 / M)
        model.means_, model.covars_ = means, covars

    return X, lengths, setup


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gmmhmm(kind, seed):
    """GMMHMM over many iterations: the components separate as in hmmlearn."""
    X, lengths, setup = gmmhmm_case(seed, kind)
    S, M = 3, 2
    ref, ours = pair("GMMHMM", setup, n_components=S, n_mix=M, covariance_type=kind, init_params="", n_iter=15, tol=-np.inf)
    fit_both([ref, ours], X, lengths)
    assert np.min(ref.covars_) > 0 or kind in ("full", "tied")  # a non-degenerate case
    assert_same_fit(ref, ours, X, lengths, rtol=1e-8)
    np.testing.assert_allclose(ref.weights_, ours.weights_, rtol=1e-6, atol=1e-9)
    # components that lost all weight: hmmlearn zeroes them (a degenerate
    # covariance), phasekit keeps their last parameters; they do not count
    used = ours.weights_ > 0
    np.testing.assert_allclose(ref.means_[used], ours.means_[used], rtol=1e-6, atol=1e-9)
    if kind == "tied":
        np.testing.assert_allclose(ref.covars_, ours.covars_, rtol=1e-6, atol=1e-9)
    else:
        np.testing.assert_allclose(ref.covars_[used], ours.covars_[used], rtol=1e-6, atol=1e-9)
    # the components of a state do separate (they start apart and stay apart)
    assert np.abs(ours.means_[:, 0] - ours.means_[:, 1]).max() > 0.1


def test_gmmhmm_degenerate_component_is_an_error():
    """A component that collapses onto one point: hmmlearn goes on with a zero
    variance ("Degenerate mixture covariance"), phasekit stops with an error
    naming the state and component."""
    X, lengths, setup = gmmhmm_case(1, "diag", degenerate=True)
    ref, ours = pair("GMMHMM", setup, n_components=3, n_mix=2, covariance_type="diag", init_params="", n_iter=15, tol=-np.inf)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref.fit(X, lengths)
    assert np.min(ref.covars_) == 0
    with pytest.raises(ValueError, match="state 1.*not positive"):
        ours.fit(X, lengths)


def test_default_initialisation_draws_hmmlearns_numbers():
    """With n_iter=0, every initial parameter but the k-means means equals hmmlearn's."""
    X, lengths = gaussian_sequences(4)
    for kind in KINDS:
        ref = hmmlearn_hmm.GaussianHMM(3, kind, random_state=11, n_iter=0).fit(X, lengths)
        ours = hmm.GaussianHMM(3, kind, random_state=11, n_iter=0).fit(X, lengths)
        np.testing.assert_array_equal(ref.startprob_, ours.startprob_)
        np.testing.assert_array_equal(ref.transmat_, ours.transmat_)
        np.testing.assert_allclose(ref._covars_, ours._covars_, rtol=1e-12)
        # the means come from a k-means of the same data: the same clusters here
        assert np.abs(np.sort(ref.means_, axis=0) - np.sort(ours.means_, axis=0)).max() < 0.05
    rng = np.random.default_rng(0)
    Xc = rng.integers(0, 4, size=(200, 1))
    ref = hmmlearn_hmm.CategoricalHMM(3, random_state=5, n_iter=0).fit(Xc)
    ours = hmm.CategoricalHMM(3, random_state=5, n_iter=0).fit(Xc)
    np.testing.assert_array_equal(ref.emissionprob_, ours.emissionprob_)
    Xp = rng.poisson(3, size=(200, 2))
    ref = hmmlearn_hmm.PoissonHMM(3, random_state=5, n_iter=0).fit(Xp)
    ours = hmm.PoissonHMM(3, random_state=5, n_iter=0).fit(Xp)
    np.testing.assert_array_equal(ref.lambdas_, ours.lambdas_)


def test_default_fit_with_restarts_is_as_good_as_hmmlearns():
    """From default initialisations (the k-means means come in another order than
    scikit-learn's, so single runs reach other local optima), the best of a few
    restarts is at least as good as hmmlearn's fit."""
    X, lengths = gaussian_sequences(5, lengths=(200, 200, 200))
    for kind in KINDS:
        ref = hmmlearn_hmm.GaussianHMM(3, kind, random_state=0, n_iter=50).fit(X, lengths)
        ours = hmm.GaussianHMM(3, kind, random_state=0, n_iter=50, restarts=5).fit(X, lengths)
        assert ours.score(X, lengths) > ref.score(X, lengths) - 1e-6 * abs(ref.score(X, lengths))


@pytest.mark.parametrize("kind", KINDS)
def test_sample_is_hmmlearns(kind):
    """sample() draws the same NumPy random stream as hmmlearn."""
    s, t, m, c = start_params(9, 3, 2, kind)
    models = []
    for module in (hmmlearn_hmm, hmm):
        model = module.GaussianHMM(3, kind)
        model.startprob_, model.transmat_, model.means_, model.covars_ = s, t, m, c
        model.n_features = 2
        models.append(model)
    Xa, Za = models[0].sample(50, random_state=3)
    Xb, Zb = models[1].sample(50, random_state=3)
    np.testing.assert_array_equal(Za, Zb)
    np.testing.assert_allclose(Xa, Xb, rtol=1e-12)


@pytest.mark.parametrize("name", ["GaussianHMM", "GMMHMM", "CategoricalHMM", "PoissonHMM"])
def test_constructor_is_hmmlearns(name):
    """Every hmmlearn argument exists, in the same position, with the same default."""
    import inspect

    ref = inspect.signature(getattr(hmmlearn_hmm, name).__init__).parameters
    ours = inspect.signature(getattr(hmm, name).__init__).parameters
    ref_names = list(ref)
    assert list(ours)[: len(ref_names)] == ref_names
    for p in ref:
        assert ours[p].default == ref[p].default, p
        assert ours[p].kind == ref[p].kind, p
    extra = [p for p in ours if p not in ref]
    assert extra == ["n_jobs", "allow_missing", "restarts"]
    assert all(ours[p].kind == inspect.Parameter.KEYWORD_ONLY for p in extra)
