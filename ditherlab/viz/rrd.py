"""Reading an ``.rrd`` file back with Rerun's own reader (``rerun.chunk.RrdReader``): what it
holds per entity, and the scalars of one entity (the tests and ``make bench`` check the view so)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rerun.chunk import RrdReader

from ditherlab.errors import DitherlabError
from ditherlab.viz.stream import TIMELINE


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
