"""Exception types. Every user-facing failure is an :class:`RdnetError`.

The CLI turns any ``RdnetError`` into a one-line message on stderr and exit code 2
(no traceback); anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import re
from pathlib import Path

_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def escape_controls(text: str) -> str:
    """``text`` (a path, a message) with control characters escaped as Python writes them (a
    newline in a file name becomes ``\\n``), so an error message stays one line."""
    return _CONTROL.sub(lambda m: repr(m.group())[1:-1], text)


class RdnetError(Exception):
    """Base class of errors caused by user input (files, parameters, arguments)."""


class FormatError(RdnetError):
    """A file cannot be read or is inconsistent: names the file and the field."""

    def __init__(self, path: str | Path | None, field: str | None, message: str):
        self.path = None if path is None else str(path)
        self.field = field
        where = []
        if self.path is not None:
            where.append(escape_controls(self.path))
        if field:
            where.append(f"field '{field}'")
        prefix = ": ".join(where)
        super().__init__(f"{prefix}: {message}" if prefix else message)


class ValidationError(RdnetError):
    """In-memory data violates an invariant (decreasing timestamps, coordinates off-sensor...)."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(f"field '{field}': {message}")


class ConfigError(RdnetError):
    """A parameter is unknown, of the wrong type or out of range; names the dotted key."""

    def __init__(self, key: str, message: str, source: str | Path | None = None):
        self.key = key
        self.detail = message
        self.source = None if source is None else str(source)
        pre = f"{escape_controls(self.source)}: " if self.source else ""
        super().__init__(f"{pre}parameter '{key}': {message}")


class ModelNotFoundError(ConfigError):
    """No trained model where one was looked for (nothing given, none trained or packaged),
    as opposed to a model that exists but is unusable (a plain ConfigError)."""
