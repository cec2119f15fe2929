"""The estimates file: what ``ditherlab replay`` writes and ``report`` and ``view`` read.

Parquet with ``t``, the sensor columns ``f_x..m_z`` and ``dither`` when present, and per variant
V among :data:`VARIANTS`: ``V/f_x .. V/m_z`` (the estimate), ``V/f_x_lo .. V/m_z_lo`` and
``V/f_x_hi .. V/m_z_hi`` (the interval), ``V/active`` (bitmask of the joints outside their
band); dither variants add ``extract/upper_j``, ``extract/lower_j``, ``extract/signal_j`` [N·m]
(the paper's extraction, written once by replay). Its key-value metadata ``ditherlab`` is JSON:
``{"schema": "ditherlab.estimates/1", "recording": ..., "model": ..., "variants": [...],
"interval": {"method": ..., "level": ...}, "components": [...], "moving_spans": ...}``.
:class:`Estimates` reads, checks and writes it (atomically).
"""

from __future__ import annotations

import contextlib
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from ditherlab.errors import ConfigError, FormatError, RecordingError
from ditherlab.io.atomic import atomic_path, plain
from ditherlab.recording import WRENCH_COLUMNS, Recording

__all__ = [
    "COMPONENTS",
    "META_KEY",
    "SCHEMA",
    "VARIANTS",
    "Estimates",
    "EstimatesWriter",
    "check_estimates_match",
]

SCHEMA = "ditherlab.estimates/1"
META_KEY = b"ditherlab"
#: the estimator variants, in file order
VARIANTS = ("nodither_band", "nodither_noband", "dither_band", "dither_noband")
#: the estimated wrench components
COMPONENTS = WRENCH_COLUMNS


@dataclass
class Estimates:
    """Estimator output per sample (see the module docstring for the columns).

    Attributes
    ----------
    data : DataFrame, one row per sample
    meta : dict with ``schema``, ``recording``, ``recording_name``, ``model``, ``variants``,
        ``interval`` (``method``, ``level``), ``components``, and ``moving_spans`` (the time spans
    in which some joint moved, [s], so that the report can tell rest from motion)
    name : where it was read from (for messages)
    """

    data: pd.DataFrame
    meta: dict[str, Any]
    name: str | None = field(default=None)

    @property
    def variants(self) -> list[str]:
        return list(self.meta.get("variants", []))

    @property
    def t(self) -> np.ndarray:
        """(N,) [s]"""
        return self.data["t"].to_numpy(dtype=float)

    @property
    def has_wrench(self) -> bool:
        return "f_x" in self.data.columns

    @property
    def wrench(self) -> np.ndarray | None:
        """F/T sensor wrench (N, 6) [N, N·m] or None."""
        if not self.has_wrench:
            return None
        return self.data[list(COMPONENTS)].to_numpy(dtype=float)

    @property
    def dither(self) -> np.ndarray | None:
        return self.data["dither"].to_numpy(dtype=bool) if "dither" in self.data.columns else None

    def F(self, variant: str) -> np.ndarray:
        """Estimated wrench of a variant, (N, 6) [N, N·m]."""
        self._check_variant(variant)
        return self.data[[f"{variant}/{c}" for c in COMPONENTS]].to_numpy(dtype=float)

    def interval(self, variant: str) -> tuple[np.ndarray, np.ndarray]:
        """Interval bounds ``(lo, hi)`` of a variant, each (N, 6) [N, N·m]."""
        self._check_variant(variant)
        lo = self.data[[f"{variant}/{c}_lo" for c in COMPONENTS]].to_numpy(dtype=float)
        hi = self.data[[f"{variant}/{c}_hi" for c in COMPONENTS]].to_numpy(dtype=float)
        return lo, hi

    def active(self, variant: str) -> np.ndarray:
        """Joints outside their band, (N, n) bool (decoded from the ``V/active`` bitmask)."""
        self._check_variant(variant)
        mask = self.data[f"{variant}/active"].to_numpy(dtype=np.int64)
        n = int(self.meta.get("n_joints") or _n_from_meta(self.meta))
        return ((mask[:, None] >> np.arange(n)) & 1).astype(bool)

    def _check_variant(self, variant: str) -> None:
        if variant not in self.variants:
            raise ConfigError(
                f"{self.name or 'estimates'}: variant {variant!r} is not in the file "
                f"(it has {', '.join(self.variants) or 'none'})"
            )

    def save(self, path: str | Path) -> Path:
        """Write the estimates as Parquet atomically (zstd; metadata JSON under ``ditherlab``)."""
        table = pa.Table.from_pandas(self.data, preserve_index=False)
        kv = dict(table.schema.metadata or {})
        kv[META_KEY] = json.dumps(self.meta, sort_keys=True, allow_nan=True).encode("utf-8")
        table = table.replace_schema_metadata(kv)
        with atomic_path(path) as tmp:
            pq.write_table(table, tmp, compression="zstd")
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> Estimates:
        """Read an estimates file; FormatError for anything that is not one."""
        p = Path(path)
        if not p.is_file():
            raise FormatError(f"{p}: no such estimates file")
        try:
            pf = pq.ParquetFile(p)
            table = pf.read()
        except (pa.ArrowException, OSError) as exc:
            raise FormatError(f"{p}: not a readable Parquet file ({exc})") from None
        # the footer's key-value metadata: a file written piece by piece (EstimatesWriter)
        # stores it there only, not in the Arrow schema
        kv = {**(table.schema.metadata or {}), **(pf.metadata.metadata or {})}
        if META_KEY not in kv:
            raise FormatError(
                f"{p}: key-value metadata 'ditherlab' is missing, expected an estimates file "
                "written by `ditherlab replay`"
            )
        try:
            meta = json.loads(kv[META_KEY].decode("utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            raise FormatError(f"{p}: metadata 'ditherlab' is not valid JSON ({exc})") from None
        if meta.get("schema") != SCHEMA:
            raise FormatError(
                f"{p}: metadata key 'schema' is {meta.get('schema')!r}, expected {SCHEMA!r} "
                "(a recording, not estimates? run `ditherlab replay` first)"
            )
        return cls(table.to_pandas(), meta, name=str(p))


class EstimatesWriter:
    """An estimates file written piece by piece (:func:`ditherlab.replay.replay_stream`): each
    :meth:`write` appends row groups, :meth:`close` stores the metadata in the footer and
    renames the temporary file onto ``path`` (atomic: an exception leaves nothing). The file is
    the one :meth:`Estimates.save` writes for the concatenated rows.

    Use as a context manager: ``with EstimatesWriter(path) as w: w.write(df); w.meta = {...}``.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.meta: dict[str, Any] | None = None
        self.rows = 0
        self._stack = contextlib.ExitStack()
        self._writer: pq.ParquetWriter | None = None
        self._schema: pa.Schema | None = None

    def __enter__(self) -> EstimatesWriter:
        self._tmp = self._stack.enter_context(atomic_path(self.path))
        return self

    def write(self, data: pd.DataFrame) -> None:
        """Append rows (the same columns and dtypes every time)."""
        if self._writer is None:
            table = pa.Table.from_pandas(data, preserve_index=False)
            self._schema = table.schema
            self._writer = pq.ParquetWriter(self._tmp, self._schema, compression="zstd")
        else:
            table = pa.Table.from_pandas(data, schema=self._schema, preserve_index=False)
        self._writer.write_table(table)
        self.rows += len(data)

    def __exit__(self, kind, exc, tb) -> bool:  # noqa: ANN001
        try:
            if kind is None:
                if self._writer is None or self.meta is None:
                    raise FormatError(f"{self.path}: no rows or no metadata to write")
                text = json.dumps(self.meta, sort_keys=True, allow_nan=True)
                self._writer.add_key_value_metadata({META_KEY: text.encode("utf-8")})
            if self._writer is not None:
                self._writer.close()
        except BaseException:
            self._stack.__exit__(*sys.exc_info())
            raise
        return bool(self._stack.__exit__(kind, exc, tb))


def _n_from_meta(meta: dict[str, Any]) -> int:
    model = meta.get("model") or {}
    return int(model.get("n_joints", 0))


def check_estimates_match(rec: Recording, est: Estimates) -> None:
    """Raise RecordingError unless ``est`` was computed from ``rec``.

    The time stamps must be identical (same count, same values) and the recording metadata stored
    in the estimates file must equal ``rec.meta``.

    Raises
    ------
    RecordingError
        One sentence naming both files and the first difference.
    """
    ename = est.name or "estimates"
    rname = rec.name or "the recording"
    t_rec, t_est = rec.t, est.data["t"].to_numpy(dtype=float)
    if len(t_rec) != len(t_est):
        raise RecordingError(
            f"{ename}: the estimates come from another recording: column t has {len(t_est)} "
            f"samples, {rname} has {len(t_rec)}"
        )
    diff = np.flatnonzero(t_rec != t_est)
    if diff.size:
        i = int(diff[0])
        raise RecordingError(
            f"{ename}: the estimates come from another recording: t in row {i + 1} is "
            f"{t_est[i]!r} s, {rname} has {t_rec[i]!r} s"
        )
    stored = est.meta.get("recording")
    if stored is None:
        raise RecordingError(f"{ename}: metadata key 'recording' is missing")
    # both as plain JSON values (tuples as lists, numpy values as Python ones); a recording's
    # metadata is JSON by contract (Recording.meta_json), so no other conversion is needed
    a, b = plain(stored), plain(rec.meta)
    if a != b:
        key = next(k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k))
        raise RecordingError(
            f"{ename}: the estimates come from another recording: metadata key {key!r} is "
            f"{_short(a.get(key))}, {rname} has {_short(b.get(key))}"
        )


def _short(v: Any, width: int = 60) -> str:
    s = repr(v)
    return s if len(s) <= width else s[: width - 3] + "..."
