"""The modal run store: identified modes updating a model through the SMC/SEMC run store (docs/modal.md).

A :class:`ModalRunStore` is the SMC/SEMC store (:class:`~seqbayes.store.smc.RunStore`: the same file
layout, resumption and hashes) of a run whose likelihood is the built-in modal one
(:mod:`seqbayes.store.modal_config`), so updates run no user code. A dataset is one record, given as

- a **tracked** modes table (a ``mode`` column: :mod:`seqbayes.structural.tracking`, ``seqbayes track``);
- an **OMA result**: a modes table without ``mode`` (``seqbayes oma``'s output, one record): its modes
  are tracked at the update against the run's current posterior (:func:`track_against_posterior`);
- a **raw record**: a CSV of accelerations, one column per channel (and optionally ``time`` [s], else
  ``[modal] record_dt``), identified by :func:`seqbayes.structural.oma.ssi_cov` and then tracked.

Tracking at the update: the model's prediction at the last posterior (the prior before the first
update) gives each mode's mean and variance; the record's poles are assigned to modes by
:func:`seqbayes.structural.tracking.assign` inside the gate ``[modal] gate`` (innovation variance: the
prediction's spread, the frequency error, the OMA's scaled sd), with the MAC against the predicted
shapes where both have shapes. Poles assigned to no mode are dropped and counted in a
:class:`ModalTrackingWarning`. The step records the SHA-256 of the file's table as read (before
tracking), so the same record given twice is refused.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .datasets import DataError, check_table, dataset_digest
from .errors import StoreError
from .modal_config import ModalRunConfig
from .modules import ModuleSource
from .registry import register
from .smc import RunStore

__all__ = ["ModalRunStore", "ModalTrackingWarning", "track_against_posterior"]

#: Most particles the posterior prediction for tracking is computed from (a systematic subsample).
TRACKING_PARTICLES = 256
_BUILT_IN = ModuleSource("seqbayes.structural.modal_likelihood", (), "", None)


class ModalTrackingWarning(UserWarning):
    """Poles of a record that were assigned to no mode (spurious) or modes it did not hold."""


def _weights(log_weights):
    w = np.exp(log_weights - np.max(log_weights))
    return w / w.sum()


def track_against_posterior(likelihood, particles, weights, frequency, std_frequency, shapes=None,
                            frequency_error: float = 0.0, std_scale: float = 1.0, gate: float = 3.5,
                            mac_gate: float = 0.8) -> np.ndarray:
    """Assign one record's poles to the model's modes as the posterior predicts them.

    Parameters
    ----------
    likelihood : ModalLikelihood
    particles : (N, d) array
    weights : (N,) array
        Normalised.
    frequency, std_frequency : (k,) arrays
        The record's poles [Hz] (an unknown sd: NaN or 0).
    shapes : (k, p) array, optional
        At the model's channels.
    frequency_error : float
        Relative prediction error of the frequencies.
    std_scale : float
        Factor on ``std_frequency``.
    gate, mac_gate : float
        As :func:`seqbayes.structural.tracking.assign`.

    Returns
    -------
    (k,) int array
        The mode (1-based) of each pole, 0 for a pole assigned to no mode.
    """
    from ..structural.tracking import assign, shape_mac

    if particles.shape[0] > TRACKING_PARTICLES:   # a systematic subsample by weight: deterministic
        u = (np.arange(TRACKING_PARTICLES) + 0.5) / TRACKING_PARTICLES
        pick = np.minimum(np.searchsorted(np.cumsum(weights), u), particles.shape[0] - 1)
        particles, weights = particles[pick], np.full(TRACKING_PARTICLES, 1.0 / TRACKING_PARTICLES)
    freqs, pred_shapes = likelihood.predict(particles)                       # (N, q), (N, p, q)
    ok = np.all(np.isfinite(freqs), axis=1)
    if not ok.any():
        raise DataError("tracking: the model predicts no finite frequency at the run's current samples")
    w = weights[ok] / weights[ok].sum()
    mean = w @ freqs[ok]
    var = w @ (freqs[ok] - mean) ** 2
    std = np.nan_to_num(np.asarray(std_frequency, dtype=float), nan=0.0)
    variance = var[None, :] + (frequency_error * mean[None, :]) ** 2 + (std_scale * std[:, None]) ** 2
    variance = np.maximum(variance, (1e-6 * mean[None, :]) ** 2)
    mac = None
    if shapes is not None and pred_shapes is not None:
        mean_shape = np.einsum("n,npq->pq", w, pred_shapes[ok] * np.sign(np.einsum(
            "npq,pq->nq", pred_shapes[ok], pred_shapes[ok][0]))[:, None, :])
        mac = shape_mac(shapes, mean_shape)
    return assign(frequency, variance, mean, gate, mac, mac_gate) + 1


@register("modal")
class ModalRunStore(RunStore):
    """An SMC/SEMC run store whose likelihood is the built-in modal one (module docstring)."""

    title = "modal SEMC/SMC"
    config_type = ModalRunConfig

    # ------------------------------------------------------------ the likelihood
    def _verified_likelihood(self, accept_model_change: bool = False):
        """The built-in likelihood (nothing of the user's is run or hashed)."""
        return self.config.build_likelihood(), _BUILT_IN

    def likelihood_candidates(self) -> list:
        return []

    def share_likelihood(self, executor, source=None) -> None:
        return None

    def user_code(self) -> None:
        return None

    def _own_attrs(self) -> dict:
        return {**super()._own_attrs(), "run_kind": "modal"}

    # ------------------------------------------------------------------ datasets
    def read_datafile(self, datafile) -> np.ndarray:
        """One record as the run's table (columns ``config.columns``): a tracked modes table, an OMA modes table
        (``mode`` 0 in every row: tracked at :meth:`assimilate`) or a raw record (identified here by SSI-cov,
        then tracked at :meth:`assimilate`).

        Raises
        ------
        DataError
            One line naming the file: not readable, several records in one file, a shape column the run
            needs missing, no mode identified.
        """
        from ..structural.modes_table import read_modes_table

        path = Path(datafile)
        if path.is_dir():
            raise DataError(f"{path}: is a folder, not a data file")
        if not path.is_file():
            raise DataError(f"{path}: no such file")
        header = _header(path)
        try:
            table = read_modes_table(path) if "frequency_hz" in header else self._identify(path, header)
        except ValueError as err:
            raise DataError(str(err) if str(err).startswith(str(path)) else f"{path}: {err}") from None
        if np.unique(np.round(table.day, 9)).size > 1:
            raise DataError(f"{path}: holds {np.unique(np.round(table.day, 9)).size} records (days); a dataset is one "
                            f"record: split the table with seqbayes track")
        return self._as_columns(table, str(path))

    def _identify(self, path: Path, header: list) -> object:
        """A raw record's modes (:func:`seqbayes.structural.oma.ssi_cov` with its defaults)."""
        from ..structural.modes_table import PoleTable
        from ..structural.oma import ssi_cov

        try:
            values = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        except ValueError as err:
            raise DataError(f"{path}: not a modes table (no frequency_hz column) nor a record of numbers: "
                            f"{err}") from None
        time = next((i for i, h in enumerate(header) if h.lower() in ("time", "t", "time_s")), None)
        if time is not None:
            dt = float(np.median(np.diff(values[:, time])))
            channels = [h for i, h in enumerate(header) if i != time]
            y = np.delete(values, time, axis=1)
        elif "record_dt" in self.config.modal:
            dt, channels, y = self.config.modal["record_dt"], header, values
        else:
            raise DataError(f"{path}: a raw record needs its sampling step: a time column (time, t) or "
                            f"[modal] record_dt in the run's configuration")
        modes = ssi_cov(y, dt)
        if np.size(modes.frequencies) == 0:
            raise DataError(f"{path}: the OMA (SSI-cov) identified no mode in this record; identify it with "
                            f"seqbayes oma and its options, and update with the modes table it writes")
        return PoleTable.from_modes(modes, channels=channels)

    def _as_columns(self, table, source: str) -> np.ndarray:
        """The run's ``(k, c)`` table of a :class:`PoleTable` (``mode`` 0 where untracked)."""
        columns = self.config.columns
        out = np.zeros((table.n_rows, len(columns)))
        out[:, 0] = table.mode if table.mode is not None else 0
        out[:, 1] = table.frequency
        out[:, 2] = np.nan_to_num(table.std_frequency, nan=0.0)
        shape_cols = [c for c in columns if c.startswith("phi_")]
        for c in shape_cols:
            channel = c[4:]
            if table.shapes is None or channel not in table.channels:
                raise DataError(f"{source}: the run uses mode shapes; column phi_{channel} is missing (it has "
                                f"{', '.join('phi_' + x for x in table.channels) or 'no shape columns'})")
            j = table.channels.index(channel)
            if not np.all(np.isfinite(table.shapes[:, j])):
                raise DataError(f"{source}: column phi_{channel} has an empty cell; every mode needs its whole shape")
            out[:, columns.index(c)] = table.shapes[:, j]
            std = table.std_shapes[:, j] if table.std_shapes is not None else np.zeros(table.n_rows)
            out[:, columns.index(f"std_phi_{channel}")] = np.nan_to_num(std, nan=0.0)
        return out

    # ------------------------------------------------------------- assimilation
    def _tracked(self, table: np.ndarray, source: str, base: int) -> np.ndarray:
        """An untracked table (``mode`` 0) with its poles assigned to modes against the posterior after ``base``
        steps (the prior's draws at 0)."""
        if base:
            record = self.result.steps[base - 1]
            particles, weights = record.posterior, _weights(record.log_weights)
        else:
            particles, weights = self.initial_particles, _weights(self.initial_log_weights)
        like = self.config.build_likelihood()
        error = like.frequency_error
        e_f = float(np.max(error.value)) if hasattr(error, "value") else float(
            np.average(particles[:, error.column], weights=weights))
        shape_cols = [i for i, c in enumerate(self.config.columns) if c.startswith("phi_")]
        modes = track_against_posterior(like, particles, weights, table[:, 1], table[:, 2],
                                        table[:, shape_cols] if shape_cols else None, e_f,
                                        self.config.modal["std_scale"], self.config.modal["gate"],
                                        self.config.modal["mac_gate"])
        kept = modes > 0
        if not kept.any():
            raise DataError(f"{source}: none of its {table.shape[0]} poles lies within the gate of a mode the run "
                            f"predicts ({', '.join(f'{f:.4g}' for f in table[:, 1])} Hz); raise [modal] gate, or "
                            f"track the records with seqbayes track")
        if not kept.all():
            warnings.warn(f"{source}: {int((~kept).sum())} of {table.shape[0]} poles assigned to no mode (spurious) "
                          f"and left out; modes {', '.join(map(str, sorted(modes[kept])))} found",
                          ModalTrackingWarning, stacklevel=3)
        out = table[kept].copy()
        out[:, 0] = modes[kept]
        return out[np.argsort(out[:, 0], kind="stable")]

    def assimilate(self, table, source: str = "<array>", *, replace_last: bool = False, write: bool = True,
                   **options):
        """Assimilate one record's table (:meth:`read_datafile`'s) and save the store; an untracked one (``mode``
        0 in every row) is tracked first against the current posterior. Other keywords as
        :meth:`RunStore.assimilate <seqbayes.store.smc.RunStore.assimilate>`."""
        raw = np.asarray(table, dtype=float)
        if raw.ndim == 2 and raw.shape[1] == len(self.config.columns) and raw.shape[0] and np.all(raw[:, 0] == 0):
            what = "table" if source == "<array>" else f"table from {source}"
            raw = check_table(raw, self.config, what)
            digest = dataset_digest(raw, self.config.columns)
            with self._updating(write, replace_last):
                if replace_last and self.n_steps == 0:
                    raise StoreError(f"{self.path}: replace_last: no step to replace")
                self.check_new_dataset(digest, replace_last)
                tracked = self._tracked(raw, source, self.n_steps - 1 if replace_last else self.n_steps)
                info = super().assimilate(tracked, source, replace_last=replace_last, write=False, **options)
                self.digests[-1] = digest           # the record as given, so that it cannot be assimilated twice
                if write:
                    self.write()
            return info
        if raw.ndim == 2 and raw.shape[0] and np.any(raw[:, 0] == 0):
            raise DataError(f"{source}: some rows have mode 0 (untracked) and others a mode; track the whole record "
                            f"or none of it")
        return super().assimilate(table, source, replace_last=replace_last, write=write, **options)

    # ------------------------------------------------- what the command line asks
    def describe(self) -> str:
        modal = self.config.modal
        what = ("each tracked mode's frequency a parameter" if modal["model"] == "modes" else
                f"{len(modal['masses'])}-storey shear building, storeys {modal['storeys']}")
        shapes = "frequencies and shapes" if "shape_error" in modal else "frequencies"
        return (f"modal run {self.path} for model {self.config.name!r}: {what}; {len(self.names)} parameters "
                f"({', '.join(self.names)}), {shapes}, {self.config.sampler} with N = {self.config.n_samples}, seed "
                f"{self.config.seed}")


def _header(path: Path) -> list:
    import csv

    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            return [h.strip() for h in next(csv.reader(fh), [])]
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a text CSV file") from None
