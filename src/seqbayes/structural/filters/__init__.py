"""Batched Kalman-type filters for the shear-building model: the exact Kalman
filter (batched over parameters), the stochastic EnKF, and the augmented-state
EKF and UKF baselines."""

from .ekf import AugmentedModel, JointFilterResult, ekf
from .enkf import (
    EnKFBank,
    EnKFResult,
    enkf_filter,
    enkf_log_likelihood,
    ensemble_moments,
    forecast,
    perturbed_observation_update,
    predictive_log_likelihood,
)
from .kalman import KalmanBank, KalmanResult, kalman_filter, kalman_log_likelihood
from .ukf import sigma_points, ukf

__all__ = [
    "AugmentedModel", "JointFilterResult", "ekf", "ukf", "sigma_points", "EnKFResult",
    "enkf_filter", "ensemble_moments", "forecast", "perturbed_observation_update",
    "predictive_log_likelihood", "KalmanResult", "kalman_filter", "KalmanBank", "kalman_log_likelihood",
    "EnKFBank", "enkf_log_likelihood",
]
