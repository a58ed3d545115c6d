"""Operational modal analysis: from ambient records to modes with standard errors (SSI-cov, automated).

(Full description below is completed in the final commit.)
"""

from .core import Poles, output_covariances, ssi_poles
from .identify import Modes, record_row, ssi_cov, stabilisation_diagram
from .settings import OMAWarning, Settings
from .simulate import ModalModel, ambient_record, building_3d, modal_record

__all__ = ["Modes", "Poles", "Settings", "OMAWarning", "output_covariances", "ssi_poles", "stabilisation_diagram",
           "ssi_cov", "record_row", "ambient_record", "ModalModel", "building_3d", "modal_record"]
