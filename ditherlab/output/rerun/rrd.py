"""Reading an ``.rrd`` file back with Rerun's own reader (``rerun.chunk.RrdReader``): what it
holds per entity, the scalars of one entity, and every row in comparable form (the tests and
``make bench`` check the view so)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from rerun.chunk import RrdReader

from ditherlab.core.errors import DitherlabError
from ditherlab.output.rerun.columns import TIMELINE


def rrd_contents(path: str | Path) -> dict[str, dict[str, int]]:
    """What an ``.rrd`` file holds, read with Rerun's own reader (``rerun.chunk.RrdReader``).

    Returns
    -------
    dict entity path (without the leading ``/``) -> component name (e.g. ``Scalars:scalars``) ->
    number of time-indexed rows; static components are counted under the key ``"static"``
    """
    out: dict[str, dict[str, int]] = {}
    for ch in RrdReader(str(path)).stream():
        ent = out.setdefault(ch.entity_path.lstrip("/"), {})
        if ch.is_static:
            ent["static"] = ent.get("static", 0) + ch.num_rows
            continue
        rb = ch.to_record_batch()
        for f in rb.schema:
            meta = f.metadata or {}
            if meta.get(b"rerun:kind") == b"data":
                ent[f.name] = ent.get(f.name, 0) + ch.num_rows
    return out


def rrd_scalars(path: str | Path, entity: str) -> tuple[np.ndarray, np.ndarray]:
    """Read one Scalars entity back from an ``.rrd`` file with Rerun's reader.

    Returns
    -------
    t : (M,) [s] the ``time`` timeline
    values : (M, k) the scalars of each row
    """
    want = "/" + entity.lstrip("/")
    ts, vs = [], []
    for ch in RrdReader(str(path)).stream():
        if ch.entity_path != want or ch.is_static:
            continue
        rb = ch.to_record_batch()
        names = rb.schema.names
        if "Scalars:scalars" not in names:
            continue
        tcol = rb.column(names.index(TIMELINE)).cast("int64").to_numpy()
        sc = rb.column(names.index("Scalars:scalars"))
        vs.append(np.asarray(sc.flatten().to_numpy(zero_copy_only=False)).reshape(len(tcol), -1))
        ts.append(tcol)
    if not ts:
        raise DitherlabError(f"{path}: entity {entity!r} has no Scalars")
    t = np.concatenate(ts)
    v = np.concatenate(vs)
    order = np.argsort(t, kind="stable")
    return t[order] / 1e9, v[order]


def rrd_rows(path: str | Path) -> dict[tuple[str, str, bool], tuple[np.ndarray | None, Any]]:
    """Every logged row of an ``.rrd`` file in a form to compare two files bit for bit.

    The chunks of an entity are joined and their rows put in time order (stable), so a file
    written in pieces compares equal to one written at once. The recording's start time
    (``RecordingInfo:start_time``, the wall clock) is left out.

    Returns
    -------
    dict (entity path, component, static) -> (times (M,) [ns] of the ``time`` timeline or None
    when static, values): float lists of one length as their bits, (M, k) int64 (NaN equal to
    NaN); anything else as Python values, a list of M
    """
    raw: dict[tuple[str, str, bool], list[tuple[np.ndarray | None, pa.Array]]] = {}
    for ch in RrdReader(str(path)).stream():
        rb = ch.to_record_batch()
        names = rb.schema.names
        t = None if ch.is_static else rb.column(names.index(TIMELINE)).cast("int64").to_numpy()
        for f in rb.schema:
            if (f.metadata or {}).get(b"rerun:kind") != b"data":
                continue
            if f.name == "RecordingInfo:start_time":
                continue
            raw.setdefault((ch.entity_path, f.name, ch.is_static), []).append(
                (t, rb.column(f.name))
            )
    out: dict[tuple[str, str, bool], tuple[np.ndarray | None, Any]] = {}
    for key, parts in raw.items():
        arr = pa.concat_arrays([a for _, a in parts])
        if key[2]:
            out[key] = (None, arr.to_pylist())
            continue
        t = np.concatenate([p[0] for p in parts if p[0] is not None])
        order = np.argsort(t, kind="stable")
        typ = arr.type
        if pa.types.is_list(typ) and pa.types.is_floating(typ.value_type):
            lens = pc.list_value_length(arr).to_numpy(zero_copy_only=False)
            if len(np.unique(lens)) == 1:
                flat = arr.flatten().to_numpy(zero_copy_only=False).astype(np.float64)
                out[key] = (t[order], flat.view(np.int64).reshape(len(arr), -1)[order])
                continue
        rows = arr.to_pylist()
        out[key] = (t[order], [rows[i] for i in order])
    return out
