"""seqbayes: on-line Bayesian model updating of engineering structures.

The public API: priors, Markov kernels, the on-line samplers SMC and SEMC, the
standalone ensemble sampler, model-class comparison and run results; and the
structural side of Lin et al. (2024): shear buildings, ground motions, filters,
sparse grids and the SG-EnMCMC identifier.
"""

from . import aies, nested, prognostics, reference
from .structural import SGEnMCMC, SGEnMCMCResult, SparseGridTransition, filters, sparsegrid, structures
from .density import GaussianMixture, MixtureSum, RunningStatistics, predictive_density, silverman_bandwidth
from .kernels import Custom, Decay, Drift, Jump, MarkovKernel, Static, jump_posterior
from .nested import KalmanInnerFilter, ParticleInnerFilter
from .prognostics import FirstPassage, time_to_threshold
from .reference import GridReference, grid_filter
from .priors import JointPrior
from .results import Result, StepInfo, StepRecord
from .rng import as_generator
from .selection import ModelComparison, compare
from .sequential import (SEMC, SMC, InnerFilterWarning, PriorDataConflictWarning, SamplerConfig, SamplerState, TemperingLimitError,
                         ZeroLikelihoodError, assimilate)
from .store import RunStore, SGRunStore, load_config, open_run, posterior_to_arviz

__version__ = "0.1.0"
__all__ = ["nested", "prognostics", "reference", "KalmanInnerFilter", "ParticleInnerFilter", "FirstPassage",
           "time_to_threshold", "GridReference", "grid_filter", "PriorDataConflictWarning", "InnerFilterWarning", "load_config", "RunStore", "SGRunStore", "open_run", "posterior_to_arviz", "aies", "filters", "sparsegrid", "structures", "SGEnMCMC", "SGEnMCMCResult", "SparseGridTransition", "GaussianMixture", "MixtureSum", "RunningStatistics", "predictive_density", "silverman_bandwidth", "Custom", "Decay", "Drift", "Jump", "jump_posterior",
           "MarkovKernel", "Static", "JointPrior", "Result", "StepInfo", "StepRecord", "as_generator",
           "ModelComparison", "compare", "SEMC", "SMC", "SamplerConfig", "SamplerState", "ZeroLikelihoodError",
           "TemperingLimitError",
           "assimilate"]
