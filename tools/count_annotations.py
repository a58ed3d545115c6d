"""Count the public functions of seqbayes whose signatures are fully annotated.

Usage: ``python tools/count_annotations.py [--list]``.

The public API is what ``seqbayes/__init__.py`` exports (``__all__``: functions, classes and
the sub-modules it names, through their own ``__all__``) plus the modules behind the command
line (``cli``, ``config``, ``store``, ``report``, ``plotting``, ``results``, ``prognostics``).
A class contributes its public methods, properties and ``__init__``, also those it inherits
from seqbayes base classes (dataclass-generated ``__init__`` excluded: it is annotated from the
fields). A function is fully annotated when every
parameter but ``self``/``cls`` has an annotation and, except for ``__init__``, so has the return
value. ``--list`` prints the functions that are not.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import sys
import types

CLI_MODULES = ("cli", "config", "store", "report", "plotting", "results", "prognostics")


def _functions_of_class(cls):
    for name, member in vars(cls).items():
        if name.startswith("_") and name != "__init__":
            continue
        if isinstance(member, property):
            if member.fget is not None:
                yield f"{cls.__qualname__}.{name}", member.fget
        elif isinstance(member, (staticmethod, classmethod)):
            yield f"{cls.__qualname__}.{name}", member.__func__
        elif inspect.isfunction(member):
            if name == "__init__" and getattr(member, "__qualname__", "").endswith("__create_fn__.<locals>.__init__"):
                continue
            if name == "__init__" and member.__code__.co_filename == "<string>":   # dataclass-generated
                continue
            yield f"{cls.__qualname__}.{name}", member


def _public(module):
    names = getattr(module, "__all__", None)
    if names is None:
        names = [n for n, v in vars(module).items() if not n.startswith("_")
                 and getattr(v, "__module__", None) == module.__name__]
    return [(n, getattr(module, n)) for n in names if hasattr(module, n)]


def public_functions() -> dict:
    """``qualified name -> function`` over the public API (see the module docstring)."""
    seqbayes = importlib.import_module("seqbayes")
    found, seen_modules = {}, set()

    def visit(obj, prefix):
        if isinstance(obj, types.ModuleType):
            if not obj.__name__.startswith("seqbayes") or obj.__name__ in seen_modules:
                return
            seen_modules.add(obj.__name__)
            for name, value in _public(obj):
                visit(value, obj.__name__)
        elif inspect.isclass(obj):
            if not getattr(obj, "__module__", "").startswith("seqbayes"):
                return
            for base in obj.__mro__:   # with the methods a public class inherits from a private base
                if getattr(base, "__module__", "").startswith("seqbayes"):
                    for qual, func in _functions_of_class(base):
                        found.setdefault(f"{base.__module__}.{qual}", func)
        elif inspect.isfunction(obj):
            if getattr(obj, "__module__", "").startswith("seqbayes"):
                found.setdefault(f"{obj.__module__}.{obj.__qualname__}", obj)

    visit(seqbayes, "seqbayes")
    for name in CLI_MODULES:
        visit(importlib.import_module(f"seqbayes.{name}"), f"seqbayes.{name}")
    return found


def fully_annotated(func) -> bool:
    signature = inspect.signature(func)
    for parameter in signature.parameters.values():
        if parameter.name in ("self", "cls"):
            continue
        if parameter.annotation is inspect.Parameter.empty:
            return False
    return func.__name__ == "__init__" or signature.return_annotation is not inspect.Signature.empty


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--list", action="store_true", help="print the functions not fully annotated")
    args = parser.parse_args(argv)
    functions = public_functions()
    missing = sorted(name for name, func in functions.items() if not fully_annotated(func))
    if args.list:
        print("\n".join(missing))
    print(f"{len(functions) - len(missing)} of {len(functions)} public functions fully annotated")
    return 0


if __name__ == "__main__":
    sys.exit(main())
