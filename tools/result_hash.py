"""A hash of the studies' results, to show that a restructuring changed nothing numerically.

Runs reduced forms of the Coulomb, damped-oscillator (ordinary and path-space steps), abrupt-drop,
SMC^2 (Kalman and particle inner filters) and SG-EnMCMC / stiffness-drop studies, and hashes every
posterior, weight, predictive draw, numeric step diagnostic (wall times excluded), forecast and the
final generator state. Bit-identical code gives the same hashes::

    python tools/result_hash.py                 # print one hash per study and the total
    python tools/result_hash.py --save h.json   # keep them
    python tools/result_hash.py --check h.json  # compare; exit 1 on any difference

Imports go through ``_load`` so the script keeps working while modules move between packages.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import importlib
import json
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

_TIME_FIELDS = {"wall_time", "elapsed", "seconds"}  # plus --skip-fields: diagnostics a commit added

#: StepInfo's diagnostics in the order and under the names its flat record had before they moved into the
#: components' records (moves, evidence, conflict, jumps, nested): a step is hashed as that flat record was, so
#: hashes of code before and after compare.
_STEP_INFO = ("step", "log_evidence_increment", "log_evidence", "ess", "resampled", "acceptance_rate", "step_size",
              "n_virtual", "n_stages", "temperatures", "n_loglike_evals", "n_nan", "n_distinct", "n_proposed",
              "n_accepted", "n_identical_partner", "log_evidence_increment_path", "evidence_ess",
              "n_independent_accepted", "n_move_evaluations", "wall_time", "prior_data_conflict",
              "conflict_parameter", "inner_ess", "ancestor_ess", "path_steps", "jump_probability", "jump_parameter",
              "jump_size", "jump_size_sd", "log_evidence_increment_se", "log_evidence_se", "n_screen_evaluations",
              "n_screened_out", "amortised_evals", "pmmh_acceptance", "pending_moves", "jump_probability_se")


def _load(name: str, *modules: str):
    """``name`` from the first of ``modules`` that defines it."""
    for module in modules:
        try:
            found = importlib.import_module(module)
        except ImportError:
            continue
        if hasattr(found, name):
            return getattr(found, name)
    raise ImportError(f"{name} not found in any of {modules}")


class _Hasher:
    def __init__(self):
        self._h = hashlib.sha256()

    def add(self, value, label=""):
        self._h.update(label.encode())
        if value is None:
            self._h.update(b"None")
        elif isinstance(value, int) and not isinstance(value, bool):  # generator states exceed int64
            self._h.update(f"int:{value}".encode())
        elif isinstance(value, (np.ndarray, np.generic, float, bool)):
            arr = np.ascontiguousarray(np.asarray(value))
            self._h.update(str(arr.dtype).encode() + str(arr.shape).encode())
            self._h.update(arr.tobytes())
        elif isinstance(value, str):
            self._h.update(value.encode())
        elif isinstance(value, dict):
            for key in sorted(value, key=str):
                if str(key) not in _TIME_FIELDS:
                    self.add(value[key], f"{label}.{key}")
        elif isinstance(value, (tuple, list)):
            for i, item in enumerate(value):
                self.add(item, f"{label}[{i}]")
        elif dataclasses.is_dataclass(value):
            for f in dataclasses.fields(value):
                if f.name not in _TIME_FIELDS:
                    self.add(getattr(value, f.name), f"{label}.{f.name}")
        else:
            raise TypeError(f"cannot hash {type(value).__name__} at {label}")

    def sampler(self, smp, label):
        for i, record in enumerate(smp.result.steps):
            self.add(record.posterior, f"{label}.{i}.posterior")
            self.add(record.log_weights, f"{label}.{i}.log_weights")
            self.add(record.predictive, f"{label}.{i}.predictive")
            self.info(record.info, f"{label}.{i}.info")
        self.add(smp.rng.bit_generator.state, f"{label}.rng")

    def info(self, info, label):
        """A StepInfo, field by field in the flat order of :data:`_STEP_INFO` (the records' fields read as
        attributes of the step); a flat record of older code, field by field as it is."""
        if not hasattr(info, "to_dict"):
            self.add(info, label)
            return
        self._h.update(label.encode())   # as add() does for a dataclass, before its fields
        for name in _STEP_INFO:
            if name not in _TIME_FIELDS:
                self.add(getattr(info, name), f"{label}.{name}")

    def hexdigest(self):
        return self._h.hexdigest()


def _samplers():
    return (_load("SEMC", "seqbayes"), _load("SMC", "seqbayes"))


def _options(cls, flat: dict) -> dict:
    """Flat settings as the sampler ``cls`` takes them: its components (``engine.settings.from_flat``), or the flat
    keywords themselves on code before the components."""
    try:
        from_flat = _load("from_flat", "seqbayes.engine.settings")
    except ImportError:
        return flat
    return from_flat(cls.__name__, **flat)


def _inner(filter_) -> dict:
    """The keyword that gives a sampler SMC^2's inner filter: ``predictive=SMC2(inner=...)``, or ``inner_filter``."""
    try:
        return {"predictive": _load("SMC2", "seqbayes.predictive.smc2")(inner=filter_)}
    except ImportError:
        return {"inner_filter": filter_}


def _sg(sampler: str) -> dict:
    """SG-EnMCMC's sampler keyword: the component of ``sg_from_flat``, or the flat ``sampler=``."""
    try:
        return _load("sg_from_flat", "seqbayes.structural.settings")(sampler=sampler)
    except ImportError:
        return {"sampler": sampler}


def coulomb(h):
    model = importlib.import_module("seqbayes.models.coulomb")
    data = model.load_experiment()
    for cls in _samplers():
        for kernel in ("T1", "T2"):
            smp = cls(model.prior(), model.kernel(kernel), model.loglike, n_samples=200, rng=np.random.default_rng(3))
            smp.run(data)
            h.sampler(smp, f"coulomb.{cls.__name__}.{kernel}")


def oscillator(h):
    osc = importlib.import_module("seqbayes.models.oscillator")
    study = importlib.import_module("seqbayes.studies.oscillator")
    # run 9 takes the path-space remedy (bridge and stored start) under T3 and T6; run 0 is ordinary
    for run, kernel in ((0, "T1"), (0, "T6"), (9, "T3"), (9, "T6")):
        problem = osc.make_problem(np.random.default_rng(getattr(study, "problem_seed", getattr(study, "_problem_seed", None))(0, run)))
        for cls in _samplers():
            smp = cls(osc.prior(), problem.kernels[kernel].kernel, osc.log_likelihood, n_samples=300,
                      rng=np.random.default_rng(7), **_options(cls, study.DEFAULT_OPTIONS[cls.__name__]))
            try:
                smp.run(problem.datasets)
                h.add(smp.predict(3), f"osc.{run}.{kernel}.{cls.__name__}.forecast")
            except Exception as err:  # a failure is a result too (same failure, same place)
                h.add(f"{type(err).__name__}: {err}", f"osc.{run}.{kernel}.{cls.__name__}.error")
            h.sampler(smp, f"osc.{run}.{kernel}.{cls.__name__}")


def abrupt_drop(h):
    osc = importlib.import_module("seqbayes.models.oscillator")
    drop = importlib.import_module("seqbayes.studies.abrupt_drop")
    data = drop.simulate(np.random.default_rng(1))
    kernels = drop.candidate_kernels()
    for name in ("jump", "decay"):
        for cls in _samplers():
            smp = cls(osc.prior(), kernels[name], osc.log_likelihood, n_samples=300, rng=np.random.default_rng(5))
            smp.run(data.datasets)
            h.sampler(smp, f"drop.{name}.{cls.__name__}")


def smc2(h):
    lg = importlib.import_module("seqbayes.models.linear_gaussian")
    kalman_inner = _load("KalmanInnerFilter", "seqbayes", "seqbayes.predictive.smc2", "seqbayes.nested")
    particle_inner = _load("ParticleInnerFilter", "seqbayes", "seqbayes.predictive.smc2", "seqbayes.nested")
    problem = lg.LinearGaussianStateSpace.mixed()
    data, _ = problem.simulate(10, rng=11)
    for cls in _samplers():
        for name, inner in (("kalman", kalman_inner(problem.observe)), ("particle", particle_inner(20))):
            smp = cls(problem.prior, problem.kernel, problem.loglike, n_samples=200, rng=4, **_inner(inner))
            smp.run(data[:6] if name == "particle" else data)
            h.sampler(smp, f"smc2.{name}.{cls.__name__}")


def sg_enmcmc(h):
    table = importlib.import_module("seqbayes.studies.shake_table")
    sgenmcmc = _load("SGEnMCMC", "seqbayes")
    data = table.make_data(table.CASES["wc1"], duration=4.0, rng=0)
    for sampler in ("resample-move", "paper"):
        try:
            sg = sgenmcmc(data["building"], 0.02, 0.7, 1.0, data["noise_std"], data["process_noise_std"],
                          **_sg(sampler))
        except TypeError:
            continue
        run = sg.run(data["u"], data["y"], rng=2)
        h.add(run, f"sg.{sampler}")


def stiffness_drop(h):
    monitor_cls = _load("StiffnessDropMonitor", "seqbayes.structural.stiffness_drop", "seqbayes.stiffness_drop")
    structures = importlib.import_module("seqbayes.structural.structures" if importlib.util.find_spec(
        "seqbayes.structural") else "seqbayes.structures")
    simulate_drop = _load("simulate_drop", "seqbayes.structural.drop_paths", "seqbayes.structural.stiffness_drop",
                          "seqbayes.stiffness_drop")
    dt = 0.02
    building = structures.ShearBuilding([1.2e4, 1.0e4], [2.0e7, 1.4e7], (0.02, 0.04))
    u = structures.kanai_tajimi(3.0, dt, 0.07, rng=1).acceleration
    y, _ = simulate_drop(building, dt, [0.9, 0.8], 1, 0.2, 70, u)
    y = y + 0.03 * np.std(y, axis=0) * np.random.default_rng(2).standard_normal(y.shape)
    mon = monitor_cls(building, dt, 0.7, 1.0, 0.03 * np.std(y, axis=0), n_particles=100)
    mon.reset(rng=7)
    for start in range(0, 150, 25):
        mon.update(u[start:start + 25], y[start:start + 25])
    h.add(list(mon.history), "drop_monitor.history")


STUDIES = {"coulomb": coulomb, "oscillator": oscillator, "abrupt_drop": abrupt_drop, "smc2": smc2,
           "sg_enmcmc": sg_enmcmc, "stiffness_drop": stiffness_drop}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", default=",".join(STUDIES), help="comma-separated studies")
    parser.add_argument("--save", help="write the hashes to this JSON file")
    parser.add_argument("--check", help="compare with the hashes in this JSON file")
    parser.add_argument("--skip-fields", default="",
                        help="comma-separated record fields not hashed: fields a commit added, so the rest of the "
                             "results can still be compared with hashes saved before it")
    args = parser.parse_args(argv)
    _TIME_FIELDS.update(name for name in args.skip_fields.split(",") if name)
    hashes = {}
    for name in args.only.split(","):
        start = time.perf_counter()
        h = _Hasher()
        STUDIES[name](h)
        hashes[name] = h.hexdigest()
        print(f"{name:15s} {hashes[name][:16]}  ({time.perf_counter() - start:.1f} s)", flush=True)
    total = hashlib.sha256("".join(hashes[k] for k in sorted(hashes)).encode()).hexdigest()
    print(f"{'total':15s} {total[:16]}")
    if args.save:
        with open(args.save, "w") as fh:
            json.dump(hashes, fh, indent=1)
    if args.check:
        with open(args.check) as fh:
            expected = json.load(fh)
        differ = [k for k in hashes if expected.get(k) != hashes[k]]
        if differ:
            print("DIFFERENT:", ", ".join(differ))
            return 1
        print("bit-identical to", args.check)
    return 0


if __name__ == "__main__":
    sys.exit(main())
