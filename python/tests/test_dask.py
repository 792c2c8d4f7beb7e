"""The Dask fit on a LocalCluster(n_workers=2) equals the in-process fit."""

import numpy as np
import pytest

pytest.importorskip("dask.bag")
distributed = pytest.importorskip("distributed")

import dask.bag as db  # noqa: E402

from conftest import gaussian_sequences  # noqa: E402
from phasekit import dask as pkdask  # noqa: E402
from phasekit import hmm  # noqa: E402
from phasekit.mixture import GaussianMixture  # noqa: E402


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


def sequences(seed=0, n=24):
    rng = np.random.default_rng(seed)
    X, lengths = gaussian_sequences(seed, n_states=3, dim=3, lengths=tuple(int(v) for v in rng.integers(40, 120, size=n)))
    return np.split(X, np.cumsum(lengths)[:-1]), lengths, X


def rel(a, b):
    return np.max(np.abs(a - b) / np.maximum(np.abs(a), 1e-300))


@pytest.mark.parametrize("kind", ["full", "diag"])
@pytest.mark.parametrize("npartitions", [1, 3, 7])
def test_hmm_dask_fit_equals_local_fit(client, kind, npartitions):
    seqs, lengths, X = sequences()
    local = hmm.GaussianHMM(3, kind, random_state=0, n_iter=8, tol=-np.inf).fit(X, lengths)
    bag = db.from_sequence(seqs, npartitions=npartitions)
    remote = pkdask.fit(hmm.GaussianHMM(3, kind, random_state=0, n_iter=8, tol=-np.inf), bag)
    assert remote.monitor_.iter == local.monitor_.iter
    assert rel(np.array(local.monitor_.history), np.array(remote.monitor_.history)) < 1e-9
    for name in ("startprob_", "transmat_", "means_", "_covars_"):
        assert rel(getattr(local, name), getattr(remote, name)) < 1e-9, name
    assert abs(remote.score(X, lengths) / local.score(X, lengths) - 1) < 1e-9


def test_other_hmms_on_dask(client):
    rng = np.random.default_rng(1)
    seqs = [rng.integers(0, 4, size=(int(n), 1)) for n in rng.integers(30, 80, size=10)]
    X = np.concatenate(seqs)
    lengths = [len(s) for s in seqs]
    local = hmm.CategoricalHMM(3, random_state=0, n_iter=5).fit(X, lengths)
    remote = pkdask.fit(hmm.CategoricalHMM(3, random_state=0, n_iter=5), db.from_sequence(seqs, npartitions=3))
    assert rel(local.emissionprob_, remote.emissionprob_) < 1e-9
    seqs = [rng.poisson(3, size=(int(n), 2)) for n in rng.integers(30, 80, size=10)]
    X = np.concatenate(seqs)
    local = hmm.PoissonHMM(2, random_state=0, n_iter=5).fit(X, [len(s) for s in seqs])
    remote = pkdask.fit(hmm.PoissonHMM(2, random_state=0, n_iter=5), db.from_sequence(seqs, npartitions=4))
    assert rel(local.lambdas_, remote.lambdas_) < 1e-9


def test_mixture_dask_fit_equals_local_fit(client):
    seqs, _, X = sequences(2)
    local = GaussianMixture(3, random_state=0, max_iter=20, tol=0).fit(X)
    remote = pkdask.fit(GaussianMixture(3, random_state=0, max_iter=20, tol=0), db.from_sequence(seqs, npartitions=5))
    assert abs(local.lower_bound_ / remote.lower_bound_ - 1) < 1e-9
    assert rel(local.means_, remote.means_) < 1e-9
    assert rel(local.covariances_, remote.covariances_) < 1e-9


def test_statistics_merge_in_any_grouping_and_pickle():
    """The statistics of parts merge to those of the whole (exact algebra: only rounding differs)."""
    import pickle

    from phasekit import _core

    seqs, lengths, X = sequences(3, n=9)
    m = hmm.GaussianHMM(3, "full", random_state=0, n_iter=2).fit(X, lengths)
    core = m._to_core()
    whole = core.expected_statistics(_core.Sequences(X, lengths)).arrays()
    parts = [core.expected_statistics(_core.Sequences(np.ascontiguousarray(s))) for s in seqs]
    parts = [pickle.loads(pickle.dumps(p)) for p in parts]
    assert len(pickle.dumps(parts[0])) < 4000  # compact: a few kB whatever the frames
    merged = _core.Statistics.merge_all(parts).arrays()
    for key in ("start", "trans", "post", "sum", "sum_sq"):
        assert rel(whole[key], merged[key]) < 1e-9 or np.allclose(whole[key], merged[key], atol=1e-9), key
    assert merged["n_frames"] == len(X) and merged["n_sequences"] == len(seqs)
    with pytest.raises(ValueError, match="not phasekit statistics"):
        _core.Statistics.from_bytes(b"garbage")
