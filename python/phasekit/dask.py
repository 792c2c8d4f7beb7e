"""Baum-Welch and mixture EM over a ``dask.bag`` of sequences.

The E-step's sufficient statistics of disjoint sequences add up, so EM is a
map-reduce. :func:`fit` runs the estimator's own EM loop (the same code as
``estimator.fit``) with an E-step that, at every iteration,

1. ships the current parameters (the estimator, a few kilobytes) to the workers,
2. runs phasekit's E-step (Rust, GIL released) on each partition's sequences,
   which returns compact statistics (phasekit's mergeable statistics in a
   binary form: per state a count, a reference point, a first and a second
   moment, a few kilobytes whatever the number of frames),
3. merges them on the client in partition order, a fixed order, so that the
   result does not depend on the scheduling,

and runs the M-step on the client. The result equals
``estimator.fit(np.concatenate(seqs), lengths)`` to about 1e-12 relative
whatever the partitioning (the merges are exact re-centrings and additions;
only the rounding of the sums depends on how the sequences are grouped).

It works on whatever Dask scheduler is active: the threaded default, a
``distributed.LocalCluster`` on a laptop, ``dask-jobqueue`` on a Slurm cluster.

Example::

    import dask.bag as db
    from distributed import Client, LocalCluster
    from phasekit import hmm, dask as pkdask

    client = Client(LocalCluster(n_workers=2, threads_per_worker=1))
    bag = db.from_sequence(sequences, npartitions=8)       # 2-D arrays, one per sequence
    model = hmm.GaussianHMM(8, "full", n_iter=20)
    pkdask.fit(model, bag)
"""

from __future__ import annotations

import numpy as np

from . import _core
from ._base import as_lengths, n_threads

__all__ = ["fit", "initialisation_sample"]


def _sequences(partition, allow_nan):
    """The sequences of one partition as C-contiguous float64 arrays (validated)."""
    from ._base import as_frames

    return [as_frames(x, allow_nan=allow_nan, name="sequence") for x in partition]


def _hmm_partition_estep(partition, estimator, threads):
    seqs = [estimator._validate_X(x) for x in partition]
    if not seqs:
        return []
    X = np.concatenate(seqs) if len(seqs) > 1 else seqs[0]
    data = _core.Sequences(np.ascontiguousarray(X), [len(s) for s in seqs])
    return [estimator._to_core().expected_statistics(data, threads)]


def _gmm_partition_estep(partition, estimator, threads):
    seqs = _sequences(partition, allow_nan=False)
    if not seqs:
        return []
    X = np.ascontiguousarray(np.concatenate(seqs)) if len(seqs) > 1 else seqs[0]
    if X.shape[1] != estimator.n_features_in_:
        raise ValueError(f"X has {X.shape[1]} features, but GaussianMixture is expecting {estimator.n_features_in_} features as input.")
    return [estimator._core().expected_statistics(_core.Sequences(X), threads)]


def initialisation_sample(bag, max_frames):
    """The first sequences of ``bag`` (in order) holding at most about ``max_frames``
    frames, and their lengths: what :func:`fit` initialises from."""
    taken, total = [], 0
    for part in bag.to_delayed():
        for x in part.compute():
            taken.append(np.asarray(x))
            total += len(taken[-1])
            if total >= max_frames:
                return taken, [len(s) for s in taken]
    if not taken:
        raise ValueError("the bag holds no sequence")
    return taken, [len(s) for s in taken]


def _estep(bag, func, threads):
    import dask

    def estep(est):
        # The estimator is the only thing shipped per iteration (its parameters);
        # dask pickles it once into the graph.
        parts = bag.map_partitions(func, dask.delayed(est, traverse=False), threads).compute()
        if not parts:
            raise ValueError("the bag holds no sequence")
        return _core.Statistics.merge_all(list(parts))

    return estep


def fit(estimator, bag, *, init_frames=1_000_000, persist=True):
    """Fits ``estimator`` on the sequences of a ``dask.bag.Bag``.

    Parameters
    ----------
    estimator : phasekit.hmm.GaussianHMM, GMMHMM, CategoricalHMM, PoissonHMM or phasekit.mixture.GaussianMixture
        An estimator of this package (its parameters and settings as for ``fit``).
    bag : dask.bag.Bag
        One 2-D array (frames × features) per element: a sequence for the HMMs,
        a block of independent frames for the mixture.
    init_frames : int
        The initialisation (k-means means, data covariance, …) uses the first
        sequences of the bag up to this many frames (all of them when the bag
        is smaller: then the fit equals the in-process fit on the concatenated
        sequences). Parameters already set and left out of ``init_params`` are
        not re-initialised.
    persist : bool
        Persist the bag in the workers' memory first (every iteration reads it).

    Returns
    -------
    estimator
        The same estimator, fitted.
    """
    import dask.bag  # noqa: F401  (a clear ImportError when dask is missing)

    if persist:
        bag = bag.persist()
    threads = n_threads(getattr(estimator, "n_jobs", None))
    sample, lengths = initialisation_sample(bag, init_frames)
    if hasattr(estimator, "_fit_restarts"):  # the HMMs
        X = estimator._validate_X(np.concatenate(sample), fitting=True)
        lengths = as_lengths(lengths, X.shape[0])
        estimator._fit_restarts(X, lengths, _estep(bag, _hmm_partition_estep, threads))
        return estimator
    if hasattr(estimator, "_run_em"):  # the mixture
        from .mixture import _validate

        X = _validate(estimator, np.concatenate(sample), reset=True, ensure_min_samples=2)
        estimator._check_parameters(X)
        estimator._run_em(X, _estep(bag, _gmm_partition_estep, threads))
        return estimator
    raise TypeError(f"phasekit.dask.fit fits phasekit's estimators, not {type(estimator).__name__}")
