"""The readers' hard cases from the fuzz suite (``tests/fuzz``): each input below, one a reader
could easily answer with a traceback, a hang, a multi-line error or a wrong acceptance, ends in
exactly one line ``error: ...`` on stderr and exit status 2, with the input untouched."""

from __future__ import annotations

import json
import re
import struct
import time
import zlib
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import ditherlab.io as dio
from ditherlab.core.errors import FormatError, RecordingError
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.io.stream import open_source

DATA = Path(__file__).resolve().parent / "data"
META = {"schema": "ditherlab.recording/1", "robot": "irb140"}


@pytest.fixture(scope="module")
def rec() -> Recording:
    """A small valid IRB140 recording: 300 rows at 250 Hz, q slowly moving, tau noisy."""
    rng = np.random.default_rng(0)
    t = np.arange(300) * 0.004
    q = 0.3 * np.sin(np.outer(t, np.arange(1, 7)) * 0.5)
    tau = rng.normal(0, 1, (300, 6))
    return Recording.from_arrays(RecordingArrays(t, q, tau), META)


def one_error(cli, *args) -> str:
    """Run the CLI; assert exit 2, nothing on stdout, one stderr line; return that line."""
    r = cli(*args)
    assert r.code == 2, (r.code, r.out, r.err)
    assert r.out == "" and "Traceback" not in r.err
    lines = r.err.splitlines()
    assert len(lines) == 1, r.err
    return lines[0]


def unchanged(path: Path, before: bytes) -> None:
    assert path.read_bytes() == before


# ------------------------------------------------------------------ Parquet
def test_corrupt_parquet_page_header_is_one_line(cli, tmp_path, rec):
    """A damaged page header: pyarrow's message runs over two lines ("Couldn't deserialize
    thrift: ...\\nDeserializing page header failed.\\n"); the error is its first line."""
    p = tmp_path / "a.parquet"
    dio.write(rec, p)
    off = pq.ParquetFile(p).metadata.row_group(0).column(1).data_page_offset
    data = bytearray(p.read_bytes())
    data[off] ^= 0xFF
    p.write_bytes(bytes(data))
    for cmd in (["info"], ["convert"], ["view"]):
        out = [tmp_path / "o.csv"] if cmd == ["convert"] else []
        save = ["--save", tmp_path / "v.rrd"] if cmd == ["view"] else []
        line = one_error(cli, *cmd, p, *out, *save)
        assert line == (
            f"error: {p}: not a readable Parquet file, truncated or corrupt (Couldn't "
            "deserialize thrift: TProtocolException: Invalid data)"
        ), line
    unchanged(p, bytes(data))
    assert not (tmp_path / "o.csv").exists() and not (tmp_path / "v.rrd").exists()
    with pytest.raises(FormatError) as exc:  # the whole-file reader: the same line
        dio.read(p)
    assert f"error: {exc.value}" == line


def test_parquet_number_stored_as_text_is_refused(cli, tmp_path, rec):
    """q_2 stored as text ("0.1", ...) is not converted to numbers without a word: it is refused
    naming the column and its Parquet type, by the whole-file and the piece readers alike."""
    table = pa.Table.from_pandas(rec.data, preserve_index=False)
    i = table.schema.get_field_index("q_2")
    table = table.set_column(i, "q_2", pa.array([repr(v) for v in rec.data["q_2"]]))
    table = table.replace_schema_metadata({b"ditherlab": json.dumps(META).encode()})
    p = tmp_path / "text.parquet"
    pq.write_table(table, p)
    want = f"error: {p}: column q_2 has Parquet type string, expected numbers (float64)"
    assert one_error(cli, "info", p) == want
    assert one_error(cli, "convert", p, tmp_path / "o.mcap") == want
    with pytest.raises(FormatError, match="column q_2 has Parquet type string"):
        dio.read(p)
    assert not (tmp_path / "o.mcap").exists()


def test_parquet_duplicated_column_is_refused(cli, tmp_path, rec):
    """Two columns named q_1 in a Parquet file: refused naming the column."""
    table = pa.Table.from_pandas(rec.data, preserve_index=False)
    table = table.append_column("q_1", table.column("q_1"))
    table = table.replace_schema_metadata({b"ditherlab": json.dumps(META).encode()})
    p = tmp_path / "dup.parquet"
    pq.write_table(table, p)
    assert one_error(cli, "info", p) == f"error: {p}: column q_1 appears more than once"


def test_parquet_duplicated_t_is_refused_before_t_is_read(cli, tmp_path, rec):
    """Two columns named t: the Source refuses a repeated name when it opens the file, before a
    piece reader could take "the" t column as a 2-D array (``ValueError: Data must be
    1-dimensional``, a traceback in view, identify, replay)."""
    table = pa.Table.from_pandas(rec.data.iloc[:1], preserve_index=False)
    table = table.append_column("t", table.column("t"))
    p = tmp_path / "dup_t.parquet"
    pq.write_table(table, p)  # no metadata: --robot
    want = f"error: {p}: column t appears more than once"
    assert one_error(cli, "view", p, "--robot", "irb140", "--save", tmp_path / "v.rrd") == want
    assert one_error(cli, "info", p, "--robot", "irb140") == want
    assert not (tmp_path / "v.rrd").exists()


# ------------------------------------------------------------------ CSV
def test_csv_duplicated_column_is_refused(cli, tmp_path, rec):
    """A second q_1 in the header, which pandas would rename q_1.1 (and then report "required
    column q_3 is missing"): the duplicate is named, with its two positions."""
    p = tmp_path / "dup.csv"
    dio.write(rec, p)
    lines = p.read_text().splitlines()
    names = lines[0].split(",")
    names[3] = "q_1"  # t, q_1, q_2, q_3 -> t, q_1, q_2, q_1
    lines[0] = ",".join(names)
    p.write_text("\n".join(lines) + "\n")
    want = (
        f"error: {p}: column q_1 appears more than once in the header line (fields 2 and 4); "
        "expected unique column names"
    )
    assert one_error(cli, "info", p) == want
    assert one_error(cli, "convert", p, tmp_path / "o.parquet") == want
    with pytest.raises(FormatError, match="column q_1 appears more than once"):
        dio.read(p)


def test_csv_row_of_200000_extra_fields_fails_fast(cli, tmp_path, rec):
    """One row with 200 000 extra fields: the first pass parses every field and stops at that
    row, rather than reading it column by column (pandas accepts a ragged row when reading some
    columns, slowly: seconds per pass, several passes) and failing later."""
    p = tmp_path / "long.csv"
    dio.write(rec, p)
    lines = p.read_text().splitlines()
    lines[3] += ",0" * 200_000
    p.write_text("\n".join(lines) + "\n")
    want = (
        f"{p}: not a readable CSV file (Error tokenizing data. C error: Expected 13 fields in "
        "line 4, saw 200013)"
    )
    t0 = time.process_time()  # CPU time of this process: the work, not the machine's load
    assert one_error(cli, "info", p) == f"error: {want}"
    assert time.process_time() - t0 < 20
    with pytest.raises(FormatError) as exc:  # the first pass, which reads t, says so
        open_source(p).times()
    assert str(exc.value) == want


# ------------------------------------------------------------------ time stamps
def test_repeated_time_stamps_are_named_not_divided_by(cli, tmp_path, rec):
    """Two rows with the same t: the contract's message, not a division by the median step (0)
    — a ZeroDivisionError in identify, replay, diagnose."""
    p = tmp_path / "two.parquet"
    data = rec.data.iloc[:2].copy()
    data.loc[1, "t"] = data.loc[0, "t"]
    table = pa.Table.from_pandas(data, preserve_index=False)
    pq.write_table(table.replace_schema_metadata({b"ditherlab": json.dumps(META).encode()}), p)
    want = (
        f"error: {p}: t is not strictly increasing: t=0.0 s in row 2 follows t=0.0 s "
        "(expected increasing sample times)"
    )
    assert one_error(cli, "identify", p, "-o", tmp_path / "m.toml", "--bootstrap", "0") == want
    assert one_error(cli, "info", p) == want
    assert not (tmp_path / "m.toml").exists()


# ------------------------------------------------------------------ MCAP
def _chunk_offsets(path: Path) -> list[int]:
    from mcap.reader import SeekingReader

    with open(path, "rb") as f:
        summary = SeekingReader(f).get_summary()
    return sorted(c.chunk_start_offset for c in summary.chunk_indexes)


def test_mcap_is_written_with_chunk_and_data_crcs(tmp_path, rec):
    """Every chunk carries the CRC of its records, and the data section's end its CRC."""
    from mcap.records import Chunk, DataEnd
    from mcap.stream_reader import StreamReader

    p = tmp_path / "a.mcap"
    dio.write(rec, p)
    with open(p, "rb") as f:
        records = list(StreamReader(f, emit_chunks=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert chunks and all(c.uncompressed_crc != 0 for c in chunks)
    (end,) = [r for r in records if isinstance(r, DataEnd)]
    assert end.data_section_crc != 0


def test_mcap_chunk_crc_is_checked_on_read(cli, tmp_path, rec):
    """A chunk whose records do not match its CRC: one line naming both CRCs."""
    p = tmp_path / "a.mcap"
    dio.write(rec, p)
    data = bytearray(p.read_bytes())
    off = _chunk_offsets(p)[0]
    # opcode, record length, message start and end time, uncompressed size, then the CRC
    crc_at = off + 1 + 8 + 8 + 8 + 8
    (stored,) = struct.unpack_from("<I", data, crc_at)
    struct.pack_into("<I", data, crc_at, stored ^ 1)
    p.write_bytes(bytes(data))
    line = one_error(cli, "info", p)
    assert line == (
        f"error: {p}: the MCAP file is truncated or corrupt (chunk CRC {stored} does not match "
        f"the stored {stored ^ 1})"
    )


def test_mcap_chunk_without_crc_is_refused(cli, tmp_path, rec):
    """ditherlab writes a CRC for every chunk: a chunk without one (the field zeroed) is not
    read unchecked."""
    p = tmp_path / "a.mcap"
    dio.write(rec, p)
    data = bytearray(p.read_bytes())
    crc_at = _chunk_offsets(p)[0] + 1 + 8 + 8 + 8 + 8
    struct.pack_into("<I", data, crc_at, 0)
    p.write_bytes(bytes(data))
    assert one_error(cli, "convert", p, tmp_path / "o.parquet") == (
        f"error: {p}: the MCAP file is truncated or corrupt (a chunk has no CRC (ditherlab MCAP "
        "files are written with chunk CRCs))"
    )
    assert not (tmp_path / "o.parquet").exists()


def test_mcap_summary_crc_is_checked(cli, tmp_path, rec):
    """A damaged byte in the summary section (channels, statistics, chunk indexes), which the
    mcap library reads without its CRC: refused."""
    p = tmp_path / "a.mcap"
    dio.write(rec, p)
    data = bytearray(p.read_bytes())
    _op, _n, start, _offsets, crc = struct.unpack_from("<BQQQI", data, len(data) - 8 - 29)
    # the message count of the statistics record (its first field), a plausible-looking change
    stats = data.index(bytes([0x0B]), start)
    data[stats + 9] ^= 0x01
    p.write_bytes(bytes(data))
    got = zlib.crc32(bytes(data[start : len(data) - 12]))
    assert one_error(cli, "info", p) == (
        f"error: {p}: the MCAP file is corrupt: its summary section has CRC {got}, the footer "
        f"says {crc}"
    )


# ------------------------------------------------------------------ ROS 2 bags
def test_bag_with_a_damaged_record_length_is_one_line(cli, tmp_path):
    """rosbag2's own cdr_test_0.mcap with bytes 219..357 removed: rosbags reads a record length
    from the wrong place and asks for that many bytes; one line, not a MemoryError traceback."""
    src = (DATA / "rosbag2" / "cdr_test_0.mcap").read_bytes()
    p = tmp_path / "cut.mcap"
    p.write_bytes(src[:219] + src[357:])
    assert one_error(cli, "info", p) == f"error: {p}: not a readable ROS 2 bag (MemoryError)"


def test_bag_record_longer_than_the_file_is_one_line(cli, tmp_path, rec):
    """A ROS 2 bag (MCAP storage) whose header record claims 1 000 000 bytes: rosbags' own
    ReaderError ("Truncated record") is among the errors caught — one line, not a traceback."""
    dio.write(rec, tmp_path / "bag", storage="mcap")
    p = tmp_path / "bag" / "bag.mcap"
    data = bytearray(p.read_bytes())
    struct.pack_into("<Q", data, 9, 10**6)  # the Header record's length (after the magic)
    p.write_bytes(bytes(data))
    line = one_error(cli, "info", p)
    assert re.fullmatch(
        rf"error: {re.escape(str(p))}: not a readable ROS 2 bag \(Truncated record at offset "
        r"17: expected 1000000 bytes, got \d+\.\)",
        line,
    ), line


def test_csv_whose_header_lost_a_comma_is_one_line(cli, tmp_path, rec):
    """``t,q_1`` written as ``tq_1``: the rows have one field more than the header, and pandas,
    asked for the first column only to count the rows, fails inside (a ValueError traceback
    "zip() argument 2 is shorter than argument 1"); the line with more fields than the header
    is named instead, before pandas reads the file."""
    p = tmp_path / "a.csv"
    dio.write(rec, p)
    text = p.read_text()
    p.write_text(text[:1] + text[2:])
    n = len(text.splitlines()[0].split(",")) - 1
    assert one_error(cli, "info", p) == (
        f"error: {p}: line 2 has {n + 1} fields but the header line has {n}; expected one field "
        "per column name on every line"
    )


def test_csv_first_line_wider_than_the_header_is_refused(cli, tmp_path, rec):
    """The first data line has more fields than the header: pandas would take the leading
    fields of every line as an index and shift the values under the wrong names, silently (t
    getting q_1's values). Refused by the whole-file and the piece reader."""
    p = tmp_path / "wide.csv"
    dio.write(rec, p)
    lines = p.read_text().splitlines()
    lines[1] += ",0,0"
    p.write_text("\n".join(lines) + "\n")
    want = (
        f"{p}: line 2 has 15 fields but the header line has 13; expected one field per column "
        "name on every line"
    )
    assert one_error(cli, "info", p) == f"error: {want}"
    with pytest.raises(FormatError) as exc:
        dio.read(p)
    assert str(exc.value) == want


def test_missing_joint_column_is_refused_by_a_reader_of_columns(cli, tmp_path, rec):
    """q_5 missing: a reader of columns refuses the file too (report reads t, the wrench and the
    dither flag through a Source, never a Recording): the Source checks the column names as the
    Recording does when it opens the file."""
    p = tmp_path / "no_q5.parquet"
    dio.write(rec, tmp_path / "full.parquet")
    table = pq.read_table(tmp_path / "full.parquet")
    pq.write_table(table.drop_columns(["q_5"]), p)
    want = f"{p}: required column q_5 is missing (found q_1..q_6, so q_1..q_6 [rad] are expected)"
    with pytest.raises(RecordingError) as exc:
        open_source(p)
    assert str(exc.value) == want
    assert one_error(cli, "view", p, "--save", tmp_path / "v.rrd") == f"error: {want}"


def test_nan_time_stamp_is_refused_by_a_reader_of_columns(cli, tmp_path, rec):
    """report and view read a recording's columns without building a Recording: Source.times()
    checks t as the Recording does, so a NaN time stamp is refused there too."""
    p = tmp_path / "nan.csv"
    dio.write(rec, p)
    lines = p.read_text().splitlines()
    cells = lines[6].split(",")
    cells[0] = "nan"
    lines[6] = ",".join(cells)
    p.write_text("\n".join(lines) + "\n")
    want = f"{p}: t has 1 NaN values in rows 6.."
    with pytest.raises(RecordingError) as exc:
        open_source(p).times()
    assert str(exc.value) == want
    assert one_error(cli, "view", p, "--save", tmp_path / "v.rrd") == f"error: {want}"
    assert not (tmp_path / "v.rrd").exists()


def test_no_numpy_warning_before_the_column_error(cli, tmp_path, rec):
    """A 5-joint log of an IRB140 with torques of 1e308 and a dither column: the search for the
    dither period (over the whole log, before any piece is checked) prints no numpy warning
    ("overflow encountered in reduce", ...) above the error line."""
    data = rec.data.drop(columns=["q_6", "tau_6"]).copy()
    data[[f"tau_{j}" for j in range(1, 6)]] = 1e308
    data["dither"] = (np.arange(len(data)) // 20) % 2 == 0
    p = tmp_path / "five.parquet"
    table = pa.Table.from_pandas(data, preserve_index=False)
    pq.write_table(table.replace_schema_metadata({b"ditherlab": json.dumps(META).encode()}), p)
    r = cli("convert", p, tmp_path / "o.csv")
    assert r.code == 2 and r.err == (
        f"error: {p}: robot 'irb140' has 6 joints but the recording has 5 (expected columns "
        "q_1..q_6)\n"
    ), r.err


# ------------------------------------------------------------------ estimates (Parquet)
def test_damaged_estimates_file_is_one_line_and_checked(tmp_path):
    """``report`` on an estimates file with a damaged page header: one line, not pyarrow's
    two-line message; and the estimates' pages carry checksums that are verified, so a damaged
    value is not read as another number."""
    from synthetic import push_recording

    from ditherlab.analysis.estimation import replay
    from ditherlab.analysis.identification import identify
    from ditherlab.data.estimates import Estimates

    rec, _ = push_recording(0, magnitudes=(5.0,), axes=("x",), signs=(1.0,))
    p = replay(rec.slice(0.0, 1.9), identify([rec], n_boot=0)).save(tmp_path / "e.parquet")
    good = p.read_bytes()
    col = pq.ParquetFile(p).metadata.row_group(0).column(1)
    data = bytearray(good)
    data[col.data_page_offset] ^= 0xFF
    p.write_bytes(bytes(data))
    with pytest.raises(FormatError) as exc:
        Estimates.load(p)
    assert str(exc.value) == (
        f"{p}: not a readable Parquet file, truncated or corrupt (Couldn't deserialize thrift: "
        "TProtocolException: Invalid data)"
    )
    data = bytearray(good)  # a byte of the page's values, its header intact
    data[col.data_page_offset + col.total_compressed_size - 8] ^= 0x01
    p.write_bytes(bytes(data))
    with pytest.raises(FormatError, match=r"^\S+: not a readable Parquet file, .*CRC checksum"):
        Estimates.load(p)


# ------------------------------------------------------------------ a header and no rows
def test_a_csv_of_its_header_line_only_is_one_line_everywhere(cli, tmp_path):
    """A CSV holding only its header line: every command that reads it (info, replay, convert,
    identify, view) says in one line that it holds no samples, exit 2, and writes nothing."""
    from ditherlab.data.torque_model import Band, TorqueModel

    csv = tmp_path / "empty.csv"
    csv.write_text("t," + ",".join(f"q_{j}" for j in range(1, 7)) + ","
                   + ",".join(f"tau_{j}" for j in range(1, 7)) + "\n")  # fmt: skip
    model = tmp_path / "m.toml"
    band = Band(-np.ones(6), np.ones(6), np.full(6, 0.1))
    TorqueModel("irb140", 6, regimes={"moving": band, "still": band}).save(model)
    before = {p.name for p in tmp_path.iterdir()}
    runs = [
        ["info", csv, "--robot", "irb140"],
        ["replay", csv, "--robot", "irb140", "--model", model, "-o", tmp_path / "e.parquet", "-q"],
        ["convert", csv, tmp_path / "c.parquet", "--robot", "irb140"],
        ["identify", csv, "--robot", "irb140", "--assume-no-force", "-o", tmp_path / "i.toml", "-q"],
        ["view", csv, "--robot", "irb140", "--save", tmp_path / "v.rrd", "-q"],
    ]  # fmt: skip
    for args in runs:
        line = one_error(cli, *args)
        assert line == (
            f"error: {csv}: the recording holds no samples (its columns and no rows); "
            "expected at least one row of data"
        ), (args[0], line)
    assert {p.name for p in tmp_path.iterdir()} == before


def test_an_unexpected_error_is_its_own_traceback(monkeypatch):
    """A bug (an exception that is not the user's) reaches Python as itself: the CLI's one-line
    handler matches its clauses without raising an error of its own on the way."""
    from ditherlab import cli as cli_module

    def boom():
        raise ZeroDivisionError("a bug")

    with pytest.raises(ZeroDivisionError, match="a bug"):
        cli_module._one_line_errors(boom)


def test_a_first_data_line_of_200000_fields_is_one_line(cli, tmp_path):
    """A first data line far longer than the header: counted before pandas reads the file (which
    would build an index of the 199 997 extra fields, for minutes), named in one line."""
    p = tmp_path / "wide.csv"
    p.write_text("t,q_1,tau_1\n" + ",".join(["1.0"] * 200_000) + "\n")
    before = p.read_bytes()
    line = one_error(cli, "info", p, "--robot", "irb140")
    assert line == (
        f"error: {p}: line 2 has 200000 fields but the header line has 3; "
        "expected one field per column name on every line"
    )
    unchanged(p, before)
