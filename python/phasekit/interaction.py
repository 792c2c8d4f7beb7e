"""The interaction pipeline of the ``phasekit`` command, from Python.

:class:`InteractionModel` fits one of the command's methods (``"hmm"``,
``"tsc-hmm"``, ``"gmm"``, ``"gmm-tsc"``, … with the same settings) to
two-person demonstrations whose columns are chosen by name, predicts the
robot's frames (mean and covariance, in data units) from the human's,
segments a demonstration into phases and transitions, predicts one frame at a
time for a control loop, and reads and writes the command's model files:
a model saved here is used by ``phasekit predict --model``, and the other way
round, with the same numbers.
"""

from __future__ import annotations

import json
import os
from collections import namedtuple

import numpy as np

from . import _core
from ._base import n_threads

__all__ = ["InteractionModel", "Prediction", "Segmentation", "DEFAULT_HUMAN", "DEFAULT_ROBOT"]

#: The command's default human columns (NuiSI).
DEFAULT_HUMAN = ["p1_wrist_*"]
#: The command's default robot columns.
DEFAULT_ROBOT = ["p2_wrist_*"]

#: The robot's predicted frames: ``mean`` (T, O) and ``covariance`` (T, O, O) or None, data units.
Prediction = namedtuple("Prediction", ["mean", "covariance"])
#: ``states`` (T,), ``transitions`` (frame indices), ``clusters`` (cluster of each transition, -1: none).
Segmentation = namedtuple("Segmentation", ["states", "transitions", "clusters"])

_OPTIONS = json.loads(_core.default_options())


def _table(demo, index, columns_hint=None):
    """``(name, columns, values)`` of a DataFrame, a 2-D array (columns ``c0``, … or
    ``columns_hint``), a :class:`phasekit.datasets.Demonstration` or such a tuple."""
    if hasattr(demo, "columns") and hasattr(demo, "to_numpy") and not isinstance(demo, tuple):
        cols = [str(c) for c in demo.columns]
        values = demo.to_numpy(dtype=np.float64)
        name = str(getattr(demo, "attrs", {}).get("path", f"demonstration {index}"))
    elif isinstance(demo, tuple) and len(demo) == 3:
        name, cols, values = str(demo[0]), [str(c) for c in demo[1]], demo[2]
    else:
        values = np.asarray(demo)
        if values.ndim != 2:
            raise ValueError(f"demonstration {index}: expected a 2-D array (frames × columns), got shape {values.shape}")
        cols = list(columns_hint) if columns_hint is not None else [f"c{j}" for j in range(values.shape[1])]
        name = f"demonstration {index}"
    values = np.ascontiguousarray(values, dtype=np.float64)
    if values.ndim != 2:
        raise ValueError(f"{name}: expected 2-D values, got shape {values.shape}")
    if values.shape[1] != len(cols):
        raise ValueError(f"{name}: {values.shape[1]} columns of values, {len(cols)} column names")
    return name, cols, values


def _patterns(sel, name):
    if sel is None:
        return None
    if isinstance(sel, (str, int, np.integer)):
        sel = [sel]
    out = []
    for s in sel:
        if isinstance(s, (int, np.integer)):
            out.append(f"c{int(s)}")
        elif isinstance(s, str):
            out.append(s)
        else:
            raise ValueError(f"{name}: columns are given by name, glob pattern or index, not {s!r}")
    if not out:
        raise ValueError(f"{name}: no column given")
    return out


class InteractionModel:
    """A model of a two-person interaction, as the ``phasekit`` command fits it.

    Parameters
    ----------
    method : str
        The command's ``--method``: ``"hmm"``, ``"tsc-hmm"`` (the paper's
        transition-state HMM), ``"gmm"``, ``"gmm-tsc"``, … with optional
        ``name:key=value`` settings (``"hmm:states=7"``).
    states : int or "auto", optional
        Base states (components for ``gmm``); ``"auto"`` chooses them by BIC.
    velocity : {"both", "human", "robot", "none"}
        Append first differences of the positions as features (the paper: both).
    standardise : bool
        Z-score the features inside the model (predictions stay in data units).
    n_jobs : int, optional
        Threads of the fit (joblib convention; None: one).
    **options
        The command's other settings: ``tsc_states``, ``window``, ``reg``,
        ``reg_units`` (``"absolute"``, data units²; ``"relative"``, a
        fraction of each feature's variance; or ``"positions"``, a fraction of
        the variance of each feature's position, a velocity's being its
        position's), ``max_iter``, ``tol``,
        ``restarts``, ``seed``, ``max_states``, ``select``, ``rho``,
        ``time_clusters``, ``emission``, ``duration``, ``max_duration``.

    Examples
    --------
    >>> model = InteractionModel("tsc-hmm", states=4).fit(demos, human=["p1_wrist_*"], robot=["p2_wrist_*"])  # doctest: +SKIP
    >>> mean, cov = model.predict(test_demo)                     # doctest: +SKIP
    >>> online = model.online(); robot = online.step(human_frame)  # doctest: +SKIP
    """

    def __init__(self, method="tsc-hmm", *, states=None, velocity="both", standardise=False, n_jobs=None, **options):
        self.method = method
        self.states = states
        self.velocity = velocity
        self.standardise = standardise
        self.n_jobs = n_jobs
        self.options = options
        self._core = None

    # -- fitting --------------------------------------------------------------------

    def _option_json(self):
        opts = {}
        for k, v in self.options.items():
            if k not in _OPTIONS:
                raise ValueError(f"unknown option {k!r} (options: {', '.join(sorted(_OPTIONS))})")
            opts[k] = v.item() if isinstance(v, np.generic) else v
        if self.states is not None:
            if self.states == "auto":
                opts["auto_states"] = True
            else:
                opts["states"] = int(self.states)
        if "select" in opts and isinstance(opts["select"], str):
            opts["select"] = opts["select"].capitalize() if opts["select"] in ("bic", "gmeans") else opts["select"]
        return json.dumps(opts)

    def fit(self, demos, human=None, robot=None):
        """Fits the method to demonstrations.

        Parameters
        ----------
        demos : list
            Demonstrations: pandas DataFrames with named columns, 2-D arrays
            (columns ``c0``, ``c1``, …), or :class:`phasekit.datasets.Demonstration`.
        human, robot : list of str or int, optional
            The human's and the robot's columns: names, glob patterns
            (``"p1_wrist_*"``) or indices. Default: the command's NuiSI columns.

        Returns
        -------
        self
        """
        if isinstance(demos, (np.ndarray,)) and demos.ndim == 2:
            demos = [demos]
        tables = [_table(d, i) for i, d in enumerate(demos)]
        if not tables:
            raise ValueError("no demonstration to fit")
        h = _patterns(human, "human") or DEFAULT_HUMAN
        r = _patterns(robot, "robot") or DEFAULT_ROBOT
        self._core = _core.InteractionCore.fit(
            tables,
            h,
            r,
            self.method,
            self.velocity,
            bool(self.standardise),
            self._option_json(),
            n_threads(self.n_jobs),
        )
        return self

    # -- the fitted model -------------------------------------------------------------

    def _fitted(self):
        if self._core is None:
            from ._base import NotFittedError

            raise NotFittedError("This InteractionModel is not fitted yet: call fit or load a model file.")
        return self._core

    def predict(self, human, return_covariance=True):
        """The robot's frames predicted from the human's, causally (frame ``t`` uses frames ``≤ t``).

        Parameters
        ----------
        human : DataFrame or array-like
            A DataFrame holding the model's human columns (by name; other
            columns are ignored), or an array whose columns are the human
            columns in the model's order (:attr:`human_columns`).
        return_covariance : bool
            Also return the predictive covariances.

        Returns
        -------
        Prediction
            ``mean`` (n_frames, n_robot_features) and ``covariance``
            (n_frames, n_robot_features, n_robot_features) or None, in data units.
        """
        core = self._fitted()
        name, cols, values = _table(human, 0, columns_hint=core.human_columns)
        mean, cov = core.predict(name, cols, values, return_covariance)
        return Prediction(mean, cov)

    def segment(self, demo):
        """Phases and transitions of a demonstration (it needs both people's columns).

        Parameters
        ----------
        demo : DataFrame or array-like
            A DataFrame with the model's human and robot columns, or an array
            whose columns are :attr:`human_columns` then :attr:`robot_columns`.

        Returns
        -------
        Segmentation
        """
        core = self._fitted()
        name, cols, values = _table(demo, 0, columns_hint=core.human_columns + core.robot_columns)
        states, transitions, clusters = core.segment(name, cols, values)
        return Segmentation(states, transitions, clusters)

    def online(self):
        """A frame-by-frame predictor for a control loop (what ``phasekit stream`` runs).

        ``step(frame)`` takes the human's raw frame (the values of
        :attr:`human_columns`, a 1-D array or a sequence; NaN = missing) and
        returns the robot's predicted frame; ``step_with_covariance(frame)``
        also returns its covariance; ``reset()`` starts a new interaction.
        """
        return self._fitted().online()

    # -- model files --------------------------------------------------------------------

    def save(self, path):
        """Writes the model file (the format of ``phasekit fit -o``), atomically."""
        self._fitted().save(os.fspath(path))

    @classmethod
    def load(cls, path):
        """Reads a model file written by ``phasekit fit -o`` or :meth:`save`."""
        core = _core.InteractionCore.load(os.fspath(path))
        model = cls(core.method)
        model._core = core
        return model

    def to_json(self):
        """The model file's text."""
        return self._fitted().to_json()

    @classmethod
    def from_json(cls, text):
        """A model from a model file's text."""
        core = _core.InteractionCore.from_json(text)
        model = cls(core.method)
        model._core = core
        return model

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_core"] = None if self._core is None else self._core.to_json()
        return state

    def __setstate__(self, state):
        text = state.pop("_core")
        self.__dict__.update(state)
        self._core = None if text is None else _core.InteractionCore.from_json(text)

    # -- what the model is ------------------------------------------------------------------

    @property
    def n_states(self):
        """Total states (components) of the model that predicts."""
        return self._fitted().n_states

    @property
    def human_columns(self):
        """The human's raw columns the model reads, in order."""
        return self._fitted().human_columns

    @property
    def robot_columns(self):
        """The robot's raw columns."""
        return self._fitted().robot_columns

    @property
    def features(self):
        """The model's features: the columns and their velocities ``d_…``."""
        return self._fitted().features

    @property
    def robot_features(self):
        """Names of the predicted robot features (the columns of :meth:`predict`'s mean)."""
        return self._fitted().robot_features

    @property
    def fit_summary(self):
        """What the fit did: iterations, log-likelihood per iteration, convergence, warnings, …"""
        return json.loads(self._fitted().fit_summary())

    def __repr__(self):
        if self._core is None:
            return f"InteractionModel({self.method!r})"
        return f"InteractionModel({self._core.method!r}, {self.n_states} states, human {self.human_columns}, robot {self.robot_columns})"
