"""Automated OMA of one record: the stabilisation diagram, clustering of its stable poles, the modes and their errors.

:func:`ssi_cov` is the entry point (see the package docstring for the whole path). Its steps:

1. :func:`~.settings.normalise`, :func:`~.settings.choose_settings` and :func:`~.settings.decimate`
   (band, decimation, block rows, orders, blocks chosen from the record);
2. the stabilisation diagram (:func:`diagram_from_svd`): the poles of orders ``2, 4, .., max_order``
   inside the band with a damping ratio in ``(0, max_damping)``; a pole is stable when the previous
   order has one within ``frequency_tol`` in frequency, ``damping_tol`` in damping (both relative)
   and with a MAC above ``mac_tol``;
3. hierarchical clustering of the stable poles (average linkage, cut at 1) on the distance
   ``|f_i - f_j| / max(f_i, f_j) / cluster_frequency + (1 - MAC_ij) / cluster_mac`` (the frequency-and-MAC
   distance of Magalhães, Cunha & Caetano 2009, who cut ``df / f + 1 - MAC`` at 0.02; with 0.02 the poles of
   a weakly excited mode in a 5-minute record, whose shapes vary from order to order, fall into several
   clusters: docs/oma.md; scaled as here, poles 0.5 % apart or with MAC 0.9 are one step apart, and close
   modes 1 % apart stay apart whatever their shapes); a cluster holding two poles at many orders is two
   modes and is split by frequency (Reynders, Houbrechts & De Roeck 2012 use the same one-pole-per-order
   rule);
4. a cluster is a mode when it holds stable poles at ``min_stable_fraction`` of the orders; its
   representative is its pole nearest the cluster's median frequency, reported with the standard
   errors of :mod:`.uncertainty` at that pole's order;
5. a result with no mode, or with further candidates that were stable at too few orders, says so
   (:class:`~.settings.OMAWarning`, and ``Modes.status`` / ``Modes.messages``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage

from .core import Poles, check_record, complex_mac, real_shapes
from .settings import Settings, choose_settings, decimate, normalise, warn
from .uncertainty import jackknife_clusters, toeplitz_blocks

__all__ = ["Modes", "ssi_cov", "record_row", "stabilisation_diagram", "diagram_from_svd", "cluster_poles", "TOLERANCES"]

#: Default stability and clustering settings (keywords of :func:`ssi_cov`).
#: A mode is reported from its poles at its lowest stable orders, where the model has no more states than
#: it needs and its standard errors are calibrated (docs/oma.md, "Calibration"), averaged over this many orders.
REPORT_ORDERS = 3
TOLERANCES = {"frequency_tol": 0.01, "damping_tol": 0.3, "mac_tol": 0.95, "max_damping": 0.15,
              "cluster_frequency": 0.0075, "cluster_mac": 0.2, "min_stable_fraction": 0.3}


@dataclass(frozen=True)
class Modes:
    """Physical modes picked from a stabilisation diagram, with their standard errors.

    Attributes
    ----------
    frequencies : (k,) array
        Natural frequencies [Hz], ascending.
    damping_ratios : (k,) array
    shapes : (p, k) array
        Real mode shapes, largest component +1.
    n_stable : (k,) int array
        How many model orders carry a stable pole of the mode.
    std_frequencies, std_damping_ratios : (k,) arrays
        Standard errors (NaN where not estimated: a record too short for 5 blocks).
    std_shapes : (p, k) array
    mpc, mpd : (k,) arrays
        Modal phase collinearity and mean phase deviation [degrees] of the reported pole.
    orders : (k,) int array
        Model order of the reported pole.
    status : str
        ``"complete"``, ``"partial"`` (candidates were left out: see ``messages``) or ``"empty"``.
    messages : tuple of str
        What the user should know (each also emitted as an ``OMAWarning``).
    settings : Settings or None
        What was chosen from the record.
    diagram : tuple of Poles
        The stabilisation diagram (frequencies in Hz of the record).
    candidates : (c,) array
        Frequencies of the clusters that were stable at too few orders.
    """

    frequencies: np.ndarray
    damping_ratios: np.ndarray
    shapes: np.ndarray
    n_stable: np.ndarray
    std_frequencies: np.ndarray = None
    std_damping_ratios: np.ndarray = None
    std_shapes: np.ndarray = None
    mpc: np.ndarray = None
    mpd: np.ndarray = None
    orders: np.ndarray = None
    status: str = "complete"
    messages: tuple = ()
    settings: Settings | None = None
    diagram: tuple = field(default=(), repr=False)
    candidates: np.ndarray = None

    def __post_init__(self):
        k, p = len(self.frequencies), self.shapes.shape[0]
        for name, shape in (("std_frequencies", (k,)), ("std_damping_ratios", (k,)), ("std_shapes", (p, k)),
                            ("mpc", (k,)), ("mpd", (k,))):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(shape, np.nan))
        if self.orders is None:
            object.__setattr__(self, "orders", np.zeros(k, dtype=int))
        if self.candidates is None:
            object.__setattr__(self, "candidates", np.zeros(0))


def _tolerances(options: dict) -> dict:
    unknown = set(options) - set(TOLERANCES)
    if unknown:
        raise TypeError(f"ssi_cov: unknown option(s) {sorted(unknown)}; known: {sorted(TOLERANCES)}")
    values = {**TOLERANCES, **options}
    for name, value in values.items():
        if not (isinstance(value, (int, float, np.floating)) and 0 < float(value) <= 1):
            raise ValueError(f"{name}: expected a value in (0, 1], got {value!r}")
    return values


def diagram_from_svd(U: np.ndarray, p: int, settings: Settings, tolerances: dict) -> list[Poles]:
    """The stabilisation diagram (step 2 of the module docstring) from the left singular vectors of ``T_s``."""
    from .core import poles_at_order

    lo, hi = settings.band
    diagram, previous = [], None
    for order in range(2, settings.max_order + 1, 2):
        poles = poles_at_order(U, p, order, settings.dt)
        inside = ((poles.frequencies >= lo) & (poles.frequencies <= hi) & (poles.damping_ratios > 0)
                  & (poles.damping_ratios < tolerances["max_damping"]))
        poles = Poles(order, poles.frequencies[inside], poles.damping_ratios[inside], poles.shapes[:, inside],
                      np.zeros(int(inside.sum()), dtype=bool), poles.mpc[inside], poles.mpd[inside])
        if previous is not None and previous.frequencies.size and poles.frequencies.size:
            df = np.abs(poles.frequencies[:, None] - previous.frequencies[None]) / poles.frequencies[:, None]
            dz = np.abs(poles.damping_ratios[:, None] - previous.damping_ratios[None]) / poles.damping_ratios[:, None]
            match = ((df < tolerances["frequency_tol"]) & (dz < tolerances["damping_tol"])
                     & (complex_mac(poles.shapes, previous.shapes) > tolerances["mac_tol"]))
            poles = Poles(order, poles.frequencies, poles.damping_ratios, poles.shapes, match.any(axis=1),
                          poles.mpc, poles.mpd)
        diagram.append(poles)
        previous = poles
    return diagram


def _split_doubles(members: np.ndarray, frequencies: np.ndarray, orders: np.ndarray) -> list[np.ndarray]:
    """A cluster with two poles at a third or more of its orders is two modes: split it at the frequency
    that best separates them (two-means in one dimension), once."""
    counts = np.bincount(np.unique(orders[members], return_inverse=True)[1])
    if np.mean(counts >= 2) < 1 / 3 or members.size < 4:
        return [members]
    f = np.sort(frequencies[members])
    costs = [np.var(f[:i]) * i + np.var(f[i:]) * (f.size - i) for i in range(1, f.size)]
    cut = f[int(np.argmin(costs)) + 1]
    low, high = members[frequencies[members] < cut], members[frequencies[members] >= cut]
    return [low, high] if low.size and high.size else [members]


def cluster_poles(diagram: list[Poles], tolerances: dict) -> list[dict]:
    """Clusters of the stable poles (step 3): each a dict of the member ``indices`` into the pooled stable
    poles, with the pooled ``frequencies``, ``damping``, ``shapes``, ``orders``, ``index`` (position
    within its order) and ``n_orders`` (distinct orders)."""
    f, z, shapes, orders, index = [], [], [], [], []
    for poles in diagram:
        stable = np.flatnonzero(poles.stable)
        f.append(poles.frequencies[stable])
        z.append(poles.damping_ratios[stable])
        shapes.append(poles.shapes[:, stable])
        orders.append(np.full(stable.size, poles.order))
        index.append(stable)
    f = np.concatenate(f)
    if f.size == 0:
        return []
    z, orders, index = np.concatenate(z), np.concatenate(orders), np.concatenate(index)
    shapes = np.concatenate(shapes, axis=1)
    if f.size == 1:
        labels = np.array([1])
    else:
        distance = (np.abs(f[:, None] - f[None]) / np.maximum(f[:, None], f[None]) / tolerances["cluster_frequency"]
                    + (1 - complex_mac(shapes, shapes)) / tolerances["cluster_mac"])
        condensed = np.clip(distance[np.triu_indices(f.size, 1)], 0, None)
        labels = fcluster(linkage(condensed, method="average"), 1.0, criterion="distance")
    groups = []
    for label in np.unique(labels):
        groups += _split_doubles(np.flatnonzero(labels == label), f, orders)
    clusters = []
    for members in groups:
        median = np.median(f[members])
        keep = []
        for order in np.unique(orders[members]):  # one pole per order: the one nearest the median
            at = members[orders[members] == order]
            keep.append(at[np.argmin(np.abs(f[at] - median))])
        keep = np.array(keep)
        clusters.append({"indices": keep, "frequencies": f, "damping": z, "shapes": shapes, "orders": orders,
                         "index": index, "n_orders": keep.size, "median": float(np.median(f[keep]))})
    return sorted(clusters, key=lambda c: c["median"])


def _empty_reason(diagram: list[Poles], clusters: list[dict], needed: int, settings: Settings) -> str:
    lo, hi = settings.band
    orders = f"orders 2-{settings.max_order}"
    duration = settings.samples * settings.dt
    if not clusters:
        return (f"no mode: no pole between {lo:.3g} and {hi:.3g} Hz is stable from one model order to the next "
                f"({orders}); the record ({duration:.4g} s, {duration * lo:.0f} cycles of {lo:.3g} Hz) may hold noise "
                f"only or be too short; try a longer record, a band around the spectrum's peaks (band=LO,HI), or a "
                f"higher max_order")
    best = max(clusters, key=lambda c: c["n_orders"])
    return (f"no mode: the best candidate, {best['median']:.4g} Hz, is stable at {best['n_orders']} of "
            f"{len(diagram)} model orders, fewer than the {needed} needed; try a longer record, a higher max_order "
            f"(now {settings.max_order}), or a band around it")


def _identify(y: np.ndarray, dt: float, band, max_order, block_rows, n_blocks, options: dict):
    tolerances = _tolerances(options)
    y, dt = check_record(y, dt, min_channels=2)
    y = normalise(y)
    settings, notes = choose_settings(y, dt, band=band, max_order=max_order, block_rows=block_rows,
                                      n_blocks=n_blocks)
    y = decimate(y, settings)
    blocks = toeplitz_blocks(y, settings.block_rows, settings.max_order, settings.n_blocks)
    diagram = diagram_from_svd(blocks.U, y.shape[1], settings, tolerances)
    return y, settings, notes, blocks, diagram, tolerances


def stabilisation_diagram(y: ArrayLike, dt: float, max_order: int | None = None, block_rows: int | None = None,
                          band=None, **tolerances) -> list[Poles]:
    """Poles at orders ``2, 4, .., max_order`` inside the band, each flagged stable or not (steps 1-2 of the
    module docstring; settings chosen from the record where not given).

    Parameters
    ----------
    y : (T, p) array
        The record (``p >= 2``).
    dt : float
        Sampling step [s].
    max_order, block_rows : int, optional
    band : (float, float), optional
        Frequencies sought [Hz].
    **tolerances
        ``frequency_tol``, ``damping_tol``, ``mac_tol``, ``max_damping`` (see :data:`TOLERANCES`).

    Returns
    -------
    list of Poles, one per order, ascending.
    """
    return _identify(y, dt, band, max_order, block_rows, 0, tolerances)[4]


def ssi_cov(y: ArrayLike, dt: float, n_modes: int | None = None, max_order: int | None = None,
            block_rows: int | None = None, band=None, n_blocks: int | None = None, **tolerances) -> Modes:
    """Identify the physical modes of an ambient record, with their standard errors.

    Parameters
    ----------
    y : (T, p) array
        Record (accelerations, one column per channel, ``p >= 2``).
    dt : float
        Sampling step [s].
    n_modes : int, optional
        Return the ``n_modes`` most persistent clusters instead of those stable at
        ``min_stable_fraction`` of the orders (``ValueError`` if the diagram has fewer).
    max_order, block_rows : int, optional
        Default: chosen from the record (:mod:`.settings`).
    band : (float, float), optional
        Frequencies sought [Hz]; default derived from the spectrum.
    n_blocks : int, optional
        Blocks for the standard errors (0: none); default 20 where the record is long enough.
    **tolerances
        ``frequency_tol``, ``damping_tol``, ``mac_tol``, ``max_damping``, ``cluster_distance``,
        ``min_stable_fraction`` (defaults :data:`TOLERANCES`).

    Returns
    -------
    Modes
        ``status == "empty"`` or ``"partial"`` comes with a message (also an ``OMAWarning``).
    """
    y, settings, notes, blocks, diagram, tolerances = _identify(y, dt, band, max_order, block_rows, n_blocks,
                                                                 tolerances)
    p = y.shape[1]
    clusters = cluster_poles(diagram, tolerances)
    counts = np.array([c["n_orders"] for c in clusters], dtype=int)
    needed = max(3, int(np.ceil(tolerances["min_stable_fraction"] * len(diagram))))
    if n_modes is None:
        chosen = np.flatnonzero(counts >= needed)
    else:
        n_modes = int(n_modes)
        if n_modes < 1:
            raise ValueError(f"n_modes: expected a positive integer, got {n_modes}")
        if len(clusters) < n_modes:
            raise ValueError(f"n_modes: the stabilisation diagram has {len(clusters)} stable modes, fewer than the "
                             f"{n_modes} asked for (a longer record or a higher max_order may help)")
        chosen = np.sort(np.argsort(-counts, kind="stable")[:n_modes])
    # a cluster stable at half the orders a mode needs is a candidate worth telling the user about
    rejected = [c for i, c in enumerate(clusters) if i not in set(chosen) and c["n_orders"] >= max(3, needed / 2)]
    modes = _report([clusters[i] for i in chosen], diagram, blocks, p, settings)
    status, messages = "complete", list(notes)
    if not chosen.size:
        status = "empty"
        messages.append(_empty_reason(diagram, clusters, needed, settings))
    elif rejected and n_modes is None:
        status = "partial"
        where = ", ".join(f"{c['median']:.4g}" for c in rejected)
        messages.append(f"partial result: {chosen.size} mode{'s' if chosen.size > 1 else ''} identified; "
                        f"{len(rejected)} further candidate{'s' if len(rejected) > 1 else ''} at "
                        f"{where} Hz {'were' if len(rejected) > 1 else 'was'} "
                        f"stable at {min(c['n_orders'] for c in rejected)}-{max(c['n_orders'] for c in rejected)} of "
                        f"{len(diagram)} orders (needed {needed}); a longer record or a higher max_order may identify "
                        f"{'them' if len(rejected) > 1 else 'it'}")
    warn(messages)
    return Modes(**modes, status=status, messages=tuple(messages), settings=settings, diagram=tuple(diagram),
                 candidates=np.array([c["median"] for c in rejected]))


def _report(clusters: list[dict], diagram: list[Poles], blocks, p: int, settings: Settings) -> dict:
    """Each chosen cluster as a mode: the means of its poles' frequencies, damping ratios and real shapes
    over its ``REPORT_ORDERS`` lowest stable orders (shapes normalised at the largest component of the one
    nearest the median frequency), with their delete-one-block jackknife standard errors
    (:func:`~.uncertainty.jackknife_clusters`)."""
    k = len(clusters)
    out = {"frequencies": np.zeros(k), "damping_ratios": np.zeros(k), "shapes": np.zeros((p, k)),
           "n_stable": np.zeros(k, dtype=int), "std_frequencies": np.full(k, np.nan),
           "std_damping_ratios": np.full(k, np.nan), "std_shapes": np.full((p, k), np.nan), "mpc": np.zeros(k),
           "mpd": np.zeros(k), "orders": np.zeros(k, dtype=int)}
    jobs = []
    for slot, c in enumerate(clusters):
        members = c["indices"][np.argsort(c["orders"][c["indices"]])[:REPORT_ORDERS]]
        f, z, shapes = c["frequencies"][members], c["damping"][members], c["shapes"][:, members]
        best = int(np.argmin(np.abs(f - c["median"])))
        reference = int(np.argmax(np.abs(shapes[:, best])))
        out["frequencies"][slot], out["damping_ratios"][slot] = np.mean(f), np.mean(z)
        out["shapes"][:, slot] = np.mean((shapes / shapes[reference]).real, axis=1)
        order, index = int(c["orders"][members[best]]), int(c["index"][members[best]])
        poles = diagram[order // 2 - 1]
        out["mpc"][slot], out["mpd"][slot] = poles.mpc[index], poles.mpd[index]
        out["orders"][slot], out["n_stable"][slot] = order, c["n_orders"]
        jobs.append((c["orders"][members], f, shapes, reference))
    if blocks.n_blocks >= 2 and jobs:
        for slot, (sf, sz, sphi) in enumerate(jackknife_clusters(blocks, p, settings.dt, jobs)):
            out["std_frequencies"][slot], out["std_damping_ratios"][slot], out["std_shapes"][:, slot] = sf, sz, sphi
    ascending = np.argsort(out["frequencies"])
    return {key: (value[:, ascending] if value.ndim == 2 else value[ascending]) for key, value in out.items()}


def record_row(y: ArrayLike, dt: float, day: float, temperature: float, n_modes: int, **options) -> np.ndarray:
    """One data-file row ``[day, temperature, f1, .., f_n_modes]`` from one ambient record.

    Parameters
    ----------
    y : (T, p) array
        The record (accelerations).
    dt : float
        Sampling step [s].
    day : float
        When the record was taken, in days (the data file's ``day`` column).
    temperature : float
        The temperature measured with it [degrees C].
    n_modes : int
        How many frequencies the row carries (``f1 .. f_n_modes``).
    **options
        Passed to :func:`ssi_cov`.

    Returns
    -------
    (2 + n_modes,) array
    """
    for name, value in (("day", day), ("temperature", temperature)):
        if not np.isfinite(float(value)):
            raise ValueError(f"{name}: must be finite, got {value}")
    modes = ssi_cov(y, dt, n_modes=n_modes, **options)
    return np.concatenate([[float(day), float(temperature)], modes.frequencies])

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
