"""Config files as dataclasses: one per table, each validating its own keys; every problem
of a file reported at once; the JSON Schema of a file generated from the same dataclasses.

A table of a TOML file (``[tow]``, ``[[targets]]``, the file itself) is a frozen dataclass
deriving from :class:`Section` whose fields are declared with :func:`key` (optional, with a
default) or :func:`required`: the field's name is the TOML key, its :class:`Key` says what
the value must be (kind, range, unit, choices). :meth:`Section.read` checks every key of the
table through :class:`~hil.toml_table.Table` (so messages keep the house style: field,
value, allowed range, what to do), then the section's own checks across its keys
(:meth:`Section.checks`), and collects every problem in a :class:`Problems` instead of
stopping at the first. :func:`json_schema` turns the same declarations into a JSON Schema
(draft 2020-12) that editors use for completion and checking.

>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Pass(Section):
...     "A pass."
...     speed_mps: float = required("number", "tow speed", lo=0.0, lo_open=True, unit="m/s")
...     repeats: int = key(1, "integer", "passes", lo=1)
>>> problems = Problems()
>>> Pass.read({"speed_mps": 1.5}, "tow", problems)
Pass(speed_mps=1.5, repeats=1)
>>> Pass.read({"speed_mp": 1.5, "repeats": 0}, "tow", problems) is None
True
>>> print(problems.error())
tow.speed_mp = 1.5 is not allowed: must be one of the keys speed_mps, repeats; remove it or \
fix its spelling (did you mean speed_mps?)
tow.repeats = 0 is not allowed: must be an integer >= 1
>>> json_schema(Pass)["properties"]["speed_mps"]
{'description': 'tow speed (m/s)', 'type': 'number', 'exclusiveMinimum': 0.0}
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, ClassVar, Self

from hil.errors import ConfigError, ConfigErrors
from hil.toml_table import Table, did_you_mean

__all__ = ["Key", "Problems", "Section", "json_schema", "key", "required"]

#: What a key may hold (:class:`Key`'s ``kind``).
KINDS = (
    "number", "integer", "flag", "text", "vector", "texts", "numbers", "points", "table",
    "section", "sections", "any",
)  # fmt: skip


@dataclass(frozen=True)
class Key:
    """What one key of a table must be.

    ``kind``: ``number`` (finite, in ``[lo, hi]``, ``lo`` exclusive with ``lo_open``),
    ``integer``, ``flag`` (a TOML boolean), ``text`` (one of ``choices`` when given),
    ``vector`` (``n`` numbers, a tuple), ``texts`` / ``numbers`` (lists), ``points`` (a list
    of at least ``n`` points ``[x, y, z]``), ``table`` (a free table, keys in ``choices``
    when given, checked by the code that uses it), ``section`` / ``sections`` (a sub-table /
    an array of tables, read as ``section``), ``any`` (checked by the section).
    """

    kind: str
    doc: str
    required: bool = False
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple[str, ...] | None = None
    n: int = 3
    section: type[Section] | None = None
    #: A sub-table left out is None (not a table of defaults): its presence means something.
    absent_none: bool = False
    #: The schema's default, when the dataclass default is derived (None) or not JSON.
    shown_default: Any = None


def key(default: Any, kind: str, doc: str, **spec: Any) -> Any:
    """A dataclass field for an optional key (``default`` when the file leaves it out)."""
    assert kind in KINDS, kind
    meta = {"key": Key(kind, doc, **spec)}
    if isinstance(default, list | dict):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def required(kind: str, doc: str, **spec: Any) -> Any:
    """A dataclass field for a key the file must give."""
    assert kind in KINDS, kind
    return dataclasses.field(metadata={"key": Key(kind, doc, required=True, **spec)})


class Problems:
    """Every problem of one file, in the order found; :meth:`error` is what to raise."""

    def __init__(self) -> None:
        self.errors: list[ConfigError] = []

    def add(self, exc: ConfigError) -> None:
        """Record ``exc`` (each one of a :class:`ConfigErrors`)."""
        self.errors.extend(exc.errors if isinstance(exc, ConfigErrors) else [exc])

    @contextmanager
    def collect(self) -> Iterator[None]:
        """Record a ConfigError raised in the block instead of letting it out."""
        try:
            yield
        except ConfigError as exc:
            self.add(exc)

    def __bool__(self) -> bool:
        return bool(self.errors)

    def error(self) -> ConfigErrors:
        """All problems as one error (one line each)."""
        return ConfigErrors(self.errors)

    def raise_any(self) -> None:
        """Raise :meth:`error` when there is a problem."""
        if self.errors:
            raise self.error()


def _keys(cls: type) -> dict[str, Key]:
    return {f.name: f.metadata["key"] for f in dataclasses.fields(cls) if "key" in f.metadata}


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _not_a_table(data: Any, path: str) -> ConfigError | None:
    if isinstance(data, list) and path and all(isinstance(x, dict) for x in data):
        return ConfigError(
            path, data, "one table (key = value pairs)",
            f"write [{path}] once; [[{path}]] makes a list of tables",
        )  # fmt: skip
    if not isinstance(data, dict):
        return ConfigError(path or "file", data, "a table (key = value pairs)")
    return None


class Section:
    """Base of a table's dataclass (see the module docstring).

    A subclass is a frozen dataclass whose fields are :func:`key` / :func:`required`; it may
    add :meth:`checks` across its own keys. ``DOCS`` names where the keys are documented
    (for the message on an unknown key).
    """

    DOCS: ClassVar[str] = ""
    #: What the table's keys are called in messages (a file of tables: ``"tables"``).
    KEY_WORD: ClassVar[str] = "keys"

    @classmethod
    def keys(cls) -> dict[str, Key]:
        """The table's keys and what each must be, in declaration order."""
        return _keys(cls)

    @classmethod
    def read_values(cls, data: Any, path: str, problems: Problems) -> dict[str, Any] | None:
        """The keys of ``data`` (the table at dotted ``path``) that are valid, as values (a
        key left out is absent, except a sub-table, read from ``{}``); None when ``data`` is
        not a table. Each problem goes to ``problems``."""
        read = cls._read_table(data, path, problems)
        return None if read is None else read[0]

    @classmethod
    def read(cls, data: Any, path: str, problems: Problems, *, quiet: bool = False) -> Self | None:
        """The table at ``path`` as this dataclass, or None when it has a problem (recorded
        in ``problems``). ``quiet``: a table the file misspelt: its missing keys are not
        reported again."""
        read = cls._read_table(data, path, Problems() if quiet else problems)
        if read is None or not read[1]:
            return None
        obj = cls(**read[0])
        before = len(problems.errors)
        for exc in obj.checks(path):
            problems.add(exc)
        return obj if len(problems.errors) == before else None

    @classmethod
    def _read_table(
        cls, data: Any, path: str, problems: Problems
    ) -> tuple[dict[str, Any], bool] | None:
        """:meth:`read_values` and whether every key was valid and every required one given."""
        bad = _not_a_table(data, path)
        if bad is not None:
            problems.add(bad)
            return None
        keys = cls.keys()
        names = tuple(keys)
        misspelt: set[str] = set()  # the keys that unknown ones resemble
        for name in data:
            if name not in keys:
                close = difflib.get_close_matches(name, names, n=1, cutoff=0.6)
                misspelt.update(close)
                hint = "remove it or fix its spelling" + did_you_mean(name, names)
                hint += f" ({cls.DOCS} lists every key)" if cls.DOCS else ""
                problems.add(
                    ConfigError(_join(path, name), data[name],
                                f"one of the {cls.KEY_WORD} {', '.join(names)}", hint)
                )  # fmt: skip
        table = Table({k: v for k, v in data.items() if k in keys}, path, names, cls.DOCS)
        values: dict[str, Any] = {}
        ok = len(table.data) == len(data)
        for name, spec in keys.items():
            if name in data:
                try:
                    values[name] = _read(table, name, spec, problems)
                except ConfigError as exc:
                    problems.add(exc)
                    ok = False
                    continue
            elif spec.kind == "section" and not spec.absent_none:
                assert spec.section is not None
                quiet = name in misspelt
                values[name] = spec.section.read({}, table.name(name), problems, quiet=quiet)
            elif spec.required:
                ok = False
                # A key misspelt is named as such (above), not also as missing.
                if name not in misspelt:
                    problems.add(ConfigError(table.name(name), None, "a value", "it is required"))
                continue
            else:
                continue
            if spec.kind == "section":
                ok &= values[name] is not None
            elif spec.kind == "sections":
                ok &= None not in values[name]
        return values, ok

    def checks(self, path: str) -> Iterator[ConfigError]:
        """The problems across this table's keys (none by default); ``path`` is its name."""
        return iter(())

    @classmethod
    def schema_rules(cls) -> dict[str, Any]:
        """What of :meth:`checks` a JSON Schema can say too (``allOf`` of ``if``/``then``
        rules, merged into the table's schema); none by default."""
        return {}


def _read(table: Table, name: str, spec: Key, problems: Problems) -> Any:
    """The value of key ``name`` (present in ``table``) checked against ``spec``."""
    v = table.data[name]
    where = table.name(name)
    kind = spec.kind
    if kind == "number":
        return table.number(name, lo=spec.lo, hi=spec.hi, lo_open=spec.lo_open, unit=spec.unit)
    if kind == "integer":
        lo = int(spec.lo) if spec.lo is not None else -(2**63)
        return table.integer(name, 0, lo, int(spec.hi) if spec.hi is not None else None)
    if kind == "flag":
        return table.flag(name, False)
    if kind == "text":
        return table.text(name, None, spec.choices)
    if kind == "vector":
        vec = table.vector(name, None, spec.n, spec.unit)
        _check_range(where, vec.tolist(), spec)
        return tuple(float(x) for x in vec)
    if kind == "texts":
        ok = isinstance(v, list) and all(isinstance(x, str) and x for x in v)
        if ok and spec.choices is not None:
            ok = all(x in spec.choices for x in v)
        if not ok:
            words = f" of {', '.join(spec.choices)}" if spec.choices else " of strings"
            raise ConfigError(where, v, f"a list{words}")
        return list(v)
    if kind == "numbers":
        if not isinstance(v, list) or not all(_finite(x) for x in v):
            raise ConfigError(where, v, "a list of finite numbers" + _unit(spec))
        _check_range(where, v, spec)
        return [float(x) for x in v]
    if kind == "points":
        ok = isinstance(v, list) and len(v) >= spec.n
        ok = ok and all(isinstance(p, list) and len(p) == 3 and all(map(_finite, p)) for p in v)
        if not ok:
            raise ConfigError(where, v, f"a list of >= {spec.n} points [x, y, z] (m)")
        return [tuple(float(c) for c in p) for p in v]
    if kind == "table":
        if not isinstance(v, dict):
            raise ConfigError(where, v, "a table of " + spec.doc)
        if spec.choices is not None:
            for k in v:
                if k not in spec.choices:
                    raise ConfigError(
                        f"{where}.{k}", v[k], f"one of the keys {', '.join(spec.choices)}",
                        "remove it or fix its spelling" + did_you_mean(k, spec.choices),
                    )  # fmt: skip
        return dict(v)
    if kind == "section":
        assert spec.section is not None
        return spec.section.read(v, where, problems)
    if kind == "sections":
        assert spec.section is not None
        if not isinstance(v, list):
            raise ConfigError(where, v, f"an array of tables [[{where}]]")
        return [spec.section.read(t, f"{where}[{i}]", problems) for i, t in enumerate(v)]
    return v


def _finite(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _unit(spec: Key) -> str:
    return f" ({spec.unit})" if spec.unit else ""


def _check_range(where: str, values: list[float], spec: Key) -> None:
    """Each of ``values`` within ``spec``'s bounds (an element named by its index)."""
    for i, x in enumerate(values):
        low = spec.lo is not None and (x <= spec.lo if spec.lo_open else x < spec.lo)
        if low or (spec.hi is not None and x > spec.hi):
            parts = [f"{'>' if spec.lo_open else '>='} {spec.lo:g}"] if spec.lo is not None else []
            parts += [f"<= {spec.hi:g}"] if spec.hi is not None else []
            unit = f" {spec.unit}" if spec.unit else ""
            raise ConfigError(f"{where}[{i}]", x, " and ".join(parts) + unit)


# ------------------------------------------------------------------------ JSON Schema
def json_schema(cls: type[Section], title: str = "", schema_id: str = "") -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of the table ``cls``; with ``title``/``schema_id`` a
    whole file's (the ``$schema`` line included)."""
    out: dict[str, Any] = {}
    if title:
        out["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        if schema_id:
            out["$id"] = schema_id
        out["title"] = title
    doc = (cls.__doc__ or "").strip().split("\n\n")[0]
    if doc and not doc.startswith(cls.__name__ + "("):
        out["description"] = " ".join(doc.split())
    out["type"] = "object"
    props: dict[str, Any] = {}
    needed: list[str] = []
    for name, spec in cls.keys().items():
        props[name] = _key_schema(spec, cls, name)
        if spec.required or (spec.kind == "section" and _has_required(spec)):
            needed.append(name)
    out["properties"] = props
    out["additionalProperties"] = False
    if needed:
        out["required"] = needed
    out.update(cls.schema_rules())
    return out


def _has_required(spec: Key) -> bool:
    return (
        spec.section is not None
        and not spec.absent_none
        and any(k.required for k in spec.section.keys().values())
    )


def _key_schema(spec: Key, cls: type, name: str) -> dict[str, Any]:
    s: dict[str, Any] = {"description": spec.doc + _unit(spec)} if spec.doc else {}
    number: dict[str, Any] = {"type": "number"}
    if spec.lo is not None:
        number["exclusiveMinimum" if spec.lo_open else "minimum"] = spec.lo
    if spec.hi is not None:
        number["maximum"] = spec.hi
    kind = spec.kind
    if kind == "number":
        s.update(number)
    elif kind == "integer":
        s["type"] = "integer"
        if spec.lo is not None:
            s["minimum"] = int(spec.lo)
        if spec.hi is not None:
            s["maximum"] = int(spec.hi)
    elif kind == "flag":
        s["type"] = "boolean"
    elif kind == "text":
        s.update({"type": "string", "minLength": 1})
        if spec.choices is not None:
            s["enum"] = list(spec.choices)
    elif kind == "vector":
        s.update({"type": "array", "items": number, "minItems": spec.n, "maxItems": spec.n})
    elif kind == "numbers":
        s.update({"type": "array", "items": number})
    elif kind == "texts":
        item: dict[str, Any] = {"type": "string", "minLength": 1}
        if spec.choices is not None:
            item["enum"] = list(spec.choices)
        s.update({"type": "array", "items": item})
    elif kind == "points":
        point = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
        s.update({"type": "array", "items": point, "minItems": spec.n})
    elif kind == "table":
        s["type"] = "object"
        if spec.choices is not None:
            s["propertyNames"] = {"enum": list(spec.choices)}
    elif kind == "section":
        assert spec.section is not None
        s.update(json_schema(spec.section))
    elif kind == "sections":
        assert spec.section is not None
        s.update({"type": "array", "items": json_schema(spec.section)})
    default = _default(cls, name, spec)
    if default is not None:
        s["default"] = default
    return s


def _default(cls: type, name: str, spec: Key) -> Any:
    if spec.shown_default is not None:
        return spec.shown_default
    if spec.kind in ("section", "sections", "table") or spec.required:
        return None
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    value = f.default
    if value is dataclasses.MISSING and f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    if isinstance(value, tuple):
        value = list(value)
    if isinstance(value, bool | int | float | str | list):
        return value
    return None
