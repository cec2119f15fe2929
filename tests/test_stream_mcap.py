"""ditherlab MCAP read and written in pieces (ditherlab.io.mcap through ditherlab.io.stream): the
blocks and every command's results equal the whole read, the incremental writer makes the bytes
of the whole write, and a damaged file is one line naming it."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from mcap.reader import SeekingReader
from mcap.writer import CompressionType, Writer
from test_stream import _awkward_cuts

from ditherlab.core.errors import FormatError
from ditherlab.data.estimates import Estimates
from ditherlab.io import mcap as mcap_io
from ditherlab.io import read, write
from ditherlab.io.stream import Source, open_source, write_stream


@pytest.fixture(scope="module")
def mc(tmp_path_factory):
    """A dithered push campaign simulated through the CLI, converted to MCAP through the CLI in
    pieces, and a model identified on another campaign."""
    from conftest import run_cli

    d = tmp_path_factory.mktemp("stream_mcap")
    pq_path, ident, model, path = (
        d / "rec.parquet",
        d / "ident.parquet",
        d / "m.toml",
        d / "rec.mcap",
    )
    for seed, out in ((23, pq_path), (24, ident)):
        args = ("--seed", str(seed), "--pushes-per-direction", "2", "-o", out, "-q")
        r = run_cli("simulate", "push-campaign", *args)
        assert r.code == 0, r.err
    r = run_cli("identify", ident, "-o", model, "--bootstrap", "0", "-q")
    assert r.code == 0, r.err
    r = run_cli("convert", pq_path, path, "--chunk", "2222")
    assert r.code == 0, r.err
    return d, pq_path, path, model


def test_source_counts_rows_from_the_summary_without_reading_messages(mc, monkeypatch):
    _, pq_path, path, _ = mc
    ref = read(pq_path)

    def no_messages(*args, **kwargs):
        raise AssertionError("a message was read")

    monkeypatch.setattr(mcap_io, "_messages", no_messages)
    monkeypatch.setattr(mcap_io, "NonSeekingReader", no_messages)
    src = open_source(path)
    assert src.bounded and src.kind == "mcap"
    assert src.n_rows == len(ref)
    assert src.columns == list(ref.data.columns)
    assert src.meta == ref.meta


def test_frames_equal_the_whole_read(mc):
    """Blocks of any length, cut inside a push, a dither period and a stick, are the rows of the
    whole read (values and dtypes), which is the Parquet recording converted."""
    _, pq_path, path, _ = mc
    ref = read(pq_path).data
    whole = mcap_io.read(path).data
    pd.testing.assert_frame_equal(whole, ref, check_exact=True)
    assert list(whole.dtypes) == list(ref.dtypes) and whole["push"].dtype == np.int64
    src = open_source(path)
    n = len(ref)
    for rows in (997, *_awkward_cuts(read(pq_path)).values(), n - 1, n, n + 5):
        blocks = list(src.frames(rows))
        assert [len(b) for b in blocks[:-1]] == [rows] * (len(blocks) - 1)
        assert 0 < len(blocks[-1]) <= rows and len(blocks) == -(-n // rows)
        for k, b in enumerate(blocks):
            part = ref.iloc[k * rows : (k + 1) * rows].reset_index(drop=True)
            pd.testing.assert_frame_equal(b, part, check_exact=True)
    for cols in (["t"], ["dither", "f_z"], ["push", "q_3", "t", "tau_ffw_6"]):
        got = pd.concat(list(src.frames(1234, cols)), ignore_index=True)
        pd.testing.assert_frame_equal(got, ref[cols], check_exact=True)
    pd.testing.assert_frame_equal(src.read().data, ref, check_exact=True)
    with pytest.raises(FormatError, match=rf"^{path}: no column nope \(columns: t, q_1,"):
        next(src.frames(100, ["nope"]))


def test_frames_read_one_block_at_a_time(mc, monkeypatch):
    """The first block of 500 rows is handed out once 500 messages on each of the 4 channels
    have been read: nothing is read ahead (as a whole read, taking every message first, would)."""
    _, _, path, _ = mc
    pulled = [0]
    messages = mcap_io._messages

    def counting(*args, **kwargs):
        for m in messages(*args, **kwargs):
            pulled[0] += 1
            yield m

    src = open_source(path)
    monkeypatch.setattr(mcap_io, "_messages", counting)
    it = src.frames(500)
    assert len(next(it)) == 500 and pulled[0] == 500 * 4
    assert len(next(it)) == 500 and pulled[0] == 1000 * 4
    it.close()
    pulled[0] = 0
    t = pd.concat(list(src.frames(700, ["t"])))
    assert pulled[0] == len(t) == src.n_rows  # only /ditherlab/joints is read for t


def test_cli_convert_to_mcap_in_pieces_is_the_whole_write(mc, cli):
    """convert writes MCAP piece by piece: the file is byte for byte the whole write's, for any
    chunk; converted back (in pieces) it is the Parquet recording."""
    d, pq_path, path, _ = mc
    n = len(read(pq_path))
    ref = write(read(pq_path), d / "ref.mcap")
    whole = d / "whole.mcap"
    assert cli("convert", pq_path, whole, "--chunk", str(n)).code == 0
    assert path.read_bytes() == ref.read_bytes() == whole.read_bytes()
    assert read(path).equals(read(pq_path))
    back = d / "back.parquet"
    r = cli("convert", path, back, "--chunk", "2222")
    assert r.code == 0, r.err
    got, want = read(back), read(pq_path)
    assert got.equals(want) and list(got.data.dtypes) == list(want.data.dtypes)
    src = open_source(pq_path)

    def whole(*args):
        raise AssertionError("the whole recording was read")

    with pytest.MonkeyPatch.context() as mp:  # written piece by piece, never read whole
        mp.setattr(Source, "read", whole)
        again = write_stream(src, d / "again.mcap", rows=3001)
    assert again.read_bytes() == ref.read_bytes()
    assert sorted(p.name for p in d.iterdir() if p.name.startswith(".")) == []


def test_cli_replay_identify_and_info_on_mcap_in_pieces_equal_the_whole(mc, cli):
    """replay, identify and info on the MCAP file with a small --chunk (cut inside a push) give
    the whole read's results, which are the Parquet file's."""
    d, pq_path, path, model = mc
    rec = read(pq_path)
    rows = _awkward_cuts(rec)["push"]
    outs = {}
    for name, src, chunk in (
        ("pq", pq_path, len(rec)),
        ("whole", path, len(rec)),
        ("cut", path, rows),
    ):
        out = d / f"est_{name}.parquet"
        r = cli("replay", src, "--model", model, "-o", out, "-q", "--chunk", str(chunk))
        assert r.code == 0, r.err
        outs[name] = (r.out.splitlines()[:-1], Estimates.load(out))
    assert outs["whole"][0] == outs["cut"][0]
    for name in ("whole", "cut"):
        pd.testing.assert_frame_equal(outs[name][1].data, outs["pq"][1].data, check_exact=True)
    assert len(outs["cut"][1].meta["moving_spans"]) > 3

    texts = {}
    for name, chunk in (("whole", 10 * len(rec)), ("cut", rows)):
        out = d / f"model_{name}.toml"
        args = ("identify", path, "--bootstrap", "3", "--seed", "2", "-q", "-o", out)
        r = cli(*args, "--chunk", str(chunk))
        assert r.code == 0, r.err
        texts[name] = out.read_text()
    assert texts["whole"] == texts["cut"]

    info = {}
    for name, src, chunk in (
        ("pq", pq_path, len(rec)),
        ("whole", path, len(rec)),
        ("cut", path, 2222),
    ):
        r = cli("info", src, "--json", "--chunk", str(chunk))
        assert r.code == 0, r.err
        info[name] = json.loads(r.out)
        info[name].pop("file")
    reg = {k: v.pop("regimes") for k, v in info.items()}
    assert info["pq"] == info["whole"] == info["cut"]
    assert reg["whole"] == reg["pq"] and reg["cut"] == pytest.approx(reg["whole"], abs=1e-12)


def _middle_chunk(path) -> tuple[int, int]:
    with open(path, "rb") as f:
        summary = SeekingReader(f).get_summary()
    assert summary is not None and len(summary.chunk_indexes) > 4
    ci = summary.chunk_indexes[len(summary.chunk_indexes) // 2]
    return ci.chunk_start_offset, ci.chunk_length


@pytest.mark.parametrize("damage", ["truncated", "flipped"])
def test_damaged_mcap_is_one_line_through_the_cli(mc, cli, tmp_path, damage):
    """A truncated file, or one with a byte flipped in a chunk half way through (found once some
    pieces were handed out), is one line naming the file, exit status 2, nothing written."""
    _, _, path, model = mc
    data = bytearray(path.read_bytes())
    if damage == "truncated":
        data = data[: int(len(data) * 0.6)]
    else:
        start, length = _middle_chunk(path)
        data[start + length // 2] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    runs = [
        ("info", bad, "--chunk", "2222"),
        ("convert", bad, tmp_path / "out.parquet", "--chunk", "2222"),
        ("convert", bad, tmp_path / "out.mcap", "--chunk", "2222"),
        ("replay", bad, "--model", model, "-o", tmp_path / "est.parquet", "-q", "--chunk", "2222"),
    ]
    for args in runs:
        r = cli(*args)
        assert r.code == 2, (args, r.err)
        assert r.err.count("\n") == 1 and "Traceback" not in r.err, r.err
        assert r.err.startswith(f"error: {bad}: the MCAP file is truncated or corrupt ("), r.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap"]


def _rewrite(src, dst, *, drop=None, swap=None, statistics=True, **writer):
    """Copy a ditherlab MCAP message by message: ``drop`` = (topic, k) leaves out the k-th
    message of a channel, ``swap`` = (topic, k) writes its messages k and k+1 in each other's
    place (their sequence numbers kept), ``statistics=False`` writes no statistics record,
    ``writer`` goes to the mcap Writer (compression, use_chunking)."""
    with open(src, "rb") as f:
        reader = SeekingReader(f)
        summary = reader.get_summary()
        meta = [m for m in reader.iter_metadata()]
        msgs = [(ch.topic, m) for _, ch, m in reader.iter_messages(log_time_order=True)]
    seen: dict[str, list[int]] = {}
    for i, (topic, _) in enumerate(msgs):
        seen.setdefault(topic, []).append(i)
    if swap:
        a, b = seen[swap[0]][swap[1]], seen[swap[0]][swap[1] + 1]
        msgs[a], msgs[b] = msgs[b], msgs[a]
    if drop:
        del msgs[seen[drop[0]][drop[1]]]
    with open(dst, "wb") as f:
        opts = {"compression": CompressionType.ZSTD, "use_statistics": statistics, **writer}
        w = Writer(f, **opts)
        w.start(profile="ditherlab", library="test")
        ids = {}
        for ch in summary.channels.values():
            s = summary.schemas[ch.schema_id]
            sid = w.register_schema(s.name, s.encoding, s.data)
            ids[ch.topic] = w.register_channel(ch.topic, ch.message_encoding, sid)
        for topic, m in msgs:
            w.add_message(ids[topic], m.log_time, m.data, m.publish_time, m.sequence)
        for m in meta:
            w.add_metadata(m.name, m.metadata)
        w.finish()
    return dst


def test_channels_must_stay_aligned_row_by_row(mc, tmp_path):
    """A channel missing a message, or messages out of row order, fail the same way read whole
    and in blocks; a file without statistics is counted and read the same."""
    d, pq_path, path, _ = mc
    ref = read(pq_path).data
    n = len(ref)
    plain = _rewrite(path, tmp_path / "nostats.mcap", statistics=False)
    with open(plain, "rb") as f:
        assert SeekingReader(f).get_summary().statistics is None
    src = open_source(plain)
    assert src.n_rows == n
    pd.testing.assert_frame_equal(pd.concat(list(src.frames(999)), ignore_index=True), ref)

    short = _rewrite(path, tmp_path / "short.mcap", drop=("/ditherlab/dither", 4321))
    msg = rf"^{short}: channel /ditherlab/dither has {n - 1} messages, expected one per sample \({n}\)$"
    with pytest.raises(FormatError, match=msg):
        read(short)
    with pytest.raises(FormatError, match=msg):
        open_source(short)

    swapped = _rewrite(path, tmp_path / "swapped.mcap", swap=("/ditherlab/wrench", 5000))
    msg = (
        rf"^{swapped}: message 5001 on channel /ditherlab/wrench has sequence 5001, expected "
        r"5000 \(one message per sample, in row order\)$"
    )
    with pytest.raises(FormatError, match=msg):
        read(swapped)
    src = open_source(swapped)
    blocks = src.frames(2000)
    assert len(next(blocks)) == 2000 and len(next(blocks)) == 2000  # rows before it are fine
    with pytest.raises(FormatError, match=msg):
        next(blocks)


def test_write_stream_refuses_a_column_that_changes_type(mc, tmp_path):
    """A CSV extra column of integers that meets an empty cell late in the file becomes float in
    that block: the MCAP written in pieces stops with the column and row named, nothing left."""
    _, pq_path, _, _ = mc
    rec = read(pq_path)
    csv = write(rec, tmp_path / "a.csv")
    lines = csv.read_text().splitlines()
    head = lines[0].split(",")
    k = head.index("push")
    row = lines[9000].split(",")
    row[k] = ""
    lines[9000] = ",".join(row)
    csv.write_text("\n".join(lines) + "\n")
    out = tmp_path / "a.mcap"
    with pytest.raises(FormatError, match=rf"^{csv}: column push changes type at row \d+ "):
        write_stream(open_source(csv), out, rows=3000)
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize(
    "writer",
    [
        {"compression": CompressionType.LZ4},
        {"compression": CompressionType.NONE},
        {"use_chunking": False},
    ],
)
def test_mcap_written_otherwise_reads_the_same(mc, tmp_path, writer):
    """lz4 chunks and a file without chunks go through the mcap library's reader, uncompressed
    chunks through ours: the same blocks."""
    _, pq_path, path, _ = mc
    ref = read(pq_path).data
    other = _rewrite(path, tmp_path / "other.mcap", **writer)
    src = open_source(other)
    assert src.bounded and src.n_rows == len(ref)
    got = pd.concat(list(src.frames(1500)), ignore_index=True)
    pd.testing.assert_frame_equal(got, ref, check_exact=True)
    got = pd.concat(list(src.frames(4000, ["t", "f_y"])), ignore_index=True)
    pd.testing.assert_frame_equal(got, ref[["t", "f_y"]], check_exact=True)
