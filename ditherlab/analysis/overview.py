"""A summary of a recording, for ``ditherlab info``: duration, rate and jitter, joints, optional
columns, and how the time divides into standing still, dithering and moving."""

from __future__ import annotations

from typing import Any

import numpy as np

from ditherlab.core.names import DITHER, MOVING, STILL, VENDOR_WRENCH_COLUMNS, WRENCH_COLUMNS
from ditherlab.data.recording import JOINT_FAMILIES, Recording, regimes
from ditherlab.io.stream import CHUNK_ROWS, Piece, Source


def regime_fractions(rec: Recording, keep: slice = slice(None)) -> dict[str, float]:
    """Fractions of the recording's time spent still, dithering and moving.

    A sample counts as ``moving`` when any joint moves (:func:`ditherlab.data.recording.regimes`),
    as ``dither`` when no joint moves and some joint dithers, else ``still``. Each sample
    weighs its time interval (``numpy.gradient(t)`` [s]), so jitter does not bias the fractions.

    Returns
    -------
    {"still": f, "dither": f, "moving": f}, summing to 1
    """
    w = _regime_time(rec, keep)
    total = float(sum(w.values()))
    return {k: v / total for k, v in w.items()}


def _regime_time(rec: Recording, keep: slice = slice(None)) -> dict[str, float]:
    """Seconds of the rows ``keep`` of ``rec`` spent still, dithering and moving."""
    r = regimes(rec)
    per_sample = np.where(
        (r == MOVING).any(axis=1), MOVING, np.where((r == DITHER).any(axis=1), DITHER, STILL)
    )[keep]
    t = rec.t
    w = (np.gradient(t) if len(t) > 1 else np.ones(1))[keep]
    return {
        name: float(w[per_sample == code].sum())
        for name, code in (("still", STILL), ("dither", DITHER), ("moving", MOVING))
    }


def describe(rec: Recording | Source, chunk_rows: int | None = None) -> dict[str, Any]:
    """A JSON-ready summary of a recording, in memory or read in pieces (a :class:`Source`:
    memory does not grow with the log's length).

    Keys: ``file``, ``samples``, ``duration_s``, ``t_start_s``, ``sample_rate_hz`` (1 / median
    interval), ``dt_median_ms``, ``dt_jitter_ms`` (standard deviation of the interval),
    ``dt_min_ms``, ``dt_max_ms`` (None for one sample), ``robot``, ``joints`` (count), ``joint_names``, ``columns``
    (which optional families exist), ``extra_columns``, ``regimes`` (:func:`regime_fractions`),
    ``q_range_rad`` and ``tau_range_nm`` (per joint ``[min, max]``), and the metadata keys
    ``source``, ``notes``, ``tool_offset``, ``payload`` when present. ``chunk_rows``: rows
    per piece of a Source (default :data:`ditherlab.io.stream.CHUNK_ROWS`).
    """
    pieces = (
        iter([Piece(rec, 0, slice(0, len(rec)), 0, 1)])
        if isinstance(rec, Recording)
        else rec.pieces(chunk_rows or CHUNK_ROWS)
    )
    t_all = rec.t if isinstance(rec, Recording) else rec.times()
    time = {"still": 0.0, "dither": 0.0, "moving": 0.0}
    qr = tr = None
    first = None
    for p in pieces:
        first = first or p.rec
        for k, v in _regime_time(p.rec, p.keep).items():
            time[k] += v
        qr = _widen(qr, p.rec.q[p.keep])
        tr = _widen(tr, p.rec.tau[p.keep])
    assert first is not None and qr is not None and tr is not None
    dt = np.diff(t_all) * 1e3 if len(t_all) > 1 else np.array([np.nan])  # [ms]
    robot = first.robot()
    cols = set(rec.columns if isinstance(rec, Source) else rec.data.columns)
    order = rec.columns if isinstance(rec, Source) else list(rec.data.columns)
    optional = {
        "dq": "dq_1" in cols,
        "tau_ffw": "tau_ffw_1" in cols,
        "temp": "temp_1" in cols,
        "wrench": first.has_wrench,
        "dither": "dither" in cols,
        "vendor": first.has_vendor,  # the vendor's own estimate (wrench or joint torques)
    }
    known = {"t", "dither", *WRENCH_COLUMNS, *VENDOR_WRENCH_COLUMNS}
    known |= {f"{p}_{j + 1}" for p in JOINT_FAMILIES for j in range(first.n)}
    total = sum(time.values())
    meta = rec.meta
    out: dict[str, Any] = {
        "file": rec.name,
        "samples": len(t_all),
        "duration_s": float(t_all[-1] - t_all[0]),
        "t_start_s": float(t_all[0]),
        "sample_rate_hz": float(1e3 / np.median(dt)),
        "dt_median_ms": float(np.median(dt)),
        "dt_jitter_ms": float(np.std(dt)),
        "dt_min_ms": float(np.min(dt)),
        "dt_max_ms": float(np.max(dt)),
        "robot": first.robot_label,
        "joints": first.n,
        "joint_names": list(robot.joint_names),
        "columns": optional,
        "extra_columns": [str(c) for c in order if c not in known],
        "regimes": {k: v / total for k, v in time.items()},
        "q_range_rad": qr.tolist(),
        "tau_range_nm": tr.tolist(),
    }
    for key in ("source", "notes", "tool_offset", "payload"):
        if key in meta:
            out[key] = meta[key]
    if len(t_all) < 2:  # one sample: no interval (None, i.e. null in JSON, not NaN)
        out.update(
            dict.fromkeys(("sample_rate_hz", *(k for k in out if k.startswith("dt_"))), None)
        )
    return out


def _widen(span: np.ndarray | None, x: np.ndarray) -> np.ndarray:
    """Per-column ``[min, max]`` (n, 2) of ``x`` (M, n), widened by an earlier ``span``."""
    lo, hi = x.min(axis=0), x.max(axis=0)
    if span is not None:
        lo, hi = np.minimum(span[:, 0], lo), np.maximum(span[:, 1], hi)
    return np.stack([lo, hi], axis=1)


def format_info(d: dict[str, Any]) -> str:
    """The summary of :func:`describe` as a few lines of text."""
    present = [k for k, v in d["columns"].items() if v]
    absent = [k for k, v in d["columns"].items() if not v]
    reg = d["regimes"]
    lines = [
        f"file       {d['file']}",
        f"robot      {d['robot']} ({d['joints']} joints: {', '.join(d['joint_names'])})",
        f"samples    {d['samples']} over {d['duration_s']:.3f} s (t = {d['t_start_s']:.3f} s "
        "onwards)",
        f"rate       {d['sample_rate_hz']:.2f} Hz (interval {d['dt_median_ms']:.3f} ms, jitter "
        f"{d['dt_jitter_ms']:.3f} ms std, {d['dt_min_ms']:.3f}..{d['dt_max_ms']:.3f} ms)"
        if d["samples"] > 1
        else "rate       unknown (one sample)",
        f"columns    t, q, tau{''.join(', ' + k for k in present)}"
        + (f"; absent: {', '.join(absent)}" if absent else ""),
    ]
    if d["extra_columns"]:
        lines.append(f"extra      {', '.join(d['extra_columns'])}")
    lines.append(
        f"regimes    still {100 * reg['still']:.1f} %, dither {100 * reg['dither']:.1f} %, "
        f"moving {100 * reg['moving']:.1f} %"
    )
    lines.append("joint      q min..max [rad]       tau min..max [N·m]")
    for j, (qr, tr) in enumerate(zip(d["q_range_rad"], d["tau_range_nm"], strict=True)):
        lines.append(f"  {j + 1:<8} {qr[0]:9.4f}..{qr[1]:<9.4f}  {tr[0]:9.3f}..{tr[1]:<9.3f}")
    for key in ("source", "notes", "tool_offset", "payload"):
        if key in d:
            lines.append(f"{key:<10} {d[key]}")
    return "\n".join(line.rstrip() for line in lines)
