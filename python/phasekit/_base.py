"""Shared plumbing: estimator base class, input validation, random states, threads."""

from __future__ import annotations

import inspect
import numbers
import os

import numpy as np

try:  # scikit-learn is optional: with it, the estimators are scikit-learn estimators.
    from sklearn.base import BaseEstimator as _SkBaseEstimator
    from sklearn.exceptions import NotFittedError as _SkNotFittedError
except ImportError:  # pragma: no cover - exercised only without scikit-learn
    _SkBaseEstimator = None
    _SkNotFittedError = None


if _SkNotFittedError is not None:
    NotFittedError = _SkNotFittedError
else:  # pragma: no cover

    class NotFittedError(ValueError, AttributeError):
        """The estimator is used before it was fitted (scikit-learn's exception when it is installed)."""


if _SkBaseEstimator is not None:
    BaseEstimator = _SkBaseEstimator
else:  # pragma: no cover

    class BaseEstimator:
        """Minimal scikit-learn-style estimator: ``get_params``, ``set_params`` and a repr."""

        @classmethod
        def _get_param_names(cls):
            sig = inspect.signature(cls.__init__)
            return sorted(
                p.name
                for p in sig.parameters.values()
                if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
            )

        def get_params(self, deep=True):
            return {name: getattr(self, name) for name in self._get_param_names()}

        def set_params(self, **params):
            valid = self._get_param_names()
            for key, value in params.items():
                if key not in valid:
                    raise ValueError(
                        f"Invalid parameter {key!r} for estimator {type(self).__name__}; "
                        f"valid parameters are {valid}"
                    )
                setattr(self, key, value)
            return self

        def __repr__(self):
            sig = inspect.signature(type(self).__init__)
            shown = []
            for name in self._get_param_names():
                default = sig.parameters[name].default
                value = getattr(self, name)
                try:
                    same = bool(np.all(value == default))
                except Exception:
                    same = False
                if not same:
                    shown.append(f"{name}={value!r}")
            return f"{type(self).__name__}({', '.join(shown)})"


def check_is_fitted(estimator, attribute):
    """Raises :class:`NotFittedError` unless ``estimator`` has ``attribute``."""
    if not hasattr(estimator, attribute):
        raise NotFittedError(
            f"This {type(estimator).__name__} instance is not fitted yet. Call 'fit' with "
            "appropriate arguments before using this estimator."
        )


def check_random_state(seed):
    """A :class:`numpy.random.RandomState` from ``None``, an int or a RandomState (as scikit-learn's)."""
    if seed is None or seed is np.random:
        return np.random.mtrand._rand
    if isinstance(seed, numbers.Integral):
        return np.random.RandomState(seed)
    if isinstance(seed, np.random.RandomState):
        return seed
    raise ValueError(f"{seed!r} cannot be used to seed a numpy.random.RandomState instance")


def as_frames(X, *, name="X", allow_nan=False, dtype=np.float64, min_rows=1):
    """``X`` as a C-contiguous float64 2-D array (no copy when it already is one).

    float32, integer and non-contiguous arrays are converted once; lists and
    pandas DataFrames are accepted. Infinity is refused, and NaN too unless
    ``allow_nan`` (then it means a missing value). Errors name the frame and
    column.
    """
    if hasattr(X, "to_numpy") and not isinstance(X, np.ndarray):  # pandas
        X = X.to_numpy()
    arr = np.asarray(X)
    if arr.dtype == object:
        try:
            arr = arr.astype(np.float64)
        except (TypeError, ValueError) as e:
            raise ValueError(f"{name}: not an array of numbers ({e})") from None
    if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == np.bool_):
        raise ValueError(f"{name}: expected numbers, got an array of dtype {arr.dtype}")
    if np.iscomplexobj(arr):
        raise ValueError(f"{name}: complex values are not supported")
    if arr.ndim != 2:
        raise ValueError(
            f"Expected 2D array, got {arr.ndim}D array instead: {name} must have shape "
            "(n_samples, n_features); reshape a single feature with X.reshape(-1, 1)"
        )
    if arr.shape[0] < min_rows:
        raise ValueError(
            f"Found array with {arr.shape[0]} sample(s) (shape={arr.shape}) while a minimum "
            f"of {min_rows} is required."
        )
    if arr.shape[1] < 1:
        raise ValueError(f"Found array with 0 feature(s) (shape={arr.shape}) while a minimum of 1 is required.")
    arr = np.ascontiguousarray(arr, dtype=dtype)
    _check_values(arr, name=name, allow_nan=allow_nan)
    return arr


def _check_values(arr, *, name, allow_nan):
    finite = np.isfinite(arr)
    if finite.all():
        return
    bad = ~finite if not allow_nan else np.isinf(arr)
    if not bad.any():
        return
    t, c = np.argwhere(bad)[0]
    v = arr[t, c]
    if np.isnan(v):
        raise ValueError(
            f"Input {name} contains NaN: frame {t}, column {c}; pass allow_missing=True to the "
            "estimator to treat NaN as a missing value"
        )
    raise ValueError(f"Input {name} contains infinity: frame {t}, column {c} ({v})")


def as_lengths(lengths, n_samples):
    """``lengths`` as a list of positive ints summing to ``n_samples`` (one sequence when None)."""
    if lengths is None:
        return [int(n_samples)]
    arr = np.asarray(lengths)
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"lengths must be a non-empty 1-D array of sequence lengths, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        if np.issubdtype(arr.dtype, np.floating) and np.all(arr == np.round(arr)):
            arr = arr.astype(np.int64)
        else:
            raise ValueError(f"lengths must hold whole numbers, got dtype {arr.dtype}")
    if (arr <= 0).any():
        k = int(np.argmax(arr <= 0))
        raise ValueError(f"lengths[{k}] is {arr[k]}: sequence {k} is empty")
    if arr.sum() != n_samples:
        raise ValueError(f"lengths array {arr} doesn't sum to {n_samples} samples")
    return [int(v) for v in arr]


def n_threads(n_jobs):
    """Threads for ``n_jobs`` with joblib's convention: None → 1, -1 → every core, -2 → all but one."""
    if n_jobs is None:
        return 1
    if not isinstance(n_jobs, numbers.Integral) or n_jobs == 0:
        raise ValueError(f"n_jobs must be a non-zero integer or None, got {n_jobs!r}")
    if n_jobs > 0:
        return int(n_jobs)
    cpus = os.cpu_count() or 1
    return max(1, cpus + 1 + int(n_jobs))


def derived_seed(random_state):
    """A 64-bit seed for phasekit's own generators, drawn from ``random_state``
    (deterministic for an int seed)."""
    rs = check_random_state(random_state)
    return int(rs.randint(np.iinfo(np.int32).max))


def param_names(cls):
    """Constructor parameter names, as scikit-learn lists them."""
    sig = inspect.signature(cls.__init__)
    return sorted(p.name for p in sig.parameters.values() if p.name != "self")
