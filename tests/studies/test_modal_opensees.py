"""A user's eigen analysis as the modal likelihood's model (FunctionModel): OpenSees (the opensees extra)
gives the shear building's modes, and the likelihood equals the built-in model's."""

import numpy as np
import pytest

from seqbayes.structural.modal_likelihood import ModalLikelihood
from seqbayes.structural.structures import ShearBuilding
from seqbayes.structural.structures.linear import FunctionModel, ShearBuildingModel

ops = pytest.importorskip("opensees.openseespy")
pytestmark = pytest.mark.slow

MASSES, STIFFNESSES = (2e5, 2e5, 2e5, 1.6e5), (3e8, 2.6e8, 2.2e8, 1.8e8)


def opensees_modes(theta):
    """The 4-storey shear building in OpenSees (zero-length springs, lumped masses): its eigen analysis."""
    ops.wipe()
    ops.model("basic", "-ndm", 1, "-ndf", 1)
    ops.node(0, 0.0)
    ops.fix(0, 1)
    for i in range(4):
        ops.node(i + 1, 0.0)
        ops.mass(i + 1, MASSES[i])
        ops.uniaxialMaterial("Elastic", i + 1, float(theta[i]) * STIFFNESSES[i])
        ops.element("zeroLength", i + 1, i, i + 1, "-mat", i + 1, "-dir", 1)
    eigenvalues = np.array(ops.eigen("-fullGenLapack", 4))
    shapes = np.array([[ops.nodeEigenvector(n + 1, m + 1, 1) for m in range(4)] for n in range(4)])
    return np.sqrt(eigenvalues) / (2 * np.pi), shapes


def test_an_opensees_eigen_analysis_is_a_model():
    theta = np.random.default_rng(0).uniform(0.7, 1.3, (5, 4))
    built_in = ShearBuildingModel(ShearBuilding(MASSES, STIFFNESSES))
    user = FunctionModel(opensees_modes, 4, 4, ("1", "2", "3", "4"))
    f_user, s_user = user.modes(theta)
    f_ref, s_ref = built_in.modes(theta)
    assert np.allclose(f_user, f_ref, rtol=1e-9)
    mac = np.einsum("npq,npq->nq", s_user, s_ref) ** 2 / (
        np.einsum("npq,npq->nq", s_user, s_user) * np.einsum("npq,npq->nq", s_ref, s_ref))
    assert np.allclose(mac, 1.0, atol=1e-9)
    data = {"mode": np.array([1, 2]), "frequency_hz": f_ref[0, :2] * 1.01, "std_frequency_hz": np.zeros(2)}
    for c in range(4):
        data[f"phi_{c + 1}"] = s_ref[0, c, :2] / np.abs(s_ref[0, :, :2]).max(axis=0)
        data[f"std_phi_{c + 1}"] = np.full(2, 0.01)
    like_user = ModalLikelihood(user, frequency_error=0.01, shape_error=0.02)
    like_ref = ModalLikelihood(built_in, frequency_error=0.01, shape_error=0.02)
    assert np.allclose(like_user(theta, data), like_ref(theta, data), rtol=1e-8)
