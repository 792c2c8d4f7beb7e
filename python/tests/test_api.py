"""Shapes, dtypes, layouts, errors, pickling, threads, missing values."""

import pickle

import numpy as np
import pytest

from conftest import gaussian_sequences, start_params
from phasekit import hmm
from phasekit.mixture import GaussianMixture


def fitted(kind="full", **kw):
    X, lengths = gaussian_sequences(0)
    return hmm.GaussianHMM(3, kind, random_state=0, n_iter=5, **kw).fit(X, lengths), X, lengths


def test_float32_noncontiguous_dataframe_and_lists_give_the_same_numbers():
    m, X, lengths = fitted()
    ref = m.score(X, lengths)
    assert m.score(X.astype(np.float32).astype(np.float64), lengths) == m.score(X.astype(np.float32), lengths)
    F = np.asfortranarray(X)
    assert not F.flags.c_contiguous
    assert m.score(F, lengths) == ref
    wide = np.zeros((X.shape[0], 4))
    wide[:, ::2] = X
    assert m.score(wide[:, ::2], lengths) == ref  # a strided view
    assert m.score(X.tolist(), lengths) == ref
    pd = pytest.importorskip("pandas")
    assert m.score(pd.DataFrame(X, columns=["a", "b"]), lengths) == ref
    assert m.score(X, np.array(lengths, dtype=np.int32)) == ref


def test_output_shapes_and_dtypes():
    m, X, lengths = fitted()
    lp, post = m.score_samples(X, lengths)
    assert isinstance(lp, float) and post.shape == (len(X), 3) and post.dtype == np.float64
    np.testing.assert_allclose(post.sum(axis=1), 1.0)
    path = m.predict(X, lengths)
    assert path.shape == (len(X),) and np.issubdtype(path.dtype, np.integer)
    assert m.means_.shape == (3, 2) and m.covars_.shape == (3, 2, 2)
    Xs, Zs = m.sample(7, random_state=0)
    assert Xs.shape == (7, 2) and Zs.shape == (7,)
    assert m.get_stationary_distribution().shape == (3,)


def test_errors_name_what_is_wrong():
    m, X, lengths = fitted()
    bad = X.copy()
    bad[5, 1] = np.nan
    with pytest.raises(ValueError, match="frame 5, column 1"):
        m.score(bad)
    bad[5, 1] = np.inf
    with pytest.raises(ValueError, match="infinity: frame 5, column 1"):
        m.fit(bad)
    with pytest.raises(ValueError, match="doesn't sum to"):
        m.score(X, [10, 20])
    with pytest.raises(ValueError, match="sequence 1 is empty"):
        m.score(X, [len(X), 0])
    with pytest.raises(ValueError, match="2D"):
        m.score(X[:, 0])
    with pytest.raises(ValueError):
        m.score(X[:, :1])  # wrong number of features
    unfitted = hmm.GaussianHMM(3)
    with pytest.raises(Exception, match="not fitted"):
        unfitted.predict(X)
    m2 = hmm.GaussianHMM(2, "full", init_params="")
    m2.startprob_ = np.array([0.5, 0.5])
    m2.transmat_ = np.array([[0.5, 0.5], [0.5, 0.5]])
    m2.means_ = np.zeros((2, 2))
    with pytest.raises(ValueError, match="symmetric, positive-definite"):
        m2.covars_ = np.array([np.eye(2), -np.eye(2)])
    m2.transmat_ = np.array([[0.5, 0.6], [0.5, 0.5]])
    m2.covars_ = np.array([np.eye(2), np.eye(2)])
    with pytest.raises(ValueError, match="transmat_ rows must sum to 1"):
        m2.score(X)
    c = hmm.CategoricalHMM(2, n_features=3, random_state=0)
    with pytest.raises(ValueError, match="Symbols should be integers"):
        c.fit(np.array([[0.5], [1.0]]))
    c.fit(np.array([[0], [1], [2], [1]]))
    with pytest.raises(ValueError, match="frame 1, column 0.*not a symbol"):
        c.score(np.array([[0], [7]]))
    p = hmm.PoissonHMM(2, random_state=0).fit(np.array([[1, 2], [3, 4], [0, 1]]))
    with pytest.raises(ValueError, match="count"):
        p.score(np.array([[1.5, 2.0]]))


def test_impossible_sequence_is_an_error_in_fit():
    X = np.array([[0], [1], [0], [1]])
    m = hmm.CategoricalHMM(2, init_params="", n_features=2)
    m.startprob_ = np.array([1.0, 0.0])
    m.transmat_ = np.array([[1.0, 0.0], [0.0, 1.0]])
    m.emissionprob_ = np.array([[1.0, 0.0], [0.0, 1.0]])
    assert m.score(X) == -np.inf
    with pytest.raises(ValueError, match="probability zero"):
        m.fit(X)


@pytest.mark.parametrize("cls", ["GaussianHMM", "GMMHMM", "CategoricalHMM", "PoissonHMM"])
def test_pickle_round_trip(cls):
    rng = np.random.default_rng(0)
    if cls == "CategoricalHMM":
        X = rng.integers(0, 3, size=(100, 1))
        m = hmm.CategoricalHMM(2, random_state=0, n_iter=3).fit(X)
    elif cls == "PoissonHMM":
        X = rng.poisson(3, size=(100, 2))
        m = hmm.PoissonHMM(2, random_state=0, n_iter=3).fit(X)
    else:
        X, _ = gaussian_sequences(1)
        m = getattr(hmm, cls)(2, random_state=0, n_iter=3).fit(X)
    m2 = pickle.loads(pickle.dumps(m))
    assert m2.score(X) == m.score(X)
    np.testing.assert_array_equal(m2.predict(X), m.predict(X))
    g = GaussianMixture(2, random_state=0).fit(rng.normal(size=(50, 2)))
    g2 = pickle.loads(pickle.dumps(g))
    Y = rng.normal(size=(5, 2))
    assert np.array_equal(g2.score_samples(Y), g.score_samples(Y))


def test_threads_give_bit_identical_fits():
    X, lengths = gaussian_sequences(2, lengths=[3000] * 6)
    a = hmm.GaussianHMM(4, "full", random_state=0, n_iter=5, n_jobs=1).fit(X, lengths)
    b = hmm.GaussianHMM(4, "full", random_state=0, n_iter=5, n_jobs=2).fit(X, lengths)
    assert list(a.monitor_.history) == list(b.monitor_.history)
    assert np.array_equal(a.means_, b.means_) and np.array_equal(a.covars_, b.covars_)
    g1 = GaussianMixture(4, random_state=0, n_jobs=1).fit(X)
    g2 = GaussianMixture(4, random_state=0, n_jobs=-1).fit(X)
    assert g1.lower_bound_ == g2.lower_bound_


def test_missing_values():
    X, lengths = gaussian_sequences(3, lengths=(200, 200))
    full = hmm.GaussianHMM(3, "full", random_state=0, n_iter=20).fit(X, lengths)
    rng = np.random.default_rng(0)
    Xm = X.copy()
    Xm[rng.random(X.shape) < 0.1] = np.nan
    with pytest.raises(ValueError, match="allow_missing"):
        hmm.GaussianHMM(3, "full").fit(Xm, lengths)
    m = hmm.GaussianHMM(3, "full", n_iter=20, allow_missing=True, init_params="")
    m.startprob_, m.transmat_, m.means_, m.covars_ = full.startprob_, full.transmat_, full.means_, full.covars_
    m.fit(Xm, lengths)
    assert np.isfinite(m.score(Xm, lengths))
    # EM on 90 % of the values stays at the complete-data fit's states and close to its means
    assert (m.predict(X, lengths) == full.predict(X, lengths)).mean() > 0.9
    assert np.abs(m.means_ - full.means_).max() < 0.3
    # the default initialisation copes with NaN too
    assert np.isfinite(hmm.GaussianHMM(3, "full", random_state=0, n_iter=5, allow_missing=True).fit(Xm, lengths).score(Xm, lengths))
    # a frame with nothing observed has density 1 under every state: it adds 0 to the score
    one = X[:1].copy()
    one[:] = np.nan
    assert m.score(one) == 0.0


def test_restarts_keep_the_best_run():
    X, lengths = gaussian_sequences(5, lengths=(200, 200, 200))
    single = [hmm.GaussianHMM(3, "full", random_state=s, n_iter=30).fit(X, lengths).score(X, lengths) for s in range(1)]
    best = hmm.GaussianHMM(3, "full", random_state=0, n_iter=30, restarts=4).fit(X, lengths)
    assert best.score(X, lengths) >= max(single) - 1e-9


def test_get_set_params_and_clone():
    sklearn_base = pytest.importorskip("sklearn.base")
    m = hmm.GaussianHMM(3, "tied", n_jobs=2, restarts=2)
    c = sklearn_base.clone(m)
    assert c.get_params() == m.get_params()
    assert "n_jobs=2" in repr(m)
