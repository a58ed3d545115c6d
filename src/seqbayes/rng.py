"""One entry point for randomness: every draw in seqbayes goes through a
:class:`numpy.random.Generator` obtained here. There is no global state."""

from __future__ import annotations

import numbers

import numpy as np

__all__ = ["as_generator", "generator_state", "generator_from_state"]


def as_generator(rng: int | np.random.Generator | None = None) -> np.random.Generator:
    """Return a :class:`numpy.random.Generator` for ``rng``.

    Parameters
    ----------
    rng : None, int, numpy.random.SeedSequence or numpy.random.Generator
        ``None`` gives fresh OS entropy (not reproducible); an int or a
        ``SeedSequence`` seeds a new PCG64 generator; a ``Generator`` is
        returned unchanged, so the caller's stream is advanced.

    Examples
    --------
    >>> as_generator(3).integers(10) == as_generator(3).integers(10)
    True
    """
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, np.random.SeedSequence):
        return np.random.default_rng(rng)
    if isinstance(rng, numbers.Integral) and not isinstance(rng, bool):
        if rng < 0:
            raise ValueError(f"rng: a seed must be non-negative, got {rng}")
        return np.random.default_rng(int(rng))
    raise TypeError(
        f"rng: expected None, an int seed or a numpy.random.Generator, got {type(rng).__name__}"
    )


def generator_state(rng: np.random.Generator) -> dict:
    """The bit generator's state as a plain dict (for persisting a run)."""
    return rng.bit_generator.state


def generator_from_state(state: dict) -> np.random.Generator:
    """Rebuild a generator from :func:`generator_state` output, bit for bit."""
    name = state.get("bit_generator") if isinstance(state, dict) else None
    kind = getattr(np.random, name, None) if isinstance(name, str) else None
    if not (isinstance(kind, type) and issubclass(kind, np.random.BitGenerator)):  # a stored state is data
        raise ValueError(f"rng state: {str(name)[:40]!r} is not a numpy bit generator")
    bit_generator = kind()
    try:
        bit_generator.state = state
    except (TypeError, ValueError, KeyError, OverflowError) as err:
        raise ValueError(f"rng state: not a {name} state ({type(err).__name__}: {str(err)[:80]})") from None
    return np.random.Generator(bit_generator)
