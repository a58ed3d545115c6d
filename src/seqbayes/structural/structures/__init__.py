"""Structures: the shear building, its discretisation and ground motions."""

from .ground_motion import (
    G,
    GroundMotion,
    band_limited_white_noise,
    kanai_tajimi,
    load_el_centro,
    read_at2,
    read_two_column,
    resample,
    scale_to_pga,
)
from .modal import ModalSummary, mac, modal_summary
from .records import ResponseRecord, read_csv, read_hdf5
from .shear_building import (
    DiscreteModel,
    Sensors,
    ShearBuilding,
    add_measurement_noise,
    discretise,
    simulate,
)

__all__ = [
    "G", "GroundMotion", "band_limited_white_noise", "kanai_tajimi", "load_el_centro", "read_at2",
    "read_two_column", "resample", "scale_to_pga", "DiscreteModel", "ShearBuilding",
    "add_measurement_noise", "discretise", "simulate", "ModalSummary", "mac", "modal_summary", "ResponseRecord",
    "read_csv", "read_hdf5", "Sensors",
]
