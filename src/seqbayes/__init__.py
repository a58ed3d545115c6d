"""seqbayes: on-line Bayesian model updating of engineering structures.

The public API: priors, Markov kernels, the on-line samplers SMC and SEMC, the
standalone ensemble sampler, model-class comparison and run results; and the
structural side of Lin et al. (2024): shear buildings, ground motions, filters,
sparse grids and the SG-EnMCMC identifier.
"""

from . import aies, filters, prognostics, reference, sparsegrid, structures
from .predictive import smc2 as nested
from .predictive.history import RunningStatistics
from .predictive.mixture import GaussianMixture, MixtureSum, predictive_density, silverman_bandwidth
from .kernels import Custom, Decay, Drift, Jump, MarkovKernel, Static, jump_posterior
from .predictive.smc2 import KalmanInnerFilter, ParticleInnerFilter
from .prognostics import FirstPassage, time_to_threshold
from .reference import GridReference, grid_filter
from .priors import JointPrior
from .results import Result, StepInfo, StepRecord
from .rng import as_generator
from .selection import ModelComparison, compare
from .engine.drivers import SEMC, SMC
from .engine.errors import InnerFilterWarning, PriorDataConflictWarning, TemperingLimitError, ZeroLikelihoodError
from .engine.pipeline import assimilate
from .engine.settings import SamplerConfig
from .engine.state import SamplerState
from .sgenmcmc import SGEnMCMC, SGEnMCMCResult, SparseGridTransition
from .config import load_config
from .store import RunStore, posterior_to_arviz
from .sgstore import SGRunStore

__version__ = "0.1.0"
__all__ = ["nested", "prognostics", "reference", "KalmanInnerFilter", "ParticleInnerFilter", "FirstPassage",
           "time_to_threshold", "GridReference", "grid_filter", "PriorDataConflictWarning", "InnerFilterWarning", "load_config", "RunStore", "SGRunStore", "posterior_to_arviz", "aies", "filters", "sparsegrid", "structures", "SGEnMCMC", "SGEnMCMCResult", "SparseGridTransition", "GaussianMixture", "MixtureSum", "RunningStatistics", "predictive_density", "silverman_bandwidth", "Custom", "Decay", "Drift", "Jump", "jump_posterior",
           "MarkovKernel", "Static", "JointPrior", "Result", "StepInfo", "StepRecord", "as_generator",
           "ModelComparison", "compare", "SEMC", "SMC", "SamplerConfig", "SamplerState", "ZeroLikelihoodError",
           "TemperingLimitError",
           "assimilate"]
