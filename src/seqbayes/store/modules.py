"""Loading the user's code (the likelihood's module) by file path, with a hash of what runs.

The trust boundary of a run (docs/guide.md, "Trust"): a configuration and a run store name a
module; :func:`locate_module` reads its files *without running them* and hashes them
(:class:`ModuleSource`): a plain module's file, or every Python file of the package it lies in
(so that an edit of ``pkg/helper.py`` changes the hash of ``pkg.model``). :func:`import_module_source`
runs exactly the bytes that were read and hashed, never the files as they are on disk later (another
process may rewrite them in between): the module and every submodule of its package, also one
imported later by the likelihood, from the config's folder by path (``sys.path`` untouched, so a
``matplotlib.py`` beside a store is never imported in place of the package) or, for an installed
module, the usual way. The run store records the hash per step and refuses a module whose content
changed.

Written by hand because :mod:`importlib` gives the pieces (``spec_from_file_location``, meta-path
finders) but not "run these bytes, which were hashed, as this dotted module and its package,
replacing a same-named module run from another folder".
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import os
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["ConfigError", "ModuleSource", "locate_module", "import_module_source", "load_located",
           "load_likelihood", "file_sha256"]


class ConfigError(ValueError):
    """A run configuration (or the module it names) is invalid; the message names the file and the field."""


def read_toml(path) -> dict:
    """The TOML run configuration at ``path`` as a dict; a missing or unreadable file, a folder or
    invalid TOML is a one-line :class:`ConfigError` naming the file."""
    from .datasets import read_regular

    path = Path(path)
    # a regular file of at most 16 MiB, read once (a FIFO or /dev/zero given as the configuration is refused)
    raw = read_regular(path, "TOML run configuration", limit=16 << 20, error=ConfigError)
    try:
        return tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: invalid TOML: byte {err.start} is not UTF-8 text") from None
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
        prints), else of every Python file of its top-level package (:func:`tree_sha256`);
        ``""`` without source files.
    folder : str or None
        The folder the module was found in (imported by file path), or None for a module
        found on ``sys.path`` (installed; imported the usual way).
    sources : dict
        Module name -> ``(file, bytes)`` of every file hashed, as read for the hash: what
        :func:`import_module_source` runs (a module found in a folder only).
    legacy_sha256 : str
        The hash seqbayes recorded before packages were hashed whole: of :attr:`files`' hex
        digests joined (the same as :attr:`sha256` for a plain module).
    """

    name: str
    files: tuple
    sha256: str
    folder: str | None = None
    sources: dict = field(default_factory=dict, repr=False, compare=False)
    legacy_sha256: str = field(default="", repr=False, compare=False)

    @property
    def package_files(self) -> int:
        """How many files the hash covers."""
        return len(self.sources) or len(self.files)

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


def _files_sha256(files, content=None) -> str:
    """Of one file, its SHA-256; of several, the SHA-256 of their hex digests joined (``content``: file ->
    bytes already read)."""
    if not files:
        return ""
    digests = [hashlib.sha256(content[f]).hexdigest() if content else file_sha256(f) for f in files]
    return digests[0] if len(digests) == 1 else hashlib.sha256(" ".join(digests).encode()).hexdigest()


def tree_sha256(sources: dict, root) -> str:
    """SHA-256 of a package's files: of the lines ``relative/path.py sha256`` in sorted order (``sources``:
    module name -> (file, bytes), ``root``: the folder the package lies in)."""
    lines = sorted(f"{Path(os.path.relpath(file, root)).as_posix()} {hashlib.sha256(content).hexdigest()}"
                   for file, content in sources.values())
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()


#: more files than this in one package is not a model's package (a whole repository?): refused
MAX_PACKAGE_FILES = 5000


def _package_sources(folder, top: str) -> dict:
    """Module name -> (file, bytes) of every Python file of the package ``folder/top`` (its subpackages
    too, and folders without ``__init__.py``, which Python imports as namespace packages); each file read
    once. Hidden folders, ``__pycache__`` and names Python cannot import are skipped; links to folders
    are not followed."""
    root = Path(folder).resolve()
    sources = {}
    for here, dirs, names in os.walk(root / top):
        rel = Path(here).relative_to(root).parts
        dirs[:] = sorted(d for d in dirs if d.isidentifier())
        for name in sorted(names):
            stem, suffix = os.path.splitext(name)
            if suffix != ".py" or not stem.isidentifier():
                continue
            module = ".".join(rel if stem == "__init__" else (*rel, stem))
            file = str(Path(here, name))
            sources[module] = (file, Path(file).read_bytes())
            if len(sources) > MAX_PACKAGE_FILES:
                raise ConfigError(f"model.likelihood: the package {top!r} in {folder} has more than "
                                  f"{MAX_PACKAGE_FILES} Python files; put the model in a package of its own")
    return sources


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
            return _in_folder(module_name, chain, folder)
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


def _in_folder(module_name: str, chain: tuple, folder) -> ModuleSource:
    """The located module ``module_name`` whose import runs ``chain`` in ``folder``: every file of its
    top-level package (or the plain module's one file) read once and hashed."""
    root = str(Path(folder).resolve())
    package = chain[0].endswith("__init__.py")
    sources = _package_sources(root, module_name.split(".")[0]) if package else {}
    parts = module_name.split(".")
    for i, file in enumerate(chain):        # the plain module, or a file the walk skipped (in a linked folder)
        sources.setdefault(".".join(parts[:i + 1]), (file, Path(file).read_bytes()))
    # a plain module keeps its file's SHA-256 (what sha256sum prints), as stores have recorded it
    sha = tree_sha256(sources, root) if package else hashlib.sha256(sources[module_name][1]).hexdigest()
    content = {file: data for file, data in sources.values()}
    return ModuleSource(module_name, chain, sha, root, sources, _files_sha256(chain, content))


class _HashedLoader(importlib.abc.Loader):
    """Runs the bytes that were hashed (not the file as it is now, nor a cached ``.pyc``)."""

    def __init__(self, source: bytes, tree: tuple):
        self.source, self.tree = source, tree

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        module.__seqbayes_sha256__ = hashlib.sha256(self.source).hexdigest()
        module.__seqbayes_tree__ = self.tree
        exec(compile(self.source, module.__spec__.origin, "exec"), module.__dict__)

    def get_source(self, name):
        return self.source.decode("utf-8", "replace")


class _HashedFinder(importlib.abc.MetaPathFinder):
    """First on ``sys.meta_path``: the modules of the user's packages that were located and hashed, from
    their hashed bytes, including submodules imported later (by the likelihood, at call time)."""

    def __init__(self):
        self.modules = {}                      # module name -> (file, bytes, is_package, (folder, sha256))

    def find_spec(self, name, path=None, target=None):
        entry = self.modules.get(name)
        if entry is None:
            return None
        file, source, package, tree = entry
        return importlib.util.spec_from_file_location(
            name, file, loader=_HashedLoader(source, tree),
            submodule_search_locations=[str(Path(file).parent)] if package else None)


_FINDER = _HashedFinder()


def _within(name: str, top: str) -> bool:
    return name == top or name.startswith(top + ".")


def import_module_source(source: ModuleSource):
    """Import a located module; one found in a folder runs the bytes :func:`locate_module` read and hashed,
    its package's too, by path (``sys.path`` untouched).

    A module of the same name cached from another folder or content (two runs in two folders both
    naming ``model:loglike``, or an edited file) is replaced, with its package; the same files with
    the same content are reused.
    """
    if source.folder is None:
        cached = sys.modules.get(source.name)
        if cached is not None and source.file and getattr(cached, "__file__", None) and \
                str(Path(cached.__file__).resolve()) != source.file:
            del sys.modules[source.name]  # run from a folder before; the installed module is wanted now
        return importlib.import_module(source.name)
    top = source.name.split(".")[0]
    tree = (source.folder, source.sha256)
    cached = sys.modules.get(source.name)
    if cached is not None and getattr(sys.modules.get(top), "__seqbayes_tree__", None) == tree \
            and getattr(cached, "__seqbayes_tree__", None) == tree:
        return cached
    if _FINDER not in sys.meta_path:
        sys.meta_path.insert(0, _FINDER)
    previous_entries = {n: e for n, e in _FINDER.modules.items() if _within(n, top)}
    previous = {n: m for n, m in sys.modules.items() if _within(n, top)}
    for name in list(previous_entries) + list(previous):
        _FINDER.modules.pop(name, None)
        sys.modules.pop(name, None)
    for name, (file, content) in source.sources.items():
        _FINDER.modules[name] = (file, content, file.endswith("__init__.py"), tree)
    try:
        return importlib.import_module(source.name)
    except BaseException:
        for name in [n for n in sys.modules if _within(n, top)]:
            del sys.modules[name]
        for name in [n for n in _FINDER.modules if _within(n, top)]:
            del _FINDER.modules[name]
        sys.modules.update(previous)
        _FINDER.modules.update(previous_entries)
        raise


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
    from collections.abc import Callable
    from typing import Any
