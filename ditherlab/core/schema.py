"""Declarative schemas for the files a user hands to ditherlab, and the one function that checks
a parsed file against one.

Every boundary has one schema written with the few node types below: the model file
(:data:`ditherlab.data.torque_model.MODEL_SCHEMA`), a recording's metadata wherever it is stored (CSV sidecar,
Parquet key-value metadata, MCAP metadata record: :data:`ditherlab.data.recording.META_SCHEMA`), a
mapping file (:data:`ditherlab.io.mapping.MAPPING_SCHEMA`) and ``simulate --config``
(:func:`ditherlab.sim.params.config_schema`, derived from the defaults). :func:`check` walks the
parsed value (TOML or JSON: dicts, lists, str, int, float, bool) and raises the boundary's error
type at the first break, as one line::

    model.toml: n_joints: got 'six'; expected an integer in [1, 64]
    model.toml: regimes.still.tau_max[1]: got '9.4'; expected a number in [-1e+06, 1e+06] [N·m]
    model.toml: regimes.still.sigma: got 5 values; expected 6 (one per joint)
    model.toml: priors: unknown key; expected one of effects, history, n_joints, ...
    model.toml: robot: missing; expected a built-in robot name such as 'irb140' or an object ...
    run.json: metadata key payload.mass: got 'two'; expected a number in [0, 10000] [kg]

Keys are dotted paths; list positions count from 1 (like joints). Numbers are ints or floats,
never bools or text, and always finite unless a node allows ``inf``; the numbers the estimator
computes with have ranges, so nothing downstream overflows (a band of ±1e308 would make
``(b - a)**2`` infinite, and numpy's overflow warning would precede the error line). A length may
name a value bound earlier in the same file (``n_joints`` binds ``n``; ``regimes.*.sigma`` has
``n`` values).

This module is one small class per node type, its messages are the project's own, and it has no
dependency; why it is not pydantic or msgspec: ``docs/design/core-schemas.md``.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ditherlab.core.errors import DitherlabError, where_prefix

__all__ = [
    "Anything",
    "Either",
    "Flag",
    "Integer",
    "ListOf",
    "MapOf",
    "Node",
    "Number",
    "Table",
    "Text",
    "check",
    "count",
    "join_key",
    "shown",
]


class _Fail(Exception):
    """A break of the schema at ``key``: what was found and what was expected."""

    def __init__(self, key: str, got: str, expected: str):
        super().__init__(key, got, expected)
        self.key, self.got, self.expected = key, got, expected


def shown(value: Any, limit: int = 40) -> str:
    """``repr`` of a value, cut to ``limit`` characters (a URDF text can be 100 kB)."""
    r = repr(value)
    return r if len(r) <= limit else r[: limit - 3] + "..."


def count(values: Any) -> str:
    """``"1 value"``, ``"5 values"``: the length of a list, for messages."""
    return f"{len(values)} value{'' if len(values) == 1 else 's'}"


def _got(value: Any) -> str:
    return f"got {shown(value)}"


def join_key(key: str, sub: Any) -> str:
    """``key.sub``; a key that is empty, not printable or holds a dot or a space is quoted
    (``'\\r'``), so that a message stays one readable line."""
    sub = str(sub)
    if not sub or not sub.isprintable() or any(c in sub for c in ". []"):
        sub = repr(sub)
    return f"{key}.{sub}" if key else sub


@dataclass(frozen=True)
class Node(ABC):
    """Base of the schema nodes (abstract: every kind says what it expects and what it
    accepts). ``bind`` names the checked value in the context, for lengths and ranges of keys
    checked after it (``n_joints`` binds ``n``)."""

    bind: str | None = field(default=None, kw_only=True)

    @abstractmethod
    def expected(self, ctx: Mapping[str, Any]) -> str:
        """What a value must be, as the message's ``expected ...`` part."""

    @abstractmethod
    def accepts(self, value: Any) -> bool:
        """Whether ``value`` is of this node's kind (for :class:`Either` to choose a member)."""

    def _check(self, value: Any, key: str, ctx: dict[str, Any]) -> None:
        if not self.accepts(value):
            raise _Fail(key, _got(value), self.expected(ctx))

    def run(self, value: Any, key: str, ctx: dict[str, Any]) -> None:
        self._check(value, key, ctx)
        if self.bind:
            ctx[self.bind] = value


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _fmt(x: float) -> str:
    return f"{x:g}"


def _limit(v: float | str | None, ctx: Mapping[str, Any]) -> float | None:
    return ctx.get(v) if isinstance(v, str) else v


@dataclass(frozen=True)
class Number(Node):
    """An int or float (not bool), finite, in ``[lo, hi]`` (``lo`` excluded when ``lo_open``;
    ``+inf`` allowed when ``inf``). ``unit`` is shown in messages, e.g. ``"N·m"``."""

    lo: float | None = None
    hi: float | None = None
    unit: str = ""
    lo_open: bool = False
    inf: bool = False

    def expected(self, ctx: Mapping[str, Any]) -> str:
        lo, hi = _limit(self.lo, ctx), _limit(self.hi, ctx)
        if lo is not None and hi is not None:
            s = f"a number in {'(' if self.lo_open else '['}{_fmt(lo)}, {_fmt(hi)}]"
        elif lo is not None:
            s = f"a number {'>' if self.lo_open else '>='} {_fmt(lo)}"
        elif hi is not None:
            s = f"a number <= {_fmt(hi)}"
        else:
            s = "a finite number"
        if self.inf:
            s += " or inf"
        return s + (f" [{self.unit}]" if self.unit else "")

    def accepts(self, value: Any) -> bool:
        return _is_number(value)

    def _check(self, value: Any, key: str, ctx: dict[str, Any]) -> None:
        lo, hi = _limit(self.lo, ctx), _limit(self.hi, ctx)
        # an int is finite however large (math.isfinite would overflow converting it)
        ok = _is_number(value) and (
            isinstance(value, int) or math.isfinite(value) or (self.inf and value == math.inf)
        )
        if ok and value != math.inf:
            ok = (lo is None or value > lo or (value == lo and not self.lo_open)) and (
                hi is None or value <= hi
            )
        if not ok:
            raise _Fail(key, _got(value), self.expected(ctx))


@dataclass(frozen=True)
class Integer(Node):
    """An int (not bool, not 6.0) in ``[lo, hi]``; a limit may name a bound value (``"n"``)."""

    lo: int | str | None = None
    hi: int | str | None = None

    def expected(self, ctx: Mapping[str, Any]) -> str:
        lo, hi = _limit(self.lo, ctx), _limit(self.hi, ctx)
        if lo is not None and hi is not None:
            return f"an integer in [{lo}, {hi}]"
        if lo is not None:
            return f"an integer >= {lo}"
        return "an integer"

    def accepts(self, value: Any) -> bool:
        return isinstance(value, int) and not isinstance(value, bool)

    def _check(self, value: Any, key: str, ctx: dict[str, Any]) -> None:
        lo, hi = _limit(self.lo, ctx), _limit(self.hi, ctx)
        if not (
            self.accepts(value) and (lo is None or value >= lo) and (hi is None or value <= hi)
        ):
            raise _Fail(key, _got(value), self.expected(ctx))


@dataclass(frozen=True)
class Text(Node):
    """A string; one of ``choices`` when given; not empty when ``nonempty``."""

    choices: tuple[str, ...] = ()
    nonempty: bool = False
    what: str = ""

    def expected(self, ctx: Mapping[str, Any]) -> str:
        if self.what:
            return self.what
        if len(self.choices) == 1:
            return repr(self.choices[0])
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        return "non-empty text" if self.nonempty else "text"

    def accepts(self, value: Any) -> bool:
        return isinstance(value, str)

    def _check(self, value: Any, key: str, ctx: dict[str, Any]) -> None:
        if not (
            isinstance(value, str)
            and (not self.choices or value in self.choices)
            and (value or not self.nonempty)
        ):
            raise _Fail(key, _got(value), self.expected(ctx))


@dataclass(frozen=True)
class Flag(Node):
    """true or false (not 0/1, not "false")."""

    def expected(self, ctx: Mapping[str, Any]) -> str:
        return "true or false"

    def accepts(self, value: Any) -> bool:
        return isinstance(value, bool)


@dataclass(frozen=True)
class Anything(Node):
    """Any value (free text fields, tables the file passes through)."""

    def expected(self, ctx: Mapping[str, Any]) -> str:
        return "any value"

    def accepts(self, value: Any) -> bool:
        return True


@dataclass(frozen=True)
class ListOf(Node):
    """A list of ``item``; ``length`` (an int, or the name of a bound value such as ``"n"``)
    or ``min_length``. ``per`` says what one item is for, in length messages ("joint")."""

    item: Node = field(default_factory=Anything)
    length: int | str | None = None
    min_length: int = 0
    per: str = ""

    def _n(self, ctx: Mapping[str, Any]) -> int | None:
        n = _limit(self.length, ctx)
        return int(n) if n is not None else None

    def expected(self, ctx: Mapping[str, Any]) -> str:
        n, item = self._n(ctx), self.item.expected(ctx)
        if n is not None:
            return f"a list of {n} values, each {item}"
        return f"a list of values, each {item}"

    def accepts(self, value: Any) -> bool:
        return isinstance(value, list | tuple)

    def _check(self, value: Any, key: str, ctx: dict[str, Any]) -> None:
        if not self.accepts(value):
            raise _Fail(key, _got(value), self.expected(ctx))
        n = self._n(ctx)
        if n is not None and len(value) != n:
            per = f" (one per {self.per})" if self.per else ""
            raise _Fail(key, f"got {count(value)}", f"expected {n}{per}")
        if len(value) < self.min_length:
            raise _Fail(key, f"got {count(value)}", f"expected at least {self.min_length}")
        for i, v in enumerate(value):
            self.item.run(v, f"{key}[{i + 1}]", ctx)


@dataclass(frozen=True)
class MapOf(Node):
    """A table with any (text) keys whose values are all ``value``."""

    value: Node = field(default_factory=Anything)
    what: str = "a table"

    def expected(self, ctx: Mapping[str, Any]) -> str:
        return self.what

    def accepts(self, value: Any) -> bool:
        return isinstance(value, Mapping)

    def _check(self, value: Any, key: str, ctx: dict[str, Any]) -> None:
        if not self.accepts(value):
            raise _Fail(key, _got(value), self.expected(ctx))
        for k, v in value.items():
            self.value.run(v, join_key(key, k), ctx)


@dataclass(frozen=True)
class Table(Node):
    """A table with known keys, checked in the order given (so that a bound value comes
    first). ``required`` keys must be present; other keys are refused unless ``open``."""

    keys: Mapping[str, Node] = field(default_factory=dict)
    required: tuple[str, ...] = ()
    open: bool = False
    what: str = ""

    def expected(self, ctx: Mapping[str, Any]) -> str:
        if self.what:
            return self.what
        return "a table {" + ", ".join(self.keys) + "}"

    def accepts(self, value: Any) -> bool:
        return isinstance(value, Mapping)

    def _check(self, value: Any, key: str, ctx: dict[str, Any]) -> None:
        if not self.accepts(value):
            raise _Fail(key, _got(value), self.expected(ctx))
        if not self.open:
            for k in value:
                if k not in self.keys:
                    raise _Fail(
                        join_key(key, k),
                        "unknown key",
                        "one of " + ", ".join(sorted(self.keys)),
                    )
        for k, node in self.keys.items():
            if k in value:
                node.run(value[k], join_key(key, k), ctx)
            elif k in self.required:
                raise _Fail(join_key(key, k), "missing", node.expected(ctx))


@dataclass(frozen=True)
class Either(Node):
    """One of several nodes: the first whose kind fits the value is checked (so a table gets
    the table's own message); a value that fits none gets ``what``."""

    options: tuple[Node, ...] = ()
    what: str = ""

    def expected(self, ctx: Mapping[str, Any]) -> str:
        return self.what or " or ".join(o.expected(ctx) for o in self.options)

    def accepts(self, value: Any) -> bool:
        return any(o.accepts(value) for o in self.options)

    def _check(self, value: Any, key: str, ctx: dict[str, Any]) -> None:
        for o in self.options:
            if o.accepts(value):
                o.run(value, key, ctx)
                return
        raise _Fail(key, _got(value), self.expected(ctx))


def check(
    value: Any,
    schema: Node,
    where: object,
    error: type[DitherlabError],
    ctx: Mapping[str, Any] | None = None,
    label: str = "",
) -> dict[str, Any]:
    """Check a parsed file against its schema.

    Parameters
    ----------
    value : the parsed file (dicts, lists, str, int, float, bool)
    schema : its :class:`Node` (usually a :class:`Table`)
    where : the file named in messages (a path, or e.g. ``"options"``)
    error : the boundary's error type (ModelError, RecordingError, ConfigError, ...)
    ctx : values bound beforehand (e.g. ``{"n": 6}``)
    label : put before the key in messages (``"metadata key "``)

    Returns
    -------
    dict
        The values bound while checking (``{"n": 6}`` for a model file).

    Raises
    ------
    error
        ``"<where>: <label><key>: got <value>; expected <what>"`` at the first break.
    """
    bound: dict[str, Any] = dict(ctx or {})
    try:
        schema.run(value, "", bound)
    except _Fail as f:
        exp = f.expected if f.expected.startswith("expected") else f"expected {f.expected}"
        key = f"{label}{f.key}" if f.key else "the file"
        raise error(f"{where_prefix(where)}{key}: {f.got}; {exp}") from None
    return bound
