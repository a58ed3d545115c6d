"""seqbayes: on-line Bayesian model updating of engineering structures.

What a user types: priors and Markov kernels, the on-line samplers SMC and SEMC (with SMC^2's inner
filters and the exact static prior's running statistics), results and model-class comparison,
first-passage forecasts, run stores, and the SG-EnMCMC identifier of Lin et al. (2024). The rest
is in the subpackages: ``engine`` (the update pipeline), ``predictive`` (predictive priors),
``moves``, ``store`` (run stores, configuration, reports), ``structural`` (buildings, filters,
sparse grids, SG-EnMCMC, the stiffness-drop monitor); ``studies`` and ``models`` hold the papers'
studies and example models.
"""

from .engine.drivers import SEMC, SMC
from .core.errors import InnerFilterWarning, PriorDataConflictWarning, TemperingLimitError, ZeroLikelihoodError
from .kernels import Custom, Decay, Drift, Jump, MarkovKernel, Static, jump_posterior
from .predictive.history import RunningStatistics
from .predictive.smc2 import KalmanInnerFilter, ParticleInnerFilter
from .priors import JointPrior
from .prognostics import time_to_threshold
from .results import Result, StepInfo
from .selection import compare
from .store import RunStore, load_config, open_run
from .structural import SGEnMCMC

from ._version import __version__
__all__ = [
    "SMC", "SEMC", "JointPrior", "MarkovKernel", "Static", "Drift", "Decay", "Jump", "Custom", "jump_posterior",
    "RunningStatistics", "KalmanInnerFilter", "ParticleInnerFilter", "Result", "StepInfo", "compare",
    "time_to_threshold", "PriorDataConflictWarning", "InnerFilterWarning", "ZeroLikelihoodError",
    "TemperingLimitError", "RunStore", "open_run", "load_config", "SGEnMCMC",
]
