"""Typed fields out of a parsed TOML mapping, every problem a one-line :class:`ConfigError` naming the file
and the field (``rig.toml``'s reader and others build on it).  tomllib parses; this checks types, ranges,
choices and unknown keys, which no small library does with our error contract."""

from __future__ import annotations

import math
from typing import Any, Mapping

from dyno.errors import ConfigError

REQUIRED = object()  # sentinel: the field has no default


class FieldReader:
    """Pulls typed fields out of a mapping; every problem becomes a ConfigError."""

    def __init__(self, path: str):
        self.path = path

    def err(self, fld: str, expected: str) -> ConfigError:
        return ConfigError(self.path, fld, expected)

    def _get(self, data: Mapping, key: str, prefix: str, default: Any):
        fld = f"{prefix}{key}"
        if key not in data:
            if default is REQUIRED:
                raise self.err(fld, "missing (required)")
            return fld, default, True
        return fld, data[key], False

    def table(self, data: Mapping, key: str) -> Mapping:
        fld, v, _ = self._get(data, key, "", REQUIRED)
        if not isinstance(v, Mapping):
            raise self.err(fld, f"expected a table [{key}], got {type(v).__name__}")
        return v

    def integer(self, data, key, prefix, lo=None, hi=None, default=None, required=True, hexfmt=False):
        fld, v, defaulted = self._get(data, key, prefix, REQUIRED if required else default)
        if defaulted:
            return v
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(fld, f"expected an integer, got {v!r}")
        fmt = (lambda x: f"0x{x:02X}") if hexfmt else str
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise self.err(fld, f"expected {fmt(lo)}..{fmt(hi)}, got {fmt(v)}")
        return v

    def number(self, data, key, prefix, *, lo: float, hi: float, default=None, required=True):
        """A finite number in ``[lo, hi]``: ``inf`` would disable a trip, ``nan`` compares false."""
        fld, v, defaulted = self._get(data, key, prefix, REQUIRED if required else default)
        if defaulted:
            return v
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.err(fld, f"expected a number {lo:g}..{hi:g}, got {v!r}")
        if not math.isfinite(v) or not lo <= v <= hi:
            raise self.err(fld, f"expected a number {lo:g}..{hi:g}, got {v!r}")
        return float(v)

    def string(self, data, key, prefix, choices=None, default=None, required=True):
        fld, v, defaulted = self._get(data, key, prefix, REQUIRED if required else default)
        if defaulted:
            return v
        if not isinstance(v, str) or not v:
            raise self.err(fld, f"expected a string, got {v!r}")
        if choices and v not in choices:
            raise self.err(fld, f"expected one of {', '.join(map(repr, choices))}, got {v!r}")
        return v

    def boolean(self, data, key, prefix, default):
        fld, v, defaulted = self._get(data, key, prefix, default)
        if not defaulted and not isinstance(v, bool):
            raise self.err(fld, f"expected true or false, got {v!r}")
        return v

    def no_extra(self, data: Mapping, allowed, prefix: str) -> None:
        for key in data:
            if key not in allowed:
                raise self.err(f"{prefix}{key}", f"unknown key (allowed: {', '.join(sorted(allowed))})")
