"""A year of identified natural frequencies of a shear building under temperature (issue 25).

The simulator behind ``benchmarks/bench_environment.py`` and docs/environment.md. Every storey
stiffness follows the temperature through one factor (the issue's form)::

    k_i(t) = k_i,ref(t) * c(T(t)),   c(T) = 1 + alpha (T - T_ref) + beta min(T, 0)

so a negative ``beta`` stiffens the structure below 0 degC (frozen deck, Z24) and a negative
``alpha`` softens it as it warms. ``k_i,ref(t)`` is the nominal stiffness, times
``1 - damage_size`` in ``damage_storey`` from ``damage_day`` on. The frequencies are those of the
shear-building eigenproblem ``K phi = w^2 M phi`` (:meth:`ShearBuilding.modes`), times
``1 + frequency_noise * e`` with ``e`` standard normal (an identified frequency's relative error).

Temperature (degC) at time ``t`` (days from 1 January)::

    T(t) = mean - seasonal_amplitude cos(2 pi (t - coldest_day) / 365)
           + daily_amplitude sin(2 pi (t - 9 h) / 1 d) + weather(t) + e_T

with ``weather`` a daily AR(1) anomaly (``weather_sd``, correlation ``weather_correlation``) held
over the day and ``e_T`` hourly noise (``temperature_noise``), clipped to
``[temperature_min, temperature_max]`` (default -10 to +30 degC).

The default building (``MASSES``, ``STIFFNESSES``) has four storeys of 200, 200, 200, 160 t and
storey stiffnesses 300, 260, 220, 180 MN/m: natural frequencies 2.09, 5.56, 8.28, 10.34 Hz. A 5 %
loss changes them by up to 1.3 %, with a different pattern in each storey.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..store.datasets import TableSpec, read_datafile, read_regular
from ..structural.structures import ShearBuilding

__all__ = ["MASSES", "STIFFNESSES", "TemperatureModel", "YearTruth", "stiffness_factor", "simulate_temperature",
           "simulate_year", "write_year_csv", "year_spec", "read_year_csv", "read_truth", "simulate_years", "DAY_RANGE",
           "TEMPERATURE_RANGE", "FREQUENCY_RANGE", "check_against_building", "check_memory", "check_days"]

MASSES = (2.0e5, 2.0e5, 2.0e5, 1.6e5)
STIFFNESSES = (3.0e8, 2.6e8, 2.2e8, 1.8e8)
CSV_HEADER = "day,temperature,f1,f2,f3,f4"

#: Default bounds of a year CSV's columns (``seqbayes environment --max-day``, ``--temperature-range`` and
#: ``--frequency-range`` change them): days since the first monitored day, at most 100 years; air and surface
#: temperatures a structure meets, in degC (the records are -89 and +57 in air; a deck in the sun reaches
#: about +70); natural frequencies in Hz of structures and machines.
DAY_RANGE = (0.0, 36525.0)
TEMPERATURE_RANGE = (-80.0, 80.0)
FREQUENCY_RANGE = (0.01, 1000.0)


@dataclass(frozen=True)
class TemperatureModel:
    """Seasonal and daily cycles, a daily weather anomaly and hourly noise, in degC (see the module)."""

    mean: float = 10.0
    seasonal_amplitude: float = 13.0
    coldest_day: float = 20.0
    daily_amplitude: float = 4.0
    weather_sd: float = 3.0
    weather_correlation: float = 0.8
    temperature_noise: float = 0.5
    temperature_min: float = -10.0
    temperature_max: float = 30.0

    def __post_init__(self):
        for name in ("seasonal_amplitude", "daily_amplitude", "weather_sd", "temperature_noise"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise ValueError(f"{name}: expected a finite value >= 0, got {getattr(self, name)}")
        if not -1 < self.weather_correlation < 1:
            raise ValueError(f"weather_correlation: expected a value in (-1, 1), got {self.weather_correlation}")
        if not self.temperature_min < self.temperature_max:
            raise ValueError("temperature_min, temperature_max: expected temperature_min < temperature_max")


@dataclass(frozen=True)
class YearTruth:
    """What a simulated year was made from (written beside the CSV as JSON)."""

    damage_day: float | None
    damage_storey: int | None
    damage_size: float
    seed: int | None
    settings: dict = field(default_factory=dict)


def stiffness_factor(temperature, alpha: float, beta: float, reference_temperature: float) -> np.ndarray:
    """``c(T) = 1 + alpha (T - T_ref) + beta min(T, 0)``, the factor on every storey stiffness.

    Examples
    --------
    >>> stiffness_factor([-10.0, 10.0, 20.0], -0.001, -0.01, 10.0).round(3).tolist()
    [1.12, 1.0, 0.99]
    """
    t = np.asarray(temperature, float)
    return 1.0 + alpha * (t - reference_temperature) + beta * np.minimum(t, 0.0)


def simulate_temperature(times, rng: np.random.Generator, model: TemperatureModel = TemperatureModel()) -> np.ndarray:
    """Temperatures (degC) at ``times`` (days from 1 January, ascending), see :class:`TemperatureModel`."""
    times = np.asarray(times, float)
    days = np.floor(times).astype(int)
    n_days = days.max() - days.min() + 1
    weather = np.empty(n_days)
    rho = model.weather_correlation
    weather[0] = rng.normal(0.0, model.weather_sd)
    innovations = rng.normal(0.0, model.weather_sd * np.sqrt(1 - rho ** 2), n_days)
    for d in range(1, n_days):  # AR(1): one value per day, a short loop over days, not particles
        weather[d] = rho * weather[d - 1] + innovations[d]
    temperature = (model.mean - model.seasonal_amplitude * np.cos(2 * np.pi * (times - model.coldest_day) / 365.0)
                   + model.daily_amplitude * np.sin(2 * np.pi * (times - 9.0 / 24.0))
                   + weather[days - days.min()] + rng.normal(0.0, model.temperature_noise, times.size))
    return np.clip(temperature, model.temperature_min, model.temperature_max)


def simulate_year(rng: np.random.Generator, *, masses=MASSES, stiffnesses=STIFFNESSES, damage_day: float | None = None,
                  damage_storey: int | None = None, damage_size: float = 0.05, alpha: float = -0.0015,
                  beta: float = -0.015, reference_temperature: float = 10.0,
                  temperature: TemperatureModel = TemperatureModel(), frequency_noise: float = 0.004,
                  sets_per_day: int = 24, n_days: int = 365, seed: int | None = None, alpha_spread: float = 0.0,
                  thermal_lag_hours: float = 0.0) -> tuple[dict, YearTruth]:
    """One year of hourly identified frequencies.

    Parameters
    ----------
    rng : numpy.random.Generator
    masses, stiffnesses : (n,) array_like
        Floor masses [kg] and nominal storey stiffnesses ``k_ref`` [N/m], bottom to top.
    damage_day : float, optional
        Time (days) from which ``damage_storey`` has lost ``damage_size`` of its stiffness; ``None``:
        no damage.
    damage_storey : int, optional
        1-based storey of the damage (required with ``damage_day``).
    damage_size : float
        Fraction of the storey stiffness lost, in (0, 1).
    alpha, beta, reference_temperature : float
        The temperature factor ``c(T)`` (:func:`stiffness_factor`).
    temperature : TemperatureModel
    frequency_noise : float
        Relative standard deviation of an identified frequency.
    sets_per_day, n_days : int
        Frequency sets per day (equally spaced from 00:00) and days.
    seed : int, optional
        Recorded in the truth only.
    alpha_spread : float
        A temperature law the monitor does not have: storey ``i`` softens with
        ``alpha (1 + alpha_spread s_i)``, ``s`` evenly spaced from -1 (bottom) to 1 (top).
    thermal_lag_hours : float
        Another: the structure follows the recorded air temperature through a first-order lag with
        this time constant (the CSV holds the air temperature).

    Returns
    -------
    table : dict
        ``day`` (S,), ``temperature`` (S,) and ``f1`` ... ``fn`` (S,) [Hz], ``S = sets_per_day * n_days``.
    truth : YearTruth
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    building = ShearBuilding(masses, stiffnesses)
    n = building.n_storeys
    for name, value in (("sets_per_day", sets_per_day), ("n_days", n_days)):
        if int(value) != value or value < 1:
            raise ValueError(f"{name}: expected a positive integer, got {value}")
    if not 0 <= frequency_noise < 0.5:
        raise ValueError(f"frequency_noise: expected a value in [0, 0.5), got {frequency_noise}")
    if (damage_day is None) != (damage_storey is None):
        raise ValueError("damage_day, damage_storey: give both or neither")
    if damage_storey is not None and not (int(damage_storey) == damage_storey and 1 <= damage_storey <= n):
        raise ValueError(f"damage_storey: expected an integer in 1..{n}, got {damage_storey}")
    if not 0 < damage_size < 1:
        raise ValueError(f"damage_size: expected a value in (0, 1), got {damage_size}")
    times = np.arange(n_days * sets_per_day) / sets_per_day
    temps = simulate_temperature(times, rng, temperature)
    factor = stiffness_factor(temps, alpha, beta, reference_temperature)
    if np.any(factor <= 0):
        raise ValueError("alpha, beta: the temperature factor c(T) is not positive over the simulated temperatures")
    if thermal_lag_hours < 0 or not np.isfinite(alpha_spread):
        raise ValueError("thermal_lag_hours, alpha_spread: expected a lag >= 0 and a finite spread")
    if alpha_spread or thermal_lag_hours:
        frequencies = _mismatched(building, times, temps, alpha, beta, reference_temperature, alpha_spread,
                                  thermal_lag_hours, damage_day, damage_storey, damage_size)
    else:
        frequencies = _matched(building, times, factor, damage_day, damage_storey, damage_size)
    frequencies = frequencies * (1.0 + frequency_noise * rng.standard_normal(frequencies.shape))
    table = {"day": times, "temperature": temps}
    table.update({f"f{r + 1}": frequencies[:, r] for r in range(n)})
    settings = {"masses": [float(m) for m in building.masses], "stiffnesses": [float(k) for k in building.stiffnesses],
                "alpha": alpha, "beta": beta, "reference_temperature": reference_temperature,
                "temperature": asdict(temperature), "frequency_noise": frequency_noise,
                "sets_per_day": int(sets_per_day), "n_days": int(n_days)}
    if alpha_spread or thermal_lag_hours:
        settings.update(alpha_spread=alpha_spread, thermal_lag_hours=thermal_lag_hours)
    truth = YearTruth(None if damage_day is None else float(damage_day),
                      None if damage_storey is None else int(damage_storey), float(damage_size), seed, settings)
    return table, truth


def _matched(building, times, factor, damage_day, damage_storey, damage_size):
    """Frequencies (S, n) when one factor c(T) scales every storey: sqrt(c) times the reference modes."""
    n = building.n_storeys
    healthy = building.modes(np.ones(n))[0][0]  # (n,) Hz at c = 1
    frequencies = np.sqrt(factor)[:, None] * healthy[None, :]  # every k_i scales by c(T): f scales by sqrt(c)
    if damage_day is not None:
        ratios = np.ones(n)
        ratios[int(damage_storey) - 1] = 1.0 - damage_size
        damaged = building.modes(ratios)[0][0]
        after = times >= damage_day
        frequencies[after] = np.sqrt(factor[after])[:, None] * damaged[None, :]
    return frequencies


def _mismatched(building, times, temps, alpha, beta, reference_temperature, alpha_spread, lag_hours, damage_day,
                damage_storey, damage_size):
    """Frequencies (S, n) of per-storey factors at the lagged structure temperature: one eigenproblem per set."""
    n = building.n_storeys
    structure = temps
    if lag_hours:
        from scipy.signal import lfilter

        keep = np.exp(-np.diff(times[:2])[0] * 24.0 / lag_hours)  # x_k = keep x_{k-1} + (1 - keep) T_k
        structure = lfilter([1 - keep], [1, -keep], temps, zi=[keep * temps[0]])[0]
    alphas = alpha * (1 + alpha_spread * np.linspace(-1, 1, n))
    ratios = (1.0 + alphas[None, :] * (structure - reference_temperature)[:, None]
              + beta * np.minimum(structure, 0.0)[:, None])
    if np.any(ratios <= 0):
        raise ValueError("alpha, beta, alpha_spread: a storey's temperature factor is not positive")
    if damage_day is not None:
        ratios[times >= damage_day, int(damage_storey) - 1] *= 1.0 - damage_size
    return building.modes(ratios)[0]


def write_year_csv(path, table: dict, truth: YearTruth) -> Path:
    """Write ``table`` as CSV (header ``day,temperature,f1,...``) and ``truth`` beside it (``.json``).

    Returns the path of the JSON sidecar.
    """
    path = Path(path)
    n_modes = sum(1 for key in table if key.startswith("f"))
    columns = ["day", "temperature"] + [f"f{r + 1}" for r in range(n_modes)]
    values = np.column_stack([table[c] for c in columns])
    np.savetxt(path, values, delimiter=",", header=",".join(columns), comments="", fmt="%.10g")
    sidecar = path.with_suffix(".json")
    sidecar.write_text(json.dumps(asdict(truth), indent=1) + "\n")
    return sidecar


def read_truth(csv_path) -> YearTruth | None:
    """The truth sidecar (``.json`` beside ``csv_path``), or ``None`` if there is none."""
    sidecar = Path(csv_path).with_suffix(".json")
    if not sidecar.exists():
        return None
    record = json.loads(sidecar.read_text())
    keys = {"damage_day", "damage_storey", "damage_size", "seed", "settings"}
    if not isinstance(record, dict) or set(record) != keys:
        raise ValueError(f"{sidecar}: not a truth sidecar (expected the keys damage_day, damage_storey, damage_size, "
                         f"seed, settings)")
    return YearTruth(**record)


def simulate_years(out_dir, n_years: int = 20, seed: int = 0, *, damage_size: float = 0.05,
                   first_damage_day: int = 183, last_damage_day: int = 350, **options) -> list[Path]:
    """Half damaged, half healthy years: ``damaged_00.csv``, ... and ``healthy_00.csv``, ... with sidecars.

    A damaged year loses ``damage_size`` of a random storey's stiffness from the start of a random
    whole day in ``[first_damage_day, last_damage_day]`` (the second half, leaving at least two
    weeks to detect it). Year ``i`` draws from ``numpy.random.default_rng([seed, i])``.
    """
    if int(n_years) != n_years or n_years < 1:
        raise ValueError(f"n_years: expected a positive integer, got {n_years}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    n_storeys = len(options.get("masses", MASSES))
    paths = []
    n_damaged = (n_years + 1) // 2
    for i in range(n_years):
        rng = np.random.default_rng([seed, i])
        damaged = i < n_damaged
        kwargs = dict(options)
        if damaged:
            kwargs.update(damage_day=float(rng.integers(first_damage_day, last_damage_day + 1)),
                          damage_storey=int(rng.integers(1, n_storeys + 1)), damage_size=damage_size)
        table, truth = simulate_year(rng, seed=seed, **kwargs)
        truth = YearTruth(truth.damage_day, truth.damage_storey, truth.damage_size, seed,
                          {**truth.settings, "year": i})
        name = f"damaged_{i:02d}.csv" if damaged else f"healthy_{i - n_damaged:02d}.csv"
        write_year_csv(out / name, table, truth)
        paths.append(out / name)
    return paths


def year_spec(n_modes: int, *, columns=None, day_range=DAY_RANGE, temperature_range=TEMPERATURE_RANGE,
              frequency_range=FREQUENCY_RANGE, hints: dict | None = None) -> TableSpec:
    """The rules of a year CSV (:class:`~seqbayes.store.datasets.TableSpec`) of ``n_modes`` frequencies.

    ``columns`` (``n_modes + 2`` names: time, temperature, frequencies) replaces the header
    ``day,temperature,f1,...,fn``; other columns are then ignored, while without it extra columns are
    refused. The days must increase from row to row (one identified set per row: a repeated or late
    set is refused) and lie in ``day_range``; temperatures lie in ``temperature_range`` [degC];
    frequencies lie in ``frequency_range`` [Hz] and increase along each row. ``hints`` maps
    ``"day"``, ``"temperature"``, ``"frequency"``, ``"extra"``, ``"header"`` and ``"ascending"`` to text
    appended to the messages (the command's options).
    """
    if int(n_modes) != n_modes or n_modes < 1:
        raise ValueError(f"n_modes: expected a positive integer, got {n_modes}")
    n_modes = int(n_modes)
    default = ["day", "temperature"] + [f"f{r + 1}" for r in range(n_modes)]
    names = list(default if columns is None else columns)
    if len(names) != n_modes + 2:
        raise ValueError(f"columns: expected {n_modes + 2} names (time, temperature, {n_modes} frequencies), got "
                         f"{len(names)}")
    hints = dict(hints or {})
    frequencies = names[2:]
    by_column = {names[0]: hints.get("day", ""), names[1]: hints.get("temperature", ""),
                 **{f: hints.get("frequency", "") for f in frequencies}}
    by_column.update({key: hints[key] for key in ("extra", "header", "ascending") if key in hints})
    describe = f"the header {','.join(default)}" if columns is None else f"the columns {', '.join(names)}"
    return TableSpec(tuple(names), time=names[0], time_range=tuple(day_range), time_order="increasing",
                     ranges={names[1]: tuple(temperature_range), **{f: tuple(frequency_range) for f in frequencies}},
                     positive=tuple(frequencies), ascending=tuple(frequencies),
                     extra="refuse" if columns is None else "ignore", describe=describe, hints=by_column)


def read_year_csv(path, n_modes: int | None = None, **options) -> dict:
    """A year CSV (header ``day,temperature,f1,...,fn``) as a dict of ``(S,)`` columns under those names.

    Read by the run store's reader (:func:`~seqbayes.store.datasets.read_datafile`) with the rules of
    :func:`year_spec` (``options`` are its keywords); ``n_modes=None`` takes as many frequencies as
    the header has ``f1, f2, ...`` columns.

    Raises
    ------
    DataError
        A ``ValueError`` naming the file, the line and what was expected (see :func:`year_spec`).
    """
    if n_modes is None:
        first = read_regular(path).split(b"\n", 1)[0].decode("utf-8-sig", "replace")
        n_modes = max(1, sum(bool(re.fullmatch(r"f\d+", h.strip())) for h in first.split(",")))
    spec = year_spec(n_modes, **options)
    values = read_datafile(path, spec)
    canonical = ["day", "temperature"] + [f"f{r + 1}" for r in range(n_modes)]
    return {name: values[:, i] for i, name in enumerate(canonical)}


#: The data's frequencies may lie at most this factor from the building's nominal ones (the prior sd of a log
#: frequency is 0.05): beyond it the building, the units or the column order is wrong, and the monitor's numbers
#: break down (at a factor of 1000 its model probabilities no longer sum to 1).
MAX_FREQUENCY_RATIO = 10.0


def check_against_building(path, building, table, names) -> None:
    """Refuse frequencies whose median lies more than :data:`MAX_FREQUENCY_RATIO` from the building's nominal
    ones: the monitor cannot explain them (its numbers break down), and they mean a wrong building or unit."""
    nominal = building.modes(np.ones((1, building.n_storeys)))[0][0]
    for r, name in enumerate(names):
        median = float(np.median(table[f"f{r + 1}"]))
        ratio = median / nominal[r]
        if not 1 / MAX_FREQUENCY_RATIO <= ratio <= MAX_FREQUENCY_RATIO:
            raise ValueError(f"{path}: the median of column {name!r} is {median:.4g} Hz, {ratio:.3g} times the "
                             f"building's natural frequency {r + 1} of {nominal[r]:.4g} Hz (from --masses and "
                             f"--stiffness); the monitor needs them within a factor of {MAX_FREQUENCY_RATIO:g}: "
                             f"check the building, the units (Hz) and the column order")


def check_memory(n_storeys: int, n_particles: int, n_days: int) -> None:
    """Refuse ``--particles`` whose arrays cannot fit in this machine's memory (numpy's MemoryError would come
    mid-run, as a traceback). Each of the ``n + 1`` models keeps about ``12 * days + 20 (n + 4) + 3 n^2``
    float64 values per particle alive (its per-day likelihoods under both states and their moves: 16.4 kB per
    particle measured on 60 days of a 2-storey building, 20 kB by this count)."""
    need = (n_storeys + 1) * n_particles * (12 * n_days + 20 * (n_storeys + 4) + 3 * n_storeys ** 2) * 8
    try:
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):  # not POSIX: no bound known
        return
    if need > have:
        raise ValueError(f"--particles {n_particles}: {n_storeys + 1} models over {n_days} days need about "
                         f"{need / 2**30:.3g} GiB of memory; this machine has {have / 2**30:.3g} GiB")


def check_days(path, days, records, trouble: str = "") -> None:
    """Refuse a year whose day table is not a set of probabilities (a numeric breakdown): ``records`` are the
    :class:`~seqbayes.structural.environment.MonitorDay` of ``days``; ``trouble`` says what numpy met."""
    for day, record in zip(days, records):
        p = np.asarray(record.model_probabilities)
        if not (np.all(np.isfinite(p)) and abs(p.sum() - 1) < 1e-6
                and -1e-9 <= record.p_damage <= 1 + 1e-9):
            probabilities = ", ".join(f"{q:.3g}" for q in p)
            raise ValueError(f"{path}: the monitor's numbers broke down on day {day} (model probabilities "
                             f"{probabilities}){'; ' + trouble if trouble else ''}: the data lie outside what this "
                             f"building's model can produce; check --masses, --stiffness, the units and the "
                             f"bounds; nothing was written")
