"""The two-storey shear building that the SG-EnMCMC store, monitor and registry tests configure: one
TOML builder, so the three files differ only in what they test (sensors, time column, ensemble size,
the stiffness-drop monitor)."""

from __future__ import annotations


def sg_toml(name: str, n_members: int, *, sensors: bool = False, time: bool = True, extra: str = "") -> str:
    """The run configuration of the two-storey building (masses 20 and 16 t, stiffnesses 30 and 20 MN/m).

    Parameters
    ----------
    name : the model's name.
    n_members : the EnKF ensemble size.
    sensors : write a ``[sensors]`` table measuring both storeys' accelerations.
    time : name a time column ``t`` in ``[data]``.
    extra : TOML appended after ``[sampler]`` (for example a ``[monitor]`` table).
    """
    text = (f'\n[model]\nname = "{name}"\n\n[building]\nmasses = [20000.0, 16000.0]\n'
            'stiffnesses = [3.0e7, 2.0e7]\ndamping_ratios = [0.02, 0.03]\n')
    if sensors:
        text += "\n[sensors]\naccelerations = [1, 2]\n"
    text += '\n[data]\ndt = 0.02\ninput = "ag"\nresponses = ["a1", "a2"]\n'
    if time:
        text += 'time = "t"\n'
    text += ("\n[priors]\nlower = 0.5\nupper = 1.5\n\n[noise]\nmeasurement_std = 0.05\n\n"
             f"[sampler]\nn_members = {n_members}\nseed = 7\n")
    return text + extra
