"""Loading the user's code (the likelihood's module) by file path, with a hash of what runs.

The trust boundary of a run (docs/guide.md, "Trust"): a configuration and a run store name a
module; :func:`locate_module` finds its files *without running them* and hashes them
(:class:`ModuleSource`), and :func:`import_module_source` runs exactly the hashed bytes, from the
config's folder by path (``sys.path`` untouched, so a ``matplotlib.py`` beside a store is never
imported in place of the package) or, for an installed module, the usual way. The run store
records the hash per step and refuses a module whose content changed.

Written by hand because :mod:`importlib` gives the pieces (``spec_from_file_location``) but not
"run these bytes, which were hashed, as this dotted module, replacing a same-named module run
from another folder".
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.machinery
import importlib.util
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

__all__ = ["ConfigError", "ModuleSource", "locate_module", "import_module_source", "load_located",
           "load_likelihood", "file_sha256"]


class ConfigError(ValueError):
    """A run configuration (or the module it names) is invalid; the message names the file and the field."""


def read_toml(path) -> dict:
    """The TOML run configuration at ``path`` as a dict; a missing or unreadable file, a folder or
    invalid TOML is a one-line :class:`ConfigError` naming the file."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a TOML run configuration") from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read: {err.strerror or err}") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: invalid TOML: {err}") from None


@dataclass(frozen=True)
class ModuleSource:
    """Where the likelihood's module lives and what it contains, found without running it.

    Attributes
    ----------
    name : str
        Dotted module name.
    files : tuple of str
        Absolute paths of the source files an import executes, outermost package first
        (one file for a plain module); empty for a module without a Python source file.
    sha256 : str
        SHA-256 of the content: of the file itself for a plain module (what ``sha256sum``
        prints), else of the files' hex digests joined; ``""`` without source files.
    folder : str or None
        The folder the module was found in (imported by file path), or None for a module
        found on ``sys.path`` (installed; imported the usual way).
    """

    name: str
    files: tuple
    sha256: str
    folder: str | None = None

    @property
    def file(self) -> str | None:
        """The module's own file (the last of :attr:`files`)."""
        return self.files[-1] if self.files else None


def split_likelihood(spec):
    if not isinstance(spec, str) or spec.count(":") != 1 or not all(spec.split(":")):
        raise ConfigError(f"model.likelihood: expected \"module:function\", got {spec!r}")
    return spec.split(":")


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 hex digest of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _files_sha256(files) -> str:
    if not files:
        return ""
    digests = [file_sha256(f) for f in files]
    return digests[0] if len(digests) == 1 else hashlib.sha256(" ".join(digests).encode()).hexdigest()


def _chain_in_folder(module_name: str, folder) -> tuple | None:
    """The files ``import module_name`` would run from ``folder`` (packages' ``__init__.py`` first), or None."""
    parts = module_name.split(".")
    files = []
    for i in range(1, len(parts) + 1):
        base = Path(folder, *parts[:i])
        if i < len(parts) or not base.with_suffix(".py").is_file():
            init = base / "__init__.py"
            if not init.is_file():
                return None
            files.append(str(init.resolve()))
        else:
            files.append(str(base.with_suffix(".py").resolve()))
    return tuple(files)


def locate_module(module_name: str, folder: str | os.PathLike | None = None,
                  search_installed: bool = True) -> ModuleSource | None:
    """Find the likelihood's module without running it: in ``folder`` first, then on ``sys.path``.

    With ``search_installed=False`` only ``folder`` is searched (None when it does not hold the module).

    Raises
    ------
    ConfigError
        The module is found nowhere.
    """
    if folder:
        chain = _chain_in_folder(module_name, folder)
        if chain:
            return ModuleSource(module_name, chain, _files_sha256(chain), str(Path(folder).resolve()))
    if not search_installed:
        return None
    try:  # sys.path only, not the module cache (which may hold a module run from some folder)
        spec = (importlib.machinery.PathFinder.find_spec(module_name) if "." not in module_name
                else importlib.util.find_spec(module_name))
    except Exception as err:  # a parent package that fails to import
        spec, reason = None, f"{type(err).__name__}: {err}"
    else:
        reason = f"ModuleNotFoundError: No module named {module_name!r}"
    if spec is None:
        where = f" (searched {folder} and sys.path)" if folder else ""
        raise ConfigError(f"model.likelihood: cannot import module {module_name!r}{where}: {reason}")
    origin = (spec.origin if spec.has_location and spec.origin and spec.origin.endswith(".py")
              and Path(spec.origin).is_file() else None)
    files = (str(Path(origin).resolve()),) if origin else ()
    return ModuleSource(module_name, files, _files_sha256(files), None)


def _exec_source(name: str, file: str, source: bytes, package: bool):
    """Run ``source`` (the bytes that were hashed, not a cached ``.pyc``) as module ``name`` from ``file``."""
    spec = importlib.util.spec_from_file_location(
        name, file, submodule_search_locations=[str(Path(file).parent)] if package else None)
    module = importlib.util.module_from_spec(spec)
    previous = sys.modules.get(name)
    sys.modules[name] = module  # pickling (process pools, Dask) and dataclasses look the module up by name
    try:
        exec(compile(source, file, "exec"), module.__dict__)
    except BaseException:
        if previous is None:
            sys.modules.pop(name, None)
        else:
            sys.modules[name] = previous
        raise
    module.__seqbayes_sha256__ = hashlib.sha256(source).hexdigest()
    return module


def import_module_source(source: ModuleSource):
    """Import a located module; one found in a folder is run from its files by path, ``sys.path`` untouched.

    A module of the same name cached from another file (two runs in two folders both
    naming ``model:loglike``) is replaced, with its submodules; the same file with the
    same content is reused.
    """
    if source.folder is None:
        cached = sys.modules.get(source.name)
        if cached is not None and source.file and getattr(cached, "__file__", None) and \
                str(Path(cached.__file__).resolve()) != source.file:
            del sys.modules[source.name]  # run from a folder before; the installed module is wanted now
        return importlib.import_module(source.name)
    parts = source.name.split(".")
    module = None
    for i, file in enumerate(source.files):
        name = ".".join(parts[:i + 1])
        content = Path(file).read_bytes()
        cached = sys.modules.get(name)
        if (cached is not None and getattr(cached, "__file__", None) and Path(cached.__file__).resolve() == Path(file)
                and getattr(cached, "__seqbayes_sha256__", None) == hashlib.sha256(content).hexdigest()):
            module = cached
            continue
        if cached is not None:
            for other in [m for m in sys.modules if m.startswith(name + ".")]:
                del sys.modules[other]
        module = _exec_source(name, file, content, package=i < len(parts) - 1 or file.endswith("__init__.py"))
        if i:
            setattr(sys.modules[".".join(parts[:i])], parts[i], module)
    return module


def _function_of(module, spec: str):
    module_name, func_name = spec.split(":")
    func = module
    for part in func_name.split("."):
        func = getattr(func, part, None)
        if func is None:
            raise ConfigError(f"model.likelihood: module {module_name!r} has no attribute {func_name!r}")
    if not callable(func):
        raise ConfigError(f"model.likelihood: {spec!r} is not callable")
    return func


def load_located(spec: str, source: ModuleSource) -> Callable[..., Any]:
    """The function named by ``spec`` from the located module ``source`` (see :func:`locate_module`)."""
    split_likelihood(spec)
    try:
        module = import_module_source(source)
    except Exception as err:
        where = f" from {source.file}" if source.file else ""
        raise ConfigError(f"model.likelihood: cannot import module {source.name!r}{where}: "
                          f"{type(err).__name__}: {err}") from err
    return _function_of(module, spec)


def load_likelihood(spec: str, search_path: str | None = None) -> Callable[..., Any]:
    """Import ``"module:function"``: from the file in ``search_path`` (a folder) if it holds one,
    else from ``sys.path``. The folder is not added to ``sys.path``.

    Raises
    ------
    ConfigError
        If the string is malformed, the module cannot be imported or the
        attribute is missing or not callable.
    """
    module_name, _ = split_likelihood(spec)
    return load_located(spec, locate_module(module_name, search_path))


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    import os
    from collections.abc import Callable
    from typing import Any
