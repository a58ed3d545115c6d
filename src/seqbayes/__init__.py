"""seqbayes: on-line Bayesian model updating of engineering structures."""

from .priors import JointPrior
from .rng import as_generator

__version__ = "0.1.0"
__all__ = ["JointPrior", "as_generator"]
