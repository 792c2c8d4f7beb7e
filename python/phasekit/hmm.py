"""Hidden Markov models with hmmlearn's interface, computed by phasekit.

``from phasekit import hmm`` in place of ``from hmmlearn import hmm``:
:class:`GaussianHMM` (``'spherical'``, ``'diag'``, ``'full'``, ``'tied'``),
:class:`GMMHMM`, :class:`CategoricalHMM` and :class:`PoissonHMM` take
hmmlearn 0.3's constructor arguments, keep its attributes in its shapes and
follow its semantics: the ``params`` / ``init_params`` letters, the Dirichlet
and normal–inverse-gamma/Wishart priors and their defaults, ``min_covar``, the
convergence monitor (``monitor_.history``, ``monitor_.converged``), EM that
runs the M-step after every E-step, ``decode(algorithm="map")``, ``sample``
drawing from the same NumPy random stream, ``aic``/``bic`` with hmmlearn's
parameter counts. With ``init_params=""`` and the same starting parameters,
``fit`` followed by ``score`` agrees with hmmlearn to 1e-8 relative and
``predict`` gives the same path.

What differs is where the work happens: every forward–backward pass, Viterbi
path and E-step runs in phasekit (Rust), with the GIL released. The E-step's
statistics come back as arrays and the M-step applies hmmlearn's formulas to
them in NumPy (a few hundred microseconds per iteration).

What hmmlearn lacks comes as extra keyword arguments with defaults that keep
hmmlearn's behaviour:

``n_jobs``
    threads of the E-step (joblib convention; ``None``: one). The result is
    bit-identical for any thread count.
``allow_missing``
    treat NaN in ``X`` as a missing value: scoring marginalises it, fitting
    uses its expected sufficient statistics (exact EM for the observed data).
    Off by default: a NaN is an error, as in hmmlearn.
``restarts``
    run the fit from that many initialisations (run 0 is hmmlearn's; run
    ``r`` draws its random initial parameters from a seed derived from
    ``random_state``) and keep the run with the highest final log-likelihood.

Differences that are deliberate (phasekit refuses input it cannot use rather
than guessing): a covariance that is not positive definite is an error
naming the state (hmmlearn retries a full covariance with ``1e-7 I`` added
and floors diagonal variances at the smallest double); a sequence with
probability zero under the model cannot be fitted (hmmlearn propagates
NaN); ``implementation`` (``"log"``/``"scaling"``) is accepted and checked
but phasekit always runs its own exact scaled recursions; the means
initialised by ``init_params`` containing ``'m'`` come from phasekit's
k-means++ (best of 10 runs, seeded from ``random_state``), not from
scikit-learn's ``KMeans``, so default-initialised fits start from other
means than hmmlearn's (start, transition, covariance, emission-probability
and rate initialisations draw the same NumPy random numbers as hmmlearn).
"""

from __future__ import annotations

import copy
import logging
import string
import sys
from collections import deque

import numpy as np

from . import _core
from ._base import (
    BaseEstimator,
    as_frames,
    as_lengths,
    check_is_fitted,
    check_random_state,
    derived_seed,
    n_threads,
)

__all__ = [
    "GaussianHMM",
    "GMMHMM",
    "CategoricalHMM",
    "PoissonHMM",
    "ConvergenceMonitor",
    "COVARIANCE_TYPES",
    "DECODER_ALGORITHMS",
]

_log = logging.getLogger(__name__)

#: Supported decoder algorithms.
DECODER_ALGORITHMS = frozenset(("viterbi", "map"))
#: Supported covariance structures.
COVARIANCE_TYPES = frozenset(("spherical", "diag", "full", "tied"))


class ConvergenceMonitor:
    """Monitors and reports convergence of EM (hmmlearn's class, same behaviour).

    Parameters
    ----------
    tol : float
        Convergence threshold: EM has converged when the log-likelihood gain
        between two iterations is below ``tol`` or ``n_iter`` iterations ran.
    n_iter : int
        Maximum number of iterations.
    verbose : bool
        Whether per-iteration reports are printed to :data:`sys.stderr`.

    Attributes
    ----------
    history : collections.deque
        The log-likelihood of every iteration (before its M-step).
    iter : int
        Number of iterations performed.
    """

    _template = "{iter:>10d} {log_prob:>16.8f} {delta:>+16.8f}"

    def __init__(self, tol, n_iter, verbose):
        self.tol = tol
        self.n_iter = n_iter
        self.verbose = verbose
        self.history = deque()
        self.iter = 0

    def __repr__(self):
        class_name = self.__class__.__name__
        params = sorted(dict(vars(self), history=list(self.history)).items())
        return "{}(\n".format(class_name) + "".join(map("    {}={},\n".format, *zip(*params))) + ")"

    def _reset(self):
        """Resets the monitor's state."""
        self.iter = 0
        self.history.clear()

    def report(self, log_prob):
        """Records (and with ``verbose`` prints) the log-likelihood of an iteration.

        Parameters
        ----------
        log_prob : float
            The log-likelihood of the data at the current iteration.
        """
        if self.verbose:
            delta = log_prob - self.history[-1] if self.history else np.nan
            message = self._template.format(iter=self.iter + 1, log_prob=log_prob, delta=delta)
            print(message, file=sys.stderr)
        precision = np.finfo(float).eps ** (1 / 2)
        if self.history and (log_prob - self.history[-1]) < -precision:
            delta = log_prob - self.history[-1]
            _log.warning(
                f"Model is not converging.  Current: {log_prob} is not greater than "
                f"{self.history[-1]}. Delta is {delta}"
            )
        self.history.append(log_prob)
        self.iter += 1

    @property
    def converged(self):
        """Whether EM converged (``n_iter`` reached or the last gain below ``tol``)."""
        return self.iter == self.n_iter or (
            len(self.history) >= 2 and self.history[-1] - self.history[-2] < self.tol
        )


def _normalize(a, axis=None):
    """hmmlearn's ``normalize``: in place, rows of zeros are left at zero."""
    a_sum = a.sum(axis)
    if axis and a.ndim > 1:
        a_sum[a_sum == 0] = 1
        shape = list(a.shape)
        shape[axis] = 1
        a_sum.shape = shape
    a /= a_sum


def _exact_rows(p):
    """Probability rows renormalised to sum to 1 (they passed hmmlearn's ``allclose`` check)."""
    p = np.array(p, dtype=np.float64, copy=True)
    s = p.sum(axis=-1, keepdims=True)
    return np.ascontiguousarray(p / s)


def _validate_covars(covars, covariance_type, n_components):
    """hmmlearn's (scikit-learn 0.19's) checks of a covariance array."""
    if covariance_type == "spherical":
        if len(covars) != n_components:
            raise ValueError("'spherical' covars have length n_components")
        elif np.any(covars <= 0):
            raise ValueError("'spherical' covars must be positive")
    elif covariance_type == "tied":
        if covars.ndim != 2 or covars.shape[0] != covars.shape[1]:
            raise ValueError("'tied' covars must have shape (n_dim, n_dim)")
        elif not np.allclose(covars, covars.T) or np.any(np.linalg.eigvalsh(covars) <= 0):
            raise ValueError("'tied' covars must be symmetric, positive-definite")
    elif covariance_type == "diag":
        if len(covars.shape) != 2:
            raise ValueError("'diag' covars must have shape (n_components, n_dim)")
        elif np.any(covars <= 0):
            raise ValueError("'diag' covars must be positive")
    elif covariance_type == "full":
        if len(covars.shape) != 3:
            raise ValueError("'full' covars must have shape (n_components, n_dim, n_dim)")
        elif covars.shape[1] != covars.shape[2]:
            raise ValueError("'full' covars must have shape (n_components, n_dim, n_dim)")
        for n, cv in enumerate(covars):
            if not np.allclose(cv, cv.T) or np.any(np.linalg.eigvalsh(cv) <= 0):
                raise ValueError("component %d of 'full' covars must be symmetric, positive-definite" % n)
    else:
        raise ValueError("covariance_type must be one of 'spherical', 'tied', 'diag', 'full'")


def _distribute_covar_matrix(tied_cv, covariance_type, n_components):
    """hmmlearn's ``distribute_covar_matrix_to_match_covariance_type``."""
    if covariance_type == "spherical":
        return np.tile(tied_cv.mean() * np.ones(tied_cv.shape[1]), (n_components, 1))
    elif covariance_type == "tied":
        return tied_cv
    elif covariance_type == "diag":
        return np.tile(np.diag(tied_cv), (n_components, 1))
    elif covariance_type == "full":
        return np.tile(tied_cv, (n_components, 1, 1))
    raise ValueError("covariance_type must be one of 'spherical', 'tied', 'diag', 'full'")


def _fill_covars(covars, covariance_type="full", n_components=1, n_features=1):
    """hmmlearn's ``fill_covars``: covariances as full matrices."""
    if covariance_type == "full":
        return covars
    elif covariance_type == "diag":
        return np.array(list(map(np.diag, covars)))
    elif covariance_type == "tied":
        return np.tile(covars, (n_components, 1, 1))
    elif covariance_type == "spherical":
        covars = np.ravel(covars)
        eye = np.eye(n_features)[np.newaxis, :, :]
        covars = covars[:, np.newaxis, np.newaxis]
        return eye * covars


def _data_cov(X):
    """``np.cov(X.T)`` (hmmlearn's), over the pairwise observed values when some are NaN."""
    if not np.isnan(X).any():
        return np.cov(X.T)
    c = np.ma.cov(np.ma.masked_invalid(X), rowvar=False).filled(np.nan)
    c = np.where(np.isnan(c), 0.0, c)
    d = np.diag(c).copy()
    d[d <= 0] = 1.0
    c[np.diag_indices_from(c)] = d
    return c


def _outer(x):
    """Outer product over the last axis."""
    return x[..., :, None] * x[..., None, :]


class _BaseHMM(BaseEstimator):
    """Shared machinery of the HMMs (hmmlearn's ``BaseHMM``)."""

    #: Attributes holding the fitted parameters (saved and restored around restarts).
    _param_attrs = ("startprob_", "transmat_")

    # -- the interface ------------------------------------------------------------

    def score_samples(self, X, lengths=None):
        """Log-likelihood of ``X`` and the state posteriors.

        Parameters
        ----------
        X : array-like, shape (n_samples, n_features)
            Feature matrix of individual samples.
        lengths : array-like of int, shape (n_sequences,), optional
            Lengths of the sequences in ``X``; they sum to ``n_samples``.

        Returns
        -------
        log_prob : float
            Log-likelihood of ``X``.
        posteriors : ndarray, shape (n_samples, n_components)
            State-membership probabilities of every sample.
        """
        core, X, lengths = self._prepare_scoring(X, lengths)
        return core.posteriors(X, lengths)

    def score(self, X, lengths=None):
        """Log-likelihood of ``X`` under the model.

        Parameters
        ----------
        X : array-like, shape (n_samples, n_features)
            Feature matrix of individual samples.
        lengths : array-like of int, shape (n_sequences,), optional
            Lengths of the sequences in ``X``; they sum to ``n_samples``.

        Returns
        -------
        log_prob : float
            Log-likelihood of ``X`` (the sum over its sequences).
        """
        core, X, lengths = self._prepare_scoring(X, lengths)
        return core.score(X, lengths)

    def decode(self, X, lengths=None, algorithm=None):
        """Most likely state sequence of ``X``.

        Parameters
        ----------
        X : array-like, shape (n_samples, n_features)
            Feature matrix of individual samples.
        lengths : array-like of int, shape (n_sequences,), optional
            Lengths of the sequences in ``X``.
        algorithm : {"viterbi", "map"}, optional
            ``"viterbi"``: the most likely path; ``"map"``: the most likely
            state of every frame. Defaults to :attr:`algorithm`.

        Returns
        -------
        log_prob : float
            ``"viterbi"``: log-probability of the path (summed over sequences);
            ``"map"``: the sum of the per-frame maximal posteriors (hmmlearn's
            value).
        state_sequence : ndarray of int, shape (n_samples,)
            The states.
        """
        check_is_fitted(self, "startprob_")
        self._check()
        algorithm = algorithm or self.algorithm
        if algorithm not in DECODER_ALGORITHMS:
            raise ValueError(f"Unknown decoder {algorithm!r}")
        core, X, lengths = self._prepare_scoring(X, lengths, checked=True)
        if algorithm == "viterbi":
            return core.viterbi(X, lengths)
        log_prob = 0.0
        states = []
        offset = 0
        _, posteriors = core.posteriors(X, lengths)
        for n in lengths:
            post = posteriors[offset : offset + n]
            log_prob += np.max(post, axis=1).sum()
            states.append(np.argmax(post, axis=1))
            offset += n
        return log_prob, np.concatenate(states)

    def predict(self, X, lengths=None):
        """Most likely state sequence of ``X`` (see :meth:`decode`).

        Returns
        -------
        state_sequence : ndarray of int, shape (n_samples,)
        """
        _, state_sequence = self.decode(X, lengths)
        return state_sequence

    def predict_proba(self, X, lengths=None):
        """State posteriors of every sample.

        Returns
        -------
        posteriors : ndarray, shape (n_samples, n_components)
        """
        _, posteriors = self.score_samples(X, lengths)
        return posteriors

    def sample(self, n_samples=1, random_state=None, currstate=None):
        """Draws samples from the model (the same NumPy random stream as hmmlearn).

        Parameters
        ----------
        n_samples : int
            Number of samples.
        random_state : RandomState or int, optional
            Defaults to the estimator's ``random_state``.
        currstate : int, optional
            State of the first sample (drawn from ``startprob_`` when None).

        Returns
        -------
        X : ndarray, shape (n_samples, n_features)
        state_sequence : ndarray of int, shape (n_samples,)
        """
        check_is_fitted(self, "startprob_")
        self._check()
        if random_state is None:
            random_state = self.random_state
        random_state = check_random_state(random_state)
        transmat_cdf = np.cumsum(self.transmat_, axis=1)
        if currstate is None:
            startprob_cdf = np.cumsum(self.startprob_)
            currstate = (startprob_cdf > random_state.rand()).argmax()
        state_sequence = [currstate]
        X = [self._generate_sample_from_state(currstate, random_state=random_state)]
        for _ in range(n_samples - 1):
            currstate = (transmat_cdf[currstate] > random_state.rand()).argmax()
            state_sequence.append(currstate)
            X.append(self._generate_sample_from_state(currstate, random_state=random_state))
        return np.atleast_2d(X), np.array(state_sequence, dtype=int)

    def get_stationary_distribution(self):
        """The stationary distribution of the chain (left eigenvector of ``transmat_`` for 1)."""
        check_is_fitted(self, "transmat_")
        eigvals, eigvecs = np.linalg.eig(self.transmat_.T)
        eigvec = np.real_if_close(eigvecs[:, np.argmax(eigvals)])
        return eigvec / eigvec.sum()

    def aic(self, X, lengths=None):
        """Akaike information criterion ``-2 log L + 2 p`` (hmmlearn's parameter count ``p``)."""
        n_params = sum(self._get_n_fit_scalars_per_param().values())
        return -2 * self.score(X, lengths=lengths) + 2 * n_params

    def bic(self, X, lengths=None):
        """Bayesian information criterion ``-2 log L + p log n_samples``."""
        n_params = sum(self._get_n_fit_scalars_per_param().values())
        return -2 * self.score(X, lengths=lengths) + n_params * np.log(len(X))

    def fit(self, X, lengths=None):
        """Estimates the parameters by Baum-Welch (EM).

        An initialisation of the parameters named in ``init_params`` (and of
        those not set yet) comes first; then ``n_iter`` E- and M-steps at most,
        stopping when the log-likelihood gains less than ``tol``.

        Parameters
        ----------
        X : array-like, shape (n_samples, n_features)
            Feature matrix of individual samples.
        lengths : array-like of int, shape (n_sequences,), optional
            Lengths of the sequences in ``X``; they sum to ``n_samples``.

        Returns
        -------
        self : object
        """
        X = self._validate_X(X, fitting=True)
        lengths = as_lengths(lengths, X.shape[0])
        self._fit_restarts(X, lengths, None)
        return self

    def _fit_restarts(self, X, lengths, estep):
        restarts = getattr(self, "restarts", 1)
        if isinstance(restarts, bool) or not isinstance(restarts, (int, np.integer)) or restarts < 1:
            raise ValueError(f"restarts must be a positive integer, got {restarts!r}")
        if restarts == 1:
            self._fit_once(X, lengths, self.random_state, estep)
            return
        seeds = check_random_state(self.random_state).randint(np.iinfo(np.int32).max, size=restarts)
        snapshot = self._snapshot()
        best = None
        for r in range(restarts):
            self._restore(snapshot)
            self._fit_once(X, lengths, self.random_state if r == 0 else int(seeds[r]), estep)
            final = self.monitor_.history[-1] if self.monitor_.history else -np.inf
            if best is None or final > best[0]:
                best = (final, self._snapshot(), copy.deepcopy(self.monitor_))
        self._restore(best[1])
        self.monitor_ = best[2]

    # -- the EM loop --------------------------------------------------------------

    def _fit_once(self, X, lengths, random_state, estep=None):
        """Initialises from ``X`` and runs EM; ``estep(estimator)`` returns the
        :class:`phasekit._core.Statistics` of the data under the estimator's
        current parameters (default: all of ``X`` in this process;
        :func:`phasekit.dask.fit` passes one that maps over a Dask bag)."""
        self._init(X, lengths, random_state)
        self._check()
        if estep is None:
            data = _core.Sequences(X, lengths)
            threads = n_threads(getattr(self, "n_jobs", None))

            def estep(est):
                return est._to_core().expected_statistics(data, threads)

        self._em(estep)

    def _em(self, estep):
        self.monitor_._reset()
        for _ in range(self.n_iter):
            arrays = estep(self).arrays()
            curr_logprob = arrays["log_likelihood"]
            lower_bound = self._compute_lower_bound(curr_logprob)
            self._do_mstep(arrays)
            self.monitor_.report(lower_bound)
            if self.monitor_.converged:
                break
            if (self.transmat_.sum(axis=1) == 0).any():
                _log.warning(
                    "Some rows of transmat_ have zero sum because no transition from the state was ever observed."
                )

    def _estep_local(self, data, threads):
        """The E-step over a :class:`phasekit._core.Sequences` in this process."""
        return self._to_core().expected_statistics(data, threads)

    def _compute_lower_bound(self, curr_logprob):
        return curr_logprob

    def _do_mstep(self, stats):
        """hmmlearn's M-step of the chain: Dirichlet priors, structural zeros kept."""
        if "s" in self.params:
            startprob_ = np.maximum(self.startprob_prior - 1 + stats["start"], 0)
            self.startprob_ = np.where(self.startprob_ == 0, 0, startprob_)
            _normalize(self.startprob_)
        if "t" in self.params:
            transmat_ = np.maximum(self.transmat_prior - 1 + stats["trans"], 0)
            new = np.where(self.transmat_ == 0, 0, transmat_)
            # A state never left in the data keeps its row (hmmlearn would
            # leave it at zero, an invalid model).
            empty = new.sum(axis=1) == 0
            new[empty] = self.transmat_[empty]
            _normalize(new, axis=1)
            self.transmat_ = new

    def _snapshot(self):
        return {a: copy.deepcopy(getattr(self, a)) for a in self._param_attrs + ("n_features",) if hasattr(self, a)}

    def _restore(self, snap):
        for a in self._param_attrs + ("n_features",):
            if a in snap:
                setattr(self, a, copy.deepcopy(snap[a]))
            elif a in self.__dict__:
                delattr(self, a)

    # -- initialisation and checks (hmmlearn's) -----------------------------------

    def _needs_init(self, code, name):
        if code in self.init_params:
            if hasattr(self, name):
                _log.warning(
                    "Even though the %r attribute is set, it will be overwritten during "
                    "initialization because 'init_params' contains %r",
                    name,
                    code,
                )
            return True
        if not hasattr(self, name):
            return True
        return False

    def _check_and_set_n_features(self, X):
        _, n_features = X.shape
        if hasattr(self, "n_features") and self.n_features is not None:
            if self.n_features != n_features:
                raise ValueError(
                    f"Unexpected number of dimensions, got {n_features} but expected {self.n_features}"
                )
        else:
            self.n_features = n_features

    def _init(self, X, lengths, random_state):
        self._check_and_set_n_features(X)
        init = 1.0 / self.n_components
        rs = check_random_state(random_state)
        if self._needs_init("s", "startprob_"):
            self.startprob_ = rs.dirichlet(np.full(self.n_components, init))
        if self._needs_init("t", "transmat_"):
            self.transmat_ = rs.dirichlet(np.full(self.n_components, init), size=self.n_components)
        n_fit_scalars_per_param = self._get_n_fit_scalars_per_param()
        if n_fit_scalars_per_param is not None:
            n_fit_scalars = sum(n_fit_scalars_per_param[p] for p in self.params if p in n_fit_scalars_per_param)
            if X.size < n_fit_scalars:
                _log.warning(
                    "Fitting a model with %d free scalar parameters with only %d data points "
                    "will result in a degenerate solution.",
                    n_fit_scalars,
                    X.size,
                )

    def _check_sum_1(self, name):
        s = getattr(self, name).sum(axis=-1)
        if not np.allclose(s, 1):
            raise ValueError(
                f"{name} must sum to 1 (got {s:.4f})"
                if s.ndim == 0
                else f"{name} rows must sum to 1 (got row sums of {s})"
                if s.ndim == 1
                else "Expected 1D or 2D array"
            )

    def _check(self):
        self.startprob_ = np.asarray(self.startprob_, dtype=np.float64)
        if len(self.startprob_) != self.n_components:
            raise ValueError("startprob_ must have length n_components")
        self._check_sum_1("startprob_")
        self.transmat_ = np.asarray(self.transmat_, dtype=np.float64)
        if self.transmat_.shape != (self.n_components, self.n_components):
            raise ValueError("transmat_ must have shape (n_components, n_components)")
        self._check_sum_1("transmat_")
        if self.implementation not in ("log", "scaling"):
            raise ValueError(f"implementation must be 'log' or 'scaling', not {self.implementation!r}")

    def _validate_X(self, X, fitting=False):
        return as_frames(X, allow_nan=getattr(self, "allow_missing", False))

    def _prepare_scoring(self, X, lengths, checked=False):
        if not checked:
            check_is_fitted(self, "startprob_")
            self._check()
        X = self._validate_X(X)
        lengths = as_lengths(lengths, X.shape[0])
        return self._to_core(), X, lengths

    def _chain(self):
        return _exact_rows(self.startprob_), _exact_rows(self.transmat_)

    def _compute_log_likelihood(self, X):
        """``log b_i(x_t)``, shape (n_samples, n_components)."""
        X = self._validate_X(X)
        return self._to_core().log_density(X)


class GaussianHMM(_BaseHMM):
    """Hidden Markov model with Gaussian emissions (hmmlearn's ``GaussianHMM``).

    Parameters
    ----------
    n_components : int
        Number of states.
    covariance_type : {"spherical", "diag", "full", "tied"}
        Covariance structure: one variance per state, a diagonal per state, a
        full matrix per state, or one full matrix shared by all states.
    min_covar : float
        Added to the diagonal of the data covariance that initialises ``covars_``.
    startprob_prior, transmat_prior : array-like or float
        Dirichlet priors of ``startprob_`` and of every row of ``transmat_``
        (1: none).
    means_prior, means_weight : array-like or float
        Mean and precision of the normal prior of ``means_``.
    covars_prior, covars_weight : array-like or float
        Parameters of the inverse-gamma (spherical, diag) or inverse-Wishart
        (full, tied) prior of the covariances, as hmmlearn applies them.
    algorithm : {"viterbi", "map"}
        Decoder of :meth:`predict`.
    random_state : RandomState or int, optional
        Seeds the initialisation and :meth:`sample`.
    n_iter : int
        Maximum number of EM iterations.
    tol : float
        Convergence threshold on the log-likelihood gain.
    verbose : bool
        Print the log-likelihood of every iteration to stderr.
    params, init_params : str
        Parameters updated by the M-step / initialised before fitting:
        ``'s'`` startprob, ``'t'`` transmat, ``'m'`` means, ``'c'`` covars.
    implementation : {"log", "scaling"}
        Accepted for compatibility; phasekit's recursions are always used.
    n_jobs : int, optional
        Threads of the E-step (bit-identical results for any count).
    allow_missing : bool
        Treat NaN as a missing value instead of an error.
    restarts : int
        Number of initialisations to fit from; the best final log-likelihood wins.

    Attributes
    ----------
    n_features : int
        Dimension of the emissions.
    monitor_ : ConvergenceMonitor
        Convergence of the last fit.
    startprob_ : ndarray, shape (n_components,)
    transmat_ : ndarray, shape (n_components, n_components)
    means_ : ndarray, shape (n_components, n_features)
    covars_ : ndarray, shape (n_components, n_features, n_features)
        Covariances as full matrices (hmmlearn's getter); set it in the shape of
        ``covariance_type``: (n_components,) spherical, (n_components,
        n_features) diag, (n_components, n_features, n_features) full,
        (n_features, n_features) tied.
    """

    _param_attrs = ("startprob_", "transmat_", "means_", "_covars_")

    def __init__(
        self,
        n_components=1,
        covariance_type="diag",
        min_covar=1e-3,
        startprob_prior=1.0,
        transmat_prior=1.0,
        means_prior=0,
        means_weight=0,
        covars_prior=1e-2,
        covars_weight=1,
        algorithm="viterbi",
        random_state=None,
        n_iter=10,
        tol=1e-2,
        verbose=False,
        params="stmc",
        init_params="stmc",
        implementation="log",
        *,
        n_jobs=None,
        allow_missing=False,
        restarts=1,
    ):
        self.n_components = n_components
        self.covariance_type = covariance_type
        self.min_covar = min_covar
        self.startprob_prior = startprob_prior
        self.transmat_prior = transmat_prior
        self.means_prior = means_prior
        self.means_weight = means_weight
        self.covars_prior = covars_prior
        self.covars_weight = covars_weight
        self.algorithm = algorithm
        self.random_state = random_state
        self.n_iter = n_iter
        self.tol = tol
        self.verbose = verbose
        self.params = params
        self.init_params = init_params
        self.implementation = implementation
        self.n_jobs = n_jobs
        self.allow_missing = allow_missing
        self.restarts = restarts
        self.monitor_ = ConvergenceMonitor(self.tol, self.n_iter, self.verbose)

    @property
    def covars_(self):
        """Covariances as full matrices, shape (n_components, n_features, n_features)."""
        return _fill_covars(self._covars_, self.covariance_type, self.n_components, self.n_features)

    @covars_.setter
    def covars_(self, covars):
        covars = np.array(covars, copy=True)
        _validate_covars(covars, self.covariance_type, self.n_components)
        self._covars_ = covars

    def _get_n_fit_scalars_per_param(self):
        nc = self.n_components
        nf = self.n_features
        return {
            "s": nc - 1,
            "t": nc * (nc - 1),
            "m": nc * nf,
            "c": {
                "spherical": nc,
                "diag": nc * nf,
                "full": nc * nf * (nf + 1) // 2,
                "tied": nf * (nf + 1) // 2,
            }[self.covariance_type],
        }

    def _init(self, X, lengths, random_state):
        super()._init(X, lengths, random_state)
        if self._needs_init("m", "means_"):
            centroids, _, _ = _core.kmeans(X, self.n_components, derived_seed(random_state), 10)
            self.means_ = centroids
        if self._needs_init("c", "covars_"):
            cv = _data_cov(X) + self.min_covar * np.eye(X.shape[1])
            if not cv.shape:
                cv.shape = (1, 1)
            self.covars_ = _distribute_covar_matrix(cv, self.covariance_type, self.n_components).copy()

    def _check(self):
        super()._check()
        check_is_fitted(self, "means_")
        self.means_ = np.asarray(self.means_, dtype=np.float64)
        if self.means_.ndim != 2 or self.means_.shape[0] != self.n_components:
            raise ValueError("means_ must have shape (n_components, n_features)")
        self.n_features = self.means_.shape[1]
        if self.covariance_type not in COVARIANCE_TYPES:
            raise ValueError(f"covariance_type must be one of {COVARIANCE_TYPES}")
        check_is_fitted(self, "_covars_")

    def _native_covars(self):
        """``(kind, values)`` for phasekit: hmmlearn's spherical covariances
        become one variance per state (a tiled 2-D array whose columns differ
        is evaluated as diagonal, as hmmlearn does)."""
        cv = np.asarray(self._covars_, dtype=np.float64)
        kind = self.covariance_type
        if kind == "spherical" and cv.ndim == 2:
            if np.all(cv == cv[:, :1]):
                cv = cv[:, 0]
            else:
                kind = "diag"
        return kind, np.ascontiguousarray(cv)

    def _to_core(self):
        start, trans = self._chain()
        kind, cv = self._native_covars()
        return _core.HmmCore.gaussian(
            start, trans, np.ascontiguousarray(self.means_, dtype=np.float64), cv, kind, self.n_features
        )

    def _do_mstep(self, stats):
        super()._do_mstep(stats)
        # phasekit's statistics about each state's reference point c (the
        # current means): n = Σγ, s = Σγ(x − c), Q = Σγ(x − c)(x − c)ᵀ.
        # hmmlearn's obs = Σγx = s + n c and its c_n (Σγ(x − μ)(x − μ)ᵀ about
        # the new means μ, plus the prior term) follow exactly, without the
        # cancellation of raw second moments.
        post, c, s, Q = stats["post"], stats["shift"], stats["sum"], stats["sum_sq"]
        obs = s + post[:, None] * c
        # A state that received no weight at all keeps its mean and covariance
        # (hmmlearn divides 0 by 0 there and the model becomes NaN).
        empty = post <= 0
        old_means, old_covars = self.means_.copy(), np.array(self._covars_, copy=True)
        means_prior = self.means_prior
        means_weight = self.means_weight
        denom = post[:, None]
        if "m" in self.params:
            self.means_ = (means_weight * means_prior + obs) / (means_weight + denom)
        if "c" in self.params:
            covars_prior = self.covars_prior
            covars_weight = self.covars_weight
            meandiff = self.means_ - means_prior
            delta = c - self.means_
            if self.covariance_type in ("spherical", "diag"):
                if Q.ndim == 3:  # full statistics of a 2-D spherical fallback
                    Q = np.diagonal(Q, axis1=1, axis2=2)
                scatter = Q + 2 * s * delta + post[:, None] * delta**2
                c_n = means_weight * meandiff**2 + scatter
                c_d = max(covars_weight - 1, 0) + denom
                self._covars_ = (covars_prior + c_n) / np.maximum(c_d, 1e-5)
                if self.covariance_type == "spherical":
                    self._covars_ = np.tile(self._covars_.mean(1)[:, None], (1, self._covars_.shape[1]))
            elif self.covariance_type in ("tied", "full"):
                sd = s[:, :, None] * delta[:, None, :]
                scatter = Q + sd + np.swapaxes(sd, 1, 2) + post[:, None, None] * _outer(delta)
                c_n = np.empty((self.n_components, self.n_features, self.n_features))
                for k in range(self.n_components):
                    c_n[k] = means_weight * np.outer(meandiff[k], meandiff[k]) + scatter[k]
                cvweight = max(covars_weight - self.n_features, 0)
                if self.covariance_type == "tied":
                    self._covars_ = (covars_prior + c_n.sum(axis=0)) / (cvweight + post.sum())
                else:
                    self._covars_ = (covars_prior + c_n) / (cvweight + post[:, None, None])
        if empty.any():
            self.means_ = np.where(empty[:, None], old_means, self.means_)
            if self.covariance_type != "tied" and np.shape(self._covars_)[0] == len(empty):
                cov = np.array(self._covars_, copy=True)
                old = old_covars if old_covars.shape == cov.shape else np.broadcast_to(old_covars.reshape(len(empty), *([1] * (cov.ndim - 1))), cov.shape)
                cov[empty] = old[empty]
                self._covars_ = cov

    def _generate_sample_from_state(self, state, random_state):
        return random_state.multivariate_normal(self.means_[state], self.covars_[state])


class CategoricalHMM(_BaseHMM):
    """Hidden Markov model with categorical emissions (hmmlearn's ``CategoricalHMM``).

    ``X`` holds symbols ``0 … n_features − 1``, shape (n_samples, 1), integer dtype.

    Parameters
    ----------
    n_components : int
        Number of states.
    startprob_prior, transmat_prior, emissionprob_prior : array-like or float
        Dirichlet priors (1: none).
    n_features : int, optional
        Number of symbols (inferred from the data when None).
    algorithm, random_state, n_iter, tol, verbose, implementation
        As for :class:`GaussianHMM`.
    params, init_params : str
        ``'s'`` startprob, ``'t'`` transmat, ``'e'`` emissionprob.
    n_jobs, allow_missing, restarts
        As for :class:`GaussianHMM` (a missing symbol is NaN in a float ``X``).

    Attributes
    ----------
    startprob_ : ndarray, shape (n_components,)
    transmat_ : ndarray, shape (n_components, n_components)
    emissionprob_ : ndarray, shape (n_components, n_features)
    monitor_ : ConvergenceMonitor
    """

    _param_attrs = ("startprob_", "transmat_", "emissionprob_")

    def __init__(
        self,
        n_components=1,
        startprob_prior=1.0,
        transmat_prior=1.0,
        *,
        emissionprob_prior=1.0,
        n_features=None,
        algorithm="viterbi",
        random_state=None,
        n_iter=10,
        tol=1e-2,
        verbose=False,
        params="ste",
        init_params="ste",
        implementation="log",
        n_jobs=None,
        allow_missing=False,
        restarts=1,
    ):
        self.n_components = n_components
        self.startprob_prior = startprob_prior
        self.transmat_prior = transmat_prior
        self.emissionprob_prior = emissionprob_prior
        self.n_features = n_features
        self.algorithm = algorithm
        self.random_state = random_state
        self.n_iter = n_iter
        self.tol = tol
        self.verbose = verbose
        self.params = params
        self.init_params = init_params
        self.implementation = implementation
        self.n_jobs = n_jobs
        self.allow_missing = allow_missing
        self.restarts = restarts
        self.monitor_ = ConvergenceMonitor(self.tol, self.n_iter, self.verbose)

    def _validate_X(self, X, fitting=False):
        arr = np.asarray(X)
        if self.allow_missing and np.issubdtype(arr.dtype, np.floating):
            observed = arr[~np.isnan(arr)]
            if observed.size and not np.all(observed == np.round(observed)):
                raise ValueError("Symbols should be integers")
        elif not np.issubdtype(arr.dtype, np.integer):
            raise ValueError("Symbols should be integers")
        X = as_frames(arr, allow_nan=self.allow_missing)
        if X.shape[1] != 1:
            raise ValueError(f"CategoricalHMM expects X of shape (n_samples, 1), got {X.shape}")
        observed = X[~np.isnan(X)]
        if observed.size and observed.min() < 0:
            raise ValueError("Symbols should be nonnegative")
        if fitting:
            if self.n_features is not None:
                if observed.size and self.n_features - 1 < observed.max():
                    raise ValueError(
                        f"Largest symbol is {int(observed.max())} but the model only emits symbols up "
                        f"to {self.n_features - 1}"
                    )
            else:
                self.n_features = int(observed.max()) + 1 if observed.size else 1
        return X

    def _check_and_set_n_features(self, X):
        pass  # done by _validate_X on fitting

    def _get_n_fit_scalars_per_param(self):
        nc = self.n_components
        nf = self.n_features
        return {"s": nc - 1, "t": nc * (nc - 1), "e": nc * (nf - 1)}

    def _init(self, X, lengths, random_state):
        super()._init(X, lengths, random_state)
        rs = check_random_state(random_state)
        if self._needs_init("e", "emissionprob_"):
            self.emissionprob_ = rs.rand(self.n_components, self.n_features)
            _normalize(self.emissionprob_, axis=1)

    def _check(self):
        super()._check()
        check_is_fitted(self, "emissionprob_")
        self.emissionprob_ = np.atleast_2d(np.asarray(self.emissionprob_, dtype=np.float64))
        if self.n_features is None:
            self.n_features = self.emissionprob_.shape[1]
        if self.emissionprob_.shape != (self.n_components, self.n_features):
            raise ValueError(f"emissionprob_ must have shape({self.n_components}, {self.n_features})")
        self._check_sum_1("emissionprob_")

    def _to_core(self):
        start, trans = self._chain()
        return _core.HmmCore.categorical(start, trans, _exact_rows(self.emissionprob_), self.n_features)

    def _do_mstep(self, stats):
        super()._do_mstep(stats)
        if "e" in self.params:
            self.emissionprob_ = np.maximum(self.emissionprob_prior - 1 + stats["counts"], 0)
            _normalize(self.emissionprob_, axis=1)

    def _generate_sample_from_state(self, state, random_state=None):
        cdf = np.cumsum(self.emissionprob_[state, :])
        random_state = check_random_state(random_state)
        return [(cdf > random_state.rand()).argmax()]


class PoissonHMM(_BaseHMM):
    """Hidden Markov model with independent Poisson counts per feature (hmmlearn's ``PoissonHMM``).

    Parameters
    ----------
    n_components : int
        Number of states.
    startprob_prior, transmat_prior : array-like or float
        Dirichlet priors (1: none).
    lambdas_prior, lambdas_weight : array-like or float
        Gamma prior of the rates (alpha–beta form).
    algorithm, random_state, n_iter, tol, verbose, implementation
        As for :class:`GaussianHMM`.
    params, init_params : str
        ``'s'`` startprob, ``'t'`` transmat, ``'l'`` lambdas.
    n_jobs, allow_missing, restarts
        As for :class:`GaussianHMM`.

    Attributes
    ----------
    startprob_ : ndarray, shape (n_components,)
    transmat_ : ndarray, shape (n_components, n_components)
    lambdas_ : ndarray, shape (n_components, n_features)
    monitor_ : ConvergenceMonitor
    """

    _param_attrs = ("startprob_", "transmat_", "lambdas_")

    def __init__(
        self,
        n_components=1,
        startprob_prior=1.0,
        transmat_prior=1.0,
        lambdas_prior=0.0,
        lambdas_weight=0.0,
        algorithm="viterbi",
        random_state=None,
        n_iter=10,
        tol=1e-2,
        verbose=False,
        params="stl",
        init_params="stl",
        implementation="log",
        *,
        n_jobs=None,
        allow_missing=False,
        restarts=1,
    ):
        self.n_components = n_components
        self.startprob_prior = startprob_prior
        self.transmat_prior = transmat_prior
        self.lambdas_prior = lambdas_prior
        self.lambdas_weight = lambdas_weight
        self.algorithm = algorithm
        self.random_state = random_state
        self.n_iter = n_iter
        self.tol = tol
        self.verbose = verbose
        self.params = params
        self.init_params = init_params
        self.implementation = implementation
        self.n_jobs = n_jobs
        self.allow_missing = allow_missing
        self.restarts = restarts
        self.monitor_ = ConvergenceMonitor(self.tol, self.n_iter, self.verbose)

    def _get_n_fit_scalars_per_param(self):
        nc = self.n_components
        nf = self.n_features
        return {"s": nc - 1, "t": nc * (nc - 1), "l": nc * nf}

    def _init(self, X, lengths, random_state):
        super()._init(X, lengths, random_state)
        rs = check_random_state(random_state)
        mean_X = np.nanmean(X)
        var_X = np.nanvar(X)
        if self._needs_init("l", "lambdas_"):
            self.lambdas_ = rs.gamma(
                shape=mean_X**2 / var_X,
                scale=var_X / mean_X,
                size=(self.n_components, self.n_features),
            )

    def _check(self):
        super()._check()
        check_is_fitted(self, "lambdas_")
        self.lambdas_ = np.atleast_2d(np.asarray(self.lambdas_, dtype=np.float64))
        n_features = getattr(self, "n_features", self.lambdas_.shape[1])
        if self.lambdas_.shape != (self.n_components, n_features):
            raise ValueError("lambdas_ must have shape (n_components, n_features)")
        self.n_features = n_features

    def _to_core(self):
        start, trans = self._chain()
        return _core.HmmCore.poisson(
            start, trans, np.ascontiguousarray(self.lambdas_, dtype=np.float64), self.n_features
        )

    def _do_mstep(self, stats):
        super()._do_mstep(stats)
        if "l" in self.params:
            alphas, betas = self.lambdas_prior, self.lambdas_weight
            n = stats["post"].sum()
            y_bar = stats["obs"] / stats["post"][:, None]
            self.lambdas_ = (alphas + n * y_bar) / (betas + n)

    def _generate_sample_from_state(self, state, random_state):
        return random_state.poisson(self.lambdas_[state])


class GMMHMM(_BaseHMM):
    """Hidden Markov model with a Gaussian mixture per state (hmmlearn's ``GMMHMM``).

    Parameters
    ----------
    n_components : int
        Number of states.
    n_mix : int
        Number of mixture components per state.
    min_covar : float
        Added to the data covariance that initialises ``covars_``.
    startprob_prior, transmat_prior, weights_prior : array-like or float
        Dirichlet priors (1: none).
    means_prior, means_weight, covars_prior, covars_weight : array-like or float, optional
        Priors of the components, with hmmlearn's defaults per covariance type
        when None.
    algorithm, random_state, n_iter, tol, verbose, implementation
        As for :class:`GaussianHMM`.
    covariance_type : {"spherical", "diag", "full", "tied"}
        ``"tied"``: all components of a state share one full covariance.
    params, init_params : str
        ``'s'``, ``'t'``, ``'m'`` means, ``'c'`` covars, ``'w'`` mixture weights.
    n_jobs, allow_missing, restarts
        As for :class:`GaussianHMM`.

    Attributes
    ----------
    weights_ : ndarray, shape (n_components, n_mix)
    means_ : ndarray, shape (n_components, n_mix, n_features)
    covars_ : ndarray
        (n_components, n_mix) spherical, (n_components, n_mix, n_features)
        diag, (n_components, n_mix, n_features, n_features) full,
        (n_components, n_features, n_features) tied.
    startprob_, transmat_, monitor_
        As for :class:`GaussianHMM`.
    """

    _param_attrs = ("startprob_", "transmat_", "weights_", "means_", "covars_")

    def __init__(
        self,
        n_components=1,
        n_mix=1,
        min_covar=1e-3,
        startprob_prior=1.0,
        transmat_prior=1.0,
        weights_prior=1.0,
        means_prior=0.0,
        means_weight=0.0,
        covars_prior=None,
        covars_weight=None,
        algorithm="viterbi",
        covariance_type="diag",
        random_state=None,
        n_iter=10,
        tol=1e-2,
        verbose=False,
        params="stmcw",
        init_params="stmcw",
        implementation="log",
        *,
        n_jobs=None,
        allow_missing=False,
        restarts=1,
    ):
        self.n_components = n_components
        self.n_mix = n_mix
        self.min_covar = min_covar
        self.startprob_prior = startprob_prior
        self.transmat_prior = transmat_prior
        self.weights_prior = weights_prior
        self.means_prior = means_prior
        self.means_weight = means_weight
        self.covars_prior = covars_prior
        self.covars_weight = covars_weight
        self.algorithm = algorithm
        self.covariance_type = covariance_type
        self.random_state = random_state
        self.n_iter = n_iter
        self.tol = tol
        self.verbose = verbose
        self.params = params
        self.init_params = init_params
        self.implementation = implementation
        self.n_jobs = n_jobs
        self.allow_missing = allow_missing
        self.restarts = restarts
        self.monitor_ = ConvergenceMonitor(self.tol, self.n_iter, self.verbose)

    def _get_n_fit_scalars_per_param(self):
        nc = self.n_components
        nf = self.n_features
        nm = self.n_mix
        return {
            "s": nc - 1,
            "t": nc * (nc - 1),
            "m": nc * nm * nf,
            "c": {
                "spherical": nc * nm,
                "diag": nc * nm * nf,
                "full": nc * nm * nf * (nf + 1) // 2,
                "tied": nc * nf * (nf + 1) // 2,
            }[self.covariance_type],
            "w": nm - 1,
        }

    def _priors(self):
        """hmmlearn's priors with its defaults per covariance type, broadcast to full shape
        (computed, not stored: the constructor's arguments stay as given)."""
        nc, nf, nm = self.n_components, self.n_features, self.n_mix
        kind = self.covariance_type
        cp, cw = self.covars_prior, self.covars_weight
        if kind == "full":
            cp = 0.0 if cp is None else cp
            cw = -(1.0 + nf + 1.0) if cw is None else cw
            cp_shape, cw_shape = (nc, nm, nf, nf), (nc, nm)
        elif kind == "tied":
            cp = 0.0 if cp is None else cp
            cw = -(nm + nf + 1.0) if cw is None else cw
            cp_shape, cw_shape = (nc, nf, nf), (nc,)
        elif kind == "diag":
            cp = -1.5 if cp is None else cp
            cw = 0.0 if cw is None else cw
            cp_shape, cw_shape = (nc, nm, nf), (nc, nm, nf)
        else:
            cp = -(nm + 2.0) / 2.0 if cp is None else cp
            cw = 0.0 if cw is None else cw
            cp_shape, cw_shape = (nc, nm), (nc, nm)
        return {
            "weights_prior": np.broadcast_to(self.weights_prior, (nc, nm)).copy(),
            "means_prior": np.broadcast_to(self.means_prior, (nc, nm, nf)).copy(),
            "means_weight": np.broadcast_to(self.means_weight, (nc, nm)).copy(),
            "covars_prior": np.broadcast_to(cp, cp_shape).copy(),
            "covars_weight": np.broadcast_to(cw, cw_shape).copy(),
        }

    def _init(self, X, lengths, random_state):
        super()._init(X, lengths, random_state)
        nc, nf, nm = self.n_components, self.n_features, self.n_mix
        seed = derived_seed(random_state)

        def compute_cv():
            return _data_cov(X) + self.min_covar * np.eye(nf)

        cv = None
        if self._needs_init("m", "means_"):
            centroids, labels, _ = _core.kmeans(X, nc, seed, 10)
            main_centroid = np.mean(centroids, axis=0)
            rs = check_random_state(seed)
            means = []
            for label in range(nc):
                X_cluster = np.ascontiguousarray(X[labels == label])
                if X_cluster.shape[0] >= nm:
                    means.append(_core.kmeans(X_cluster, nm, seed + 1 + label, 10)[0])
                else:
                    if cv is None:
                        cv = compute_cv()
                    means.append(rs.multivariate_normal(main_centroid, cov=cv, size=nm))
            self.means_ = np.stack(means)
        if self._needs_init("w", "weights_"):
            self.weights_ = np.full((nc, nm), 1 / nm)
        if self._needs_init("c", "covars_"):
            if cv is None:
                cv = compute_cv()
            if not cv.shape:
                cv.shape = (1, 1)
            if self.covariance_type == "tied":
                self.covars_ = np.zeros((nc, nf, nf))
                self.covars_[:] = cv
            elif self.covariance_type == "full":
                self.covars_ = np.zeros((nc, nm, nf, nf))
                self.covars_[:] = cv
            elif self.covariance_type == "diag":
                self.covars_ = np.zeros((nc, nm, nf))
                self.covars_[:] = np.diag(cv)
            elif self.covariance_type == "spherical":
                self.covars_ = np.zeros((nc, nm))
                self.covars_[:] = cv.mean()

    def _check(self):
        super()._check()
        check_is_fitted(self, "means_")
        self.means_ = np.array(self.means_, dtype=np.float64)
        if not hasattr(self, "n_features") or self.n_features is None:
            self.n_features = self.means_.shape[2]
        nc, nf, nm = self.n_components, self.n_features, self.n_mix
        if self.covariance_type not in COVARIANCE_TYPES:
            raise ValueError(f"covariance_type must be one of {COVARIANCE_TYPES}")
        self.weights_ = np.array(self.weights_, dtype=np.float64)
        if self.weights_.shape != (nc, nm):
            raise ValueError(
                f"weights_ must have shape (n_components, n_mix), actual shape: {self.weights_.shape}"
            )
        self._check_sum_1("weights_")
        if self.means_.shape != (nc, nm, nf):
            raise ValueError(
                f"means_ must have shape (n_components, n_mix, n_features), actual shape: {self.means_.shape}"
            )
        self.covars_ = np.array(self.covars_, dtype=np.float64)
        needed = {
            "spherical": (nc, nm),
            "tied": (nc, nf, nf),
            "diag": (nc, nm, nf),
            "full": (nc, nm, nf, nf),
        }[self.covariance_type]
        if self.covars_.shape != needed:
            raise ValueError(
                f"{self.covariance_type!r} mixture covars must have shape {needed}, "
                f"actual shape: {self.covars_.shape}"
            )
        if self.covariance_type in ("spherical", "diag"):
            if np.any(self.covars_ < 0):
                raise ValueError(f"{self.covariance_type!r} mixture covars must be non-negative")

    def _to_core(self):
        start, trans = self._chain()
        return _core.HmmCore.gaussian_mixture(
            start,
            trans,
            _exact_rows(self.weights_),
            np.ascontiguousarray(self.means_),
            np.ascontiguousarray(self.covars_),
            self.covariance_type,
            self.n_mix,
            self.n_features,
        )

    def _do_mstep(self, stats):
        super()._do_mstep(stats)
        nf = self.n_features
        nm = self.n_mix
        pr = self._priors()
        post_mix_sum = stats["post_mix"]
        post_sum = post_mix_sum.sum(axis=1)
        # Inner statistics about each component's reference point c = the
        # current means μ_old: m_n = Σγx = s + n c; hmmlearn's c_n is
        # Σγ(x − μ_old)(x − μ_old)ᵀ = Q exactly.
        c, s, Q = stats["shift"], stats["sum"], stats["sum_sq"]
        old_means = self.means_.copy()
        if "w" in self.params:
            alphas_minus_one = pr["weights_prior"] - 1
            w_n = post_mix_sum + alphas_minus_one
            w_d = (post_sum + alphas_minus_one.sum(axis=1))[:, None]
            self.weights_ = w_n / w_d
        if "m" in self.params:
            m_n = pr["means_weight"][:, :, None] * pr["means_prior"] + s + post_mix_sum[:, :, None] * c
            m_d = post_mix_sum + pr["means_weight"]
            m_d[(self.weights_ == 0) & (m_n == 0).all(axis=-1)] = 1
            self.means_ = m_n / m_d[:, :, None]
            empty = post_mix_sum <= 0
            self.means_[empty] = old_means[empty]
        if "c" in self.params:
            lambdas, mus = pr["means_weight"], pr["means_prior"]
            centered_means = self.means_ - mus
            kind = self.covariance_type
            if kind == "full":
                psis_t = np.transpose(pr["covars_prior"], axes=(0, 1, 3, 2))
                nus = pr["covars_weight"]
                c_n = psis_t + lambdas[:, :, None, None] * _outer(centered_means)
                c_n += Q
                c_d = (post_mix_sum + 1 + nus + nf + 1)[:, :, None, None]
            elif kind == "diag":
                alphas, betas = pr["covars_prior"], pr["covars_weight"]
                c_n = lambdas[:, :, None] * centered_means**2 + 2 * betas
                c_n += Q
                c_d = post_mix_sum[:, :, None] + 1 + 2 * (alphas + 1)
            elif kind == "spherical":
                alphas, betas = pr["covars_prior"], pr["covars_weight"]
                c_n = lambdas * np.einsum("...i,...i", centered_means, centered_means) + 2 * betas
                c_n += Q.sum(axis=-1)
                c_d = nf * (post_mix_sum + 1) + 2 * (alphas + 1)
            else:  # tied
                psis_t = np.transpose(pr["covars_prior"], axes=(0, 2, 1))
                nus = pr["covars_weight"]
                c_n = np.einsum("ij,ijkl->ikl", lambdas, _outer(centered_means)) + psis_t
                c_n += Q.sum(axis=1)
                c_d = (post_sum + nm + nus + nf + 1)[:, None, None]
            new = c_n / c_d
            # A component with no weight keeps its covariance (hmmlearn's
            # becomes 0 there: a degenerate component phasekit refuses).
            empty = post_mix_sum <= 0
            if kind != "tied" and empty.any():
                new[empty] = self.covars_[empty]
            self.covars_ = new

    def _generate_sample_from_state(self, state, random_state):
        cur_weights = self.weights_[state]
        i_gauss = random_state.choice(self.n_mix, p=cur_weights)
        if self.covariance_type == "tied":
            covs = self.covars_
        else:
            covs = self.covars_[:, i_gauss]
            covs = _fill_covars(covs, self.covariance_type, self.n_components, self.n_features)
        return random_state.multivariate_normal(self.means_[state, i_gauss], covs[state])
