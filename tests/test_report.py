"""Tests of ditherlab.output.report_page and the `ditherlab report` command."""

from __future__ import annotations

import json

import numpy as np
import pytest
from synthetic import push_recording

from ditherlab.analysis.detection import NoPushesError
from ditherlab.analysis.estimation import replay
from ditherlab.analysis.identification import identify
from ditherlab.app.report import make_report
from ditherlab.data.estimates import Estimates, EstimatesSource
from ditherlab.output.report_page import paper_table, summary_text

MAGS = (5.0, 15.0, 30.0, 50.0)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    plain, _ = push_recording(4, magnitudes=MAGS)
    dith, _ = push_recording(4, dither=True, magnitudes=MAGS)
    model = identify([plain, dith], n_boot=0)
    d = tmp_path_factory.mktemp("est")
    paths = []
    for name, r in (("plain", plain), ("dither", dith)):
        est = replay(r, model)
        paths.append(est.save(d / f"{name}.parquet"))
    return paths, (plain, dith)


def test_report_files_and_numbers(tmp_path, pair):
    """The report folder holds Markdown, HTML, JSON (same numbers) and the figures."""
    paths, recs = pair
    out = tmp_path / "rep"
    a = make_report(paths, out, recordings=list(recs), n_boot=20)
    for f in (
        "report.md",
        "report.html",
        "report.json",
        "fig6_estimates.png",
        "detection.png",
        "fig2_torques.png",
        "fig4_extraction.png",
        "fig5_dither_control.png",
    ):
        assert (out / f).stat().st_size > 0, f
        assert f in a["files"]
    j = json.loads((out / "report.json").read_text())
    assert (
        j["conditions"]["dither_band"]["directions"]["x"]
        == a["conditions"]["dither_band"]["directions"]["x"]
    )
    md = (out / "report.md").read_text()
    assert "32 N / 40 N" in md and "10 N / 20 N" in md and "![" in md
    assert "<table>" in (out / "report.html").read_text()
    head, rows = paper_table(a)
    assert [r[0] for r in rows] == ["x", "y", "z"] and len(head) == 6
    assert "22 N / 30 N" in summary_text(a)


def test_report_reads_the_extraction_replay_wrote(tmp_path, pair, monkeypatch):
    """Fig. 4 takes upper, lower and signal from the estimates file (extract/*_j, written by
    replay) and its period from the file's metadata: the extraction is not redone."""
    import ditherlab.output.report_page as report
    from ditherlab.io import write

    paths, recs = pair

    def no_extraction(*args, **kwargs):
        raise AssertionError("the report redid the dither extraction")

    monkeypatch.setattr(report, "extract_dither", no_extraction)
    rec_paths = [write(r, tmp_path / f"rec{k}.parquet") for k, r in enumerate(recs)]
    for given in (list(recs), rec_paths):  # in memory, and files read in pieces
        a = make_report(paths, tmp_path / "rep", recordings=given, n_boot=5, chunk_rows=1000)
        assert "fig4_extraction.png" in a["files"] and "fig5_dither_control.png" in a["files"]
    est = EstimatesSource(paths[1])
    log = report.RecordingLog(recs[1], 1000)
    n = len(recs[1])
    upper, lower, signal, period = report._extraction(log, log.estimates_of([est]), 0, n)
    full = Estimates.load(paths[1])
    assert period == full.meta["dither_period"]
    assert np.array_equal(signal[:, 1], full.data["extract/signal_2"].to_numpy())
    assert np.array_equal(upper[:, 5], full.data["extract/upper_6"].to_numpy())
    # both recordings share time stamps and metadata: their own copied columns tell them apart
    both = [EstimatesSource(p) for p in paths]
    for given in (recs, rec_paths):
        logs = [report.RecordingLog(r, 1000) for r in given]
        assert [g.estimates_of(both).name for g in logs] == [str(p) for p in paths]
        assert logs[0].estimates_of([est]) is None


def test_report_is_deterministic(tmp_path, pair):
    """The same estimates and seed give an identical report.json."""
    paths, _ = pair
    make_report(paths, tmp_path / "a", n_boot=20, figures=False)
    make_report(paths, tmp_path / "b", n_boot=20, figures=False)
    assert (tmp_path / "a" / "report.json").read_text() == (
        tmp_path / "b" / "report.json"
    ).read_text()


def test_cli_report_json(tmp_path, cli, pair):
    """`ditherlab report --json` prints the numbers that report.json holds."""
    paths, _ = pair
    out = tmp_path / "rep"
    r = cli("report", *paths, "-o", out, "--json", "--bootstrap", "10", "-q")
    assert r.code == 0, r.err
    printed = json.loads(r.out)
    stored = json.loads((out / "report.json").read_text())
    assert printed["conditions"] == stored["conditions"]


def test_cli_report_without_pushes_exit_2(tmp_path, cli):
    """Estimates without pushes: one line, exit 2, no report folder."""
    rec, _ = push_recording(0, magnitudes=(5.0,), axes=("x",), signs=(1.0,))
    rest = rec.slice(0.0, 1.9)  # before the first push
    est = replay(rest, identify([rec], n_boot=0))
    p = est.save(tmp_path / "rest.parquet")
    out = tmp_path / "rep"
    r = cli("report", p, "-o", out, "-q")
    assert r.code == 2
    assert r.err.count("\n") == 1 and "no pushes found" in r.err
    assert not out.exists()
    with pytest.raises(NoPushesError):
        make_report([p], out)
    assert not out.exists()


def test_cli_report_on_a_recording_exit_2(tmp_path, cli, pair):
    """A recording given where estimates are expected: one line naming the file, exit 2."""
    from ditherlab.io import write

    src = write(pair[1][0].slice(0, 5.0), tmp_path / "rec.parquet")
    r = cli("report", src, "-o", tmp_path / "rep", "-q")
    assert r.code == 2 and "expected 'ditherlab.estimates/1'" in r.err
    assert not (tmp_path / "rep").exists()


def test_cli_report_with_a_missing_recording_writes_nothing(tmp_path, cli, pair):
    """A --recording that does not exist: one line naming it, exit 2, and no report folder
    (the recordings are opened before anything is written)."""
    paths, _ = pair
    out = tmp_path / "rep"
    r = cli("report", *paths, "-o", out, "--recording", tmp_path / "nope.parquet", "-q")
    assert r.code == 2 and r.err.count("\n") == 1 and "nope.parquet" in r.err, r.err
    assert not out.exists()


def test_fig5_measures_a_sine_dither_as_its_peak(tmp_path, monkeypatch):
    """Fig. 5's measured amplitude uses the recording's waveform: on a sine dither it settles on
    the peak set-point (the loop's target), not on 2/pi of it (a square wave's reading)."""
    from ditherlab.output.report_page import figs
    from ditherlab.sim import simulate

    seen = {}
    real = figs.fig5_dither_control

    def capture(t, centre, amplitude, ffw, tau, gravity, band, amp_ref, path, joint):
        seen.update(amplitude=np.asarray(amplitude), amp_ref=amp_ref, t=np.asarray(t))
        return real(t, centre, amplitude, ffw, tau, gravity, band, amp_ref, path, joint)

    monkeypatch.setattr(figs, "fig5_dither_control", capture)
    cfg = {"dither": {"waveform": "sine"}}
    recs = [simulate("push-campaign", seed=31, dither=d, pushes_per_direction=2, config=cfg)
            for d in (False, True)]  # fmt: skip
    model = identify(recs, n_boot=0)
    paths = [replay(r, model).save(tmp_path / f"{k}.parquet") for k, r in enumerate(recs)]
    make_report(paths, tmp_path / "rep", recordings=recs, n_boot=5)
    settled = seen["amplitude"][seen["t"] > seen["t"][-1] - 3.0]  # the last 3 s shown
    assert seen["amp_ref"] is not None
    assert np.median(settled) == pytest.approx(seen["amp_ref"], rel=0.1)


def test_coverage_at_rest_per_axis(tmp_path, pair):
    """report.json and report.md give the interval coverage and width at rest per axis; each
    is the fraction of the rest samples (the report's own rest mask) whose interval holds the
    sensor force along that axis, and their mean is the per-condition coverage at rest."""
    import pandas as pd

    from ditherlab.analysis.detection import pushes_and_rest

    paths, recs = pair
    out = tmp_path / "rep"
    make_report([paths[0]], out, recordings=[recs[0]], n_boot=5)
    est = Estimates.load(paths[0])
    src = EstimatesSource.of(est)
    _, _, _, rest = pushes_and_rest(src, 1.0, 65_536)
    df = pd.read_parquet(paths[0])
    j = json.loads((out / "report.json").read_text())
    for cond in ("nodither_band", "nodither_noband"):
        c = j["conditions"][cond]
        per = c["coverage_rest_axes"]
        for ax in "xyz":
            f = df[f"f_{ax}"].to_numpy()[rest]
            lo = df[f"{cond}/f_{ax}_lo"].to_numpy()[rest]
            hi = df[f"{cond}/f_{ax}_hi"].to_numpy()[rest]
            assert per[ax] == pytest.approx(np.mean((lo <= f) & (f <= hi)), abs=1e-12)
            w = (hi - lo)[np.isfinite(hi - lo)]
            assert c["width_rest_axes"][ax] == pytest.approx(np.mean(w), rel=1e-9)
        assert np.mean(list(per.values())) == pytest.approx(c["coverage_rest"], abs=1e-12)
    md = (out / "report.md").read_text()
    assert "coverage at rest x / y / z" in md and "coverage during pushes x / y / z" in md
