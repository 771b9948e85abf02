"""One reader and one table helper for every TOML file the project reads.

Experiment files, scenarios and sweep files are read by :func:`read_toml` (a file that is not
UTF-8 text or not TOML is refused with one line naming the file and the first bad byte or
line) and checked through :class:`Table`: every key read is type-checked, unknown keys are
refused, and the only booleans are TOML's ``true``/``false`` (the string ``"false"`` is an
error, never true).

>>> t = Table({"reverberation": "false"}, "simulation", ("reverberation",))
>>> t.flag("reverberation", True)
Traceback (most recent call last):
...
hil.errors.ConfigError: simulation.reverberation = 'false' is not allowed: must be true or \
false (a TOML boolean, unquoted); write reverberation = false
>>> Table({"speed_mps": 1.5}, "tow", ("speed_mps",)).number("speed_mps", lo=0.0, unit="m/s")
1.5
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError

__all__ = ["Table", "did_you_mean", "parse_toml", "read_text_file", "read_toml"]

#: The byte order mark some editors put first in a UTF-8 file: not part of the text.
_BOM = "\ufeff"


def did_you_mean(word: str, choices: tuple[str, ...] | list[str]) -> str:
    """`` (did you mean X?)`` for the choice closest to a misspelt ``word``, else ``""``.

    >>> did_you_mean("speed_mp", ("start_m", "speed_mps"))
    ' (did you mean speed_mps?)'
    >>> did_you_mean("colour", ("start_m",))
    ''
    """
    import difflib

    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]}?)" if close else ""


def parse_toml(text: str, what: str, source: str = "<text>") -> dict[str, Any]:
    """Parse TOML ``text`` (the ``what`` file, from ``source``) or raise a one-line error. A
    leading byte order mark (some editors write one) is not part of the TOML."""
    try:
        return tomllib.loads(text.removeprefix(_BOM))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(
            what, source, f"valid TOML ({exc})", f"fix the {what} file (or is it the right file?)"
        ) from None


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """Read the ``what`` file (``"experiment"``, ``"scenario"``, ``"sweep"``) at ``path``.

    Raises :class:`ConfigError` for binary or non-UTF-8 content and for invalid TOML;
    ``FileNotFoundError`` and friends propagate (the command line reports them).
    """
    return parse_toml(read_text_file(path, what), what, str(path))


def read_text_file(path: str | Path, what: str) -> str:
    """The UTF-8 text of the ``what`` file at ``path``; binary content or a folder is a
    ConfigError."""
    if Path(path).is_dir():
        raise ConfigError(what, str(path), "a file, not a folder", f"give the {what} file in it")
    raw = Path(path).read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            what, str(path), "a UTF-8 text file",
            f"byte {exc.start} is 0x{raw[exc.start]:02x}, not text: is it the right file?",
        ) from None  # fmt: skip
    if "\x00" in text:
        raise ConfigError(
            what, str(path), "a UTF-8 text file",
            f"byte {text.index(chr(0))} is a NUL: is it the right file?",
        )  # fmt: skip
    return text


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _range(lo: float | None, hi: float | None, lo_open: bool, unit: str) -> str:
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"<= {hi:g}")
    return " and ".join(parts) + (f" {unit}" if unit else "")


class Table:
    """A TOML table with its dotted path (for messages); unknown keys refused on creation.

    Parameters
    ----------
    data:
        The parsed table (must be a dict).
    path:
        Its dotted name as the user wrote it (``"tow"``, ``"targets[0]"``; ``""`` for the top).
    allowed:
        Keys the table may hold.
    docs:
        Where the keys are documented, for the message on an unknown key.
    """

    def __init__(self, data: Any, path: str, allowed: tuple[str, ...], docs: str = "") -> None:
        if isinstance(data, list) and path and all(isinstance(x, dict) for x in data):
            raise ConfigError(
                path,
                data,
                "one table (key = value pairs)",
                f"write [{path}] once; [[{path}]] makes a list of tables",
            )
        if not isinstance(data, dict):
            raise ConfigError(path or "file", data, "a table (key = value pairs)")
        for key in data:
            if key not in allowed:
                hint = "remove it or fix its spelling" + did_you_mean(key, allowed)
                hint += f" ({docs} lists every key)" if docs else ""
                raise ConfigError(
                    _join(path, key), data[key], f"one of the keys {', '.join(allowed)}", hint
                )
        self.data, self.path, self.docs = data, path, docs

    def name(self, key: str) -> str:
        """The dotted name of ``key`` in this table."""
        return _join(self.path, key)

    def has(self, key: str) -> bool:
        """Whether the file gives ``key``."""
        return key in self.data

    def _required(self, key: str, what: str) -> ConfigError:
        return ConfigError(self.name(key), None, what, "it is required")

    def number(
        self, key: str, default: float | None = None, *, lo: float | None = None,
        hi: float | None = None, lo_open: bool = False, unit: str = "",
    ) -> float:  # fmt: skip
        """A finite number (int or float, not a bool or a string) in ``[lo, hi]``."""
        kind = "a finite number" + (f" in {unit}" if unit else "")
        if key not in self.data:
            if default is None:
                raise self._required(key, kind)
            return default
        v = self.data[key]
        if not _is_number(v):
            hint = f"write {key} = 1.5 (unquoted)" if isinstance(v, str) else ""
            raise ConfigError(self.name(key), v, kind, hint)
        if (lo is not None and (v <= lo if lo_open else v < lo)) or (hi is not None and v > hi):
            raise ConfigError(self.name(key), v, _range(lo, hi, lo_open, unit))
        return float(v)

    def integer(self, key: str, default: int, lo: int, hi: int | None = None) -> int:
        """An integer (not a bool) in ``[lo, hi]``."""
        v = self.data.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or v < lo or (hi is not None and v > hi):
            rng = f"an integer >= {lo}" + (f" and <= {hi}" if hi is not None else "")
            raise ConfigError(self.name(key), v, rng)
        return int(v)

    def flag(self, key: str, default: bool) -> bool:
        """A TOML boolean; ``"false"`` (a string) is refused, never read as true."""
        v = self.data.get(key, default)
        if not isinstance(v, bool):
            word = "false" if str(v).strip().lower() in ("false", "no", "off", "0") else "true"
            raise ConfigError(
                self.name(key), v, "true or false (a TOML boolean, unquoted)",
                f"write {key} = {word}",
            )  # fmt: skip
        return v

    def text(
        self, key: str, default: str | None = None, choices: tuple[str, ...] | None = None
    ) -> str:
        """A non-empty string, one of ``choices`` when given."""
        if key not in self.data and default is None:
            raise self._required(key, "a string")
        v = self.data.get(key, default)
        if choices is not None and v not in choices:
            raise ConfigError(self.name(key), v, f"one of {', '.join(choices)}")
        if not isinstance(v, str) or not v:
            raise ConfigError(self.name(key), v, "a non-empty string")
        return v

    def vector(
        self, key: str, default: tuple[float, ...] | None = None, n: int = 3, unit: str = ""
    ) -> NDArray[np.float64]:
        """A list of ``n`` finite numbers, as a float64 array of shape ``(n,)``."""
        kind = f"a list of {n} finite numbers" + (f" ({unit})" if unit else "")
        if key not in self.data and default is None:
            raise self._required(key, kind)
        v = self.data.get(key, default)
        if not (isinstance(v, list | tuple) and len(v) == n and all(_is_number(x) for x in v)):
            raise ConfigError(self.name(key), v, kind)
        return np.asarray(v, dtype=np.float64)

    def point(
        self, key: str, default: tuple[float, float, float] | None = None
    ) -> tuple[float, float, float]:
        """``[x, y, z]`` in metres, as a tuple."""
        x, y, z = (float(c) for c in self.vector(key, default, 3, "m"))
        return (x, y, z)

    def sub(self, key: str, allowed: tuple[str, ...]) -> Table:
        """The sub-table ``key`` (empty when absent)."""
        return Table(self.data.get(key, {}), self.name(key), allowed, self.docs)
