"""Recordings processed in pieces (ditherlab.io.stream): the pieces tile the recording, and every
command that reads in pieces gives exactly the whole-recording result, with the cuts placed
inside a dither period, a push and a stick."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ditherlab.analysis.identification import identify
from ditherlab.core.spill import Spill
from ditherlab.core.timeseries import causal_mean
from ditherlab.data.estimates import Estimates
from ditherlab.data.recording import Recording, regimes
from ditherlab.data.torque_model import TorqueModel
from ditherlab.io import read, write
from ditherlab.io.stream import open_source
from ditherlab.physics.dither import extract_dither

#: where the pieces are cut: ``make test`` cuts during a push; at the dither and in a stick
#: stretch the same checks run in the study tier (``make study``)
WHERE = [
    "push",
    pytest.param("dither", marks=pytest.mark.study),
    pytest.param("stick", marks=pytest.mark.study),
]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """A dithered push campaign and a model, both made through the CLI."""
    from conftest import run_cli

    d = tmp_path_factory.mktemp("stream")
    rec = d / "rec.parquet"
    r = run_cli(
        "simulate", "push-campaign", "--seed", "23", "--pushes-per-direction", "2", "-o", rec, "-q"
    )
    assert r.code == 0, r.err
    ident = d / "ident.parquet"
    r = run_cli(
        "simulate",
        "push-campaign",
        "--seed",
        "24",
        "--pushes-per-direction",
        "2",
        "-o",
        ident,
        "-q",
    )
    assert r.code == 0, r.err
    model = d / "model.toml"
    r = run_cli("identify", ident, "-o", model, "--bootstrap", "0", "-q")
    assert r.code == 0, r.err
    return d, rec, model


def _awkward_cuts(rec: Recording, first: int = 0) -> dict[str, int]:
    """Row counts whose first cut falls inside a push, inside a dither period (mid-period, the
    dither on) and inside a stick (a joint that stopped moving a moment ago), at or after row
    ``first``."""
    F = np.abs(rec.wrench[:, :3]).max(axis=1)
    push = np.flatnonzero(F > 5.0)
    on = np.flatnonzero(rec.dither)
    reg = regimes(rec)
    stopped = np.flatnonzero((reg[:-1, 1] == 2) & (reg[1:, 1] != 2)) + 1
    push, on, stopped = push[push >= first], on[on >= first], stopped[stopped >= first]
    rate = rec.sample_rate
    cuts = {
        "push": int(push[len(push) // 2]),
        "dither": int(on[len(on) // 3]) + int(0.03 * rate),
        "stick": int(stopped[len(stopped) // 2]) + 3 if len(stopped) else 3000,
    }
    return {k: max(v, 2100) for k, v in cuts.items()}


def test_pieces_tile_the_recording_and_see_its_whole_time_base(campaign):
    d, path, _ = campaign
    rec = read(path)
    # a jittered CSV without logged velocities: the derivative and period paths of the pieces
    jit = rec.data.drop(columns=[f"dq_{j}" for j in range(1, 7)]).copy()
    jit["t"] = jit["t"] + np.random.default_rng(1).uniform(0, 4e-4, len(jit))
    whole = Recording(jit, rec.meta)
    csv = write(whole, d / "jitter.csv")
    whole = read(csv)
    src = open_source(csv)
    assert src.n_rows == len(whole) and src.bounded
    pieces = list(src.pieces(rows=2345))
    assert [p.index for p in pieces] == list(range(len(pieces))) and pieces[0].count == len(pieces)
    owned = np.concatenate([p.rec.t[p.keep] for p in pieces])
    assert np.array_equal(owned, whole.t)
    ref_reg, ref_ext = regimes(whole), extract_dither(whole)
    for p in pieces:
        a, b = p.owned
        assert np.array_equal(regimes(p.rec)[p.keep], ref_reg[a:b])
        assert np.array_equal(p.rec.ddq[p.keep], whole.ddq[a:b])
        ext = extract_dither(p.rec)
        assert ext.period == ref_ext.period
        assert np.array_equal(ext.signal[p.keep], ref_ext.signal[a:b])
        assert np.array_equal(ext.valid[p.keep], ref_ext.valid[a:b])
    # one robot (URDF parsed once, one pinocchio model and result cache) for every piece
    assert all(p.rec.robot() is pieces[0].rec.robot() for p in pieces[1:])
    # one metadata object, checked and copied once, equal to the whole recording's
    assert all(p.rec.meta is pieces[0].rec.meta for p in pieces[1:])
    assert pieces[0].rec.meta == whole.meta and pieces[0].rec.meta is not src.meta
    assert np.array_equal(
        np.concatenate([p.rec.robot().gravity(p.rec.q)[p.keep] for p in pieces]),
        whole.robot().gravity(whole.q),
    )


def test_default_chunk_holds_four_contexts_at_5_khz(tmp_path):
    """At 5 kHz four 12 s contexts (diagnose's) are 240 004 rows, more than the default chunk:
    the default grows to them and the pieces still tile the log; a smaller chunk asked for is
    refused."""
    from ditherlab.core.errors import ConfigError
    from ditherlab.data.recording import RecordingArrays
    from ditherlab.io.format import CHUNK_ROWS

    n = 300_000  # 60 s at 5 kHz
    t = np.arange(n) / 5000.0
    q = np.tile([0.0, 0.3, 0.2, 0.0, 1.0, 0.0], (n, 1))
    rec = Recording.from_arrays(RecordingArrays(t, q, np.zeros((n, 6))), {"robot": "irb140"})
    src = open_source(write(rec, tmp_path / "fast.parquet"))
    pieces = list(src.pieces(halo_s=12.0))
    assert len(pieces) == 2 and pieces[0].owned == (0, 240_004)
    assert np.array_equal(np.concatenate([p.rec.t[p.keep] for p in pieces]), t)
    with pytest.raises(ConfigError, match="chunk size 65537 rows is below four times"):
        next(src.pieces(CHUNK_ROWS + 1, halo_s=12.0))


@pytest.mark.parametrize("where", ["push", "dither", "stick"])
def test_cli_replay_in_pieces_equals_the_whole(campaign, cli, where):
    d, path, model = campaign
    rec = read(path)
    rows = _awkward_cuts(rec)[where]
    whole, cut = d / f"whole_{where}.parquet", d / f"cut_{where}.parquet"
    r = cli("replay", path, "--model", model, "-o", whole, "-q", "--chunk", str(len(rec)))
    assert r.code == 0, r.err
    r2 = cli("replay", path, "--model", model, "-o", cut, "-q", "--chunk", str(rows))
    assert r2.code == 0, r2.err
    # the summary (force error, coverage) is over the whole file
    assert r.out.splitlines()[:-1] == r2.out.splitlines()[:-1]
    a, b = Estimates.load(whole), Estimates.load(cut)
    assert len(rec) > rows  # two pieces at least, the first cut where asked
    pd.testing.assert_frame_equal(a.data, b.data, check_exact=True)
    assert a.meta == b.meta
    assert len(a.meta["moving_spans"]) > 3


def test_chunk_below_its_context_is_one_line(campaign, cli):
    d, path, model = campaign
    out = d / "tiny.parquet"
    r = cli("replay", path, "--model", model, "-o", out, "-q", "--chunk", "100")
    assert r.code == 2
    assert r.err.count("\n") == 1
    assert "chunk size 100 rows is below four times the 501-row context" in r.err
    assert not out.exists()


def test_cli_info_in_pieces_equals_the_whole(campaign, cli):
    import json

    _, path, _ = campaign
    n = len(read(path))
    whole = json.loads(cli("info", path, "--json", "--chunk", str(n)).out)
    cut = json.loads(cli("info", path, "--json", "--chunk", "2222").out)
    fr_w, fr_c = whole.pop("regimes"), cut.pop("regimes")
    assert whole == cut
    # fractions are sums over the pieces: equal to the last bits
    assert fr_w == pytest.approx(fr_c, abs=1e-12) and fr_w["dither"] > 0.1


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_cli_convert_in_pieces_equals_the_whole(campaign, cli, suffix):
    d, path, _ = campaign
    whole, cut = d / f"whole{suffix}", d / f"cut{suffix}"
    n = len(read(path))
    assert cli("convert", path, whole, "--chunk", str(n)).code == 0
    r = cli("convert", path, cut, "--chunk", "2222")
    assert r.code == 0, r.err
    assert read(cut).equals(read(whole)) and read(cut).equals(read(path))
    if suffix == ".csv":
        assert cut.read_bytes() == whole.read_bytes()
    else:
        import pyarrow.parquet as pq

        assert pq.ParquetFile(cut).metadata.num_row_groups == -(-n // 2222)


def test_a_piece_that_breaks_the_contract_is_named(campaign, cli):
    """Time stamps that go back across a cut are caught (the pieces overlap)."""
    d, path, _ = campaign
    rec = read(path)
    data = rec.data.copy()
    t = data["t"].to_numpy().copy()
    t[3000:] -= 0.5  # back in time at row 3001, inside the second piece's context
    data["t"] = t
    bad = d / "bad.parquet"
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(data, preserve_index=False)
    table = table.replace_schema_metadata({b"ditherlab": rec.meta_json().encode()})
    pq.write_table(table, bad)
    out = d / "bad_out.parquet"
    r = cli("convert", bad, out, "--chunk", "2600")
    assert r.code == 2 and r.err.count("\n") == 1, r.err
    assert "t" in r.err and "increasing" in r.err, r.err
    assert not out.exists()


@pytest.fixture(scope="module")
def still_campaign(campaign):
    """A push campaign without dither (the still regime), made through the CLI."""
    from conftest import run_cli

    d = campaign[0]
    rec = d / "still.parquet"
    r = run_cli(
        "simulate",
        "push-campaign",
        "--seed",
        "25",
        "--no-dither",
        "--pushes-per-direction",
        "2",
        "-o",
        rec,
        "-q",
    )
    assert r.code == 0, r.err
    return rec


@pytest.mark.parametrize("where", WHERE)
def test_cli_identify_in_pieces_equals_the_whole(campaign, still_campaign, cli, where):
    """Two recordings (dithered and not: every regime), cut at an awkward place: the model file
    is byte for byte the one identified whole, and the one the in-memory path gives."""
    d, path, _ = campaign
    rec = read(path)
    rows = _awkward_cuts(rec)[where]
    assert len(rec) > rows
    whole, cut = d / f"m_whole_{where}.toml", d / f"m_cut_{where}.toml"
    args = ("identify", path, still_campaign, "--bootstrap", "4", "--seed", "3", "-q")
    r = cli(*args, "-o", whole, "--chunk", str(10 * len(rec)))
    assert r.code == 0, r.err
    r2 = cli(*args, "-o", cut, "--chunk", str(rows))
    assert r2.code == 0, r2.err
    assert r.out.splitlines()[:-1] == r2.out.splitlines()[:-1]
    assert whole.read_text() == cut.read_text()
    m = TorqueModel.load(whole)
    assert set(m.regimes) == {"still", "dither", "moving"}
    assert all(np.all(b.stderr["sigma"] > 0) for b in m.regimes.values())
    # the in-memory path (demo, fleet) gives the same model
    mem = identify([read(path), read(still_campaign)], n_boot=4, seed=3)
    for name, b in m.regimes.items():
        for k in ("tau_min", "tau_max", "sigma"):
            np.testing.assert_array_equal(getattr(b, k), getattr(mem.regimes[name], k))


def test_identify_spilled_to_disk_equals_held_in_memory(campaign, still_campaign):
    """A spill budget of a few kB writes the residual samples to disk after every piece: the
    model is the same to the bit."""
    _, path, _ = campaign
    srcs = [open_source(path), open_source(still_campaign)]
    held = identify(srcs, n_boot=3, seed=1, chunk_rows=4000)
    spilled = identify(srcs, n_boot=3, seed=1, chunk_rows=4000, spill_bytes=4096)
    for name, b in held.regimes.items():
        for k in ("tau_min", "tau_max", "sigma", "coulomb", "viscous"):
            if getattr(b, k) is not None:
                np.testing.assert_array_equal(getattr(b, k), getattr(spilled.regimes[name], k))
        for k, v in b.stderr.items():
            np.testing.assert_array_equal(v, spilled.regimes[name].stderr[k])
    assert held.notes == spilled.notes


def test_spill_keeps_order_and_cleans_up():
    with Spill(budget=100) as sp:
        rng = np.random.default_rng(0)
        parts = {k: [rng.normal(size=int(rng.integers(0, 40))) for _ in range(7)] for k in "ab"}
        for i in range(7):
            for k in "ab":
                sp.append(k, parts[k][i])
        sp.append("flag", np.array([True, False]))
        assert sp.spilled > 0
        for k in "ab":
            np.testing.assert_array_equal(sp.load(k), np.concatenate(parts[k]))
            assert sp.count(k) == sum(len(p) for p in parts[k])
        np.testing.assert_array_equal(sp.load("flag"), [True, False])
        sp.flush()  # everything held goes to disk; the arrays are unchanged
        assert not any(sp._held.values())
        for k in "ab":
            np.testing.assert_array_equal(sp.load(k), np.concatenate(parts[k]))
        with pytest.raises(TypeError, match="spill key 'a' holds float64, got int64"):
            sp.append("a", np.arange(3))
        folder = sp._dir
        assert folder is not None and folder.exists()
    assert not folder.exists() and sp.count("a") == 0
    with Spill() as small:  # under the budget: flush keeps it in memory, no folder
        small.append("x", np.arange(5.0))
        small.flush()
        assert small._dir is None and small.load("x").tolist() == [0, 1, 2, 3, 4]


def test_causal_mean_does_not_depend_on_where_the_array_starts():
    """A window mean's value is its window's alone: a piece with w - 1 rows of context gives
    the whole array's values to the bit (a running cumsum carried the rounding of all before)."""
    x = np.random.default_rng(2).normal(size=(5000, 3)) * 1e3 + 1e6
    w = 37
    whole = causal_mean(x, w)
    for start in (36, 37, 1234, 4000):
        part = causal_mean(x[start - w + 1 :], w)
        np.testing.assert_array_equal(part[w - 1 :], whole[start:])
    ref = np.array([x[max(0, i - w + 1) : i + 1].mean(axis=0) for i in range(0, 5000, 97)])
    np.testing.assert_allclose(whole[::97], ref, rtol=1e-12)


@pytest.fixture(scope="module")
def replayed(campaign, still_campaign):
    """The estimates of the dithered and of the undithered campaign, replayed through the CLI."""
    from conftest import run_cli

    d, path, model = campaign
    out = []
    for rec in (path, still_campaign):
        est = d / f"est_{rec.stem}.parquet"
        r = run_cli("replay", rec, "--model", model, "-o", est, "-q")
        assert r.code == 0, r.err
        out.append(est)
    return out


@pytest.mark.parametrize("where", WHERE)
def test_cli_report_in_pieces_equals_the_whole(campaign, still_campaign, replayed, cli, where):
    """The report of both campaigns with their recordings, the estimates and recordings read in
    pieces cut at an awkward place: report.json and every figure byte for byte the ones read
    whole (and, for one cut, the in-memory path's)."""
    import json

    from ditherlab.app.report import make_report

    d, path, _ = campaign
    rec = read(path)
    rows = _awkward_cuts(rec)[where]
    n = max(len(rec), len(read(still_campaign)))
    assert len(rec) > rows  # two pieces at least, the first cut where asked
    args = ("report", *replayed, "--recording", path, "--recording", still_campaign)
    out = {}
    for name, chunk in (("whole", n), ("cut", rows)):
        out[name] = d / f"report_{where}_{name}"
        r = cli(*args, "-o", out[name], "--bootstrap", "20", "-q", "--chunk", str(chunk))
        assert r.code == 0, r.err
    whole = json.loads((out["whole"] / "report.json").read_text())
    assert len(whole["files"]) == 8  # Figs. 2, 4, 5, 6, the detection curves, md, html, json
    for f in whole["files"]:
        assert (out["whole"] / f).read_bytes() == (out["cut"] / f).read_bytes(), f
    pushes = [len(r["pushes"]) for r in whole["recordings"]]
    assert min(pushes) >= 6 and set(whole["conditions"]) == {
        "nodither_band",
        "nodither_noband",
        "nodither_band (dither on)",
        "nodither_noband (dither on)",
        "dither_band",
        "dither_noband",
    }
    if where == "push":
        mem = make_report(
            [Estimates.load(p) for p in replayed],
            d / "report_memory",
            recordings=[read(path), read(still_campaign)],
            n_boot=20,
        )
        for key in ("conditions", "recordings"):  # as JSON text: NaN equal to NaN
            assert json.dumps(mem[key]) == json.dumps(whole[key])


@pytest.mark.parametrize(
    "where, estimates", [("push", True), ("dither", True), ("stick", True), ("dither", False)]
)
def test_cli_view_in_pieces_equals_the_whole(campaign, replayed, cli, where, estimates):
    """The view of the dithered campaign with its model (and estimates), the recording read in
    pieces cut at an awkward place: every row of the .rrd read back (all entities, times and
    values, bit for bit) is the one written from the whole log; without the estimates the
    extraction is redone on each piece."""
    from ditherlab.output.rerun.rrd import rrd_contents, rrd_rows

    d, path, model = campaign
    rec = read(path)
    rows = _awkward_cuts(rec)[where]
    assert len(rec) > rows
    args = ["view", path, "--model", model, "-q"]
    if estimates:
        args += ["--estimates", replayed[0]]
    out, printed = {}, {}
    for name, chunk in (("whole", len(rec)), ("cut", rows)):
        out[name] = d / f"view_{where}_{estimates}_{name}.rrd"
        r = cli(*args, "--save", out[name], "--chunk", str(chunk))
        assert r.code == 0, r.err
        printed[name] = r.out.replace(str(out[name]), "OUT")
    assert printed["whole"] == printed["cut"]  # the row count
    whole, cut = rrd_rows(out["whole"]), rrd_rows(out["cut"])
    assert whole.keys() == cut.keys()
    for key, (t, v) in whole.items():
        assert (t is None) == (cut[key][0] is None), key
        assert t is None or np.array_equal(t, cut[key][0]), key
        if isinstance(v, np.ndarray):
            assert np.array_equal(v, cut[key][1]), key
        else:
            assert v == cut[key][1], key
    # what the comparison covered: full-rate series, thinned ones, 3D, events across the cut
    c = rrd_contents(out["whole"])
    assert c["joints/2/tau"]["Scalars:scalars"] == len(rec)
    assert 0 < c["joints/2/extract"]["Scalars:scalars"] < len(rec)
    assert c["robot/skeleton"]["LineStrips3D:strips"] == -(-len(rec) // 10)
    assert c["events/pushes"]["TextLog:text"] == 3 * 12
    assert c["events/dither"]["TextLog:text"] >= 1
    assert ("events/detections/dither_band" in c) == estimates


@pytest.fixture(scope="module")
def long_campaign(campaign):
    """A dithered push campaign long enough for diagnose's 12 s context (about 30 000 rows)."""
    from conftest import run_cli

    d = campaign[0]
    rec = d / "long.parquet"
    r = run_cli(
        "simulate", "push-campaign", "--seed", "23", "--pushes-per-direction", "6", "-o", rec, "-q"
    )
    assert r.code == 0, r.err
    return rec


def _close(a, b, path="") -> None:
    """JSON values equal, floats to 1e-9 relative (sums gathered piece by piece)."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert b == pytest.approx(a, rel=1e-9, abs=1e-12, nan_ok=True), path
    else:
        assert a == b, path


@pytest.mark.parametrize("where", WHERE)
def test_cli_diagnose_in_pieces_equals_the_whole(campaign, long_campaign, cli, where):
    """diagnose read in pieces cut inside a push, a dither period or a stick gives the whole
    recording's diagnosis: residual, force error and coverage, worst windows, every candidate's
    evidence and parameters, the verdict, the notes (sums to 1e-9 relative; the suggestions
    themselves exactly)."""
    import json

    _, _, model = campaign
    rec = read(long_campaign)
    rows = _awkward_cuts(rec, first=12_000)[where]
    assert 12_000 <= rows < len(rec) - 3000
    args = ("diagnose", long_campaign, "--model", model, "--no-history", "--json", "-q")
    whole = cli(*args, "--chunk", str(10 * len(rec)))
    assert whole.code == 0, whole.err
    cut = cli(*args, "--chunk", str(rows))
    assert cut.code == 0, cut.err
    a, b = json.loads(whole.out), json.loads(cut.out)
    assert [(c["effect"], c["joints"], c["suggested"]) for c in a["candidates"]] == [
        (c["effect"], c["joints"], c["suggested"]) for c in b["candidates"]
    ]
    _close(a, b)
    assert a["force"]["coverage"] is not None and a["residual"]["worst_windows"]
    # a chunk shorter than four times the 12 s context: one line, exit 2
    r = cli(*args, "--chunk", "5000")
    assert r.code == 2 and r.err.count("\n") == 1 and "context" in r.err, r.err
