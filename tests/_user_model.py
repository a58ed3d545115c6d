"""The small user model the config, store and CLI tests write to a folder: a free decay
y(t) = A exp(-b t) + Gaussian noise, its likelihood in a Python module next to a TOML run
configuration that names it ``module:function``.

Each test file gives the module its own name: the configuration imports the likelihood by
module name, and Python keeps the first module of a name for the whole test session.
"""

from __future__ import annotations

import dataclasses

import numpy as np

CONFIG = """\
[model]
name = "{name}"
likelihood = "{module}:{func}"
[data]
columns = ["t", "y"]
{data}
[priors]
{amplitude} = {{ dist = "uniform", loc = 0.5, scale = 2.0 }}
b = {{ dist = "uniform", loc = 0.0, scale = 1.0 }}
[kernel]
{kernel}
[sampler]
type = "{sampler}"
n_samples = {n_samples}
seed = {seed}
"""


def write_model(folder, module, noise=0.1, *, by_name=False, extra=""):
    """Write ``folder/module.py`` with ``loglike(theta, data)``, the Gaussian log-likelihood of
    y = theta[:, 0] exp(-theta[:, 1] t) with noise sd ``noise``. ``data`` is the (n, 2) table of
    t, y, or with ``by_name`` the dict of columns (``format = "columns"``); ``extra`` is further
    source appended to the module."""
    t_y = 'data["t"], data["y"]' if by_name else "data[:, 0], data[:, 1]"
    (folder / f"{module}.py").write_text(f"""
import numpy as np
def loglike(theta, data):
    t, y = {t_y}
    pred = theta[:, [0]] * np.exp(-theta[:, [1]] * t[None, :])
    return -0.5 * np.sum((y - pred) ** 2, axis=1) / {noise} ** 2
""" + extra)


def write_config(path, module, *, n_samples, seed, name="decay", func="loglike", amplitude="a", kernel="",
                 data="", sampler="SEMC"):
    """Write the run configuration of the decay model to ``path`` and return ``path``: uniform priors
    on the amplitude (named ``amplitude``) and b, ``kernel`` the [kernel] lines (none: every
    parameter static), ``data`` further [data] lines."""
    path.write_text(CONFIG.format(name=name, module=module, func=func, data=data, amplitude=amplitude, kernel=kernel,
                                  sampler=sampler, n_samples=n_samples, seed=seed))
    return path


def decay_tables(amplitudes, t, noise, seed, rate=0.4):
    """One (len(t), 2) table of t, y = a exp(-rate t) + noise N(0, 1) per amplitude a, the noise
    drawn in order from ``default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    return [np.column_stack([t, a * np.exp(-rate * t) + noise * rng.standard_normal(t.size)]) for a in amplitudes]


LINE_MODEL = """
import numpy as np
def loglike(theta, data):
    pred = theta[:, [0]] + theta[:, [1]] * data[:, 0][None, :]
    return -0.5 * np.sum((data[:, 1][None, :] - pred) ** 2, axis=1) / {noise} ** 2
"""


def line_model(noise: float) -> str:
    """Source of a module whose ``loglike`` is the straight line y = a + b t with Gaussian noise sd ``noise``;
    the data table's columns are (t, y)."""
    return LINE_MODEL.format(noise=noise)


def assert_same_steps(steps_a, steps_b):
    """Two runs' steps are bit-identical: samples, weights, predictive and every diagnostic but the wall time."""
    assert len(steps_a) == len(steps_b)
    for a, b in zip(steps_a, steps_b):
        np.testing.assert_array_equal(a.posterior, b.posterior)
        np.testing.assert_array_equal(a.log_weights, b.log_weights)
        np.testing.assert_array_equal(a.predictive, b.predictive)
        info_a, info_b = dataclasses.asdict(a.info), dataclasses.asdict(b.info)
        info_a.pop("wall_time"), info_b.pop("wall_time")  # the only field allowed to differ
        np.testing.assert_equal(info_a, info_b)  # every diagnostic, NaN == NaN
