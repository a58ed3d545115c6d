"""Run stores: a monitoring run kept in one NetCDF-4 file that resumes exactly where it stopped.

One base (:mod:`seqbayes.store.base`: hashes, open, append and whole writes, duplicate checks, over
:mod:`seqbayes.store.files`: the redo journal, atomic writes, and :mod:`seqbayes.store.locks`) and one
backend per run kind, found through :mod:`seqbayes.store.registry`: SMC/SEMC runs (:class:`RunStore`),
SG-EnMCMC runs (:class:`SGRunStore`) and modal runs (:class:`ModalRunStore`, :mod:`seqbayes.store.modal`) and monitor runs (:class:`MonitorRunStore`,
:mod:`seqbayes.store.monitor`). :func:`open_run` opens any run, :func:`create_run` starts one from
:func:`load_config`'s configuration.
"""

from .config import ConfigError, RunConfig, load_config
from .datasets import DataError
from .errors import BoundWarning, DuplicateDatasetError, ModelChangedError, StoreError, StoreLockTimeout, StoreWarning
from .registry import create_run, open_run
# the backends register their run kinds as they are imported
from .modal import ModalRunStore
from .monitor import MonitorRunStore
from .sg import SGRunStore
from .smc import RunStore, posterior_to_arviz

__all__ = ["RunStore", "SGRunStore", "ModalRunStore", "MonitorRunStore", "open_run", "create_run", "load_config", "StoreError", "DuplicateDatasetError",
           "ModelChangedError", "BoundWarning", "ConfigError", "DataError", "RunConfig", "posterior_to_arviz",
           "StoreLockTimeout", "StoreWarning"]
