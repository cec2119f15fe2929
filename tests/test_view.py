"""Tests of ditherlab.output.rerun (the Rerun view): every check reads the .rrd back with Rerun's reader."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from ditherlab.app.view import save_view_files
from ditherlab.core.errors import DitherlabError, FormatError, RecordingError
from ditherlab.core.files import plain
from ditherlab.core.names import FORCE_AXES, WRENCH_COLUMNS
from ditherlab.core.timeseries import causal_mean
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.output.diagnosis_report import load_report, write_report
from ditherlab.output.rerun import rerun_log as rl
from ditherlab.physics.dither import dither_period

PAPER_POSE = np.array([0.0, 0.0, 0.0, 0.0, np.pi / 2, 0.0])
FS = 250.0


def synthetic_campaign(
    duration: float = 12.0, seed: int = 0, source: str = "synthetic"
) -> Recording:
    """A small push campaign: paper pose, three pushes along x, y, z, dither on for the second half."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration * FS)) / FS
    N, n = len(t), 6
    q = PAPER_POSE + 1e-4 * rng.standard_normal((N, n))
    tau = 5.0 * np.sin(0.3 * t)[:, None] + rng.standard_normal((N, n))
    w = 0.3 * rng.standard_normal((N, 6))
    for k, (t0, axis) in enumerate(((2.0, 0), (5.0, 1), (9.0, 2))):
        span = (t >= t0) & (t < t0 + 1.0)
        w[span, axis] += -(15.0 + 5 * k) * np.sin(np.pi * (t[span] - t0)) ** 2
    dither = t >= duration / 2
    ffw = np.where(dither[:, None], 3.0 * np.sign(np.sin(80 * t))[:, None] + 0.5, 0.0) * np.ones(n)
    amp_ref = {f"dither_amp_ref_{j + 1}": np.where(dither, 2.7, 0.0) for j in range(n)}
    return Recording.from_arrays(
        RecordingArrays(t, q, tau, wrench=w, dither=dither, tau_ffw=ffw, extra=amp_ref),
        {"robot": "irb140", "source": source, "sample_rate_hz": FS},
        name=f"{source}.parquet",
    )


def write_estimates(rec: Recording, path: Path, seed: int = 1) -> Path:
    """An estimates file in the agreed format (schema ditherlab.estimates/1) for ``rec``."""
    rng = np.random.default_rng(seed)
    N, n = len(rec), rec.n
    cols: dict[str, np.ndarray] = {"t": rec.t}
    for k, c in enumerate(WRENCH_COLUMNS):
        cols[c] = rec.wrench[:, k]
    cols["dither"] = rec.dither
    variants = ["nodither_band", "dither_band"]
    for v in variants:
        F = np.where(np.abs(rec.wrench) > 5, 0.7 * rec.wrench, 0.0)  # held at the prior in between
        for k, c in enumerate(WRENCH_COLUMNS):
            cols[f"{v}/{c}"] = F[:, k]
            cols[f"{v}/{c}_lo"] = F[:, k] - 4.0 - rng.random(N)
            cols[f"{v}/{c}_hi"] = F[:, k] + 4.0 + rng.random(N)
        cols[f"{v}/active"] = (np.abs(F[:, :3]).sum(axis=1) > 0).astype(np.int64) * 0b000110
    # Extraction: one value per 20-sample dither period (piecewise constant), per joint.
    period = np.arange(N) // 20
    for j in range(1, n + 1):
        lvl = rng.standard_normal(period.max() + 1)[period]
        cols[f"extract/upper_{j}"] = lvl + 2.5
        cols[f"extract/lower_{j}"] = lvl - 2.5
        cols[f"extract/signal_{j}"] = lvl
    meta = {
        "schema": "ditherlab.estimates/1",
        "recording": rec.meta,
        "recording_name": rec.name,
        "model": {},
        "variants": variants,
        "interval": {"method": "set_membership", "level": 0.95},
        "components": ["f_x", "f_y", "f_z"],
    }
    table = pa.table(cols).replace_schema_metadata({"ditherlab": json.dumps(meta)})
    pq.write_table(table, path)
    return path


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("view")
    rec = synthetic_campaign()
    rec_path = d / "campaign.parquet"
    import ditherlab

    ditherlab.write(rec, rec_path)
    rec = ditherlab.read(rec_path)
    est_path = write_estimates(rec, d / "campaign-estimates.parquet")
    out = d / "campaign.rrd"
    summary = rl.save_view(rec, out, estimates=rl.load_estimates(est_path))
    return {
        "dir": d,
        "rec": rec,
        "rec_path": rec_path,
        "est_path": est_path,
        "rrd": out,
        "summary": summary,
        "contents": rl.rrd_contents(out),
    }


def test_thin_mask_matches_slow_reference():
    """The fast thinning keeps exactly the samples a per-sample loop keeps (neighbours equal)."""
    rng = np.random.default_rng(3)
    v = rng.integers(0, 3, size=(500, 2)).astype(float)
    v[rng.random(500) < 0.05, 1] = np.nan
    fast = rl.thin_mask(v)
    same = lambda a, b: bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))  # noqa: E731
    slow = [
        i in (0, len(v) - 1) or not (same(v[i], v[i - 1]) and same(v[i], v[i + 1]))
        for i in range(len(v))
    ]
    assert fast.tolist() == slow


def test_envelope_mask_keeps_each_bins_ends_and_extremes():
    """The decimated view (series_rate) keeps, per bin, its first and last samples and every
    column's smallest and largest value (NaN ignored), and nothing else."""
    from ditherlab.output.rerun.columns import envelope_mask

    rng = np.random.default_rng(5)
    t = np.sort(rng.uniform(3.0, 13.0, 800))
    v = rng.normal(size=(800, 3))
    v[rng.random(800) < 0.05, 2] = np.nan
    keep = envelope_mask(t, v, 2.0, 3.0)
    bins = np.floor((t - 3.0) * 2.0).astype(int)
    slow = np.zeros(len(t), dtype=bool)
    for b in np.unique(bins):
        idx = np.flatnonzero(bins == b)
        slow[[idx[0], idx[-1]]] = True
        for c in range(v.shape[1]):
            col = v[idx, c]
            if np.isfinite(col).any():
                slow[idx[np.nanargmin(col)]] = slow[idx[np.nanargmax(col)]] = True
    assert keep.tolist() == slow.tolist()


def test_rrd_has_every_series_at_full_rate(campaign):
    """Per-joint torques and sensor forces are in the file with one row per recording sample."""
    c, N, n = campaign["contents"], len(campaign["rec"]), campaign["rec"].n
    for j in range(1, n + 1):
        assert c[f"joints/{j}/tau"]["Scalars:scalars"] == N
        assert c[f"joints/{j}/tau_bar"]["Scalars:scalars"] == N
    for a in FORCE_AXES:
        assert c[f"force/{a}/sensor"]["Scalars:scalars"] == N
        for v in ("nodither_band", "dither_band"):
            assert 0 < c[f"force/{a}/{v}"]["Scalars:scalars"] <= N
    assert "force/x/dither_noband" not in c


def test_rrd_3d_entities_at_the_3d_rate(campaign):
    """Robot links, skeleton, arrows and interval boxes are logged at 25 Hz (one per 10 samples)."""
    c = campaign["contents"]
    M = len(rl.decimate_index(campaign["rec"].t, 25.0))
    assert M == int(np.ceil(len(campaign["rec"]) / 10))
    robot = campaign["rec"].robot()
    for link in robot.link_poses(PAPER_POSE):
        assert c[f"robot/links/{link}"]["Transform3D:translation"] == M
    assert c["robot/skeleton"]["LineStrips3D:strips"] == M
    assert c["robot/force/sensor"]["Arrows3D:vectors"] == M
    assert c["robot/force/dither_band"]["Arrows3D:origins"] == M
    assert c["robot/force/dither_band/interval"]["Boxes3D:half_sizes"] == M


def test_estimate_series_equals_estimates_file_exactly(campaign):
    """The logged estimate and interval, read back and put on every sample, equal the file's columns bit for bit."""
    est = rl.load_estimates(campaign["est_path"]).data
    t = est["t"].to_numpy()
    for v in ("nodither_band", "dither_band"):
        for a in FORCE_AXES:
            tk, vals = rl.rrd_scalars(campaign["rrd"], f"force/{a}/{v}")
            idx = np.searchsorted(t, tk - 1e-7)
            np.testing.assert_allclose(t[idx], tk, atol=1e-8)
            for k, col in enumerate((f"{v}/f_{a}", f"{v}/f_{a}_lo", f"{v}/f_{a}_hi")):
                full = est[col].to_numpy()
                assert np.array_equal(vals[:, k], full[idx])  # every logged value is the file's
                assert np.array_equal(np.interp(t, t[idx], vals[:, k]), full)  # and nothing is lost


def test_extraction_where_dither_is_on(campaign):
    """The extraction is logged where the dither was on over a whole window (the file's values, bit
    for bit, nothing lost) and NaN elsewhere."""
    rec = campaign["rec"]
    est = rl.load_estimates(campaign["est_path"]).data
    t = est["t"].to_numpy()
    tk, vals = rl.rrd_scalars(campaign["rrd"], "joints/3/extract")
    idx = np.searchsorted(t, tk - 1e-7)
    on = np.isfinite(vals[:, 0])
    assert vals.shape[1] == 5 and (~on).sum() == 2  # the NaN stretch costs two rows
    g = rec.robot().gravity(rec.q)[:, 2]
    assert np.array_equal(vals[on, 4], g[idx][on])
    assert t[idx][on].min() > 6.0 and t[idx][~on].max() < 6.1  # dither on from t = 6 s
    for k, s in enumerate(("upper", "lower", "signal")):
        full = est[f"extract/{s}_3"].to_numpy()
        assert np.array_equal(vals[on, k], full[idx][on])
        late = t >= tk[on][0]
        assert np.array_equal(np.interp(t[late], t[idx][on], vals[on, k]), full[late])
    tk, vals = rl.rrd_scalars(campaign["rrd"], "joints/3/dither/amplitude/extracted")
    assert set(vals[np.isfinite(vals[:, 0]), 0]) == {2.5}
    tk, vals = rl.rrd_scalars(campaign["rrd"], "joints/3/dither/amplitude/amp_ref")
    assert set(vals[:, 0]) == {0.0, 2.7} and len(tk) == 4  # a step: both ends of both runs
    assert rec.n == 6


def test_tau_bar_is_tau_minus_gravity(campaign):
    """The gravity-compensated torque in the file is tau - g(q) from the robot model."""
    rec = campaign["rec"]
    _, vals = rl.rrd_scalars(campaign["rrd"], "joints/2/tau_bar")
    expected = rec.tau[:, 1] - rec.robot().gravity(rec.q)[:, 1]
    np.testing.assert_array_equal(vals[:, 0], expected)
    jtf = np.einsum("nij,ni->nj", rec.robot().jacobian(rec.q), rec.wrench)
    np.testing.assert_allclose(vals[:, 1], jtf[:, 1], atol=1e-9)
    assert np.ptp(rec.robot().gravity(PAPER_POSE)[0]) > 1.0  # gravity is not trivially zero here


def test_arrows_start_at_the_tool_point(campaign):
    """Force arrows start at the tool point of pinocchio's forward kinematics and scale the sensor force."""
    from rerun.chunk import RrdReader

    rec = campaign["rec"]
    idx = rl.decimate_index(rec.t, 25.0)
    tool = rec.robot().tool_pose(rec.q[idx])[:, :3, 3]
    for ch in RrdReader(str(campaign["rrd"])).stream():
        if ch.entity_path == "/robot/force/sensor" and not ch.is_static:
            rb = ch.to_record_batch().to_pydict()
            origins = np.array([r[0] for r in rb["Arrows3D:origins"]])
            vectors = np.array([r[0] for r in rb["Arrows3D:vectors"]])
    np.testing.assert_allclose(origins, tool, atol=1e-6)
    np.testing.assert_allclose(vectors, 0.005 * rec.wrench[idx, :3], atol=1e-6)
    assert abs(tool[0, 2] - 0.647) < 0.01  # the paper's pose: flange centre 0.647 m high


def test_events_dither_and_pushes(campaign):
    """The event log holds dither on at t=6 s and three pushes with their peaks at the sensor's peaks."""
    from rerun.chunk import RrdReader

    rows = {}
    for ch in RrdReader(str(campaign["rrd"])).stream():
        if ch.entity_path.startswith("/events/") and not ch.is_static:
            d = ch.to_record_batch().to_pydict()
            if "TextLog:text" in d:
                rows.setdefault(ch.entity_path, []).extend(
                    (tt.total_seconds(), x[0])
                    for tt, x in zip(d["time"], d["TextLog:text"], strict=True)
                )
    assert rows["/events/dither"] == [(6.0, "dither on")]
    pushes = rows["/events/pushes"]
    peaks = [(tt, x) for tt, x in pushes if "peak" in x]
    assert [round(tt, 1) for tt, _ in peaks] == [2.5, 5.5, 9.5]
    assert len(pushes) == 9
    assert "events/detections/dither_band" in campaign["contents"]


def test_model_bands_and_blueprint(campaign, tmp_path):
    """With a model: band edges as given, the residual tau - g - J^T F per joint, and a blueprint."""
    from rerun.chunk import RrdReader

    from ditherlab.data.torque_model import Band, TorqueModel

    rec = campaign["rec"]
    model = TorqueModel(
        robot="irb140",
        n=6,
        regimes={
            "still": Band(-np.arange(1, 7.0), np.arange(1, 7.0) + 0.5, np.ones(6)),
            "dither": Band(-0.1 * np.arange(1, 7.0), 0.1 * np.arange(1, 7.0), np.ones(6)),
        },
    )
    out = tmp_path / "m.rrd"
    rl.save_view(rec, out, model=model)
    t, v = rl.rrd_scalars(out, "joints/4/band/still")
    np.testing.assert_array_equal(v, [[-4.0, 4.5], [-4.0, 4.5]])
    np.testing.assert_allclose(t, [rec.t[0], rec.t[-1]], atol=1e-8)
    _, v = rl.rrd_scalars(out, "joints/4/band/dither")
    np.testing.assert_array_equal(v[0], [-0.4, 0.4])
    assert len(RrdReader(str(out)).blueprints()) == 1
    # The base model's friction residual: tau - g(q) - J^T F_sensor, per joint.
    _, v = rl.rrd_scalars(out, "joints/2/residual/v1")
    robot = rec.robot()
    jtf = np.einsum("nij,ni->nj", robot.jacobian(rec.q), rec.wrench)
    np.testing.assert_allclose(v[:, 0], (rec.tau - robot.gravity(rec.q) - jtf)[:, 1], atol=1e-9)


def test_estimates_from_another_recording_are_refused(campaign, tmp_path, cli):
    """Estimates of a recording with other time stamps or other metadata give one line and exit 2."""
    other = synthetic_campaign(duration=8.0)
    est_t = write_estimates(other, tmp_path / "other-t.parquet")
    r = cli("view", campaign["rec_path"], "--estimates", est_t, "--save", tmp_path / "x.rrd")
    assert r.code == 2
    assert r.err.strip().count("\n") == 0
    assert (
        "other-t.parquet: the estimates come from another recording: column t has 2000 samples"
        in r.err
    )
    est_m = write_estimates(synthetic_campaign(source="robot-42"), tmp_path / "other-meta.parquet")
    r = cli("view", campaign["rec_path"], "--estimates", est_m, "--save", tmp_path / "x.rrd")
    assert r.code == 2 and r.err.strip().count("\n") == 0
    assert "metadata key 'source' is 'robot-42'" in r.err
    assert not (tmp_path / "x.rrd").exists()


def test_missing_files_give_one_line(campaign, tmp_path, cli):
    """A missing recording or estimates file gives one line on stderr and exit 2, nothing written."""
    out = tmp_path / "x.rrd"
    r = cli("view", tmp_path / "nope.parquet", "--save", out)
    assert r.code == 2 and r.err.startswith("error: ") and r.err.strip().count("\n") == 0
    assert "nope.parquet" in r.err
    r = cli("view", campaign["rec_path"], "--estimates", tmp_path / "nope-e.parquet", "--save", out)
    assert (
        r.code == 2
        and r.err.strip() == f"error: {tmp_path / 'nope-e.parquet'}: no such estimates file"
    )
    assert not out.exists()


def test_cli_save_writes_rrd_and_says_how_to_open(campaign, tmp_path, cli):
    """`view --save` writes the file and prints the rerun command that opens it; never over an input."""
    out = tmp_path / "v.rrd"
    r = cli("view", campaign["rec_path"], "--estimates", campaign["est_path"], "--save", out, "-q")
    assert r.code == 0, r.err
    assert f"rerun {out}" in r.out
    assert rl.rrd_contents(out)["force/z/dither_band"]["Scalars:scalars"] > 0
    r = cli("view", campaign["rec_path"], "-q")
    assert r.code == 2 and "exactly one output" in r.err
    with pytest.raises(DitherlabError, match="refusing to write over the input"):
        rl.save_view(campaign["rec"], campaign["rrd"], inputs=[campaign["rrd"]])


def test_check_estimates_match_accepts_its_own(campaign):
    """The estimates written for a recording pass the check after a Parquet round trip of both."""
    rl.check_estimates_match(campaign["rec"], rl.load_estimates(campaign["est_path"]))
    with pytest.raises(RecordingError, match="t in row 1"):
        shifted = campaign["rec"].with_columns(t=campaign["rec"].t + 1.0)
        rl.check_estimates_match(shifted, rl.load_estimates(campaign["est_path"]))


def test_link_transforms_equal_pinocchio_poses(campaign):
    """Each link's logged translation and quaternion give back pinocchio's link pose at that sample."""
    from rerun.chunk import RrdReader
    from scipy.spatial.transform import Rotation

    rec = campaign["rec"]
    idx = rl.decimate_index(rec.t, 25.0)
    poses = rec.robot().link_poses(rec.q[idx])
    seen = 0
    for ch in RrdReader(str(campaign["rrd"])).stream():
        name = ch.entity_path.removeprefix("/robot/links/")
        if name not in poses or ch.is_static:
            continue
        d = ch.to_record_batch().to_pydict()
        trans = np.array([r[0] for r in d["Transform3D:translation"]])
        quat = np.array([r[0] for r in d["Transform3D:quaternion"]])
        np.testing.assert_allclose(trans, poses[name][:, :3, 3], atol=1e-6)
        np.testing.assert_allclose(
            Rotation.from_quat(quat).as_matrix(), poses[name][:, :3, :3], atol=1e-6
        )
        seen += 1
    assert seen == len(poses)


def test_real_ur10e_log_without_sensor(tmp_path):
    """The real UR10e log (embedded URDF, ~94 Hz, no F/T sensor) gives torques and a moving robot, no force plots."""
    import ditherlab

    path = Path(__file__).resolve().parents[1] / "recordings" / "ur10e-static.parquet"
    rec = ditherlab.read(path)
    rl.save_view(rec, tmp_path / "ur.rrd")
    c = rl.rrd_contents(tmp_path / "ur.rrd")
    assert c["joints/6/tau"]["Scalars:scalars"] == len(rec)
    assert c["robot/links/tool0"]["Transform3D:translation"] == len(rl.decimate_index(rec.t, 25.0))
    assert not any(k.startswith(("force/", "robot/force", "events/pushes")) for k in c)


def test_progress_reaches_total(campaign, tmp_path):
    """The progress callback counts up to its total and ends there."""
    calls = []
    rl.save_view(campaign["rec"], tmp_path / "p.rrd", progress=lambda d, t: calls.append((d, t)))
    done = [d for d, _ in calls]
    assert done == sorted(done) and calls[-1][0] == calls[-1][1] > 0


def test_residual_per_model_version_from_history(campaign, tmp_path):
    """Each rebuildable version of the history gets its residual: v2 with ft_bias removes J^T bias."""
    from ditherlab.data.torque_model import Band, EffectSpec, TorqueModel

    rec = campaign["rec"]
    bias = {"f_x": 2.0, "f_y": -1.0, "f_z": 0.5, "m_x": 0.0, "m_y": 0.0, "m_z": 0.0}
    model = TorqueModel(
        robot="irb140",
        n=6,
        version=2,
        regimes={"still": Band(-np.ones(6), np.ones(6), np.ones(6))},
        effects=[EffectSpec("ft_bias", [], bias)],
        history=[
            {"version": 1, "effects": [], "torque_rms": [1.0] * 6},
            {"version": 2, "effects": ["ft_bias"], "torque_rms": [0.5] * 6},
            {"version": 3, "effects": ["viscous"], "torque_rms": [0.4] * 6},  # not rebuildable
        ],
    )
    assert list(rl.model_versions(model)) == [1, 2]
    out = tmp_path / "h.rrd"
    rl.save_view(rec, out, model=model)
    robot = rec.robot()
    J, g = robot.jacobian(rec.q), robot.gravity(rec.q)
    b = np.array(list(bias.values()))
    v1 = rec.tau - g - np.einsum("nij,ni->nj", J, rec.wrench)
    v2 = rec.tau - g - np.einsum("nij,ni->nj", J, rec.wrench - b)
    _, r1 = rl.rrd_scalars(out, "joints/1/residual/v1")
    _, r2 = rl.rrd_scalars(out, "joints/1/residual/v2")
    np.testing.assert_allclose(r1[:, 0], v1[:, 0], atol=1e-9)
    np.testing.assert_allclose(r2[:, 0], v2[:, 0], atol=1e-9)
    assert np.abs(r1 - r2).max() > 0.1
    c = rl.rrd_contents(out)
    assert "joints/1/residual/v3" not in c
    assert c["history/torque_rms/6"]["static"] == 1


def test_diagnosis_report_at_worst_windows(campaign, tmp_path, cli):
    """A diagnose report.json puts one entry per worst window with the suggested effect on that joint."""
    from rerun.chunk import RrdReader

    report = {
        "model": ["model v1 (irb140)"],
        "version": 1,
        "effects": [],
        "recordings": [campaign["rec"].name],
        "residual": {
            "worst_windows": [
                {
                    "recording": campaign["rec"].name,
                    "t0": 5.0,
                    "t1": 6.0,
                    "energy": 9.0,
                    "worst_joint": 2,
                    "worst_joint_ratio": 3.0,
                },
                {
                    "recording": campaign["rec"].name,
                    "t0": 2.5,
                    "t1": 3.5,
                    "energy": 4.0,
                    "worst_joint": 5,
                    "worst_joint_ratio": 2.0,
                },
            ]
        },
        "candidates": [
            {
                "effect": "payload",
                "joints": [2, 3],
                "suggested": True,
                "explained_fraction": 0.4,
                "text": "payload on joints 2, 3: explains 40.0 % (suggested)",
            },
            {
                "effect": "viscous",
                "joints": [5],
                "suggested": False,
                "explained_fraction": 0.01,
                "text": "viscous on joint 5: explains 1.0 % (not suggested)",
            },
        ],
        "force": None,
        "skipped": {},
        "history": [],
        "notes": [],
        "verdict": None,
    }
    path = tmp_path / "report.json"
    path.write_text(json.dumps(report))
    out = tmp_path / "d.rrd"
    r = cli("view", campaign["rec_path"], "--diagnosis", path, "--save", out, "-q")
    assert r.code == 0, r.err
    rows = []
    for ch in RrdReader(str(out)).stream():
        if ch.entity_path == "/diagnosis" and not ch.is_static:
            d = ch.to_record_batch().to_pydict()
            rows += [
                (tt.total_seconds(), x[0])
                for tt, x in zip(d["time"], d["TextLog:text"], strict=True)
            ]
    assert [tt for tt, _ in rows] == [2.5, 5.0]
    assert "joint 2 at 3x the noise floor; suggested: payload on joints 2, 3" in rows[1][1]
    assert "no suggested effect acts on this joint" in rows[0][1]
    (tmp_path / "bad.json").write_text("{}")
    bad = ("--diagnosis", tmp_path / "bad.json", "--save", out, "--force", "-q")
    r = cli("view", campaign["rec_path"], *bad)
    assert r.code == 2 and "bad.json: key 'model' is missing" in r.err
    assert r.err.count("\n") == 1


def test_fig4_signal_minus_gravity_and_shrunk_band(campaign, tmp_path):
    """Fig. 4: the extracted signal minus gravity through the dither window (as the dither
    variants read it), and the still band shrunk by the amplitude under dither."""
    from ditherlab.data.torque_model import Band, TorqueModel

    rec = campaign["rec"]
    est = rl.load_estimates(campaign["est_path"]).data
    model = TorqueModel(
        robot="irb140", n=6, regimes={"still": Band(-4 * np.ones(6), 4.5 * np.ones(6), np.ones(6))}
    )
    out = tmp_path / "f4.rrd"
    rl.save_view(rec, out, estimates=rl.load_estimates(campaign["est_path"]), model=model)
    robot = rec.robot()
    w = int(round(dither_period(rec) * rec.sample_rate))
    g = causal_mean(robot.gravity(rec.q), w)
    t, v = rl.rrd_scalars(out, "joints/2/fig4/signal_bar")
    idx = np.searchsorted(rec.t, t - 1e-7)
    on = np.isfinite(v[:, 0])
    expected = (est["extract/signal_2"].to_numpy() - g[:, 1])[idx]
    np.testing.assert_allclose(v[on, 0], expected[on], atol=1e-9)
    assert on.sum() > 1000 and not np.isfinite(v[t < 5.9, 0]).any()
    t, v = rl.rrd_scalars(out, "joints/2/band/dither_shrunk")
    before, during = v[t < 5.9], v[t > 6.2]
    np.testing.assert_array_equal(np.unique(before, axis=0), [[-4.0, 4.5]])
    np.testing.assert_array_equal(np.unique(during, axis=0), [[-1.5, 2.0]])


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """The real chain on a small simulated push campaign: simulate, identify, replay, then view."""
    import warnings

    import ditherlab
    from ditherlab.analysis.estimation import replay
    from ditherlab.analysis.identification import identify
    from ditherlab.sim import simulate

    d = tmp_path_factory.mktemp("sim")
    rec = simulate(
        "push-campaign", seed=0, pushes_per_direction=1, magnitude_min=10.0, magnitude_max=30.0
    )
    rec_path = d / "campaign.parquet"
    ditherlab.write(rec, rec_path)
    rec = ditherlab.read(rec_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        model = identify([rec], n_boot=2)
    model_path = model.save(d / "model.toml")
    est = replay(rec, model)
    est_path = est.save(d / "estimates.parquet")
    return {
        "dir": d,
        "rec": rec,
        "rec_path": rec_path,
        "model_path": model_path,
        "est": rl.load_estimates(est_path),
        "est_path": est_path,
    }


@pytest.fixture(scope="module")
def simulated_view(simulated):
    """``ditherlab view`` of the simulated campaign with its estimates and model, saved once:
    (the .rrd path, the CLI result)."""
    from conftest import run_cli

    out = simulated["dir"] / "campaign.rrd"
    r = run_cli(
        "view",
        simulated["rec_path"],
        "--estimates",
        simulated["est_path"],
        "--model",
        simulated["model_path"],
        "--save",
        out,
        "-q",
    )
    return out, r


def test_simulated_campaign_view(simulated, simulated_view):
    """On the simulator's campaign the CLI writes every series at full rate, the estimates exactly
    as replay wrote them, the simulated pushes and the Fig. 5 set-point."""
    out, r = simulated_view
    assert r.code == 0, r.err
    assert r.out.strip().endswith(f"open it with: rerun {out}")
    rec, est = simulated["rec"], simulated["est"]
    N = len(rec)
    c = rl.rrd_contents(out)
    for j in range(1, 7):
        assert c[f"joints/{j}/tau"]["Scalars:scalars"] == N
        assert c[f"joints/{j}/tau_bar"]["Scalars:scalars"] == N
        assert c[f"joints/{j}/residual/v1"]["Scalars:scalars"] == N
        assert f"joints/{j}/dither/amplitude/set_point" in c
    assert est.variants == ["nodither_band", "nodither_noband", "dither_band", "dither_noband"]
    for v in est.variants:
        for a in FORCE_AXES:
            tk, vals = rl.rrd_scalars(out, f"force/{a}/{v}")
            idx = np.searchsorted(rec.t, tk - 1e-7)
            F = est.data[f"{v}/f_{a}"].to_numpy()
            assert np.array_equal(vals[:, 0], F[idx])
            assert np.array_equal(np.interp(rec.t, rec.t[idx], vals[:, 0]), F)
    pushes = rec.meta["sim"]["pushes"]
    assert c["events/pushes_simulated"]["TextLog:text"] == 3 * len(pushes)
    assert c["events/dither"]["TextLog:text"] == 2


def test_blueprint_points_at_logged_entities(simulated_view):
    """Every view origin and content query of the stored blueprint matches logged entities, except
    those for inputs this campaign lacks (model history, diagnosis)."""
    import fnmatch

    from rerun.chunk import RrdReader

    out, r = simulated_view
    assert r.code == 0, r.err
    entities = set(rl.rrd_contents(out))
    reader = RrdReader(str(out))
    origins, queries = {}, {}
    for ch in reader.stream(store=reader.blueprints()[0]):
        d = ch.to_record_batch().to_pydict()
        view = ch.entity_path.removesuffix("/ViewContents")
        if "ViewBlueprint:space_origin" in d:
            origins[view] = d["ViewBlueprint:space_origin"][-1][0]
        if "ViewContents:query" in d:
            queries[view] = d["ViewContents:query"][-1]
    assert len(origins) > 40
    unmatched = set()
    for view, origin in origins.items():
        for q in queries.get(view, ["$origin/**"]):
            pat = q.replace("$origin", origin.rstrip("/")).lstrip("/").replace("/**", "*")
            if not any(fnmatch.fnmatchcase(e, pat) for e in entities):
                unmatched.add(pat)
    allowed = (
        "history/*",
        "diagnosis*",
        "info/diagnosis*",
        "info/history*",
        "joints/*/dither/centre*",
    )
    assert unmatched and all(any(fnmatch.fnmatchcase(u, a) for a in allowed) for u in unmatched), (
        unmatched
    )


def test_save_view_files_for_the_demo(simulated):
    """The demo's one call writes the .rrd from file paths and refuses to write over an input."""
    out = save_view_files(
        simulated["rec_path"],
        simulated["dir"] / "demo.rrd",
        estimates=simulated["est_path"],
        model=simulated["model_path"],
    )
    assert rl.rrd_contents(out)["force/x/dither_band"]["Scalars:scalars"] > 0
    odd = simulated["dir"] / "model-named.rrd"  # a model file may have any name
    odd.write_bytes(simulated["model_path"].read_bytes())
    with pytest.raises(DitherlabError, match="refusing to write over the input"):
        save_view_files(simulated["rec_path"], odd, model=odd)
    assert odd.read_bytes() == simulated["model_path"].read_bytes()


def test_window_mean_equals_the_extraction_centre(campaign):
    """The fast window mean the view logs as the centre (identify.causal_mean) equals
    ditherlab.physics.dither.extract's centre (the paper's period mean)."""
    from ditherlab.core.timeseries import causal_mean
    from ditherlab.physics.dither import extract

    rec = campaign["rec"]
    ext = extract(rec.tau, rec.t, 2 * np.pi / 80)
    np.testing.assert_allclose(causal_mean(rec.tau, ext.window), ext.centre, atol=1e-9)


@pytest.mark.slow
def test_demo_writes_rrd_and_says_how_to_open(tmp_path, capsys):
    """`make demo` (ditherlab.app.demo.main) writes demo.rrd with the estimates and prints `rerun <path>`."""
    import warnings

    from ditherlab.app.demo import main

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert main(["--out", str(tmp_path), "--pushes", "1", "--quiet"]) == 0
    out = capsys.readouterr().out
    rrd = tmp_path / "demo.rrd"
    assert f"open it with: rerun {rrd}" in out
    c = rl.rrd_contents(rrd)
    # the default view: the envelope over 0.5 s bins (--full-view: every sample)
    assert c["force/z/dither_band"]["Scalars:scalars"] > 100
    # the residual of the demo's model, whose version is 2 when the identification campaign's
    # dithered pushes identify dither_extraction (v1 otherwise)
    from ditherlab.data.torque_model import TorqueModel

    version = TorqueModel.load(tmp_path / "model.toml").version
    assert f"joints/1/residual/v{version}" in c and "robot/force/dither_band/interval" in c


def test_model_of_another_robot_is_refused(campaign, tmp_path, cli):
    """A model identified on another robot gives one line naming both robots and exit 2."""
    from ditherlab.data.torque_model import Band, TorqueModel

    m = TorqueModel(
        robot="ur10e", n=6, regimes={"still": Band(-np.ones(6), np.ones(6), np.ones(6))}
    )
    path = m.save(tmp_path / "ur.toml")
    r = cli("view", campaign["rec_path"], "--model", path, "--save", tmp_path / "x.rrd", "-q")
    assert r.code == 2 and r.err.strip().count("\n") == 0
    assert "robot is irb140 with 6 joints but the model" in r.err and "ur10e" in r.err


def test_foreign_log_through_a_mapping(shared_data, tmp_path, cli):
    """A vendor CSV (real UR10e free motion) is viewed through its mapping file: the robot moves in 3D."""
    out = tmp_path / "ur.rrd"
    csv = shared_data / "ur10e" / "no_torque.csv"
    r = cli("view", csv, "--mapping", "ur10e", "--save", out, "-q")
    assert r.code == 0, r.err
    c = rl.rrd_contents(out)
    n = sum(1 for _ in csv.open())
    assert c["joints/1/tau"]["Scalars:scalars"] == n
    t, _ = rl.rrd_scalars(out, "joints/1/tau")
    assert t[-1] - t[0] > 5.0


def test_recording_id_follows_the_inputs(campaign):
    """Same inputs give the same Rerun recording id; other estimates of the same recording another."""
    rec = campaign["rec"]
    est = rl.load_estimates(campaign["est_path"])
    a = rl.new_stream(rec, est).get_recording_id()
    assert a == rl.new_stream(rec, rl.load_estimates(campaign["est_path"])).get_recording_id()
    assert a != rl.new_stream(rec).get_recording_id()


def test_merge_spans_against_a_loop():
    """Runs closer than the gap merge; others stay apart (checked against a per-sample loop)."""
    t = np.arange(20) * 0.1
    flag = np.array([0, 1, 1, 0, 1, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1], dtype=bool)
    assert rl.merge_spans(t, flag, 0.25) == [(1, 5), (8, 10), (17, 20)]
    assert rl.merge_spans(t, flag, 0.05) == [(1, 3), (4, 5), (8, 10), (17, 20)]
    spans, cur = [], None
    for i, f in enumerate(flag):  # reference: close a span when the gap to the next run is long
        if f and cur is None:
            cur = [i, i + 1]
        elif f:
            if t[i] - t[cur[1] - 1] < 0.25:
                cur[1] = i + 1
        if f and cur[1] != i + 1:
            spans.append(tuple(cur))
            cur = [i, i + 1]
    spans.append(tuple(cur))
    assert rl.merge_spans(t, flag, 0.25) == spans


def test_lead_through_online_estimate_and_motion(tmp_path):
    """A simulated lead-through (Fig. 7): the controller's online estimate is logged per axis and
    the tool moves in 3D."""
    from rerun.chunk import RrdReader

    from ditherlab.sim import simulate

    rec = simulate("lead-through", seed=0)
    out = tmp_path / "lt.rrd"
    rl.save_view(rec, out)
    t, v = rl.rrd_scalars(out, "force/x/online")
    idx = np.searchsorted(rec.t, t - 1e-7)
    assert np.array_equal(v[:, 0], rec.data["fhat_x"].to_numpy()[idx])
    for ch in RrdReader(str(out)).stream():
        if ch.entity_path == "/robot/links/tool0" and not ch.is_static:
            p = np.array(
                [r[0] for r in ch.to_record_batch().to_pydict()["Transform3D:translation"]]
            )
    assert np.ptp(p, axis=0).max() > 0.02  # the tool travelled more than 2 cm


def test_rerun_cli_verifies_the_file(simulated_view, tmp_path):
    """Rerun's own `rerun rrd verify` loads and interprets the written file without error (and
    rejects a truncated copy, so the check can fail)."""
    import subprocess
    import sys

    rerun = Path(sys.executable).parent / "rerun"
    if not rerun.exists():
        pytest.skip("the rerun CLI of rerun-sdk is not installed beside this Python")
    out, r = simulated_view
    assert r.code == 0, r.err
    ok = subprocess.run([rerun, "rrd", "verify", out], capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and "verified without error" in ok.stdout + ok.stderr
    bad = tmp_path / "cut.rrd"
    bad.write_bytes(out.read_bytes()[: out.stat().st_size // 2])
    cut = subprocess.run([rerun, "rrd", "verify", bad], capture_output=True, text=True, timeout=120)
    assert cut.returncode != 0


@pytest.mark.study
def test_real_diagnosis_object(simulated, tmp_path):
    """A Diagnosis from ditherlab.analysis.diagnosis is logged: one entry per worst window, its joint named."""
    import warnings

    from ditherlab.analysis.diagnosis import diagnose
    from ditherlab.data.torque_model import TorqueModel

    model = TorqueModel.load(simulated["model_path"])
    rec = simulated["rec"]
    if "moving" not in model.regimes:  # diagnose needs a band for every regime it meets
        model.regimes["moving"] = model.regimes["still"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        d = diagnose([rec], model, effects=["viscous", "payload"])
    out = tmp_path / "diag.rrd"
    rl.save_view(rec, out, model=model, diagnosis=d)
    c = rl.rrd_contents(out)
    assert c["diagnosis"]["TextLog:text"] == len(d.windows) > 0
    assert c["info/diagnosis"]["static"] == 1
    # the round trip the view relies on: write_report -> load_report gives the same fields
    write_report(d, tmp_path / "diag")
    rep = load_report(tmp_path / "diag" / "report.json")
    want = plain(d.to_dict())
    assert list(want) == list(vars(rep))
    for key, value in want.items():
        assert json.dumps(getattr(rep, key), sort_keys=True) == json.dumps(value, sort_keys=True)
    assert rep.version == model.version and rep.recordings == [rec.name]
    assert rep.worst_windows == d.windows and len(rep.candidates) == len(d.candidates)
    assert [c["text"] for c in rep.suggested] == [c.text() for c in d.suggested]
    out2 = tmp_path / "diag2.rrd"
    rl.save_view(rec, out2, model=model, diagnosis=rep)
    assert rl.rrd_contents(out2)["diagnosis"] == c["diagnosis"]


def _diagnosis_dict() -> dict:
    """The smallest valid report.json: every key of Diagnosis.to_dict, one window, one candidate."""
    return {
        "model": ["model v2 (irb140)"],
        "version": 2,
        "effects": [{"name": "viscous"}],
        "recordings": ["a.parquet"],
        "residual": {
            "torque_rms": [1.0],
            "worst_windows": [
                {
                    "recording": "a.parquet",
                    "t0": 1.0,
                    "t1": 2.0,
                    "energy": 3.0,
                    "worst_joint": 1,
                    "worst_joint_ratio": 2.0,
                }
            ],
        },
        "force": None,
        "candidates": [
            {
                "effect": "payload",
                "joints": [1],
                "explained_fraction": 0.5,
                "suggested": True,
                "text": "payload on joint 1",
            }
        ],
        "skipped": {},
        "history": [],
        "notes": [],
        "verdict": None,
    }


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.pop("history"), "key 'history' is missing"),
        (lambda d: d.update(extra=1), "key 'extra' is unknown"),
        (lambda d: d.update(version="2"), "key 'version' is \"2\", expected an integer"),
        (lambda d: d.update(version=True), "key 'version' is true, expected an integer"),
        (lambda d: d.update(force=[]), "key 'force' is [], expected an object or null"),
        (lambda d: d.update(verdict="bad"), "key 'verdict' is \"bad\", expected an object or null"),
        (lambda d: d["residual"].pop("worst_windows"), "key 'residual.worst_windows' is missing"),
        (
            lambda d: d["residual"]["worst_windows"][0].pop("t0"),
            "key 'residual.worst_windows[0].t0' is missing",
        ),
        (
            lambda d: d["candidates"][0].update(suggested="yes"),
            "key 'candidates[0].suggested' is \"yes\", expected true or false",
        ),
    ],
)
def test_load_report_refuses_what_is_not_a_diagnosis(tmp_path, edit, message):
    """load_report: one line naming the file, the key and what was expected."""
    good = tmp_path / "report.json"
    good.write_text(json.dumps(_diagnosis_dict()))
    rep = load_report(good)
    assert rep.version == 2 and rep.worst_windows[0]["worst_joint"] == 1
    assert rep.to_dict() == _diagnosis_dict()
    d = _diagnosis_dict()
    edit(d)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(d))
    with pytest.raises(FormatError) as exc:
        load_report(bad)
    text = str(exc.value)
    assert text.startswith(f"{bad}: ") and message in text and "\n" not in text


def test_load_report_missing_or_not_json(tmp_path):
    with pytest.raises(FormatError, match="no such diagnosis file"):
        load_report(tmp_path / "none.json")
    (tmp_path / "x.json").write_text("[1, 2]")
    with pytest.raises(FormatError, match="holds a list, expected the report.json"):
        load_report(tmp_path / "x.json")
    (tmp_path / "y.json").write_text("{")
    with pytest.raises(FormatError, match="not a JSON diagnosis report"):
        load_report(tmp_path / "y.json")


def test_load_report_of_a_report_without_a_verdict(tmp_path):
    """A report.json written before the verdict existed still loads (verdict None)."""
    d = _diagnosis_dict()
    d.pop("verdict")
    p = tmp_path / "report.json"
    p.write_text(json.dumps(d))
    rep = load_report(p)
    assert rep.verdict is None and rep.version == 2
