"""phasekit: learning interactions from demonstrations with probabilistic models.

* :mod:`phasekit.hmm` — hmmlearn's ``GaussianHMM``, ``GMMHMM``, ``CategoricalHMM``
  and ``PoissonHMM``, computed by phasekit (``from phasekit import hmm`` in place
  of ``from hmmlearn import hmm``);
* :mod:`phasekit.mixture` — scikit-learn's ``GaussianMixture``;
* :mod:`phasekit.gmr` — Gaussian mixture regression (static and HMM-based);
* :class:`InteractionModel` — the ``phasekit`` command's pipeline: fit a method
  to two-person demonstrations, predict the robot from the human (batch or one
  frame at a time), segment, save and load the command's model files;
* :mod:`phasekit.datasets` — demonstration folders as the command reads them;
* :mod:`phasekit.dask` — Baum-Welch and mixture EM over a ``dask.bag`` of
  sequences (import it explicitly; it needs ``dask``).
"""

from . import _core, datasets, gmr, hmm, mixture
from ._core import __version__
from .interaction import InteractionModel, Prediction, Segmentation

__all__ = [
    "__version__",
    "hmm",
    "mixture",
    "gmr",
    "datasets",
    "InteractionModel",
    "Prediction",
    "Segmentation",
]
