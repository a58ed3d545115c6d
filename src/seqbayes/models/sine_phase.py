"""A nonlinear problem with one static and one drifting parameter and an exact grid-filter answer (issue 23).

``y_j = a sin(x_s + u_j) + e_j`` at five phases ``u_j`` in ``[0, pi]``, ``e_j ~ N(0, 0.5^2)``: a static amplitude
``a ~ U(0.2, 3)`` and a drifting phase ``x_s`` (random walk, sd 0.05, ``x_1 ~ U(-3, 3)``). SMC^2 runs it with its
default particle inner filter; :meth:`SinePhase.exact` is the grid filter of :func:`seqbayes.reference.grid_filter`.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from ..kernels import Drift, MarkovKernel, Static
from ..priors import JointPrior
from ..reference import GridStep, grid_filter

__all__ = ["SinePhase"]


class SinePhase:
    """The model, its simulator and its exact filter."""

    box = np.array([[0.2, 3.0], [-3.0, 3.0]])
    u = np.linspace(0.0, np.pi, 5)
    noise, drift = 0.5, 0.05

    def __init__(self):
        self.prior = JointPrior({"a": stats.uniform(0.2, 2.8), "x": stats.uniform(-3.0, 6.0)})
        self.kernel = MarkovKernel([Static(), Drift(0.0, noise_std=self.drift)])

    def loglike(self, theta: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``log p(y | theta)`` for ``theta (N, 2)`` and one dataset ``y (5,)``, returns ``(N,)``."""
        mean = theta[:, :1] * np.sin(theta[:, 1:2] + self.u)
        return (-0.5 * np.sum((y - mean) ** 2, axis=1) / self.noise**2
                - self.u.size * np.log(self.noise * np.sqrt(2 * np.pi)))

    def simulate(self, steps: int, rng) -> list[np.ndarray]:
        """``steps`` datasets from ``a = 1.2`` and a phase starting at 0.3."""
        rng = np.random.default_rng(rng)
        x = 0.3 + np.cumsum(np.r_[0.0, rng.normal(0.0, self.drift, steps - 1)])
        return [1.2 * np.sin(xs + self.u) + rng.normal(0.0, self.noise, self.u.size) for xs in x]

    def exact(self, data, n_points=(1601, 201)) -> list[GridStep]:
        """The exact filter's steps (``mean``, ``std``, ``log_evidence_increment``): 1601 points on the static
        amplitude's axis (fixed at step 1, so fine enough for its posterior sd at s = 300, ~0.02)."""

        def log_likelihood(axes, y):
            a, x = axes[0][:, None, None], axes[1][None, :, None]
            r = y - a * np.sin(x + self.u)
            return (-0.5 * np.sum(r**2, axis=2) / self.noise**2
                    - self.u.size * np.log(self.noise * np.sqrt(2 * np.pi)))

        return grid_filter(data, log_likelihood, self.box, [lambda v: v, lambda v: v], [0.0, self.drift], n_points)
