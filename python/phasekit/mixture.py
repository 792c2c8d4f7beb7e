"""scikit-learn's ``GaussianMixture``, computed by phasekit.

``from phasekit.mixture import GaussianMixture`` in place of
``from sklearn.mixture import GaussianMixture``: the same constructor
arguments, attributes (``weights_``, ``means_``, ``covariances_``,
``precisions_``, ``precisions_cholesky_``, ``converged_``, ``n_iter_``,
``lower_bound_``, ``n_features_in_``) and methods (``fit``, ``fit_predict``,
``predict``, ``predict_proba``, ``score``, ``score_samples``, ``sample``,
``bic``, ``aic``), and scikit-learn's EM: its M-step (``reg_covar`` added to
the diagonal, ``10 ε`` added to every component count), its convergence test
on the mean log-likelihood per sample, ``n_init`` runs keeping the best,
``warm_start``. With ``weights_init``, ``means_init`` and ``precisions_init``
the fit agrees with scikit-learn's to 1e-8.

The E-step (densities and responsibilities of every frame) runs in phasekit
with the GIL released; the M-step applies scikit-learn's formulas to the
statistics in NumPy.

Differences: ``init_params="kmeans"`` runs phasekit's k-means (k-means++
seeding, seeded from ``random_state``) instead of scikit-learn's ``KMeans``;
``init_params="k-means++"`` and ``"random_from_data"`` start with weights
normalised to sum to 1 (scikit-learn's first E-step uses weights summing to
``n_components / n_samples``; the responsibilities are the same); a
covariance that is not positive definite is an error naming the component.
Extra keyword: ``n_jobs`` (threads of the E-step; bit-identical results).
"""

from __future__ import annotations

import warnings

import numpy as np

from . import _core
from ._base import BaseEstimator, check_is_fitted, check_random_state, derived_seed, n_threads

try:
    from sklearn.base import DensityMixin as _DensityMixin
    from sklearn.exceptions import ConvergenceWarning
except ImportError:  # pragma: no cover

    class _DensityMixin:
        _estimator_type = "DensityEstimator"

        def score(self, X, y=None):
            pass

    class ConvergenceWarning(UserWarning):
        """EM stopped before converging."""


__all__ = ["GaussianMixture"]

_KINDS = ("full", "tied", "diag", "spherical")
_INITS = ("kmeans", "random", "random_from_data", "k-means++")


def _validate(est, X, *, reset, ensure_min_samples=1):
    """scikit-learn's input validation (``n_features_in_``, feature names) when it
    is installed, an equivalent check otherwise; returns C-contiguous float64."""
    try:
        from sklearn.utils.validation import validate_data  # scikit-learn >= 1.6
    except ImportError:
        validate_data = None
    kwargs = dict(reset=reset, dtype=[np.float64, np.float32], ensure_min_samples=ensure_min_samples)
    if validate_data is not None:
        X = validate_data(est, X, **kwargs)
    elif hasattr(est, "_validate_data"):
        X = est._validate_data(X, **kwargs)
    else:  # pragma: no cover - without scikit-learn
        from ._base import as_frames

        X = as_frames(X, min_rows=ensure_min_samples)
        if reset:
            est.n_features_in_ = X.shape[1]
        elif X.shape[1] != est.n_features_in_:
            raise ValueError(
                f"X has {X.shape[1]} features, but {type(est).__name__} is expecting "
                f"{est.n_features_in_} features as input."
            )
    return np.ascontiguousarray(X, dtype=np.float64)


def _native_covariances(covariances, kind):
    return np.ascontiguousarray(covariances, dtype=np.float64)


def _precision_cholesky(covariances, kind):
    """scikit-learn's ``_compute_precision_cholesky``."""
    msg = (
        "Fitting the mixture model failed because some components have ill-defined empirical "
        "covariance (for instance caused by singleton or collapsed samples). Try to decrease the "
        "number of components, or increase reg_covar."
    )
    if kind == "full":
        n_components, n_features, _ = covariances.shape
        out = np.empty((n_components, n_features, n_features))
        for k, cov in enumerate(covariances):
            try:
                cov_chol = np.linalg.cholesky(cov)
            except np.linalg.LinAlgError:
                raise ValueError(msg) from None
            out[k] = _solve_lower(cov_chol, np.eye(n_features)).T
        return out
    if kind == "tied":
        n_features = covariances.shape[0]
        try:
            cov_chol = np.linalg.cholesky(covariances)
        except np.linalg.LinAlgError:
            raise ValueError(msg) from None
        return _solve_lower(cov_chol, np.eye(n_features)).T
    if np.any(np.less_equal(covariances, 0.0)):
        raise ValueError(msg)
    return 1.0 / np.sqrt(covariances)


def _solve_lower(L, B):
    """``L⁻¹ B`` for lower-triangular ``L`` (forward substitution)."""
    n = L.shape[0]
    X = np.zeros_like(B, dtype=np.float64)
    for i in range(n):
        X[i] = (B[i] - L[i, :i] @ X[:i]) / L[i, i]
    return X


def _covariances_from_precisions(precisions, kind):
    """Covariances of given precisions (for ``precisions_init``)."""
    if kind == "full":
        return np.array([np.linalg.inv(p) for p in precisions])
    if kind == "tied":
        return np.linalg.inv(precisions)
    return 1.0 / np.asarray(precisions, dtype=np.float64)


class GaussianMixture(_DensityMixin, BaseEstimator):
    """Gaussian mixture fitted by EM (scikit-learn's ``GaussianMixture``).

    Parameters
    ----------
    n_components : int
        Number of mixture components.
    covariance_type : {"full", "tied", "diag", "spherical"}
        Covariance structure of the components.
    tol : float
        Convergence threshold on the change of the mean log-likelihood per sample.
    reg_covar : float
        Added to the diagonal of every covariance.
    max_iter : int
        Maximum number of EM iterations per initialisation.
    n_init : int
        Number of initialisations; the best lower bound is kept.
    init_params : {"kmeans", "k-means++", "random", "random_from_data"}
        How the responsibilities that start EM are chosen.
    weights_init, means_init, precisions_init : array-like, optional
        Initial parameters (``precisions_init`` in the shape of ``covariance_type``).
    random_state : int or RandomState, optional
        Seeds the initialisation and :meth:`sample`.
    warm_start : bool
        Start a new ``fit`` from the last fitted parameters.
    verbose, verbose_interval : int
        Progress messages.
    n_jobs : int, optional
        Threads of the E-step (joblib convention; bit-identical results).

    Attributes
    ----------
    weights_ : ndarray, shape (n_components,)
    means_ : ndarray, shape (n_components, n_features)
    covariances_ : ndarray
        (n_components,) spherical, (n_features, n_features) tied,
        (n_components, n_features) diag, (n_components, n_features, n_features) full.
    precisions_, precisions_cholesky_ : ndarray
        Inverses of the covariances and their Cholesky factors, same shapes.
    converged_ : bool
    n_iter_ : int
    lower_bound_ : float
        Mean log-likelihood per sample of the best run.
    n_features_in_ : int
    """

    def __init__(
        self,
        n_components=1,
        *,
        covariance_type="full",
        tol=1e-3,
        reg_covar=1e-6,
        max_iter=100,
        n_init=1,
        init_params="kmeans",
        weights_init=None,
        means_init=None,
        precisions_init=None,
        random_state=None,
        warm_start=False,
        verbose=0,
        verbose_interval=10,
        n_jobs=None,
    ):
        self.n_components = n_components
        self.covariance_type = covariance_type
        self.tol = tol
        self.reg_covar = reg_covar
        self.max_iter = max_iter
        self.n_init = n_init
        self.init_params = init_params
        self.weights_init = weights_init
        self.means_init = means_init
        self.precisions_init = precisions_init
        self.random_state = random_state
        self.warm_start = warm_start
        self.verbose = verbose
        self.verbose_interval = verbose_interval
        self.n_jobs = n_jobs

    # -- parameter checks -----------------------------------------------------------

    def _check_parameters(self, X):
        def positive_int(name, v, low):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise ValueError(f"The '{name}' parameter of GaussianMixture must be an int in the range [{low}, inf). Got {v!r} instead.")

        positive_int("n_components", self.n_components, 1)
        positive_int("max_iter", self.max_iter, 0)
        positive_int("n_init", self.n_init, 1)
        positive_int("verbose_interval", self.verbose_interval, 1)
        for name in ("tol", "reg_covar"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not v >= 0:
                raise ValueError(f"The '{name}' parameter of GaussianMixture must be a float in the range [0.0, inf). Got {v!r} instead.")
        if self.covariance_type not in _KINDS:
            raise ValueError(
                f"The 'covariance_type' parameter of GaussianMixture must be a str among {set(_KINDS)}. Got {self.covariance_type!r} instead."
            )
        if self.init_params not in _INITS:
            raise ValueError(
                f"The 'init_params' parameter of GaussianMixture must be a str among {set(_INITS)}. Got {self.init_params!r} instead."
            )
        n_features = X.shape[1]
        k = self.n_components
        if self.weights_init is not None:
            w = np.asarray(self.weights_init, dtype=np.float64)
            if w.shape != (k,):
                raise ValueError(f"The parameter 'weights' should have the shape of ({k},), but got {w.shape}")
            if np.any(w < 0) or np.any(w > 1):
                raise ValueError(f"The parameter 'weights' should be in the range [0, 1], but got max value {w.max():.5f}, min value {w.min():.5f}")
            if not np.allclose(np.abs(1.0 - np.sum(w)), 0.0):
                raise ValueError(f"The parameter 'weights' should be normalized, but got sum(weights) = {np.sum(w):.5f}")
        if self.means_init is not None:
            m = np.asarray(self.means_init, dtype=np.float64)
            if m.shape != (k, n_features):
                raise ValueError(f"The parameter 'means' should have the shape of {(k, n_features)}, but got {m.shape}")
        if self.precisions_init is not None:
            p = np.asarray(self.precisions_init, dtype=np.float64)
            shape = {
                "full": (k, n_features, n_features),
                "tied": (n_features, n_features),
                "diag": (k, n_features),
                "spherical": (k,),
            }[self.covariance_type]
            if p.shape != shape:
                raise ValueError(f"The parameter '{self.covariance_type} precision' should have the shape of {shape}, but got {p.shape}")

    # -- EM -------------------------------------------------------------------------

    def fit(self, X, y=None):
        """Estimates the parameters with EM.

        Parameters
        ----------
        X : array-like, shape (n_samples, n_features)
        y : ignored

        Returns
        -------
        self : GaussianMixture
        """
        self.fit_predict(X, y)
        return self

    def fit_predict(self, X, y=None):
        """Fits the model and returns the most probable component of every sample.

        Returns
        -------
        labels : ndarray of int, shape (n_samples,)
        """
        X = _validate(self, X, reset=True, ensure_min_samples=2)
        self._check_parameters(X)
        if X.shape[0] < self.n_components:
            raise ValueError(
                "Expected n_samples >= n_components "
                f"but got n_components = {self.n_components}, n_samples = {X.shape[0]}"
            )
        data = _core.Sequences(X)
        threads = n_threads(self.n_jobs)
        self._run_em(X, lambda est: est._core().expected_statistics(data, threads))
        return self._core().responsibilities(X).argmax(axis=1)

    def _run_em(self, X, estep):
        """scikit-learn's EM loop; ``X`` initialises, ``estep(estimator)`` returns
        the :class:`phasekit._core.Statistics` of all the data under the current
        parameters (in this process, or over a Dask bag)."""
        do_init = not (self.warm_start and hasattr(self, "converged_"))
        n_init = self.n_init if do_init else 1
        max_lower_bound = -np.inf
        self.converged_ = False
        random_state = check_random_state(self.random_state)
        best_params, best_n_iter = None, 0
        for init in range(n_init):
            if self.verbose == 1:
                print(f"Initialization {init}")
            if do_init:
                self._initialize_parameters(X, random_state)
            lower_bound = -np.inf if do_init else self.lower_bound_
            if self.max_iter == 0:
                best_params = self._get_parameters()
                best_n_iter = 0
            else:
                converged = False
                for n_iter in range(1, self.max_iter + 1):
                    prev_lower_bound = lower_bound
                    stats = estep(self).arrays()
                    log_prob_norm = stats["log_likelihood"] / stats["n_frames"]
                    self._m_step(stats)
                    lower_bound = log_prob_norm
                    change = lower_bound - prev_lower_bound
                    if self.verbose >= 1 and n_iter % self.verbose_interval == 0:
                        print(f"  Iteration {n_iter}\t change: {change}")
                    if abs(change) < self.tol:
                        converged = True
                        break
                if self.verbose >= 1:
                    print(f"Initialization {'converged' if converged else 'did not converge'}. lower bound {lower_bound}")
                if lower_bound > max_lower_bound or max_lower_bound == -np.inf:
                    max_lower_bound = lower_bound
                    best_params = self._get_parameters()
                    best_n_iter = n_iter
                    self.converged_ = converged
        if not self.converged_ and self.max_iter > 0:
            warnings.warn(
                "Best performing initialization did not converge. Try different init parameters, "
                "or increase max_iter, tol, or check for degenerate data.",
                ConvergenceWarning,
            )
        self._set_parameters(best_params)
        self.n_iter_ = best_n_iter
        self.lower_bound_ = max_lower_bound

    def _initialize_parameters(self, X, random_state):
        n_samples = X.shape[0]
        k = self.n_components
        if self.weights_init is not None and self.means_init is not None and self.precisions_init is not None:
            self._initialize(X, None)
            return
        if self.init_params == "kmeans":
            resp = np.zeros((n_samples, k))
            _, labels, _ = _core.kmeans(X, k, derived_seed(random_state), 1)
            resp[np.arange(n_samples), labels] = 1
        elif self.init_params == "random":
            resp = random_state.uniform(size=(n_samples, k))
            resp /= resp.sum(axis=1)[:, np.newaxis]
        elif self.init_params == "random_from_data":
            resp = np.zeros((n_samples, k))
            indices = random_state.choice(n_samples, size=k, replace=False)
            resp[indices, np.arange(k)] = 1
        else:  # k-means++ seeding only
            resp = np.zeros((n_samples, k))
            centroids, _, _ = _core.kmeans(X, k, derived_seed(random_state), 1, 0)
            for j, c in enumerate(centroids):
                resp[np.argmin(((X - c) ** 2).sum(axis=1)), j] = 1
        self._initialize(X, resp)

    def _initialize(self, X, resp):
        n_samples = X.shape[0]
        weights = means = covariances = None
        if resp is not None:
            stats = _core.GmmCore.weighted_statistics(
                X, np.ascontiguousarray(resp, dtype=np.float64), self.covariance_type
            ).arrays()
            weights, means, covariances = self._estimate_parameters(stats)
            if self.weights_init is None:
                weights = weights / n_samples
        self.weights_ = weights if self.weights_init is None else np.asarray(self.weights_init, dtype=np.float64)
        self.means_ = means if self.means_init is None else np.asarray(self.means_init, dtype=np.float64)
        if self.precisions_init is None:
            self.covariances_ = covariances
            self.precisions_cholesky_ = _precision_cholesky(covariances, self.covariance_type)
        else:
            p = np.asarray(self.precisions_init, dtype=np.float64)
            self.covariances_ = _covariances_from_precisions(p, self.covariance_type)
            if self.covariance_type == "full":
                self.precisions_cholesky_ = np.array([np.linalg.cholesky(q) for q in p])
            elif self.covariance_type == "tied":
                self.precisions_cholesky_ = np.linalg.cholesky(p)
            else:
                self.precisions_cholesky_ = np.sqrt(p)

    def _estimate_parameters(self, stats):
        """scikit-learn's ``_estimate_gaussian_parameters`` from phasekit's statistics:
        per component the count n, its reference point c, s = Σr(x − c) and
        Q = Σr(x − c)(x − c)ᵀ (or its diagonal)."""
        post, c, s, Q = stats["post"], stats["shift"], stats["sum"], stats["sum_sq"]
        nk = post + 10 * np.finfo(np.float64).eps
        obs = s + post[:, None] * c
        means = obs / nk[:, None]
        delta = c - means
        reg = self.reg_covar
        kind = self.covariance_type
        if kind in ("full", "tied"):
            sd = s[:, :, None] * delta[:, None, :]
            scatter = Q + sd + np.swapaxes(sd, 1, 2) + post[:, None, None] * (delta[:, :, None] * delta[:, None, :])
            d = scatter.shape[1]
            if kind == "full":
                cov = scatter / nk[:, None, None]
                cov[:, np.arange(d), np.arange(d)] += reg
            else:
                cov = scatter.sum(axis=0) / nk.sum()
                cov[np.arange(d), np.arange(d)] += reg
        else:
            scatter = Q + 2 * s * delta + post[:, None] * delta**2
            cov = scatter / nk[:, None] + reg
            if kind == "spherical":
                cov = cov.mean(1)
        return nk, means, cov

    def _m_step(self, stats):
        self.weights_, self.means_, self.covariances_ = self._estimate_parameters(stats)
        self.weights_ = self.weights_ / self.weights_.sum()
        self.precisions_cholesky_ = _precision_cholesky(self.covariances_, self.covariance_type)

    def _get_parameters(self):
        return (self.weights_, self.means_, self.covariances_, self.precisions_cholesky_)

    def _set_parameters(self, params):
        self.weights_, self.means_, self.covariances_, self.precisions_cholesky_ = params
        kind = self.covariance_type
        if kind == "full":
            self.precisions_ = np.empty(self.precisions_cholesky_.shape)
            for k, prec_chol in enumerate(self.precisions_cholesky_):
                self.precisions_[k] = np.dot(prec_chol, prec_chol.T)
        elif kind == "tied":
            self.precisions_ = np.dot(self.precisions_cholesky_, self.precisions_cholesky_.T)
        else:
            self.precisions_ = self.precisions_cholesky_**2

    def _core(self):
        w = np.asarray(self.weights_, dtype=np.float64)
        w = w / w.sum()
        return _core.GmmCore(
            w,
            np.ascontiguousarray(self.means_, dtype=np.float64),
            _native_covariances(self.covariances_, self.covariance_type),
            self.covariance_type,
            self.means_.shape[1],
        )

    # -- the fitted model -------------------------------------------------------------

    def _fitted(self, X):
        check_is_fitted(self, "means_")
        return _validate(self, X, reset=False)

    def score_samples(self, X):
        """Log-likelihood of every sample, shape (n_samples,)."""
        X = self._fitted(X)
        return self._core().score_samples(X)

    def score(self, X, y=None):
        """Mean log-likelihood per sample."""
        return float(self.score_samples(X).mean())

    def predict(self, X):
        """Most probable component of every sample, shape (n_samples,)."""
        X = self._fitted(X)
        return self._core().responsibilities(X).argmax(axis=1)

    def predict_proba(self, X):
        """Responsibilities, shape (n_samples, n_components)."""
        X = self._fitted(X)
        return self._core().responsibilities(X)

    def sample(self, n_samples=1):
        """Draws samples (the same NumPy random stream as scikit-learn).

        Returns
        -------
        X : ndarray, shape (n_samples, n_features)
        y : ndarray of int, shape (n_samples,)
            The components.
        """
        check_is_fitted(self, "means_")
        if n_samples < 1:
            raise ValueError(
                "Invalid value for 'n_samples': %d . The sampling requires at least one sample." % (self.n_components)
            )
        _, n_features = self.means_.shape
        rng = check_random_state(self.random_state)
        n_samples_comp = rng.multinomial(n_samples, self.weights_)
        if self.covariance_type == "full":
            X = np.vstack(
                [
                    rng.multivariate_normal(mean, covariance, int(sample))
                    for (mean, covariance, sample) in zip(self.means_, self.covariances_, n_samples_comp)
                ]
            )
        elif self.covariance_type == "tied":
            X = np.vstack(
                [rng.multivariate_normal(mean, self.covariances_, int(sample)) for (mean, sample) in zip(self.means_, n_samples_comp)]
            )
        else:
            X = np.vstack(
                [
                    mean + rng.standard_normal(size=(sample, n_features)) * np.sqrt(covariance)
                    for (mean, covariance, sample) in zip(self.means_, self.covariances_, n_samples_comp)
                ]
            )
        y = np.concatenate([np.full(sample, j, dtype=int) for j, sample in enumerate(n_samples_comp)])
        return (X, y)

    def _n_parameters(self):
        _, n_features = self.means_.shape
        if self.covariance_type == "full":
            cov_params = self.n_components * n_features * (n_features + 1) / 2.0
        elif self.covariance_type == "diag":
            cov_params = self.n_components * n_features
        elif self.covariance_type == "tied":
            cov_params = n_features * (n_features + 1) / 2.0
        else:
            cov_params = self.n_components
        mean_params = n_features * self.n_components
        return int(cov_params + mean_params + self.n_components - 1)

    def bic(self, X):
        """Bayesian information criterion ``-2 log L + p log n``."""
        X = self._fitted(X)
        return -2 * self.score(X) * X.shape[0] + self._n_parameters() * np.log(X.shape[0])

    def aic(self, X):
        """Akaike information criterion ``-2 log L + 2 p``."""
        X = self._fitted(X)
        return -2 * self.score(X) * X.shape[0] + 2 * self._n_parameters()
