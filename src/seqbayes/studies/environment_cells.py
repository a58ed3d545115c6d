"""The misspecification matrix's simulator (issue 40): named cells of years whose law the monitor does not have.

Every cell is one :class:`YearBase` (what all cells share) plus one :class:`Misspecification` (what the cell
departs in), :data:`CELLS`. A year of cell ``c`` is hourly sets of identified natural frequencies of a shear
building (:func:`simulate_cell_year`); the CSV (:func:`write_cell_year`) holds what a monitoring system has
(interfaces.md, "The year CSV"):

    day, temperature, [humidity], f1, ..., fn, [sf1, ..., sfn]

with ``temperature`` the AIR temperature a weather station gives, an empty cell where a mode was not identified
and ``sfj`` the identification's standard error [Hz]; the truth sidecar (``.json``, :class:`YearTruth`) holds
every setting and every drawn value.

The structure (storey ``i`` of ``n``, bottom to top) has the stiffness

    k_i(t) = k_i^true * (1 - delta_i(t)) * c_i(t)
    c_i(t) = [1 + a_i alpha (T_s(t) - T_ref) + b_i beta m(T_s(t) - T_0; w)] * [1 + gamma (RH(t) - RH_ref)]

- ``T_s`` the structure's temperature, a first-order lag of the air temperature with time constant
  ``thermal_lag_hours`` (:func:`structure_temperature`; 0: the air temperature itself);
- ``a_i, b_i`` per-storey factors on the temperature and freezing coefficients, each uniform in
  ``1 +- sensitivity_scatter`` (0: one law for every storey, as the old monitor has);
- ``m(x; w) = -w log(1 + exp(-x / w))`` the smooth freezing knee at ``T_0`` of width ``w``
  (:func:`freezing_knee`; ``w = 0`` is the kink ``min(x, 0)``), ``T_0`` and ``w`` drawn per year;
- ``RH`` the relative humidity of :class:`HumidityModel`, ``gamma`` its effect per %RH (written to the CSV only
  when the cell says so);
- ``k^true``, and the masses, the nominal values the monitor is given (:data:`MASSES`, :data:`STIFFNESSES`)
  scattered per year by ``mass_scatter`` and ``stiffness_scatter`` (uniform, relative);
- ``delta_i(t)`` the loss: ``size`` in ``element`` from the start of ``day`` on (:class:`Damage`).

Frequencies are the eigenvalues of ``K(t) phi = w^2 M phi`` for every set, times ``1 + s e`` with ``e``
standard normal and ``s`` drawn per set and mode uniform in ``frequency_noise``; in a share
``missing_fraction`` of the sets one or more modes are missing (``k`` of them with probability proportional to
``2^-k``, ``k = 1 .. n - 1``, which ones at random).

Common random numbers: a year draws every component (weather, humidity, building, law, noise, missing modes)
from its own child of the year's generator (``Generator.spawn``), so year ``i`` of two cells has the same air
temperature, building and noise draws, and the cells differ only in what they change.
"""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from ..structural.structures import ShearBuilding
from .environment import MASSES, STIFFNESSES, TemperatureModel, YearTruth, simulate_temperature

__all__ = ["HumidityModel", "YearBase", "Misspecification", "Damage", "CELLS", "BASELINE_CELL", "KINDS",
           "structure_temperature", "freezing_knee", "simulate_humidity", "simulate_cell_year", "write_cell_year",
           "read_cell_year", "year_generator", "draw_damage", "cell_year", "with_days"]

#: The kinds of year of the matrix: name -> loss size (0: healthy).
KINDS = {"healthy": 0.0, "loss5": 0.05, "loss2": 0.02}


@dataclass(frozen=True)
class HumidityModel:
    """Relative humidity [%]: a seasonal cycle (wettest at the coldest time of year), a daily cycle opposite to the
    air temperature's (driest in the afternoon), a daily AR(1) weather anomaly and hourly noise, clipped.

    ``RH(t) = mean + seasonal_amplitude cos(2 pi (t - wettest_day) / 365) - daily_amplitude sin(2 pi (t - 9 h))
    + weather(t) + e``, the daily phase that of :class:`~seqbayes.studies.environment.TemperatureModel`.
    """

    mean: float = 75.0
    seasonal_amplitude: float = 8.0
    wettest_day: float = 20.0
    daily_amplitude: float = 12.0
    weather_sd: float = 8.0
    weather_correlation: float = 0.6
    noise: float = 2.0
    minimum: float = 20.0
    maximum: float = 100.0

    def __post_init__(self):
        for name in ("seasonal_amplitude", "daily_amplitude", "weather_sd", "noise"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise ValueError(f"{name}: expected a finite value >= 0, got {getattr(self, name)}")
        if not -1 < self.weather_correlation < 1:
            raise ValueError(f"weather_correlation: expected a value in (-1, 1), got {self.weather_correlation}")
        if not 0 <= self.minimum < self.maximum <= 100:
            raise ValueError("minimum, maximum: expected 0 <= minimum < maximum <= 100 (%RH)")


@dataclass(frozen=True)
class YearBase:
    """What every cell of the matrix shares: the nominal building and its per-year scatter, the temperature law,
    the weather, the sampling. ``alpha`` [1/degC] softens every storey as it warms, ``beta`` [1/degC] stiffens it
    below the freezing knee (the law of docs/environment.md, ``c(T) = 1 + alpha (T - T_ref) + beta min(T, 0)``)."""

    masses: tuple = MASSES
    stiffnesses: tuple = STIFFNESSES
    mass_scatter: float = 0.05
    stiffness_scatter: float = 0.10
    alpha: float = -0.0015
    beta: float = -0.015
    reference_temperature: float = 10.0
    reference_humidity: float = 70.0
    temperature: TemperatureModel = TemperatureModel()
    humidity: HumidityModel = HumidityModel()
    sets_per_day: int = 24
    n_days: int = 365

    def __post_init__(self):
        if len(self.masses) != len(self.stiffnesses) or len(self.masses) < 2:
            raise ValueError("masses, stiffnesses: expected as many of each, at least 2 storeys")
        for name in ("mass_scatter", "stiffness_scatter"):
            if not 0 <= getattr(self, name) < 0.5:
                raise ValueError(f"{name}: expected a value in [0, 0.5), got {getattr(self, name)}")
        for name in ("sets_per_day", "n_days"):
            value = getattr(self, name)
            if int(value) != value or value < 1:
                raise ValueError(f"{name}: expected a positive integer, got {value}")


@dataclass(frozen=True)
class Misspecification:
    """What a cell departs in from the law the old monitor has (every field at its default: that law).

    Attributes
    ----------
    thermal_lag_hours : float
        Time constant of the structure's first-order lag behind the air temperature [h].
    sensitivity_scatter : float
        Per-storey factors on ``alpha`` and ``beta``, each uniform in ``1 +- sensitivity_scatter``.
    knee_location, knee_width : (2,) tuple of float
        Ranges [degC] of the freezing knee's location ``T_0`` and width ``w``, drawn per year
        (``(0, 0), (0, 0)``: the kink at 0 degC).
    humidity_effect : float
        ``gamma``, the relative stiffness change per %RH (``-2e-4``: -0.2 % of stiffness, -0.1 % of every
        frequency, per 10 %RH).
    humidity_in_csv : bool
        Write the humidity as a covariate column (the cell of the matrix does not: the monitor is not given it).
    frequency_noise : (2,) tuple of float
        Range of a set's relative frequency error (standard deviation), drawn per set and mode.
    report_std : bool
        Write each set's standard errors ``sf1..sfn`` [Hz] (the drawn standard deviation times the frequency).
    missing_fraction : float
        Share of the sets with one or more modes missing (empty cells).
    """

    thermal_lag_hours: float = 0.0
    sensitivity_scatter: float = 0.0
    knee_location: tuple = (0.0, 0.0)
    knee_width: tuple = (0.0, 0.0)
    humidity_effect: float = 0.0
    humidity_in_csv: bool = False
    frequency_noise: tuple = (0.004, 0.004)
    report_std: bool = False
    missing_fraction: float = 0.0

    def __post_init__(self):
        if not (np.isfinite(self.thermal_lag_hours) and self.thermal_lag_hours >= 0):
            raise ValueError(f"thermal_lag_hours: expected a finite value >= 0, got {self.thermal_lag_hours}")
        if not 0 <= self.sensitivity_scatter < 1:
            raise ValueError(f"sensitivity_scatter: expected a value in [0, 1), got {self.sensitivity_scatter}")
        for name, low in (("knee_location", -np.inf), ("knee_width", 0.0), ("frequency_noise", 0.0)):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and low <= lo <= hi):
                raise ValueError(f"{name}: expected a range (low, high) with {low} <= low <= high, got {(lo, hi)}")
        if not self.frequency_noise[1] < 0.5:
            raise ValueError(f"frequency_noise: expected values below 0.5, got {self.frequency_noise}")
        if not 0 <= self.missing_fraction < 1:
            raise ValueError(f"missing_fraction: expected a value in [0, 1), got {self.missing_fraction}")
        if not np.isfinite(self.humidity_effect):
            raise ValueError(f"humidity_effect: expected a finite value, got {self.humidity_effect}")


#: The matrix's cells: each is the common base (:class:`YearBase`, the old monitor's law with the
#: nominal building scattered) with one departure.
CELLS = {
    "lag0": Misspecification(),
    "lag3": Misspecification(thermal_lag_hours=3.0),
    "lag6": Misspecification(thermal_lag_hours=6.0),
    "lag12": Misspecification(thermal_lag_hours=12.0),
    "scatter30": Misspecification(sensitivity_scatter=0.3),
    "knee": Misspecification(knee_location=(-2.0, 2.0), knee_width=(0.5, 2.0)),
    "humidity": Misspecification(humidity_effect=-2e-4),
    "noise_missing": Misspecification(frequency_noise=(0.003, 0.005), report_std=True, missing_fraction=0.2),
}
#: The cell with no departure: the common baseline.
BASELINE_CELL = "lag0"


@dataclass(frozen=True)
class Damage:
    """A loss of ``size`` of ``element``'s (1-based storey) stiffness from the start of ``day`` on."""

    day: float
    element: int
    size: float

    def __post_init__(self):
        if not 0 < self.size < 1:
            raise ValueError(f"size: expected a loss in (0, 1), got {self.size}")
        if int(self.element) != self.element or self.element < 1:
            raise ValueError(f"element: expected a 1-based storey, got {self.element}")
        if not np.isfinite(self.day) or self.day < 0:
            raise ValueError(f"day: expected a finite day >= 0, got {self.day}")


def structure_temperature(times, air, lag_hours: float) -> np.ndarray:
    """The structure's temperature ``(S,)``: the first-order lag ``dT_s/dt = (T - T_s) / tau`` of the air
    temperature ``air (S,)`` at equally spaced ``times (S,)`` [days], held constant over each step (exact for such
    an input), starting at the air temperature; ``lag_hours = 0`` returns ``air``.

    Examples
    --------
    >>> structure_temperature([0, 0.5, 1.0], [0.0, 10.0, 10.0], 12.0).round(4).tolist()
    [0.0, 6.3212, 8.6466]
    """
    air = np.asarray(air, float)
    if lag_hours == 0:
        return air.copy()
    from scipy.signal import lfilter

    times = np.asarray(times, float)
    step = np.diff(times)
    if step.size and not np.allclose(step, step[0]):
        raise ValueError("times: expected equally spaced times")
    keep = np.exp(-(step[0] if step.size else 1.0) * 24.0 / lag_hours)  # x_k = keep x_{k-1} + (1 - keep) T_k
    return lfilter([1 - keep], [1, -keep], air, zi=[keep * air[0]])[0]


def freezing_knee(temperature, location: float = 0.0, width: float = 0.0) -> np.ndarray:
    """``m(T - T_0; w) = -w log(1 + exp(-(T - T_0) / w))``, the smooth ``min(T - T_0, 0)`` (the kink when ``w = 0``).

    Examples
    --------
    >>> freezing_knee([-5.0, 0.0, 5.0]).tolist()
    [-5.0, 0.0, 0.0]
    >>> freezing_knee([-5.0, 0.0, 5.0], 0.0, 1.0).round(4).tolist()
    [-5.0067, -0.6931, -0.0067]
    """
    x = np.asarray(temperature, float) - location
    if width == 0:
        return np.minimum(x, 0.0)
    return -width * np.logaddexp(0.0, -x / width)


def simulate_humidity(times, rng: np.random.Generator, model: HumidityModel = HumidityModel()) -> np.ndarray:
    """Relative humidity [%] at ``times`` (days from 1 January, ascending), see :class:`HumidityModel`."""
    times = np.asarray(times, float)
    days = np.floor(times).astype(int)
    n_days = days.max() - days.min() + 1
    rho = model.weather_correlation
    weather = np.empty(n_days)
    weather[0] = rng.normal(0.0, model.weather_sd)
    innovations = rng.normal(0.0, model.weather_sd * np.sqrt(1 - rho ** 2), n_days)
    for d in range(1, n_days):  # AR(1) over days: a short loop over days
        weather[d] = rho * weather[d - 1] + innovations[d]
    humidity = (model.mean + model.seasonal_amplitude * np.cos(2 * np.pi * (times - model.wettest_day) / 365.0)
                - model.daily_amplitude * np.sin(2 * np.pi * (times - 9.0 / 24.0))
                + weather[days - days.min()] + rng.normal(0.0, model.noise, times.size))
    return np.clip(humidity, model.minimum, model.maximum)


def _missing_mask(rng: np.random.Generator, n_sets: int, n_modes: int, fraction: float) -> np.ndarray:
    """``(S, n)`` bool, True where a mode is missing: ``fraction`` of the sets lose ``k`` modes, ``P(k) ~ 2^-k``."""
    incomplete = rng.random(n_sets) < fraction
    sizes = np.arange(1, n_modes)
    p = 0.5 ** sizes / np.sum(0.5 ** sizes)
    k = rng.choice(sizes, size=n_sets, p=p)
    order = np.argsort(rng.random((n_sets, n_modes)), axis=1)  # a random permutation of the modes per set
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.arange(n_modes)[None, :].repeat(n_sets, 0), axis=1)
    return incomplete[:, None] & (rank < k[:, None])


def simulate_cell_year(rng: np.random.Generator, cell: Misspecification, *, base: YearBase = YearBase(),
                       damage: Damage | None = None, seed=None, label: dict | None = None) -> tuple[dict, YearTruth]:
    """One year of identified sets of ``cell`` (module docstring).

    Parameters
    ----------
    rng : numpy.random.Generator
        The year's generator; every component draws from its own child (common random numbers across cells).
    cell : Misspecification
    base : YearBase
    damage : Damage, optional
        ``None``: a healthy year.
    seed : optional
        Recorded in the truth only.
    label : dict, optional
        Recorded in the truth's settings (the cell's name, the year's kind and index).

    Returns
    -------
    table : dict
        ``day (S,)`` [days], ``temperature (S,)`` [degC, air], ``humidity (S,)`` [%] if the cell writes it,
        ``f1 .. fn (S,)`` [Hz, NaN where missing] and ``sf1 .. sfn (S,)`` [Hz] if it reports them;
        ``S = sets_per_day * n_days``.
    truth : YearTruth
        ``damage_day``, ``damage_storey``, ``damage_size`` (0 when healthy) and ``settings``: the base, the cell,
        every drawn value (true masses and stiffnesses, per-storey factors, knee) and ``label``.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    if not isinstance(cell, Misspecification):
        raise TypeError(f"cell: expected a Misspecification, got {type(cell).__name__}")
    n = len(base.masses)
    if damage is not None and damage.element > n:
        raise ValueError(f"damage: element {damage.element} is not a storey of this {n}-storey building")
    weather_rng, humidity_rng, building_rng, law_rng, noise_rng, missing_rng = rng.spawn(6)
    times = np.arange(base.n_days * base.sets_per_day) / base.sets_per_day
    air = simulate_temperature(times, weather_rng, base.temperature)
    humidity = simulate_humidity(times, humidity_rng, base.humidity)
    masses = np.asarray(base.masses) * (1 + base.mass_scatter * building_rng.uniform(-1, 1, n))
    stiffnesses = np.asarray(base.stiffnesses) * (1 + base.stiffness_scatter * building_rng.uniform(-1, 1, n))
    alpha_factors = 1 + cell.sensitivity_scatter * law_rng.uniform(-1, 1, n)
    beta_factors = 1 + cell.sensitivity_scatter * law_rng.uniform(-1, 1, n)
    knee_location = float(law_rng.uniform(*cell.knee_location))
    knee_width = float(law_rng.uniform(*cell.knee_width))
    structure = structure_temperature(times, air, cell.thermal_lag_hours)
    ratios = (1 + base.alpha * alpha_factors[None, :] * (structure - base.reference_temperature)[:, None]
              + base.beta * beta_factors[None, :] * freezing_knee(structure, knee_location, knee_width)[:, None])
    ratios = ratios * (1 + cell.humidity_effect * (humidity - base.reference_humidity))[:, None]
    if np.any(ratios <= 0):
        raise ValueError("base, cell: a storey's stiffness factor is not positive over the simulated year")
    if damage is not None:
        ratios[times >= damage.day, damage.element - 1] *= 1 - damage.size
    exact = ShearBuilding(masses, stiffnesses).modes(ratios)[0]  # (S, n) Hz, one eigenproblem per set
    noise_sd = noise_rng.uniform(*cell.frequency_noise, size=exact.shape)
    observed = exact * (1 + noise_sd * noise_rng.standard_normal(exact.shape))
    missing = _missing_mask(missing_rng, times.size, n, cell.missing_fraction)
    observed[missing] = np.nan
    table = {"day": times, "temperature": air}
    if cell.humidity_in_csv:
        table["humidity"] = humidity
    table.update({f"f{r + 1}": observed[:, r] for r in range(n)})
    if cell.report_std:
        table.update({f"sf{r + 1}": np.where(missing[:, r], np.nan, noise_sd[:, r] * observed[:, r])
                      for r in range(n)})
    settings = {"base": _jsonable(asdict(base)), "cell": _jsonable(asdict(cell)),
                "drawn": {"masses": masses.tolist(), "stiffnesses": stiffnesses.tolist(),
                          "alpha_factors": alpha_factors.tolist(), "beta_factors": beta_factors.tolist(),
                          "knee_location": knee_location, "knee_width": knee_width,
                          "missing_share": float(missing.any(axis=1).mean())},
                "nominal": {"masses": [float(m) for m in base.masses],
                            "stiffnesses": [float(k) for k in base.stiffnesses]},
                **(label or {})}
    truth = YearTruth(None if damage is None else float(damage.day), None if damage is None else int(damage.element),
                      0.0 if damage is None else float(damage.size), seed, settings)
    return table, truth


def _jsonable(value):
    """Tuples as lists, numpy scalars as floats (a dataclass's ``asdict`` for JSON)."""
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _column_order(table: dict) -> list:
    frequencies = sorted((k for k in table if k.startswith("f") and k[1:].isdigit()), key=lambda k: int(k[1:]))
    errors = sorted((k for k in table if k.startswith("sf") and k[2:].isdigit()), key=lambda k: int(k[2:]))
    covariates = [k for k in table if k not in {"day", "temperature", *frequencies, *errors}]
    return ["day", "temperature", *covariates, *frequencies, *errors]


def write_cell_year(path, table: dict, truth: YearTruth) -> Path:
    """Write ``table`` as the year CSV of interfaces.md (an empty cell for NaN) and ``truth`` beside it (``.json``).

    Written to a temporary name and renamed, so that a killed run leaves no half file. Returns the sidecar's path.
    """
    import os

    path = Path(path)
    columns = _column_order(table)
    values = np.column_stack([np.asarray(table[c], float) for c in columns])
    # a name of this process's own: two runs that simulate the same year never write into one file
    partial = path.with_name(f"{path.name}.{os.getpid()}.part")
    with open(partial, "w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        writer.writerows([["" if np.isnan(v) else f"{v:.10g}" for v in row] for row in values])
    sidecar = path.with_suffix(".json")
    sidecar_partial = sidecar.with_name(f"{sidecar.name}.{os.getpid()}.part")
    sidecar_partial.write_text(json.dumps(asdict(truth), indent=1) + "\n")
    sidecar_partial.replace(sidecar)
    partial.replace(path)  # the CSV last: its presence says the year is complete
    return sidecar


def read_cell_year(path) -> dict:
    """A year CSV written by :func:`write_cell_year` as a dict of ``(S,)`` columns, NaN for an empty cell."""
    path = Path(path)
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    if not rows or rows[0][:2] != ["day", "temperature"]:
        raise ValueError(f"{path}: expected a year CSV whose header starts with day,temperature")
    header, body = rows[0], rows[1:]
    try:
        values = np.array([[float(v) if v != "" else np.nan for v in row] for row in body], float)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    values = values.reshape(len(body), len(header))
    return {name: values[:, i] for i, name in enumerate(header)}


def year_generator(seed: int, purpose: int, kind: str, index: int) -> np.random.Generator:
    """The generator of year ``index`` of ``kind`` (:data:`KINDS`) for ``purpose`` (0: the matrix, 1: the alarm
    calibration set): independent of the cell, so that the cells share their years' random numbers."""
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    return np.random.default_rng([int(seed), int(purpose), list(KINDS).index(kind), int(index)])


def draw_damage(rng: np.random.Generator, kind: str, n_storeys: int, window: tuple) -> Damage | None:
    """The loss of a year of ``kind``: a random storey from the start of a random whole day in ``window``
    (inclusive); ``None`` for a healthy year."""
    size = KINDS[kind]
    day = int(rng.integers(window[0], window[1] + 1))
    element = int(rng.integers(1, n_storeys + 1))
    return None if size == 0 else Damage(float(day), element, size)


def cell_year(cell_name: str, kind: str, index: int, *, seed: int = 0, purpose: int = 0,
              base: YearBase = YearBase(), damage_window: tuple = (183, 335), cells: dict = CELLS
              ) -> tuple[dict, YearTruth]:
    """Year ``index`` of ``kind`` in the cell ``cell_name`` of ``cells``: :func:`simulate_cell_year` with the
    generator of :func:`year_generator` and the loss of :func:`draw_damage` (drawn first, from its own child)."""
    if cell_name not in cells:
        raise ValueError(f"cell_name: expected one of {', '.join(cells)}, got {cell_name!r}")
    if not 0 <= damage_window[0] <= damage_window[1] < base.n_days:
        raise ValueError(f"damage_window: expected days within the year (0..{base.n_days - 1}), got {damage_window}")
    rng = year_generator(seed, purpose, kind, index)
    damage_rng, year_rng = rng.spawn(2)
    damage = draw_damage(damage_rng, kind, len(base.masses), damage_window)
    label = {"cell_name": cell_name, "kind": kind, "index": int(index), "purpose": int(purpose),
             "damage_window": [int(d) for d in damage_window]}
    return simulate_cell_year(year_rng, cells[cell_name], base=base, damage=damage, seed=seed, label=label)


def with_days(base: YearBase, n_days: int) -> YearBase:
    """``base`` with ``n_days`` days (the reduced matrix's shorter years)."""
    return replace(base, n_days=int(n_days))
