"""ditherlab's own MCAP files (profile ``ditherlab``), written and read with the ``mcap`` library.

Layout, chosen so that any MCAP tool (Foxglove, ``mcap cat``, PlotJuggler) can show the data:

- every channel has message encoding ``json`` and a ``jsonschema`` schema; one message per
  sample on each channel, ``log_time = publish_time`` = the sample time in ns (shifted so the
  first sample is >= 0 when ``t`` starts negative), ``sequence`` = the row index; the messages
  are written row by row (a row's message on each channel, then the next row's) and read back
  in that order, a block of rows at a time (:func:`layout`, :func:`frames`);
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

The file is chunked (zstd), indexed, with a summary, and CRCs of every chunk, the data section
and the summary; the reader checks every chunk's CRC (a chunk without one is refused) and the
summary's, so a damaged byte is an error, not different data. JSON numbers carry Python's
``repr`` of each float, so the round trip is exact.

Read whole or in blocks of rows (:func:`layout` opens the file, :meth:`Layout.frames`), written
whole or block by block (:func:`write_frames`): :data:`FORMAT`. A ``.mcap`` file of another
profile may be a ROS 2 bag (:mod:`ditherlab.io.rosbag`).
"""

from __future__ import annotations

import json
import math
import re
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import pandas as pd
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import NonSeekingReader, SeekingReader
from mcap.records import Chunk
from mcap.writer import CompressionType, Writer
from zstandard import ZstdError

from ditherlab.core.errors import ConfigError, FormatError, one_line
from ditherlab.core.files import atomic_path
from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.core.version import __version__
from ditherlab.data.recording import JOINT_FAMILIES, Recording
from ditherlab.io.common import (
    META_OPTIONS,
    check_options,
    dumps_meta,
    loads_meta,
    meta_from_options,
)
from ditherlab.io.format import Format

#: the first bytes of every MCAP file
MAGIC = b"\x89MCAP"
PROFILE = "ditherlab"
#: the layout's version, in the metadata record's ``format``
LAYOUT_VERSION = "ditherlab.mcap/1"
JOINTS, WRENCH, DITHER, EXTRA = (
    "/ditherlab/joints",
    "/ditherlab/wrench",
    "/ditherlab/dither",
    "/ditherlab/extra",
)
_AXES = ("x", "y", "z")
_JOINT_COL = re.compile(rf"^({'|'.join(JOINT_FAMILIES)})_(\d+)$")


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


class _Encoder:
    """How the rows of one recording's table become messages (the layout in the module
    docstring): fixed by its first block of rows, which every later block must match."""

    def __init__(self, data: pd.DataFrame, path: Path, name: str):
        self.name = name
        n = 0
        while f"q_{n + 1}" in data.columns:
            n += 1
        self.fam = {p: [f"{p}_{j + 1}" for j in range(n)] for p in JOINT_FAMILIES}
        self.present = [p for p in JOINT_FAMILIES if n and self.fam[p][0] in data.columns]
        self.wrench = "f_x" in data.columns
        self.dither = "dither" in data.columns
        known = {"t", "dither", *WRENCH_COLUMNS, *(c for p in self.present for c in self.fam[p])}
        self.extras = [c for c in data.columns if c not in known]
        for c in self.extras:
            kind = data[c].dtype.kind
            if kind not in "fiubO" or (kind == "O" and not data[c].map(type).eq(str).all()):
                raise ConfigError(
                    f"{path}: extra column {c} has dtype {data[c].dtype}, which ditherlab MCAP "
                    "cannot store (expected numbers, booleans or text)"
                )
        self.columns = [[str(c), str(data[c].dtype)] for c in data.columns]
        self.offset = min(0.0, float(data["t"].to_numpy(dtype=float)[0]))  # [s]
        self.topics = [
            topic
            for topic, on in (
                (JOINTS, True),
                (WRENCH, self.wrench),
                (DITHER, self.dither),
                (EXTRA, bool(self.extras)),
            )
            if on
        ]

    def check(self, data: pd.DataFrame, start: int) -> None:
        """Raise FormatError when ``data`` (rows from ``start`` on) has other columns or dtypes
        than the first block."""
        got = [[str(c), str(data[c].dtype)] for c in data.columns]
        if got == self.columns:
            return
        names, now_names = [c for c, _ in self.columns], [c for c, _ in got]
        if now_names != names:
            raise FormatError(
                f"{self.name}: the columns change at row {start + 1} ({', '.join(now_names)}); "
                f"expected {', '.join(names)}"
            )
        c, was, now = next(
            (a[0], a[1], b[1]) for a, b in zip(self.columns, got, strict=True) if a != b
        )
        raise FormatError(
            f"{self.name}: column {c} changes type at row {start + 1} ({was} -> {now}); "
            "expected one type per column"
        )

    def rows(self, data: pd.DataFrame) -> Iterator[tuple[int, tuple[dict[str, Any], ...]]]:
        """``(log_time [ns], message bodies in the order of topics)`` for each row of ``data``."""
        t = data["t"].to_numpy(dtype=float)
        stamps = np.round((t - self.offset) * 1e9).astype(np.int64).tolist()  # [ns]
        t_list = t.tolist()
        blocks = [data[self.fam[p]].to_numpy(dtype=float).tolist() for p in self.present]
        joints = (
            {"t": ti, **dict(zip(self.present, vals, strict=True))}
            for ti, *vals in zip(t_list, *blocks, strict=True)
        )
        parts: list[Iterator[dict[str, Any]]] = [joints]
        if self.wrench:
            w = data[list(WRENCH_COLUMNS)].to_numpy(dtype=float).tolist()
            parts.append(
                {
                    "t": ti,
                    "force": dict(zip(_AXES, wi[:3], strict=True)),
                    "torque": dict(zip(_AXES, wi[3:], strict=True)),
                }
                for ti, wi in zip(t_list, w, strict=True)
            )
        if self.dither:
            parts.append(
                {"t": ti, "active": bool(d)}
                for ti, d in zip(t_list, data["dither"].tolist(), strict=True)
            )
        if self.extras:
            names = [str(c) for c in self.extras]
            cols = [_encode_extra(data[c].tolist(), data[c].dtype.kind) for c in self.extras]
            parts.append(
                {"t": ti, **dict(zip(names, vals, strict=True))}
                for ti, *vals in zip(t_list, *cols, strict=True)
            )
        return zip(stamps, zip(*parts, strict=True), strict=True)


def write(rec: Recording, path: Path) -> Path:
    """Write ``rec`` atomically as a ditherlab MCAP file (layout in the module docstring):
    :func:`write_frames` with the whole table as one block."""
    return write_frames([rec.data], rec.meta, path, name=rec.name)


def write_frames(
    frames: Iterable[pd.DataFrame],
    meta: dict[str, Any],
    path: Path,
    name: str | None = None,
) -> Path:
    """Write a recording given as consecutive blocks of its table, atomically, as a ditherlab
    MCAP file; memory holds one block (and the writer's current chunk, 1 MiB).

    Parameters
    ----------
    frames : the table's rows in order, in blocks with the same columns and dtypes (a contract
        checked :class:`~ditherlab.data.recording.Recording` table: ``t`` (N,) [s], ``q_j`` [rad], ...)
    meta : the recording's metadata ; path : the ``.mcap`` file to write
    name : the recording's name (stored, and named in errors; default ``path``)

    The file depends only on the rows, not on how they are cut into blocks. Raises ConfigError
    for an extra column MCAP cannot store and FormatError for a block whose columns or dtypes
    differ from the first block's; the target is then untouched.
    """
    path = Path(path)
    where = name or str(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        enc: _Encoder | None = None
        # CRCs of every chunk, the data section and the summary: a reader finds a damaged byte
        w = Writer(f, compression=CompressionType.ZSTD, enable_crcs=True, enable_data_crcs=True)
        channel: list[int] = []
        start = 0
        for data in frames:
            if enc is None:
                enc = _Encoder(data, path, where)
                w.start(profile=PROFILE, library=f"ditherlab {__version__}")
                for topic in enc.topics:
                    schema_name, schema = SCHEMAS[topic]
                    sid = w.register_schema(schema_name, "jsonschema", json.dumps(schema).encode())
                    channel.append(w.register_channel(topic, "json", sid))
            else:
                enc.check(data, start)
            for i, (ns, bodies) in enumerate(enc.rows(data), start):
                for cid, body in zip(channel, bodies, strict=True):
                    w.add_message(
                        cid,
                        log_time=ns,
                        publish_time=ns,
                        sequence=i,
                        data=json.dumps(body, allow_nan=False).encode(),
                    )
            start += len(data)
        if enc is None or start == 0:
            raise FormatError(f"{where}: the recording has no rows; nothing to write to {path}")
        w.add_metadata(
            "ditherlab",
            {
                "format": LAYOUT_VERSION,
                "recording": dumps_meta(meta),
                "columns": json.dumps(enc.columns),
                "name": name or "",
            },
        )
        w.finish()
    return path


# ------------------------------------------------------------------------------ read
#: what a damaged file makes the mcap library (or zstandard, json) raise
_DAMAGE = (
    McapError,
    ZstdError,
    struct.error,
    ValueError,
    EOFError,
    OSError,
    KeyError,
    MemoryError,  # a damaged record length: the library reads that many bytes
)
_FAST_COMPRESSIONS = ("zstd", "")  # chunks _messages decompresses itself
_RECORD = struct.Struct("<BQ")  # opcode, length
_MESSAGE = struct.Struct("<HI")  # channel id, sequence (then log time, publish time, data)


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
        raise FormatError(f"{path}: not a readable MCAP file ({one_line(exc)})") from None
    encodings = {s.encoding for s in summary.schemas.values()} if summary else set()
    return profile, encodings


def profile_text(profile: str, encodings: set[str]) -> str:
    """What an MCAP file holds, by its :func:`header_profile`, for a message."""
    return f"MCAP profile {profile!r} with schema encodings {sorted(encodings) or 'none'}"


def _check(path: Path) -> str | None:
    """None for a ditherlab MCAP file (profile ``ditherlab``), else what the file holds;
    FormatError when it is not a readable MCAP file."""
    profile, encodings = header_profile(path)
    return None if profile == PROFILE else profile_text(profile, encodings)


@dataclass
class Layout:
    """What a ditherlab MCAP file holds, from its summary and metadata record (no message read
    when the summary has statistics): the file opened for reading in blocks of rows
    (:class:`ditherlab.io.format.Table`).

    Attributes
    ----------
    path : the file ; meta : the recording's metadata (reader options applied)
    dtypes : ``[name, dtype]`` of the table's columns, in order
    counts : messages per topic ; n_rows : samples (messages on ``/ditherlab/joints``)
    """

    path: Path
    meta: dict[str, Any]
    dtypes: list[list[str]]
    counts: dict[str, int]
    n_rows: int
    t = None
    rec = None

    @property
    def name(self) -> str:
        """The file, for messages."""
        return str(self.path)

    @property
    def columns(self) -> list[str]:
        """The column names, in table order."""
        return [c for c, _ in self.dtypes]

    def frames(self, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
        """:func:`frames` of this file."""
        return frames(self, rows, columns)


def layout(path: Path, **options: Any) -> Layout:
    """The :class:`Layout` of a ditherlab MCAP file (options as for :func:`read`).

    Raises FormatError naming the file when it is truncated, corrupt, not a ditherlab MCAP file,
    or a channel has other than one message per sample.
    """
    path = Path(path)
    check_options(options, META_OPTIONS, "MCAP", str(path))
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
            _check_summary_crc(f, path)
            records = [m for m in reader.iter_metadata() if m.name == "ditherlab"]
            counts: dict[str, int] = {}
            if summary.statistics is not None:
                for cid, k in summary.statistics.channel_message_counts.items():
                    topic = summary.channels[cid].topic
                    counts[topic] = counts.get(topic, 0) + k
            else:  # no statistics: count the messages (one pass, nothing kept)
                for topic, _, _ in _messages(f, {c.topic for c in summary.channels.values()}):
                    counts[topic] = counts.get(topic, 0) + 1
    except FormatError:
        raise
    except _DAMAGE as exc:
        raise FormatError(
            f"{path}: the MCAP file is truncated or corrupt ({one_line(exc)})"
        ) from None
    if not records:
        raise FormatError(f"{path}: MCAP metadata record 'ditherlab' is missing")
    info = records[-1].metadata
    stored = loads_meta(info.get("recording", ""), str(path))
    meta = meta_from_options(stored, options, where=str(path))
    try:
        columns = json.loads(info.get("columns", "[]"))
        columns = [[str(c), str(d)] for c, d in columns]
    except (ValueError, TypeError) as exc:
        raise FormatError(
            f"{path}: MCAP metadata 'columns' is not a JSON list of [name, dtype] ({one_line(exc)})"
        ) from None
    n_rows = counts.get(JOINTS, 0)
    if not n_rows:
        raise FormatError(f"{path}: channel {JOINTS} has no messages")
    for topic, k in counts.items():
        if k != n_rows:
            raise FormatError(
                f"{path}: channel {topic} has {k} messages, expected one per sample ({n_rows})"
            )
    return Layout(path, meta, columns, counts, n_rows)


_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, summary offset start, CRC


def _check_summary_crc(f: BinaryIO, path: Path) -> None:
    """FormatError when the summary section (channels, statistics, chunk indexes) does not
    match the CRC in the footer (the mcap library does not check it); a CRC of 0 means none was
    written."""
    f.seek(0, 2)
    size = f.tell()
    f.seek(size - 8 - _FOOTER.size)
    _op, _n, start, _offsets, crc = _FOOTER.unpack(f.read(_FOOTER.size))
    if not crc or not start:
        return
    f.seek(start)
    got = zlib.crc32(f.read(size - 8 - 4 - start))
    if got != crc:
        raise FormatError(
            f"{path}: the MCAP file is corrupt: its summary section has CRC {got}, the footer "
            f"says {crc}"
        )


def _topic(column: str) -> str:
    """The channel that stores ``column`` (the module docstring's layout)."""
    if column == "t" or _JOINT_COL.match(column):
        return JOINTS
    if column in WRENCH_COLUMNS:
        return WRENCH
    return DITHER if column == "dither" else EXTRA


def frames(lay: Layout, rows: int, columns: list[str] | None = None) -> Iterator[pd.DataFrame]:
    """The table of a ditherlab MCAP file in consecutive blocks of ``rows`` rows (the last one
    shorter), optionally only some ``columns``; only the channels those columns need are read.

    The messages are taken in file order (the order they were written: row order); on each
    channel message ``k`` must have ``sequence == k``, so the channels stay aligned row by row.
    Memory holds one block and one decompressed chunk. Raises FormatError naming the file for a
    damaged chunk (CRC, decompression), a message out of place, or a message count that differs
    from the summary's.
    """
    path = lay.path
    dtypes = dict((c, d) for c, d in lay.dtypes)
    if columns is None:
        cols = lay.dtypes
        topics = list(lay.counts)  # every channel, so every message is counted
    else:
        missing = [c for c in columns if c not in dtypes]
        if missing:
            raise FormatError(
                f"{path}: no column {missing[0]} (columns: {', '.join(dtypes) or 'none'})"
            )
        cols = [[c, dtypes[c]] for c in columns]
        topics = list(dict.fromkeys(_topic(c) for c in columns))
    for c, _ in cols:
        if _topic(c) not in lay.counts:
            raise FormatError(f"{path}: column {c} is listed in the metadata but not stored")
    pending: dict[str, list[bytes]] = {t: [] for t in topics}
    seen = dict.fromkeys(topics, 0)
    try:
        with open(path, "rb") as f:
            for topic, sequence, data in _messages(f, set(topics)):
                k = seen[topic]
                if sequence != k:
                    raise FormatError(
                        f"{path}: message {k + 1} on channel {topic} has sequence "
                        f"{sequence}, expected {k} (one message per sample, in row order)"
                    )
                seen[topic] = k + 1
                pending[topic].append(data)
                if len(pending[topic]) >= rows and all(len(v) >= rows for v in pending.values()):
                    batch = {t: _decode(v[:rows]) for t, v in pending.items()}
                    for v in pending.values():
                        del v[:rows]
                    yield _table(batch, cols, path)
            if any(seen[t] != lay.counts[t] for t in topics):
                raise FormatError(
                    f"{path}: the MCAP file is corrupt: {sum(seen.values())} messages read, "
                    f"{sum(lay.counts[t] for t in topics)} listed in its summary"
                )
            if pending[topics[0]]:
                yield _table({t: _decode(v) for t, v in pending.items()}, cols, path)
    except FormatError:
        raise
    except _DAMAGE as exc:
        raise FormatError(
            f"{path}: the MCAP file is truncated or corrupt ({one_line(exc)})"
        ) from None


def _messages(f: BinaryIO, topics: set[str]) -> Iterator[tuple[str, int, bytes]]:
    """``(topic, sequence, data)`` of the messages on ``topics``, in file order, one chunk
    decompressed (and its CRC checked) at a time, following the summary's chunk indexes.

    The records inside a chunk are parsed here (opcode, length, then a message's channel id,
    sequence, log and publish time, data: the MCAP specification): the mcap library's record
    objects cost about half the time of a read. A file without chunk indexes, or with chunks
    compressed otherwise than ditherlab writes them (zstd) or uncompressed, is read with the
    library's linear reader (the same messages, slower).
    """
    f.seek(0)
    summary = SeekingReader(f, validate_crcs=True).get_summary()
    assert summary is not None  # layout() refused a file without one
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    if not chunks or any(c.compression not in _FAST_COMPRESSIONS for c in chunks):
        f.seek(0)
        for _schema, ch, m in NonSeekingReader(f, validate_crcs=True).iter_messages(
            topics=list(topics), log_time_order=False
        ):
            yield ch.topic, m.sequence, m.data
        return
    wanted = {cid: ch.topic for cid, ch in summary.channels.items() if ch.topic in topics}
    for ci in chunks:
        if ci.message_index_offsets and not wanted.keys() & ci.message_index_offsets.keys():
            continue  # the chunk's message indexes list none of the wanted channels
        f.seek(ci.chunk_start_offset)
        if f.read(1)[0] != Opcode.CHUNK:
            raise McapError(f"no chunk record at offset {ci.chunk_start_offset}")
        f.seek(8, 1)  # the record length
        buf = _chunk_bytes(Chunk.read(ReadDataStream(f)))
        pos, size = 0, len(buf)
        while pos < size:
            op, length = _RECORD.unpack_from(buf, pos)
            pos += 9
            if op == Opcode.MESSAGE:
                cid, seq = _MESSAGE.unpack_from(buf, pos)
                if cid in wanted:
                    yield wanted[cid], seq, buf[pos + 22 : pos + length]
            pos += length
        if pos != size:
            raise McapError(f"a record overruns the chunk at offset {ci.chunk_start_offset}")


def _chunk_bytes(chunk: Chunk) -> bytes:
    """A chunk's records, decompressed; McapError when its CRC or size does not match."""
    if chunk.compression == "zstd":
        data = zstandard.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "":
        data = chunk.data
    else:  # not reached: _messages reads other compressions with the library
        raise McapError(f"unknown chunk compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise McapError(f"a chunk holds {len(data)} bytes, {chunk.uncompressed_size} expected")
    if not chunk.uncompressed_crc:  # ditherlab writes one for every chunk
        raise McapError("a chunk has no CRC (ditherlab MCAP files are written with chunk CRCs)")
    crc = zlib.crc32(data)
    if crc != chunk.uncompressed_crc:
        raise McapError(f"chunk CRC {crc} does not match the stored {chunk.uncompressed_crc}")
    return data


def _decode(datas: list[bytes], step: int = 16384) -> list[Any]:
    """The JSON bodies of messages, decoded ``step`` at a time in one call each (a JSON array of
    them); one at a time when that does not give one value per message, so a bad message fails
    on its own."""
    out: list[Any] = []
    for a in range(0, len(datas), step):
        part = datas[a : a + step]
        try:
            values = json.loads(b"[" + b",".join(part) + b"]")
        except ValueError:
            values = None
        if values is None or len(values) != len(part):
            values = [json.loads(d) for d in part]
        out += values
    return out


def read(path: Path, **options: Any) -> Recording:
    """Read a ditherlab MCAP file whole (:func:`frames` with one block of all rows).

    Options ``robot``, ``tool_offset``, ... override the stored metadata. Raises FormatError
    naming the file when it is truncated, corrupt, or not a ditherlab MCAP file.
    """
    lay = layout(path, **options)
    (data,) = list(frames(lay, lay.n_rows))
    return Recording(data, lay.meta, name=str(path))


def _is_float(dtype: str) -> bool:
    try:
        return np.dtype(dtype).kind == "f"
    except TypeError:
        return False


def _table(
    batch: dict[str, list[dict[str, Any]]], columns: list[list[str]], path: Path
) -> pd.DataFrame:
    """The one definition of how messages become columns: the rows of ``batch`` (per topic, the
    same rows' message bodies, in order) as a table of ``columns`` (``[name, dtype]``)."""
    try:
        return _columns(batch, columns, path)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise FormatError(
            f"{path}: a message does not match the ditherlab MCAP layout "
            f"({type(exc).__name__}: {exc})"
        ) from None


def _columns(
    batch: dict[str, list[dict[str, Any]]], columns: list[list[str]], path: Path
) -> pd.DataFrame:
    want = {name for name, _ in columns}
    cols: dict[str, Any] = {}
    joints = batch.get(JOINTS)
    if joints:
        if "t" in want:
            cols["t"] = [m["t"] for m in joints]
        for p in JOINT_FAMILIES:
            if p in joints[0] and any(_topic_family(c) == p for c in want):
                block = np.array([m[p] for m in joints], dtype=float)
                for j in range(block.shape[1]):
                    cols[f"{p}_{j + 1}"] = block[:, j]
    if WRENCH in batch:
        for k, c in enumerate(WRENCH_COLUMNS):
            if c in want:
                part, axis = ("force", "torque")[k // 3], _AXES[k % 3]
                cols[c] = [m[part][axis] for m in batch[WRENCH]]
    if DITHER in batch and "dither" in want:
        cols["dither"] = [m["active"] for m in batch[DITHER]]
    extra_rows = batch.get(EXTRA, [])
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


def _topic_family(column: str) -> str | None:
    m = _JOINT_COL.match(column)
    return m.group(1) if m else None


FORMAT = Format(
    name="mcap",
    title="a ditherlab MCAP file (profile 'ditherlab')",
    read=read,
    suffixes=(".mcap",),
    magic=(MAGIC,),
    check=_check,
    open=layout,
    write=write,
    output_suffixes=(".mcap",),
    write_stream=write_frames,
)
