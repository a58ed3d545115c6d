"""The discrete state-space matrices of a batch of stiffness ratios: exact, or interpolated on a sparse grid.

A *transition* is a callable ``transition(theta (N, d)) -> DiscreteModel`` with the matrices
``A, B0, B1 (N, ...)`` of the exact first-order-hold discretisation and ``H``. The filters and the
identifiers only call it; :func:`~seqbayes.structural.surrogate.choose_transition` picks one by
measurement, and :func:`~seqbayes.structural.structures.bouc_wen.bouc_wen_transition` gives the
Bouc-Wen ones.
"""

from __future__ import annotations

import numpy as np

from . import sparsegrid
from .structures.shear_building import DiscreteModel, ShearBuilding, discretise

__all__ = ["ExactTransition", "SparseGridTransition"]


class ExactTransition:
    """Discrete matrices from one matrix exponential per member (the reference)."""

    def __init__(self, building: ShearBuilding, dt: float, hold: str = "foh",
                 channels: str = "absolute_acceleration"):
        self.building, self.dt, self.hold, self.channels = building, float(dt), hold, channels

    def __call__(self, theta) -> DiscreteModel:
        return discretise(self.building, theta, self.dt, self.hold, self.channels)


class SparseGridTransition:
    """``A, B0, B1`` of the exact discretisation interpolated over ``theta`` (Eqs. 18, 21).

    The observation matrix ``H(theta)`` is affine in ``theta`` and is evaluated
    exactly. Built once on the box ``[lower, upper]`` (the prior support).

    Parameters
    ----------
    building : ShearBuilding
    dt : float
    lower, upper : (d,) arrays
        The box of ``theta``.
    level : int
        Sparse-grid level ``n`` (paper: 6).
    hold, channels, basis : see :func:`~seqbayes.structural.structures.discretise` and
        :class:`~seqbayes.structural.sparsegrid.SparseGrid`.
    """

    def __init__(self, building: ShearBuilding, dt: float, lower: ArrayLike, upper: ArrayLike, level: int = 6,
                 hold: str = "foh", channels: str = "absolute_acceleration", basis: str = "modified"):
        self.building, self.dt, self.hold, self.channels = building, float(dt), hold, channels
        self.m = building.state_dim
        lower = np.asarray(lower, float)
        upper = np.asarray(upper, float)
        building.check_sampling(dt, upper)  # stiffest corner: highest mode

        def matrices(theta):
            model = discretise(building, theta, dt, hold, channels)
            return np.concatenate([model.A.reshape(len(theta), -1), model.B0, model.B1], axis=1)

        self.interpolant = sparsegrid.interpolate(matrices, building.n_storeys, level, lower, upper,
                                                  basis=basis)

    @property
    def n_points(self) -> int:
        return self.interpolant.grid.n_points

    def __call__(self, theta) -> DiscreteModel:
        theta = np.atleast_2d(np.asarray(theta, float))
        flat = self.interpolant(theta)
        m, n = self.m, theta.shape[0]
        A = flat[:, : m * m].reshape(n, m, m)
        B0 = flat[:, m * m : m * m + m]
        B1 = flat[:, m * m + m :]
        H = self.building.observation_matrix(theta, self.channels)
        return DiscreteModel(A, B0, B1, H, self.dt, self.hold)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
