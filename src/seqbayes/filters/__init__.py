"""Batched Kalman-type filters for the shear-building model: the exact Kalman
filter (batched over parameters), the stochastic EnKF, and the augmented-state
EKF and UKF baselines."""

from .ekf import AugmentedModel, JointFilterResult, ekf
from .enkf import (
    EnKFResult,
    enkf_filter,
    ensemble_moments,
    forecast,
    perturbed_observation_update,
    predictive_log_likelihood,
)
from .kalman import KalmanResult, kalman_filter
from .ukf import sigma_points, ukf

__all__ = [
    "AugmentedModel", "JointFilterResult", "ekf", "ukf", "sigma_points", "EnKFResult",
    "enkf_filter", "ensemble_moments", "forecast", "perturbed_observation_update",
    "predictive_log_likelihood", "KalmanResult", "kalman_filter",
]
