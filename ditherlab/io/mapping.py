"""Foreign logs: a TOML mapping file turns a vendor's CSV into a Recording without code.

``read(path, mapping="file.toml")`` (or a built-in mapping name such as ``"ur10e"``, see
:func:`builtin_mappings`). The mapping file has these tables (``ditherlab/io/mappings/ur10e.toml``
is a complete example)::

    [input]                 # how to parse the file
    format = "csv"          # the only input format so far
    header = false          # true: the first line names the columns
    delimiter = ","         # any single character, or "whitespace"
    comment = "#"           # optional: lines starting with it are skipped
    skip_rows = 0           # optional: lines to skip before the header / data

    [time]
    column = 1              # 1-based index (as in a spreadsheet) or a header name
    unit = "s"              # s | ms | us | ns
    # add = { column = 11, unit = "ns" }   # optional: a second column added (seconds + nanoseconds)

    [robot]                 # a built-in name, or a URDF path relative to the mapping file
    name = "irb140"         #   (the URDF text is embedded into the recording's metadata)
    # urdf = "robots/my_arm.urdf"; tool_frame = "tool0"; tool_offset = [0, 0, 0.1]
    # payload = { mass = 1.5, com = [0, 0, 0.05] }

    [meta]                  # optional: copied into the metadata (source, notes, sample_rate_hz...)

    [columns.q]             # q, dq, tau, tau_ffw, temp: one source column per joint
    columns = [2, 3, 4, 5, 6, 7]
    unit = "rad"            # q: rad | deg;  dq: rad/s | deg/s;  tau, tau_ffw: N·m;  temp: °C
    scale = 1.0             # optional: a number or one per joint
    factors = [...]         # optional: more factors (numbers or per-joint lists), multiplied
    offset = 0.0            # optional: a number or one per joint, added after scaling

    [columns.wrench]        # optional: six columns f_x, f_y, f_z [N], m_x, m_y, m_z [N·m]
    [columns.vendor_wrench] # optional: the vendor's own wrench estimate, six columns f_vendor_x ..
                            #   m_vendor_z; a scale per component turns its sign and axes into
                            #   the F/T columns' (the wrench the robot exerts, base axes)
    [columns.tau_ext_vendor]  # optional: the vendor's external joint torques [N·m], one per joint
    [columns.dither]        # optional: `column = k`; nonzero means dither on

    [extra]                 # optional: more columns passed through: name = { column, scale, offset }

The value of each recording column is ``raw × scale × Π factors × unit factor + offset``
(e.g. motor current [A] × torque constant [N·m/A] × gear ratio → tau [N·m]). Every key is
checked (:data:`MAPPING_SCHEMA`, then against the log): an unknown table, key or unit, a value of
the wrong kind, a list of the wrong length, a column out of range or not in the header raises
ConfigError naming the mapping file and the key.
"""

from __future__ import annotations

import codecs
import csv
import difflib
import math
import re
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ditherlab.core.errors import ConfigError, FormatError, one_line
from ditherlab.core.names import VENDOR_TAU_FAMILY, VENDOR_WRENCH_COLUMNS, WRENCH_COLUMNS
from ditherlab.core.schema import Either, Flag, Integer, ListOf, MapOf, Number, Table, Text, check
from ditherlab.data.recording import (
    PAYLOAD_NODE,
    SCHEMA,
    STORED_META_SCHEMA,
    TOOL_OFFSET_NODE,
    Recording,
)
from ditherlab.io.common import (
    MAPPINGS_DIR,
    META_OPTIONS,
    builtin_mappings,
    check_options,
    looks_numeric,
    meta_from_options,
    robot_spec,
)
from ditherlab.io.format import Format

FAMILY_UNITS: dict[str, dict[str, float]] = {
    "q": {"rad": 1.0, "deg": math.pi / 180},
    "dq": {"rad/s": 1.0, "deg/s": math.pi / 180},
    "tau": {"N·m": 1.0, "Nm": 1.0, "N*m": 1.0},
    "tau_ffw": {"N·m": 1.0, "Nm": 1.0, "N*m": 1.0},
    "temp": {"°C": 1.0, "degC": 1.0, "C": 1.0},
    VENDOR_TAU_FAMILY: {"N·m": 1.0, "Nm": 1.0, "N*m": 1.0},
}
#: The six-column families: the F/T sensor's wrench and the vendor's own estimate of it.
WRENCH_FAMILIES = {"wrench": WRENCH_COLUMNS, "vendor_wrench": VENDOR_WRENCH_COLUMNS}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_COLUMN = Either(
    options=(Integer(1), Text(nonempty=True)),
    what="a column number (1-based) or a header name",
)
_NUMBER = Number(-1e12, 1e12)
_FACTOR = Either(
    options=(_NUMBER, ListOf(item=_NUMBER)),
    what="a number or a list of numbers (one per column)",
)


def _family_node(units: tuple[str, ...] = ()) -> Table:
    return Table(
        keys={
            "columns": ListOf(item=_COLUMN, min_length=1),
            "unit": Text(choices=units),
            "scale": _FACTOR,
            "factors": ListOf(item=_FACTOR),
            "offset": _FACTOR,
        },
        required=("columns",),
    )


#: The mapping file (the module docstring shows it); lengths and columns are checked against
#: the log when it is read.
MAPPING_SCHEMA = Table(
    keys={
        "input": Table(
            keys={
                "format": Text(choices=("csv",)),
                "header": Flag(),
                "delimiter": Text(nonempty=True, what="one character or 'whitespace'"),
                "comment": Text(nonempty=True),
                "skip_rows": Integer(0),
                "encoding": Text(nonempty=True, what="a text encoding such as 'utf-8'"),
            }
        ),
        "time": Table(
            keys={
                "column": _COLUMN,
                "unit": Text(choices=tuple(TIME_UNITS)),
                "offset": Number(-1e12, 1e12, "s"),
                "add": Table(
                    keys={"column": _COLUMN, "unit": Text(choices=tuple(TIME_UNITS))},
                    required=("column", "unit"),
                ),
            }
        ),
        "robot": Table(
            keys={
                "name": Text(nonempty=True, what="a built-in robot name"),
                "urdf": Text(nonempty=True, what="the path of a URDF file"),
                "tool_frame": Text(nonempty=True, what="the name of a URDF link"),
                "tool_offset": TOOL_OFFSET_NODE,
                "payload": PAYLOAD_NODE,
            }
        ),
        "meta": STORED_META_SCHEMA,
        "columns": Table(
            keys={
                **{fam: _family_node(tuple(units)) for fam, units in FAMILY_UNITS.items()},
                **{fam: _family_node() for fam in WRENCH_FAMILIES},
                "dither": Table(keys={"column": _COLUMN}, required=("column",)),
            },
            required=("q", "tau"),
        ),
        "extra": MapOf(
            value=Table(
                keys={"column": _COLUMN, "scale": _NUMBER, "offset": _NUMBER, "unit": Text()},
                required=("column",),
            )
        ),
    },
    required=("time", "robot", "columns"),
)


def mapping_path(mapping: str | Path) -> Path:
    """The mapping file for a path or a built-in mapping name; ConfigError when there is none."""
    p = Path(mapping).expanduser()
    if p.is_file():
        return p
    if str(mapping) in builtin_mappings():
        return MAPPINGS_DIR / f"{mapping}.toml"
    raise ConfigError(
        f"mapping {str(mapping)!r} is neither a file nor a built-in mapping (expected a TOML "
        f"file or one of: {', '.join(builtin_mappings())})"
    )


def load_mapping(mapping: str | Path) -> tuple[dict[str, Any], Path]:
    """Parse and check a mapping file; returns (mapping dict, its path)."""
    p = mapping_path(mapping)
    try:
        spec = tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not a valid TOML file ({exc})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a valid TOML file (not UTF-8 text)") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the mapping file ({exc.strerror})") from None
    check(spec, MAPPING_SCHEMA, p, ConfigError)
    encoding = spec.get("input", {}).get("encoding", "utf-8")
    try:
        codecs.lookup(encoding)
    except LookupError:
        raise ConfigError(
            f"{p}: input.encoding: got {encoding!r}; expected a text encoding such as 'utf-8'"
        ) from None
    return spec, p


def _check_widths(
    path: Path, mp: Path, delim: str, skip: int, comment: str | None, encoding: str
) -> None:
    """The first two lines read (after ``skip`` and comments) must have the same number of
    fields: pandas takes the first line's count for every row, so a first line of 200 000
    fields would have it parse every row that wide (minutes) before any message."""
    seen: list[tuple[int, int]] = []
    try:
        with open(path, encoding=encoding, newline="") as f:
            for number, line in enumerate(f, start=1):
                if number <= skip or not line.strip():
                    continue
                if comment and line.lstrip().startswith(comment):
                    continue
                if delim == "whitespace":
                    width = len(line.split())
                else:
                    width = len(next(csv.reader([line], delimiter=delim, skipinitialspace=True)))
                seen.append((number, width))
                if len(seen) == 2:
                    break
    except (UnicodeDecodeError, csv.Error, StopIteration):
        return  # pandas' own reading gives the message
    if len(seen) == 2 and seen[0][1] != seen[1][1]:
        (a, na), (b, nb) = seen
        raise FormatError(
            f"{path}: line {a} has {na} fields but line {b} has {nb}; expected the same number "
            f"of fields on every line (as described by {mp})"
        )


def read(path: Path, mapping: str | Path, **options: Any) -> Recording:
    """Read the foreign log ``path`` as described by ``mapping`` (file or built-in name).

    Options ``robot``, ``tool_offset``, ... override the mapping's robot and metadata.
    Raises FormatError when the log does not exist or a cell is not a number, ConfigError for
    a bad mapping.
    """
    path = Path(path)
    if not path.exists():
        raise FormatError(f"{path}: no such file")
    check_options(options, META_OPTIONS, "mapped", str(path))
    spec, mp = load_mapping(mapping)
    header = bool(spec.get("input", {}).get("header", True))
    cols = _table(_Columns(_parse(path, spec, mp), path, mp, header), spec, mp)
    meta = meta_from_options(_meta(spec, mp, options.get("robot")), options, where=str(path))
    meta.setdefault("mapping", mp.name)
    return Recording(pd.DataFrame(cols), meta, name=str(path))


def _parse(path: Path, spec: dict[str, Any], mp: Path) -> pd.DataFrame:
    """The log's cells as text, parsed as the mapping's ``[input]`` says; FormatError when the
    file cannot be parsed so."""
    inp = spec.get("input", {})
    delim = inp.get("delimiter", ",")
    skip = int(inp.get("skip_rows", 0))
    _check_widths(path, mp, delim, skip, inp.get("comment"), inp.get("encoding", "utf-8"))
    try:
        return pd.read_csv(
            path,
            header=0 if inp.get("header", True) else None,
            sep=r"\s+" if delim == "whitespace" else delim,
            comment=inp.get("comment"),
            skiprows=skip,
            dtype=str,
            keep_default_na=False,
            encoding=inp.get("encoding", "utf-8"),
            skipinitialspace=True,
        )
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise FormatError(
            f"{path}: cannot be parsed as described by {mp} ({one_line(exc)})"
        ) from None


def _table(reader: _Columns, spec: dict[str, Any], mp: Path) -> dict[str, np.ndarray]:
    """The recording's columns from the log's: ``t`` [s], the joint families (SI units), the
    wrench [N, N·m], the dither flag and the extra columns, as the mapping says."""
    cols: dict[str, np.ndarray] = {}
    tspec = spec["time"]
    tunit = tspec.get("unit", "s")  # units, kinds and keys: checked by MAPPING_SCHEMA
    cols["t"] = reader.get(tspec.get("column"), "t", "time.column") * TIME_UNITS[tunit] + float(
        tspec.get("offset", 0.0)
    )
    if "add" in tspec:  # e.g. a stamp's nanoseconds beside its seconds
        add = tspec["add"]
        cols["t"] = (
            cols["t"] + reader.get(add["column"], "t", "time.add.column") * TIME_UNITS[add["unit"]]
        )
    n = len(spec["columns"]["q"].get("columns", []))
    for fam in FAMILY_UNITS:
        sub = spec["columns"].get(fam)
        if sub is not None:
            cols.update(_family(reader, sub, fam, n, mp))
    for fam in WRENCH_FAMILIES:
        if fam in spec["columns"]:
            cols.update(_family(reader, spec["columns"][fam], fam, 6, mp))
    if "dither" in spec["columns"]:
        d = reader.get(spec["columns"]["dither"].get("column"), "dither", "columns.dither.column")
        cols["dither"] = d != 0
    for name, sub in spec.get("extra", {}).items():
        v = reader.get(sub.get("column"), name, f"extra.{name}.column")
        cols[name] = v * _number(sub.get("scale", 1.0), mp, f"extra.{name}.scale") + _number(
            sub.get("offset", 0.0), mp, f"extra.{name}.offset"
        )
    return cols


def _meta(spec: dict[str, Any], mp: Path, given: Any = None) -> dict[str, Any]:
    """The recording's metadata from the mapping: its ``[meta]`` and ``[robot]`` (a URDF path
    relative to the mapping file, its text embedded). A ``[robot]`` that names no robot (an arm
    whose URDF is not built in) takes the reader option ``robot`` (``given``)."""
    meta = {"schema": SCHEMA, **spec.get("meta", {})}
    rob = spec["robot"]
    if "urdf" in rob:  # a path relative to the mapping file; its text goes into the metadata
        meta["robot"] = robot_spec(
            Path(str(rob["urdf"])),
            base_dir=mp.parent,
            tool_frame=rob.get("tool_frame"),
            where=f"{mp}: robot.urdf",
        )
    elif "name" in rob:
        meta["robot"] = str(rob["name"])
    elif given is None:
        raise ConfigError(
            f"{mp}: table [robot] names no robot ('name' or 'urdf'); expected --robot with a "
            "built-in name or the path of the arm's URDF file"
        )
    for key in ("tool_offset", "payload"):
        if key in rob:
            meta[key] = rob[key]
    return meta


def _number(v: Any, mp: Path, key: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ConfigError(f"{mp}: {key} is {v!r}, expected a number")
    return float(v)


def _per_joint(v: Any, n: int, mp: Path, key: str) -> np.ndarray:
    """A number or a list of n numbers → (n,)."""
    if isinstance(v, list):
        if len(v) != n:
            raise ConfigError(f"{mp}: {key} has {len(v)} values, expected {n} (one per column)")
        return np.array([_number(x, mp, key) for x in v])
    return np.full(n, _number(v, mp, key))


def _family(
    reader: _Columns, sub: dict[str, Any], fam: str, n: int, mp: Path
) -> dict[str, np.ndarray]:
    key = f"columns.{fam}"
    src = sub.get("columns")
    if not isinstance(src, list) or len(src) != n:
        raise ConfigError(
            f"{mp}: {key}.columns is {src!r}, expected a list of {n} columns (one per "
            f"{'wrench component' if fam in WRENCH_FAMILIES else 'joint'})"
        )
    if fam in WRENCH_FAMILIES:
        unit_factor = 1.0
        names = list(WRENCH_FAMILIES[fam])
    else:
        units = FAMILY_UNITS[fam]
        unit_factor = units[sub.get("unit", next(iter(units)))]
        names = [f"{fam}_{j + 1}" for j in range(n)]
    scale = _per_joint(sub.get("scale", 1.0), n, mp, f"{key}.scale")
    factors = sub.get("factors", [])
    if not isinstance(factors, list):
        raise ConfigError(f"{mp}: {key}.factors is {factors!r}, expected a list")
    for k, f in enumerate(factors):
        scale = scale * _per_joint(f, n, mp, f"{key}.factors[{k + 1}]")
    offset = _per_joint(sub.get("offset", 0.0), n, mp, f"{key}.offset")
    return {
        name: reader.get(c, name, f"{key}.columns[{j + 1}]") * scale[j] * unit_factor + offset[j]
        for j, (name, c) in enumerate(zip(names, src, strict=True))
    }


class _Columns:
    """Resolve mapping column references (1-based index or header name) to float arrays."""

    def __init__(self, raw: pd.DataFrame, path: Path, mp: Path, header: bool):
        self.raw, self.path, self.mp, self.header = raw, path, mp, header

    def get(self, ref: Any, target: str, key: str) -> np.ndarray:
        ncol = self.raw.shape[1]
        if isinstance(ref, bool) or ref is None:
            raise ConfigError(f"{self.mp}: {key} is {ref!r}, expected a column number or name")
        if isinstance(ref, int):
            if not 1 <= ref <= ncol:
                raise ConfigError(
                    f"{self.mp}: {key} is {ref}, but {self.path} has {ncol} columns "
                    f"(expected 1..{ncol})"
                )
            col = self.raw.iloc[:, ref - 1]
            label = f"column {ref}"
        else:
            if not self.header:
                raise ConfigError(
                    f"{self.mp}: {key} is {ref!r}, but input.header is false (expected a column "
                    "number)"
                )
            if ref not in self.raw.columns:
                names = [str(c) for c in self.raw.columns]
                hint = (
                    f"the first line of {self.path} holds numbers, not names: a file without a "
                    "header line needs a mapping with input.header = false"
                    if _looks_like_data(names)
                    else _expected_names(str(ref), names)
                )
                raise ConfigError(
                    f"{self.mp}: {key} is {ref!r}, but the header of {self.path} has no such "
                    f"column ({hint})"
                )
            col = self.raw[ref]
            label = f"column {ref!r}"
        text = col.astype(str).str.strip()
        values = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float)
        bad = np.isnan(values) & ~text.str.lower().isin(["nan"]).to_numpy()
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise FormatError(
                f"{self.path}: {label} ({target}) has a non-numeric value {col.iloc[i]!r} in "
                f"data row {i + 1}, expected a number"
            )
        return values


def _looks_like_data(names: list[str]) -> bool:
    """Whether a header's names are numbers: a line of data read as the header (split on any
    delimiter, since the mapping's may not be the file's; pandas renames repeats ``x.1``)."""
    tokens = [t for c in names for t in re.split(r"[,;\s]+", c) if t]
    return bool(tokens) and all(
        looks_numeric(t) or looks_numeric(re.sub(r"\.\d+$", "", t)) for t in tokens
    )


def _expected_names(ref: str, names: list[str], show: int = 12) -> str:
    """'expected one of ...' for a column name not in a header: all names when there are few,
    else the closest ones (a vendor header can have a hundred columns)."""
    if len(names) <= show:
        return f"expected one of: {', '.join(names)}"
    close = difflib.get_close_matches(ref, names, n=3, cutoff=0.6)
    if close:
        return f"expected one of its {len(names)} names; closest: {', '.join(close)}"
    return f"expected one of its {len(names)} names: {', '.join(names[:show])}, ..."


def _read_mapped(path: Path, **options: Any) -> Recording:
    """:func:`read` with the mapping given as the reader option ``mapping``."""
    mapping = options.pop("mapping")
    return read(path, mapping, **options)


def _mapping_files(mapping: str | Path) -> list[Path]:
    """The mapping file that the option ``mapping`` names."""
    return [mapping_path(mapping)]


#: vendor logs through a mapping file: chosen by ``mapping=``, read whole, never written
FORMAT = Format(
    name="mapping",
    title="a foreign log read through a mapping file",
    read=_read_mapped,
    option="mapping",
    inputs=_mapping_files,
)
