"""The measured choice between exact transitions and sparse-grid surrogates:
what does not depend on timings (accuracy gates, the record of the choice,
the wiring into SG-EnMCMC). No test asserts which candidate is faster."""

import numpy as np
import pytest

from seqbayes.structural.settings import sg_from_flat
from seqbayes import SGEnMCMC
from seqbayes.structural.transitions import ExactTransition, SparseGridTransition
from seqbayes.structural.structures import ShearBuilding
from seqbayes.structural.structures.bouc_wen import BoucWenBuilding, BoucWenExponential, BoucWenRK4
from seqbayes.studies.shake_table import synthetic_record
from seqbayes.structural.surrogate import Measurement, SurrogateChoice, choose_transition

BUILDING = ShearBuilding([2.2e4, 1.5e4], [2.8e7, 1.9e7], (0.02, 0.05))


def test_linear_grid_levels_are_gated_by_accuracy():
    choice = choose_transition(BUILDING, 0.02, 0.7, 1.0, 64, measurement=Measurement(repeats=1))
    grids = [c for c in choice.candidates if c["name"] == "grid"]
    errors = [c["error"] for c in grids]
    assert all(b < a for a, b in zip(errors, errors[1:]))  # refining helps
    assert [c["accurate"] for c in grids] == [False] * (len(grids) - 1) + [True]  # stops at the first within tol
    assert grids[-1]["error"] <= 3e-6
    assert choice.kind in ("exact", "grid") and choice.reason
    if choice.kind == "grid":
        assert isinstance(choice.transition, SparseGridTransition) and choice.level == grids[-1]["level"]
    else:
        assert isinstance(choice.transition, ExactTransition) and choice.level is None
    summary = choice.as_dict()
    assert summary["kind"] == choice.kind and len(summary["candidates"]) == len(choice.candidates)


def test_no_accurate_grid_means_exact():
    choice = choose_transition(BUILDING, 0.02, 0.7, 1.0, 16,
                               measurement=Measurement(tol=1e-30, levels=(1, 2, 3), repeats=1))
    assert choice.kind == "exact" and isinstance(choice.transition, ExactTransition)
    assert "no grid level within tol" in choice.reason
    capped = choose_transition(BUILDING, 0.02, 0.7, 1.0, 16,
                               measurement=Measurement(tol=1e-30, max_points=6, repeats=1))
    assert "not built" in capped.candidates[-1]["note"]


@pytest.mark.slow
def test_bouc_wen_candidates_and_accuracy_gate():
    bw = BoucWenBuilding.from_yield_drift(BUILDING, 0.004, alpha=0.3)
    u = np.random.default_rng(0).standard_normal(120) * 2.0
    with pytest.raises(ValueError, match="probe"):
        choose_transition(bw, 0.02, 0.7, 1.0, 8)
    choice = choose_transition(bw, 0.02, 0.7, 1.0, 8, probe=u, enkf_members=4,
                               measurement=Measurement(repeats=1, n_test=4, levels=(2, 3)))
    names = [c["name"] for c in choice.candidates]
    assert names[0] == "rk4" and "exponential" in names
    chosen = [c for c in choice.candidates if c["accurate"]]
    assert chosen and all(c["error"] <= 1e-2 for c in chosen)
    assert isinstance(choice.transition, (BoucWenRK4, BoucWenExponential))
    strict = choose_transition(bw, 0.02, 0.7, 1.0, 8, probe=u, enkf_members=4,
                               measurement=Measurement(repeats=1, n_test=4, tol=1e-12, levels=(2,),
                                                       exponential_substeps=(1,)))
    assert strict.kind == "exact" and strict.integrator == "rk4" and "no candidate" in strict.reason


def test_sgenmcmc_records_the_choice():
    data = synthetic_record(BUILDING, [0.82, 0.9], 2.0, rng=7)
    sg = SGEnMCMC(BUILDING, 0.02, 0.7, 1.0, data["noise_std"], data["process_noise_std"], n_members=64,
                  **sg_from_flat(surrogate="auto", surrogate_options={"repeats": 1}))
    assert isinstance(sg.surrogate_choice, SurrogateChoice)
    run = sg.run(data["u"], data["y"], rng=1)
    assert run.surrogate["kind"] == sg.surrogate_choice.kind and run.surrogate["reason"]
    plain = SGEnMCMC(BUILDING, 0.02, 0.7, 1.0, data["noise_std"], data["process_noise_std"], n_members=64)
    assert plain.run(data["u"], data["y"], rng=1).surrogate == {}
    with pytest.raises(ValueError, match="surrogate"):
        SGEnMCMC(BUILDING, 0.02, 0.7, 1.0, data["noise_std"], **sg_from_flat(surrogate="always"))
    with pytest.raises(ValueError, match="transition"):
        SGEnMCMC(BUILDING, 0.02, 0.7, 1.0, data["noise_std"], **sg_from_flat(surrogate="auto",
                                                                             transition=ExactTransition(BUILDING,
                                                                                                        0.02)))
