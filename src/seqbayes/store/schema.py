"""What every run kind's configuration shares (:class:`~seqbayes.store.config.RunConfig`,
:class:`~seqbayes.store.sg_config.SGRunConfig`): the checks of a TOML table's fields, whose errors name the field
(:func:`fail`, :func:`table`, :func:`check_keys`, :func:`number`, :func:`numbers`), and :class:`StoredConfig`, the
plain form a run store keeps, its fingerprint and the fields in which two configurations differ."""

from __future__ import annotations

import difflib
import hashlib
import json
import math

from .modules import ConfigError

__all__ = ["fail", "table", "check_keys", "number", "numbers", "StoredConfig"]


def fail(source, field_name, message):
    """Raise :class:`~seqbayes.store.modules.ConfigError` ``"source: field: message"``."""
    raise ConfigError(f"{source}: {field_name}: {message}")


def table(raw, key, source, required=True) -> dict:
    """The TOML table ``raw[key]`` (``{}`` when absent and not ``required``)."""
    value = raw.get(key)
    if value is None:
        if required:
            fail(source, f"[{key}]", "missing section")
        return {}
    if not isinstance(value, dict):
        fail(source, key, f"expected a table, got {type(value).__name__}")
    return value


def check_keys(values, allowed, source, prefix) -> None:
    """Refuse a key of the table ``values`` not in ``allowed``, suggesting the closest one."""
    if not isinstance(values, dict):
        fail(source, prefix, f"expected a table, got {values!r}")
    for key in values:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), sorted(allowed), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            fail(source, f"{prefix}.{key}", f"unknown setting{hint}; expected one of {', '.join(sorted(allowed))}")


def number(value, source, name, *, integer=False, positive=False):
    """``value`` as a finite float (or an int with ``integer``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        fail(source, name, f"expected a number, got {value!r}")
    if integer and int(value) != value:
        fail(source, name, f"expected an integer, got {value!r}")
    if not math.isfinite(value):
        fail(source, name, f"expected a finite number, got {value!r}")
    if positive and value <= 0:
        fail(source, name, f"must be positive, got {value!r}")
    return int(value) if integer else float(value)


def numbers(value, source, name, n=None, positive=False, allow_empty=False) -> list:
    """A number or a list of numbers as a list of floats (``n``: broadcast a number to ``n``)."""
    values = value if isinstance(value, list) else [value]
    if not values and not allow_empty:
        fail(source, name, "expected a number or a non-empty list of numbers")
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            fail(source, name, f"expected finite numbers, got {value!r}")
        if positive and v <= 0:
            fail(source, name, f"must be positive, got {value!r}")
        out.append(float(v))
    if n is not None:
        if not isinstance(value, list):
            out = out * n
        elif len(out) != n:
            fail(source, name, f"expected {n} values (one per storey/channel) or one number, got {len(out)}")
    return out


class StoredConfig:
    """The part of a run kind's configuration the run store relies on: ``to_dict()`` (its plain, JSON-able form,
    each subclass's), the :meth:`fingerprint` of what defines the model and the random stream (all but
    :attr:`unfingerprinted`) and the fields in which another configuration differs."""

    #: Keys of ``to_dict()`` that do not define the model (a display name, the folder it was read from, ...).
    unfingerprinted: tuple = ("name", "search_path")

    def fingerprint(self) -> str:
        """SHA-256 of everything that defines the model and the random stream."""
        content = {k: v for k, v in self.to_dict().items() if k not in self.unfingerprinted}
        return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()

    def differing_fields(self, other) -> list[str]:
        """The fields (``key.sub`` inside a table) in which ``other`` defines another model than this one."""
        mine, theirs = self.to_dict(), other.to_dict()
        out = []
        for key in sorted(set(mine) | set(theirs)):
            if key in self.unfingerprinted:
                continue
            if isinstance(mine.get(key), dict) and isinstance(theirs.get(key), dict):
                out += [f"{key}.{sub}" for sub in sorted(set(mine[key]) | set(theirs[key]))
                        if mine[key].get(sub) != theirs[key].get(sub)]
            elif json.dumps(mine.get(key), sort_keys=True) != json.dumps(theirs.get(key), sort_keys=True):
                out.append(key)
        return out
