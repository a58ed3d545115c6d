"""Run stores: a monitoring run kept in one NetCDF-4 file that resumes exactly where it stopped."""

from .config import ConfigError, RunConfig, load_config
from .datasets import DataError
from .sg import SGRunStore
from .smc import BoundWarning, DuplicateDatasetError, ModelChangedError, RunStore, StoreError, posterior_to_arviz

__all__ = ["RunStore", "SGRunStore", "StoreError", "DuplicateDatasetError", "ModelChangedError", "BoundWarning",
           "ConfigError", "DataError", "RunConfig", "load_config", "posterior_to_arviz"]
