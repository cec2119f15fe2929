"""The vendor's own estimate: its recording columns, kept through convert, written by replay
beside ditherlab's estimate, and compared with it by report and view."""

from __future__ import annotations

import json

import numpy as np
import pytest
from synthetic import push_recording

import ditherlab as dl
from ditherlab.analysis.identification import identify
from ditherlab.analysis.vendor import VENDOR_ESTIMATE_COLUMNS, vendor_wrench
from ditherlab.core.errors import RecordingError
from ditherlab.core.names import FORCE_AXES, VENDOR_WRENCH_COLUMNS
from ditherlab.data.estimates import Estimates
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.output.rerun import rerun_log as rl

#: the vendor's error planted on the forces: a bias [N] and white noise of this σ [N]
BIAS = np.array([2.0, -1.0, 0.5])
SIGMA = 0.5


def _with_vendor(rec: Recording, seed: int = 7) -> Recording:
    """``rec`` with a vendor's wrench estimate: the sensor plus BIAS and noise of σ SIGMA."""
    rng = np.random.default_rng(seed)
    w = rec.wrench.copy()
    w[:, :3] += BIAS + rng.normal(0, SIGMA, (len(rec), 3))
    return rec.with_columns(**{c: w[:, k] for k, c in enumerate(VENDOR_WRENCH_COLUMNS)})


def _small(n: int = 3, **extra) -> Recording:
    t = np.arange(50) / 100.0
    q = np.tile([0.0, 0.3, 0.2, 0.0, 1.0, 0.0], (50, 1))
    return Recording.from_arrays(
        RecordingArrays(t, q, np.zeros((50, 6)), **extra), {"robot": "irb140"}
    )


def test_vendor_wrench_is_all_six_or_none():
    """A recording with five of the six vendor columns is refused, naming the missing one."""
    rec = _small(vendor_wrench=np.ones((50, 6)))
    assert rec.has_vendor and rec.vendor_wrench.shape == (50, 6)
    with pytest.raises(RecordingError, match="column m_vendor_z is missing: the vendor's estimate"):
        Recording(rec.data.drop(columns=["m_vendor_z"]), rec.meta)


def test_tau_ext_vendor_is_a_whole_joint_family():
    """tau_ext_vendor_1..n is all joints or none, like every per-joint family."""
    rec = _small(tau_ext_vendor=np.ones((50, 6)))
    assert rec.tau_ext_vendor.shape == (50, 6) and rec.vendor_wrench is None
    with pytest.raises(RecordingError, match="required column tau_ext_vendor_4 is missing"):
        Recording(rec.data.drop(columns=["tau_ext_vendor_4"]), rec.meta)


def test_wrench_from_external_joint_torques_is_least_squares():
    """From tau_ext = J^T F alone the vendor's wrench is F again (the IRB140 away from
    singularity: J^T is square and well conditioned)."""
    rng = np.random.default_rng(2)
    base = _small()
    J = base.robot().jacobian(base.q)
    F = rng.normal(0, [10, 10, 10, 1, 1, 1], (len(base), 6))
    rec = base.with_columns(
        **{f"tau_ext_vendor_{j + 1}": np.einsum("tkj,tk->tj", J, F)[:, j] for j in range(6)}
    )
    got, source = vendor_wrench(rec)
    assert source == "joint torques"
    np.testing.assert_allclose(got, F, atol=1e-8)


@pytest.mark.parametrize("suffix", [".parquet", ".csv", ".mcap"])
def test_convert_keeps_the_vendor_columns(cli, tmp_path, suffix):
    """convert Parquet -> CSV / MCAP / Parquet keeps both kinds of vendor columns exactly."""
    rng = np.random.default_rng(4)
    rec = _small(vendor_wrench=rng.normal(size=(50, 6)), tau_ext_vendor=rng.normal(size=(50, 6)))
    src = tmp_path / "in.parquet"
    dl.write(rec, src)
    dst = tmp_path / f"out{suffix}"
    res = cli("convert", src, dst)
    assert res.code == 0, res.err
    back = dl.read(dst)
    np.testing.assert_array_equal(back.vendor_wrench, rec.vendor_wrench)
    np.testing.assert_array_equal(back.tau_ext_vendor, rec.tau_ext_vendor)


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    """A push campaign with a vendor's estimate, replayed and reported through the CLI."""
    from conftest import run_cli

    d = tmp_path_factory.mktemp("vendor")
    plain, _ = push_recording(3, magnitudes=(5.0, 15.0, 30.0, 50.0))
    model = identify([plain], n_boot=0)
    model.save(d / "model.toml")
    rec = _with_vendor(plain)
    dl.write(rec, d / "rec.parquet")
    rep = run_cli(
        "replay", d / "rec.parquet", "--model", d / "model.toml", "-o", d / "est.parquet", "-q"
    )
    assert rep.code == 0, rep.err
    out = run_cli("report", d / "est.parquet", "-o", d / "rep", "--json", "-q")
    assert out.code == 0, out.err
    return {"dir": d, "rec": rec, "replay": rep.out, "report": json.loads(out.out)}


def test_replay_writes_the_vendor_estimate_beside_ditherlab(replayed):
    """The estimates file holds vendor/f_x..m_z equal to the recording's vendor columns, and the
    replay's summary prints its error RMS: sqrt(bias² + σ²) per axis."""
    est = Estimates.load(replayed["dir"] / "est.parquet")
    np.testing.assert_array_equal(
        est.data[list(VENDOR_ESTIMATE_COLUMNS)].to_numpy(), replayed["rec"].vendor_wrench
    )
    assert est.meta["vendor"] == {"source": "wrench"} and "vendor" not in est.variants
    line = next(x for x in replayed["replay"].splitlines() if x.strip().startswith("vendor"))
    rms = np.sqrt(BIAS**2 + SIGMA**2)
    assert f"{rms[0]:.1f}/{rms[1]:.1f}/{rms[2]:.1f} N" in line and "no interval" in line


def test_report_compares_both_with_the_same_metrics(replayed):
    """The report's vendor section has the planted bias at rest and error RMS for the vendor,
    the same noise level and thresholds as the report's own table for ditherlab's variant, and
    coverage only for ditherlab's."""
    a = replayed["report"]
    rows = a["vendor"]["estimators"]
    assert set(rows) == {"nodither_band", "nodither_noband", "vendor"}
    v = rows["vendor"]
    for k, ax in enumerate(FORCE_AXES):
        assert v["bias_rest"][ax] == pytest.approx(BIAS[k], abs=0.05)
        assert v["error_rms"][ax] == pytest.approx(np.hypot(BIAS[k], SIGMA), abs=0.05)
    assert v["coverage"] is None
    ours = a["conditions"]["nodither_band"]
    assert rows["nodither_band"]["noise_level"] == ours["noise_level"]
    assert rows["nodither_band"]["coverage"] == ours["coverage_rest"]
    for ax, d in ours["directions"].items():
        assert rows["nodither_band"]["directions"][ax]["response_min"] == d["response_min"]
    # the vendor's estimate follows every push within its noise: it responds to the 15 N pushes
    for ax in FORCE_AXES:
        assert v["directions"][ax]["response_min"] < 20.0
    md = (replayed["dir"] / "rep" / "report.md").read_text()
    assert "## The vendor's estimate beside ditherlab's" in md and "| vendor |" in md


def test_view_shows_the_vendor_estimate(replayed, tmp_path):
    """The Rerun view logs the vendor's estimate per force axis, one value per sample."""
    d = replayed["dir"]
    out = tmp_path / "v.rrd"
    rl.save_view(dl.read(d / "rec.parquet"), out, estimates=rl.load_estimates(d / "est.parquet"))
    c = rl.rrd_contents(out)
    for ax in FORCE_AXES:
        assert c[f"force/{ax}/vendor"]["Scalars:scalars"] == len(replayed["rec"])
