"""Gaussian mixture regression: the output dims of a joint model predicted from its input dims.

``GMR(model, input_dims, output_dims)`` takes a fitted joint model over input
and output dims together:

* a Gaussian mixture (:class:`phasekit.mixture.GaussianMixture`, or
  scikit-learn's: anything with ``weights_``, ``means_``, ``covariances_`` and
  ``covariance_type``) gives *static* GMR: every frame's weights are the
  responsibilities of its input values, ``h_k(x_i) ∝ π_k N(x_i; μ_k^i, Σ_k^ii)``;
* a Gaussian HMM (:class:`phasekit.hmm.GaussianHMM`, or hmmlearn's) gives
  *HMM-GMR*: frame ``t``'s weights are the forward (filtered) state
  probabilities of the inputs ``x^i_{1:t}``, so the prediction is causal and
  the online form carries its belief from frame to frame.

In both cases the prediction of frame ``t`` is the mixture of the
conditionals ``E[x_o | x_i, k] = μ_k^o + Σ_k^oi (Σ_k^ii)⁻¹ (x_i − μ_k^i)``
(Cholesky solves, no inverse) and its covariance is the mixture's total
covariance ``Σ_k h_k (Σ_k^o|i + m_k m_kᵀ) − m mᵀ``. A NaN input value is
missing: the conditionals use the observed inputs only.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from . import _core
from ._base import as_frames

__all__ = ["GMR", "GMRPrediction"]

#: A prediction: ``mean`` (T, O), ``covariance`` (T, O, O) or None, ``weights`` (T, K).
GMRPrediction = namedtuple("GMRPrediction", ["mean", "covariance", "weights"])


def _dims(dims, name, n):
    arr = np.asarray(dims)
    if arr.ndim != 1 or arr.size == 0 or not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name} must be a non-empty list of dimension indices, got {dims!r}")
    out = [int(d) for d in arr]
    for d in out:
        if not 0 <= d < n:
            raise ValueError(f"{name}: dimension {d} out of range for a {n}-dimensional model")
    return out


def _core_of(model):
    """The compiled joint model of a fitted mixture or HMM (phasekit's, scikit-learn's or hmmlearn's)."""
    if hasattr(model, "startprob_"):
        if hasattr(model, "_to_core") and type(model).__name__ == "GaussianHMM":
            model._check()
            return _core.GmrCore.from_hmm, model._to_core(), model.n_features
        if not hasattr(model, "covars_") or np.ndim(model.means_) != 2:
            raise ValueError("GMR needs a Gaussian HMM (GaussianHMM) or a Gaussian mixture")
        covars = np.ascontiguousarray(model.covars_, dtype=np.float64)  # full matrices (hmmlearn's getter)
        start = np.asarray(model.startprob_, dtype=np.float64)
        trans = np.asarray(model.transmat_, dtype=np.float64)
        means = np.ascontiguousarray(model.means_, dtype=np.float64)
        core = _core.HmmCore.gaussian(
            start / start.sum(), trans / trans.sum(axis=1, keepdims=True), means, covars, "full", means.shape[1]
        )
        return _core.GmrCore.from_hmm, core, means.shape[1]
    if hasattr(model, "weights_") and hasattr(model, "covariances_"):
        w = np.asarray(model.weights_, dtype=np.float64)
        means = np.ascontiguousarray(model.means_, dtype=np.float64)
        core = _core.GmmCore(
            w / w.sum(),
            means,
            np.ascontiguousarray(model.covariances_, dtype=np.float64),
            model.covariance_type,
            means.shape[1],
        )
        return _core.GmrCore.from_gmm, core, means.shape[1]
    raise ValueError(
        f"GMR needs a fitted Gaussian mixture or Gaussian HMM, got {type(model).__name__} "
        "(is it fitted?)"
    )


class GMR:
    """Gaussian mixture regression of ``output_dims`` on ``input_dims`` under a fitted joint model.

    Parameters
    ----------
    model : GaussianMixture or GaussianHMM
        A fitted joint model (phasekit's, scikit-learn's or hmmlearn's).
    input_dims, output_dims : sequence of int
        The model's dimensions given as input and predicted (disjoint).

    Examples
    --------
    >>> gmm = GaussianMixture(4).fit(np.hstack([human, robot]))   # doctest: +SKIP
    >>> gmr = GMR(gmm, input_dims=[0, 1, 2], output_dims=[3, 4, 5])  # doctest: +SKIP
    >>> mean, cov, _ = gmr.predict(human_test)                    # doctest: +SKIP
    """

    def __init__(self, model, input_dims, output_dims):
        build, core, n = _core_of(model)
        self.input_dims = _dims(input_dims, "input_dims", n)
        self.output_dims = _dims(output_dims, "output_dims", n)
        self._core = build(core, self.input_dims, self.output_dims)

    @property
    def n_inputs(self):
        """Number of input dims."""
        return self._core.n_in

    @property
    def n_outputs(self):
        """Number of output dims."""
        return self._core.n_out

    def predict(self, X, return_covariance=True):
        """Predicts the outputs of input frames ``X``.

        Parameters
        ----------
        X : array-like, shape (n_frames, n_inputs)
            Input values in ``input_dims`` order, one frame per row (one
            sequence, for HMM-GMR); NaN marks a missing value.
        return_covariance : bool
            Also compute the predictive covariances.

        Returns
        -------
        GMRPrediction
            ``mean`` (n_frames, n_outputs), ``covariance`` (n_frames, n_outputs,
            n_outputs) or None, ``weights`` (n_frames, n_components).
        """
        X = as_frames(X, allow_nan=True)
        if X.shape[1] != self.n_inputs:
            raise ValueError(f"X has {X.shape[1]} columns, the regression has {self.n_inputs} input dims")
        mean, cov, weights = self._core.predict(X, return_covariance)
        return GMRPrediction(mean, cov, weights)

    def online(self):
        """A frame-by-frame predictor: ``step(frame)`` returns the output mean,
        ``step_with_covariance(frame)`` ``(mean, covariance)``, ``reset()``
        starts a new sequence."""
        return self._core.online()
