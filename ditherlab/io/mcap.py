"""ditherlab's own MCAP files (profile ``ditherlab``), written and read with the ``mcap`` library.

Layout, chosen so that any MCAP tool (Foxglove, ``mcap cat``, PlotJuggler) can show the data:

- every channel has message encoding ``json`` and a ``jsonschema`` schema; one message per
  sample on each channel, ``log_time = publish_time`` = the sample time in ns (shifted so the
  first sample is >= 0 when ``t`` starts negative), ``sequence`` = the row index;
- ``/ditherlab/joints`` (schema ``ditherlab.JointSample``):
  ``{"t": s, "q": [rad], "tau": [N·m], "dq"?: [rad/s], "tau_ffw"?: [N·m], "temp"?: [°C]}``;
- ``/ditherlab/wrench`` (``ditherlab.Wrench``, only with F/T columns):
  ``{"t": s, "force": {"x","y","z"} [N], "torque": {"x","y","z"} [N·m]}``;
- ``/ditherlab/dither`` (``ditherlab.Dither``): ``{"t": s, "active": bool}``;
- ``/ditherlab/extra`` (``ditherlab.Extra``): ``{"t": s, "<column>": value, ...}`` for the extra
  columns (NaN → null, ±inf → "inf"/"-inf");
- a Metadata record ``ditherlab`` with ``recording`` (the recording's metadata JSON),
  ``columns`` (JSON list of ``[name, dtype]`` in table order) and ``format``
  (``"ditherlab.mcap/1"``).

The file is chunked (zstd), indexed, with CRCs and a summary. JSON numbers carry Python's
``repr`` of each float, so the round trip is exact.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.writer import CompressionType, Writer
from zstandard import ZstdError

import ditherlab
from ditherlab.errors import ConfigError, FormatError
from ditherlab.io.atomic import atomic_path
from ditherlab.io.common import (
    META_OPTIONS,
    check_options,
    dumps_meta,
    loads_meta,
    meta_from_options,
)
from ditherlab.recording import JOINT_FAMILIES, WRENCH_COLUMNS, Recording

PROFILE = "ditherlab"
FORMAT = "ditherlab.mcap/1"
JOINTS, WRENCH, DITHER, EXTRA = (
    "/ditherlab/joints",
    "/ditherlab/wrench",
    "/ditherlab/dither",
    "/ditherlab/extra",
)
_AXES = ("x", "y", "z")


def _array(desc: str) -> dict[str, Any]:
    return {"type": "array", "items": {"type": "number"}, "description": desc}


_VEC3 = {"type": "object", "properties": {a: {"type": "number"} for a in _AXES}}
SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    JOINTS: (
        "ditherlab.JointSample",
        {
            "type": "object",
            "title": "ditherlab.JointSample",
            "properties": {
                "t": {"type": "number", "description": "sample time [s]"},
                "q": _array("joint positions [rad]"),
                "dq": _array("joint velocities [rad/s]"),
                "tau": _array("motor torque reference, arm side [N·m]"),
                "tau_ffw": _array("torque feedforward sent [N·m]"),
                "temp": _array("joint temperatures [°C]"),
            },
            "required": ["t", "q", "tau"],
        },
    ),
    WRENCH: (
        "ditherlab.Wrench",
        {
            "type": "object",
            "title": "ditherlab.Wrench",
            "description": "F/T sensor wrench at the tool point, base-frame axes",
            "properties": {"t": {"type": "number"}, "force": _VEC3, "torque": _VEC3},
            "required": ["t", "force", "torque"],
        },
    ),
    DITHER: (
        "ditherlab.Dither",
        {
            "type": "object",
            "title": "ditherlab.Dither",
            "properties": {"t": {"type": "number"}, "active": {"type": "boolean"}},
            "required": ["t", "active"],
        },
    ),
    EXTRA: (
        "ditherlab.Extra",
        {
            "type": "object",
            "title": "ditherlab.Extra",
            "description": "extra columns passed through untouched",
            "properties": {"t": {"type": "number"}},
            "additionalProperties": {"type": ["number", "string", "boolean", "null"]},
        },
    ),
}


# ------------------------------------------------------------------------------ write
def _encode_extra(values: list[Any], kind: str) -> list[Any]:
    if kind != "f":
        return values
    out: list[Any] = []
    for v in values:
        if math.isnan(v):
            out.append(None)
        elif math.isinf(v):
            out.append("inf" if v > 0 else "-inf")
        else:
            out.append(v)
    return out


def write(rec: Recording, path: Path) -> Path:
    """Write ``rec`` atomically as a ditherlab MCAP file (layout in the module docstring)."""
    data = rec.data
    n, t = rec.n, rec.t
    fam = {p: [f"{p}_{j + 1}" for j in range(n)] for p in JOINT_FAMILIES}
    present = [p for p in JOINT_FAMILIES if fam[p][0] in data.columns]
    known = {"t", "dither", *WRENCH_COLUMNS, *(c for p in present for c in fam[p])}
    extras = [c for c in data.columns if c not in known]
    for c in extras:
        kind = data[c].dtype.kind
        if kind not in "fiubO" or (kind == "O" and not data[c].map(type).eq(str).all()):
            raise ConfigError(
                f"{path}: extra column {c} has dtype {data[c].dtype}, which ditherlab MCAP "
                "cannot store (expected numbers, booleans or text)"
            )
    columns = [[str(c), str(data[c].dtype)] for c in data.columns]

    offset = min(0.0, float(t[0]))
    stamps = np.round((t - offset) * 1e9).astype(np.int64).tolist()  # [ns]
    t_list = t.tolist()
    rows: dict[str, list[dict[str, Any]]] = {}
    rows[JOINTS] = [{"t": ti} for ti in t_list]
    for p in present:
        block = data[fam[p]].to_numpy(dtype=float).tolist()
        for r, v in zip(rows[JOINTS], block, strict=True):
            r[p] = v
    if rec.has_wrench:
        w = data[list(WRENCH_COLUMNS)].to_numpy(dtype=float).tolist()
        rows[WRENCH] = [
            {
                "t": ti,
                "force": dict(zip(_AXES, wi[:3], strict=True)),
                "torque": dict(zip(_AXES, wi[3:], strict=True)),
            }
            for ti, wi in zip(t_list, w, strict=True)
        ]
    if "dither" in data.columns:
        rows[DITHER] = [
            {"t": ti, "active": bool(d)}
            for ti, d in zip(t_list, data["dither"].tolist(), strict=True)
        ]
    if extras:
        cols = {c: _encode_extra(data[c].tolist(), data[c].dtype.kind) for c in extras}
        rows[EXTRA] = [{"t": ti} for ti in t_list]
        for c, vals in cols.items():
            for r, v in zip(rows[EXTRA], vals, strict=True):
                r[str(c)] = v

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile=PROFILE, library=f"ditherlab {ditherlab.__version__}")
        channel: dict[str, int] = {}
        for topic in rows:
            name, schema = SCHEMAS[topic]
            sid = w.register_schema(name, "jsonschema", json.dumps(schema).encode())
            channel[topic] = w.register_channel(topic, "json", sid)
        for i, ns in enumerate(stamps):
            for topic, msgs in rows.items():
                w.add_message(
                    channel[topic],
                    log_time=ns,
                    publish_time=ns,
                    sequence=i,
                    data=json.dumps(msgs[i], allow_nan=False).encode(),
                )
        w.add_metadata(
            "ditherlab",
            {
                "format": FORMAT,
                "recording": dumps_meta(rec.meta),
                "columns": json.dumps(columns),
                "name": rec.name or "",
            },
        )
        w.finish()
    return Path(path)


# ------------------------------------------------------------------------------ read
def header_profile(path: Path) -> tuple[str, set[str]]:
    """The MCAP header's profile and the set of schema encodings in the summary.

    Raises FormatError when the file is not MCAP or its header cannot be read.
    """
    try:
        with open(path, "rb") as f:
            reader = SeekingReader(f)
            profile = reader.get_header().profile
            try:
                summary = reader.get_summary()
            except (McapError, struct.error, ValueError, EOFError):
                summary = None
    except (McapError, struct.error, ValueError, EOFError, OSError) as exc:
        raise FormatError(f"{path}: not a readable MCAP file ({exc})") from None
    encodings = {s.encoding for s in summary.schemas.values()} if summary else set()
    return profile, encodings


def read(path: Path, **options: Any) -> Recording:
    """Read a ditherlab MCAP file.

    Options ``robot``, ``tool_offset``, ... override the stored metadata. Raises FormatError
    naming the file when it is truncated, corrupt, or not a ditherlab MCAP file.
    """
    check_options(options, META_OPTIONS, "MCAP", str(path))
    msgs: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    try:
        with open(path, "rb") as f:
            reader = SeekingReader(f, validate_crcs=True)
            header = reader.get_header()
            summary = reader.get_summary()
            if summary is None:
                raise FormatError(
                    f"{path}: the MCAP file is truncated (no summary section: the "
                    "writer did not finish)"
                )
            if header.profile != PROFILE:
                raise FormatError(
                    f"{path}: MCAP profile is {header.profile!r}, expected "
                    f"{PROFILE!r} (a ditherlab MCAP file)"
                )
            records = [m for m in reader.iter_metadata() if m.name == "ditherlab"]
            for _schema, channel, message in reader.iter_messages(log_time_order=False):
                msgs.setdefault(channel.topic, []).append(
                    (message.sequence, json.loads(message.data))
                )
    except FormatError:
        raise
    except (McapError, ZstdError, struct.error, ValueError, EOFError, OSError, KeyError) as exc:
        raise FormatError(f"{path}: the MCAP file is truncated or corrupt ({exc})") from None
    if not records:
        raise FormatError(f"{path}: MCAP metadata record 'ditherlab' is missing")
    info = records[-1].metadata
    got = sum(len(v) for v in msgs.values())
    if summary.statistics and got != summary.statistics.message_count:
        raise FormatError(
            f"{path}: the MCAP file is corrupt: {got} messages read, "
            f"{summary.statistics.message_count} listed in its summary"
        )
    stored = loads_meta(info.get("recording", ""), str(path))
    meta = meta_from_options(stored, options, where=str(path))
    columns = json.loads(info.get("columns", "[]"))
    data = _table(msgs, columns, path)
    return Recording(data, meta, name=str(path))


def _is_float(dtype: str) -> bool:
    try:
        return np.dtype(dtype).kind == "f"
    except TypeError:
        return False


def _table(
    msgs: dict[str, list[tuple[int, dict[str, Any]]]], columns: list[list[str]], path: Path
) -> pd.DataFrame:
    ordered = {k: [m for _, m in sorted(v, key=lambda x: x[0])] for k, v in msgs.items()}
    joints = ordered.get(JOINTS)
    if not joints:
        raise FormatError(f"{path}: channel {JOINTS} has no messages")
    n_rows = len(joints)
    for topic, rows in ordered.items():
        if len(rows) != n_rows:
            raise FormatError(
                f"{path}: channel {topic} has {len(rows)} messages, "
                f"expected one per sample ({n_rows})"
            )
    cols: dict[str, Any] = {"t": [m["t"] for m in joints]}
    for p in JOINT_FAMILIES:
        if p in joints[0]:
            block = np.array([m[p] for m in joints], dtype=float)
            for j in range(block.shape[1]):
                cols[f"{p}_{j + 1}"] = block[:, j]
    if WRENCH in ordered:
        for k, c in enumerate(WRENCH_COLUMNS):
            part, axis = ("force", "torque")[k // 3], _AXES[k % 3]
            cols[c] = [m[part][axis] for m in ordered[WRENCH]]
    if DITHER in ordered:
        cols["dither"] = [m["active"] for m in ordered[DITHER]]
    extra_rows = ordered.get(EXTRA, [])
    out: dict[str, pd.Series] = {}
    for name, dtype in columns:
        if name in cols:
            values = cols[name]
        elif extra_rows and name in extra_rows[0]:
            values = [m[name] for m in extra_rows]
            if _is_float(dtype):
                values = [math.nan if v is None else float(v) for v in values]
        else:
            raise FormatError(f"{path}: column {name} is listed in the metadata but not stored")
        out[name] = pd.Series(values, dtype=dtype)
    return pd.DataFrame(out)
