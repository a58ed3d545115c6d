"""Step-size adaptation of the SEMC sampler (Sec. 3.1, Algorithm 2 lines 9-21)."""

from __future__ import annotations

import numpy as np

__all__ = ["paper_target_acceptance", "next_step_size", "MIN_STEP_SIZE"]

#: Algorithm 2 line 15: the step size never drops below 1.01.
MIN_STEP_SIZE = 1.01


def paper_target_acceptance(dim: int) -> float:
    """``0.21 / d + 0.23`` (Eq. 10), a random-walk rule of thumb (Roberts et al. 1997)."""
    if dim < 1:
        raise ValueError(f"dim: must be >= 1, got {dim}")
    return 0.21 / dim + 0.23


def next_step_size(step_size: float, acceptance: float, target: float) -> float:
    """``max(u exp(alpha - alpha_tr), 1.01)`` (Eq. 9 and Algorithm 2 line 15).

    >>> round(next_step_size(2.0, 0.5, 0.5), 6)
    2.0
    """
    if not np.isfinite(acceptance):
        return float(step_size)
    return float(max(step_size * np.exp(acceptance - target), MIN_STEP_SIZE))  # Eq. (9)
