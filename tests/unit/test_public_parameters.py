"""No public callable takes more than 12 parameters (issue 39): settings travel as components, not flat keyword lists.

A frozen record's constructor (a dataclass: a result, a configuration read from a TOML table) is data, one field per
stored value, and is not counted; ``StepInfo``'s own cap (15 core fields) is tested in tests/unit/test_sampler_api.py.
"""

import dataclasses
import importlib
import inspect
import pkgutil

import seqbayes

MAX_PARAMETERS = 12


def _public_callables():
    for info in pkgutil.walk_packages(seqbayes.__path__, "seqbayes."):
        if ".data" in info.name or info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name, None)
            if getattr(obj, "__module__", None) != module.__name__:
                continue                      # re-exported: counted where it is defined
            if inspect.isfunction(obj):
                yield f"{module.__name__}.{name}", obj
            elif inspect.isclass(obj):
                if not dataclasses.is_dataclass(obj):
                    yield f"{module.__name__}.{name}", obj
                for attr, value in vars(obj).items():
                    if not attr.startswith("_") and (inspect.isfunction(value)
                                                     or isinstance(value, (staticmethod, classmethod))):
                        yield f"{module.__name__}.{name}.{attr}", getattr(obj, attr)


def test_no_public_callable_takes_more_than_12_parameters():
    over = []
    for name, obj in _public_callables():
        try:
            parameters = inspect.signature(obj).parameters
        except (TypeError, ValueError):
            continue
        count = sum(p.name not in ("self", "cls") for p in parameters.values())
        if count > MAX_PARAMETERS:
            over.append(f"{name}: {count}")
    assert not over, over


def test_the_count_sees_the_samplers():
    names = dict(_public_callables())
    assert "seqbayes.engine.drivers.SEMC" in names and "seqbayes.structural.sgenmcmc.SGEnMCMC" in names
