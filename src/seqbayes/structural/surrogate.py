"""Choose by measurement between the exact transition and a sparse-grid surrogate
(one that pays for itself at the run's sizes).

Lin et al. (2024, Eq. 18) interpolate the state recursion over the stiffness
ratios ``theta`` on a sparse grid so that a batch of members needs no
per-member discretisation. Whether that pays depends on the model and the
run's sizes, so :func:`choose_transition` measures it on the machine, at the
run's sizes, and keeps the cheaper candidate among those accurate enough:

* **Linear shear building** (:class:`~seqbayes.structural.structures.ShearBuilding`):
  the candidates are the exact discretisation (one batched matrix exponential
  per call, :class:`~seqbayes.structural.transitions.ExactTransition`) and sparse grids of
  increasing level (:class:`~seqbayes.structural.transitions.SparseGridTransition`). A
  grid's accuracy is the largest relative error of its ``A, B0, B1`` (each
  block relative to its largest entry) at ``n_test`` random ``theta`` of the
  box (default ``tol`` 3e-6, which keeps the log-likelihood of a long record
  accurate); the lowest level within ``tol`` is the grid candidate (levels whose
  grid would exceed ``max_points`` points are skipped). Cost of a run:
  exact ``rows * t_exact``; grid ``t_build + rows * t_interp``, with ``t`` per
  row measured on a batch of ``n_members`` rows (least of ``repeats``) and
  ``rows = expected_rows`` (default ``50 * n_members``, about what the
  resample-move sampler evaluates on a 3-4 storey record; docs/benchmarks.md).
* **Bouc-Wen building** (:class:`~seqbayes.structural.structures.bouc_wen.BoucWenBuilding`):
  every step of every ensemble member needs an integration, so the cost is
  per step: the candidates are RK4 with the fewest sub-steps (of
  ``rk4_substeps``, at most ``substeps``) within ``tol``,
  the exponential integrator with exact matrices at the fewest sub-steps
  (of ``exponential_substeps``) within ``tol``, and the same with its
  matrices on sparse grids of increasing level (until they match the exact
  matrices to 1e-4). The
  accuracy is the largest relative error of the simulated channels on the
  first ``probe_steps`` of the run's own record (``probe``) at ``n_test``
  random ``theta`` against RK4 with 32 sub-steps; the cost is the time of one
  ensemble step of ``n_members x enkf_members`` states (least of
  ``repeats``) times ``steps`` plus the matrices' build time.

The choice depends on the machine's timings, so two machines may choose
differently; the choice, the reason and every measurement are returned
(:class:`SurrogateChoice`, recorded in the SG-EnMCMC result) so that a run
can be repeated with the same transition (``level=``). Test draws come from
their own generator (``seed``), never from the run's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields

import numpy as np

from . import sparsegrid
from .structures.bouc_wen import BoucWenBuilding, BoucWenExponential, BoucWenRK4, simulate_bouc_wen
from .structures.shear_building import ShearBuilding, discretise
from .transitions import ExactTransition, SparseGridTransition

__all__ = ["SurrogateChoice", "Measurement", "choose_transition", "DEFAULT_ROWS_PER_PARTICLE"]

DEFAULT_ROWS_PER_PARTICLE = 50


@dataclass(frozen=True)
class SurrogateChoice:
    """The transition chosen by :func:`choose_transition` and why.

    Attributes
    ----------
    kind : str
        ``"exact"`` or ``"grid"``.
    level : int or None
        The grid level (``None`` for exact).
    integrator : str or None
        Bouc-Wen: ``"rk4"`` or ``"exponential"``.
    reason : str
        One sentence with the numbers that decided.
    candidates : tuple of dict
        Every candidate measured: ``name``, ``level``, ``error``, ``build_seconds``,
        ``seconds`` (per call of ``n_members`` rows, or per ensemble step),
        ``run_seconds`` (the cost model's total), ``accurate``, ``note``.
    transition : object
        The chosen transition (callable on ``theta (N, d)``).
    """

    kind: str
    level: int | None
    integrator: str | None
    reason: str
    candidates: tuple
    transition: object = field(repr=False, compare=False)

    def as_dict(self) -> dict:
        """Plain summary (no transition object) for results and reports."""
        return {"kind": self.kind, "level": self.level, "integrator": self.integrator, "reason": self.reason,
                "candidates": [dict(c) for c in self.candidates]}


def _best_time(function, repeats: int) -> float:
    """Least time of ``repeats`` calls: on a shared machine the least disturbed
    call estimates the intrinsic cost (medians of 3 varied 10x at load 9)."""
    times = []
    for _ in range(repeats):  # loop over repeats only
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.min(times))


def _block_error(approx, exact, blocks) -> float:
    """Largest relative error over blocks (column slices) of flattened matrices."""
    worst = 0.0
    for sl in blocks:
        scale = max(float(np.abs(exact[:, sl]).max()), 1e-300)
        worst = max(worst, float(np.abs(approx[:, sl] - exact[:, sl]).max()) / scale)
    return worst


@dataclass(frozen=True)
class Measurement:
    """How :func:`choose_transition` measures the candidates.

    Attributes
    ----------
    tol : float, optional
        Accuracy required: relative matrix error for the linear building
        (default ``3e-6``: the log-likelihood error grows with the matrix
        error and the record; 3e-6 keeps it to a few hundredths of a nat per
        500 steps, docs/benchmarks.md), relative response error for Bouc-Wen
        (default ``1e-2``).
    levels : sequence of int
        Grid levels tried, lowest first.
    max_points : int
        Skip a level whose grid has more points.
    expected_rows : int, optional
        Linear: rows of ``theta`` transformed in a run (default
        ``50 * n_members``).
    repeats : int
        Timings are the least of this many calls.
    n_test : int
        ``theta`` draws for the accuracy check.
    seed : int
        Seed of the generator of the test draws.
    probe_steps : int
        Bouc-Wen: the first ``probe_steps`` samples of the probe measure the accuracy.
    substeps : int
        Bouc-Wen: RK4 sub-steps of the exact candidate (the fallback).
    exponential_substeps : sequence of int
        Bouc-Wen: sub-steps tried for the exponential integrator (the fewest
        within ``tol`` is kept, and its matrices are then put on grids).
    rk4_substeps : sequence of int
        Bouc-Wen: RK4 sub-steps tried, fewest first (up to ``substeps``).
    """

    tol: float | None = None
    levels: tuple = (1, 2, 3, 4, 5, 6)
    max_points: int = 20000
    expected_rows: int | None = None
    repeats: int = 5
    n_test: int = 64
    seed: int = 0
    probe_steps: int = 200
    substeps: int = 4
    exponential_substeps: tuple = (1, 2, 4, 8)
    rk4_substeps: tuple = (1, 2, 4)

    def __post_init__(self):
        if not isinstance(self.repeats, (int, np.integer)) or self.repeats < 1:
            raise ValueError(f"repeats: expected a positive integer, got {self.repeats!r}")

    @classmethod
    def keywords(cls, options: dict) -> dict:
        """:func:`choose_transition`'s keywords of flat ``options`` (SG-EnMCMC's ``surrogate_options``): this
        record's fields as ``measurement=``, the rest as they are."""
        names = {f.name for f in fields(cls)}
        rest = {k: v for k, v in options.items() if k not in names}
        return {**rest, "measurement": cls(**{k: v for k, v in options.items() if k in names})}


def choose_transition(building, dt: float, lower, upper, n_members: int, *, channels="absolute_acceleration",
                      probe=None, enkf_members: int = 50, steps: int | None = None,
                      measurement: Measurement = Measurement()) -> SurrogateChoice:
    """Measure the exact transition against sparse grids and return the cheaper
    accurate one (module docstring).

    Parameters
    ----------
    building : ShearBuilding or BoucWenBuilding
    dt : float
    lower, upper : (d,) arrays
        The prior box of ``theta`` (the grid's box).
    n_members : int
        Particles ``N`` of the run (the batch the timings use).
    channels : str or Sensors
    probe : (T,) array
        Bouc-Wen: the run's ground acceleration (required); its first
        ``measurement.probe_steps`` samples measure the accuracy.
    enkf_members : int
        Bouc-Wen: EnKF members per particle (the ensemble step timed has
        ``n_members x enkf_members`` states).
    steps : int, optional
        Bouc-Wen: steps of the run (default ``len(probe)``); with the
        resample-move sampler the histories are re-filtered at every move,
        so this undercounts, equally for every candidate.
    measurement : Measurement
        The accuracy required and how the candidates are measured.

    Returns
    -------
    SurrogateChoice
    """
    lower = np.broadcast_to(np.asarray(lower, float), (building.n_storeys,)).copy()
    upper = np.broadcast_to(np.asarray(upper, float), (building.n_storeys,)).copy()
    if not isinstance(n_members, (int, np.integer)) or n_members < 1:
        raise ValueError(f"n_members: expected a positive integer, got {n_members!r}")
    rng = np.random.default_rng(measurement.seed)
    box = (lower, upper)
    if isinstance(building, BoucWenBuilding):
        tol = 1e-2 if measurement.tol is None else measurement.tol
        return _choose_bouc_wen(building, dt, box, n_members, channels, tol, measurement, rng, probe, enkf_members,
                                steps)
    if not isinstance(building, ShearBuilding):
        raise TypeError(f"building: expected a ShearBuilding or BoucWenBuilding, got {type(building).__name__}")
    return _choose_linear(building, dt, box, n_members, channels, 3e-6 if measurement.tol is None else measurement.tol,
                          measurement, rng)


def _choose_linear(building, dt, box, n_members, channels, tol, measurement: Measurement, rng):
    lower, upper = box
    levels, max_points, expected_rows = measurement.levels, measurement.max_points, measurement.expected_rows
    repeats, n_test = measurement.repeats, measurement.n_test
    d, m = building.n_storeys, building.state_dim
    rows = DEFAULT_ROWS_PER_PARTICLE * n_members if expected_rows is None else int(expected_rows)
    batch = lower + (upper - lower) * rng.random((n_members, d))
    test = lower + (upper - lower) * rng.random((n_test, d))
    exact = ExactTransition(building, dt, channels=channels)
    t_exact = _best_time(lambda: exact(batch), repeats)
    reference = discretise(building, test, dt, channels=channels)
    ref_flat = np.concatenate([reference.A.reshape(n_test, -1), reference.B0, reference.B1], axis=1)
    blocks = [slice(0, m * m), slice(m * m, m * m + m), slice(m * m + m, m * m + 2 * m)]
    exact_total = rows / n_members * t_exact
    candidates = [{"name": "exact", "level": None, "error": 0.0, "build_seconds": 0.0, "seconds": t_exact,
                   "run_seconds": exact_total, "accurate": True, "note": "batched matrix exponential"}]
    grid_choice = None
    for level in levels:
        points = sparsegrid.point_count(d, level)
        if points > max_points:
            candidates.append({"name": "grid", "level": level, "error": float("nan"), "build_seconds": float("nan"),
                               "seconds": float("nan"), "run_seconds": float("inf"), "accurate": False,
                               "note": f"{points} points > max_points {max_points}: not built"})
            break
        start = time.perf_counter()
        grid = SparseGridTransition(building, dt, lower, upper, level, channels=channels)
        build = time.perf_counter() - start
        t_grid = _best_time(lambda: grid(batch), repeats)
        approx = grid.interpolant(test)
        error = _block_error(approx, ref_flat, blocks)
        entry = {"name": "grid", "level": level, "error": error, "build_seconds": build, "seconds": t_grid,
                 "run_seconds": build + rows / n_members * t_grid, "accurate": error <= tol,
                 "note": f"{points} points"}
        candidates.append(entry)
        if error <= tol:
            grid_choice = (entry, grid)
            break
    if grid_choice is not None and grid_choice[0]["run_seconds"] < exact_total:
        entry, grid = grid_choice
        reason = (f"sparse grid level {entry['level']} (error {entry['error']:.1e} <= tol {tol:.0e}): build "
                  f"{entry['build_seconds']:.3f} s + {rows} rows at {entry['seconds'] / n_members * 1e6:.1f} us = "
                  f"{entry['run_seconds']:.3f} s < exact {exact_total:.3f} s ({t_exact / n_members * 1e6:.1f} us/row)")
        return SurrogateChoice("grid", entry["level"], None, reason, tuple(candidates), grid)
    if grid_choice is None:
        reason = (f"exact: no grid level within tol {tol:.0e} (tried {[c['level'] for c in candidates[1:]]}, "
                  f"errors {[float('%.1e' % c['error']) for c in candidates[1:]]})")
    else:
        entry = grid_choice[0]
        reason = (f"exact: {exact_total:.3f} s for {rows} rows <= grid level {entry['level']} "
                  f"{entry['run_seconds']:.3f} s (build {entry['build_seconds']:.3f} s, "
                  f"{entry['seconds'] / n_members * 1e6:.1f} vs {t_exact / n_members * 1e6:.1f} us/row)")
    return SurrogateChoice("exact", None, None, reason, tuple(candidates), exact)


def _choose_bouc_wen(building, dt, box, n_members, channels, tol, measurement: Measurement, rng, probe, enkf_members,
                     steps):
    lower, upper = box
    levels, max_points, repeats, n_test = (measurement.levels, measurement.max_points, measurement.repeats,
                                           measurement.n_test)
    probe_steps, substeps = measurement.probe_steps, measurement.substeps
    exponential_substeps, rk4_substeps = measurement.exponential_substeps, measurement.rk4_substeps
    if probe is None:
        raise ValueError("probe: a Bouc-Wen building needs the run's ground acceleration to measure accuracy "
                         "(the nonlinearity depends on the amplitude)")
    probe = np.asarray(probe, float)
    if probe.ndim != 1 or probe.size < 2:
        raise ValueError(f"probe: expected a 1-D ground acceleration, got shape {probe.shape}")
    steps = probe.size if steps is None else int(steps)
    u = probe[:probe_steps]
    d, m = building.n_storeys, building.state_dim
    test = lower + (upper - lower) * rng.random((n_test, d))
    batch = lower + (upper - lower) * rng.random((n_members, d))
    ensemble = 1e-3 * rng.standard_normal((n_members, enkf_members, m))
    reference = simulate_bouc_wen(BoucWenRK4(building, dt, 32, channels), test, u)
    scale = max(float(np.abs(reference).max()), 1e-300)

    def measure(name, level, make):
        start = time.perf_counter()
        transition = make()
        build = time.perf_counter() - start
        t_matrices = _best_time(lambda: transition(batch), repeats)
        model = transition(batch)
        t_step = _best_time(lambda: model.propagate(ensemble, 0.1, 0.2), repeats)
        error = float(np.abs(simulate_bouc_wen(transition, test, u) - reference).max()) / scale
        return {"name": name, "level": level, "error": error, "build_seconds": build, "seconds": t_step,
                "run_seconds": build + t_matrices + steps * t_step, "accurate": error <= tol,
                "note": f"matrices {t_matrices * 1e3:.2f} ms per call"}, transition

    measured = []
    for count in sorted(set(rk4_substeps) | {substeps}):  # RK4 with the fewest sub-steps within tol
        entry = measure("rk4", None, lambda: BoucWenRK4(building, dt, count, channels))
        entry[0]["note"] += f"; {count} sub-steps"
        measured.append(entry)
        if entry[0]["accurate"] or count == substeps:
            break
    split = 1
    for split in exponential_substeps:  # the fewest sub-steps of the exponential integrator within tol
        entry = measure("exponential", None, lambda: BoucWenExponential(building, dt, channels=channels,
                                                                         substeps=split))
        entry[0]["note"] += f"; {split} sub-steps"
        measured.append(entry)
        if entry[0]["accurate"]:
            break
    for level in levels:  # its matrices on a sparse grid, up to the level that matches the exact ones
        points = sparsegrid.point_count(d, level)
        if points > max_points:
            break
        entry = measure("exponential-grid", level,
                        lambda: BoucWenExponential(building, dt, level, lower, upper, channels=channels,
                                                   substeps=split))
        measured.append(entry)
        matrix_error = _grid_matrix_error(building, dt, entry[1], test)
        entry[0]["note"] += f"; {split} sub-steps; matrix error {matrix_error:.1e}"
        if matrix_error <= 1e-4:  # the grid is as good as the exact matrices: higher levels only cost more
            break
    accurate = [(e, t) for e, t in measured if e["accurate"]]
    candidates = tuple(e for e, _ in measured)
    if not accurate:
        entry, transition = [(e, t) for e, t in measured if e["name"] == "rk4"][-1]
        reason = (f"exact RK4 ({transition.substeps} sub-steps): no candidate within tol {tol:.0e} "
                  f"(RK4 error {entry['error']:.1e})")
        return SurrogateChoice("exact", None, "rk4", reason, candidates, transition)
    entry, transition = min(accurate, key=lambda et: et[0]["run_seconds"])
    others = ", ".join(f"{e['name']}{'' if e['level'] is None else ' ' + str(e['level'])} x{t.substeps} "
                       f"{e['run_seconds']:.2f} s (error {e['error']:.1e})" for e, t in measured if e is not entry)
    reason = (f"{entry['name']}{'' if entry['level'] is None else ' level ' + str(entry['level'])} "
              f"x{transition.substeps}: "
              f"error {entry['error']:.1e} <= tol {tol:.0e}, {entry['run_seconds']:.2f} s for {steps} steps of "
              f"{n_members} x {enkf_members} states; others: {others}")
    kind = "grid" if entry["name"] == "exponential-grid" else "exact"
    integrator = "rk4" if entry["name"] == "rk4" else "exponential"
    return SurrogateChoice(kind, entry["level"], integrator, reason, candidates, transition)


def _grid_matrix_error(building, dt, transition, test):
    exact = building.exponential_matrices(test, dt / transition.substeps)
    return float(np.abs(transition.matrices(test) - exact).max()) / max(float(np.abs(exact).max()), 1e-300)
