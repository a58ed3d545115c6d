"""The structural side (Lin et al. 2024): on-line identification of a shear building's storey stiffnesses.

Subpackages and modules, lowest layer first:

- :mod:`~seqbayes.structural.structures`: the models. The linear shear building and its exact
  discretisation, Bouc-Wen hysteretic storeys, ground motions, measured response records and
  modal summaries.
- :mod:`~seqbayes.structural.sparsegrid`: Smolyak sparse-grid interpolation (hierarchical hat basis).
- :mod:`~seqbayes.structural.filters`: batched filters over parameter values: the exact Kalman
  filter, the stochastic EnKF, and the augmented-state EKF and UKF baselines.
- :mod:`~seqbayes.structural.transitions`: the state-transition matrices of a batch of parameter
  values, exact or interpolated on a sparse grid; :mod:`~seqbayes.structural.surrogate` chooses
  between them by measurement.
- :mod:`~seqbayes.structural.sgenmcmc`: the SG-EnMCMC identifier (the exact-posterior
  resample-move sampler and the paper's ensemble variant in :mod:`~seqbayes.structural.ensemble`),
  with its result record and summaries in :mod:`~seqbayes.structural.summaries`.
- :mod:`~seqbayes.structural.stiffness_drop`: on-line detection of a storey stiffness drop and its
  attribution to a storey; the drop's path model and exact references in
  :mod:`~seqbayes.structural.drop_paths`.
- :mod:`~seqbayes.structural.environment`: damage against temperature on identified natural
  frequencies, as model selection between no damage and a loss in each storey.
- The modal path (docs/modal.md): :mod:`~seqbayes.structural.modes_table` (poles and modes as CSV),
  :mod:`~seqbayes.structural.tracking` (poles of many records tracked into modes),
  :mod:`~seqbayes.structural.modal_likelihood` (identified modes as the measurement of a model of
  :mod:`~seqbayes.structural.structures.linear`) and :mod:`~seqbayes.structural.modal_references` (its
  exact references).
"""

from . import filters, sparsegrid, structures
from .environment import EnvironmentMonitor, FrequencyLikelihood
from .modal_likelihood import ModalLikelihood
from .modes_table import PoleTable, read_modes_table
from .tracking import track_poles
from .sgenmcmc import SGEnMCMC
from .stiffness_drop import DropBlock, StiffnessDropMonitor
from .structures import DiscreteModel, GroundMotion, Sensors, ShearBuilding, discretise, kanai_tajimi, simulate
from .structures.bouc_wen import BoucWenBuilding
from .summaries import SGEnMCMCResult
from .surrogate import SurrogateChoice, choose_transition
from .transitions import ExactTransition, SparseGridTransition

__all__ = [
    "filters", "sparsegrid", "structures",
    "ShearBuilding", "BoucWenBuilding", "Sensors", "DiscreteModel", "discretise", "simulate", "GroundMotion",
    "kanai_tajimi",
    "ExactTransition", "SparseGridTransition", "SurrogateChoice", "choose_transition",
    "SGEnMCMC", "SGEnMCMCResult", "StiffnessDropMonitor", "DropBlock", "EnvironmentMonitor", "FrequencyLikelihood",
    "ModalLikelihood", "PoleTable", "read_modes_table", "track_poles",
]
