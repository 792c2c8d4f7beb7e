"""Demonstration files and folders, read exactly as the ``phasekit`` command reads them.

A demonstration is a CSV file with a header and one row per frame (an empty
cell, ``NaN`` or ``NA`` is a missing value; infinity is refused) or a 2-D
float NPY array (columns ``c0``, ``c1``, …). Errors name the file, row and
column.
"""

from __future__ import annotations

import os
from collections import namedtuple

from . import _core

__all__ = ["Demonstration", "Action", "read_demonstration", "load_demonstrations", "load_action", "load_dataset"]

#: One demonstration: where it came from, its column names, its values (n_frames, n_columns).
Demonstration = namedtuple("Demonstration", ["path", "columns", "values"])
#: One action folder: its name and its ``train_*`` and ``test_*`` demonstrations.
Action = namedtuple("Action", ["name", "train", "test"])


def _out(t, as_frame):
    path, columns, values = t
    if not as_frame:
        return Demonstration(path, list(columns), values)
    import pandas as pd

    df = pd.DataFrame(values, columns=columns)
    df.attrs["path"] = path
    return df


def read_demonstration(path, *, as_frame=False):
    """Reads one CSV or NPY demonstration.

    Parameters
    ----------
    path : str or os.PathLike
    as_frame : bool
        Return a pandas DataFrame (its ``attrs["path"]`` names the file)
        instead of a :data:`Demonstration`.
    """
    return _out(_core.read_table(os.fspath(path)), as_frame)


def load_demonstrations(paths, *, action=None, as_frame=False):
    """The training demonstrations of ``phasekit fit --data PATHS [--action ACTION]``.

    Files are read as given; a folder contributes its ``train_*.csv`` /
    ``train_*.npy`` files, sorted by name (with ``action``, its subfolder of
    that name). All must have the same columns.

    Returns
    -------
    list of Demonstration (or of DataFrame with ``as_frame``)
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    return [_out(t, as_frame) for t in _core.load_training([os.fspath(p) for p in paths], action)]


def load_action(path, *, as_frame=False):
    """One action folder (``train_*`` and ``test_*`` CSV/NPY files): an :data:`Action`."""
    name, train, test = _core.load_action(os.fspath(path))
    return Action(name, [_out(t, as_frame) for t in train], [_out(t, as_frame) for t in test])


def load_dataset(path, *, as_frame=False):
    """A folder of action folders (or one action folder), as ``phasekit evaluate --data`` reads it."""
    return [
        Action(name, [_out(t, as_frame) for t in train], [_out(t, as_frame) for t in test])
        for name, train, test in _core.load_dataset(os.fspath(path))
    ]
