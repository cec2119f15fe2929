"""``ditherlab robot --sensitivity`` given a measured noise level (``--noise-level X,Y,Z`` or
``--report report.json``) instead of the predicted one, and the sweep's prediction given each
point's measured noise level.

The noise level ``m`` [N] enters the threshold as the hand derivations of
``tests/test_sensitivity.py`` say: one joint alone carrying y (lever ``l``, band ``W``), a push
responds once the estimate ``P - W/(2l)`` beyond the edge exceeds ``m``; with dither and a
linear transmission ``g`` once ``g pk P l`` exceeds ``W/2 + m l``. The report's noise level is
read from its matching condition (``dither_band`` / ``nodither_band``), not recomputed.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from conftest import run_cli

from ditherlab.analysis.sensitivity import Bands, predict, transmission_table
from ditherlab.analysis.sensitivity_plant import extraction_peak
from ditherlab.data.torque_model import Band, TorqueModel
from ditherlab.robot import PAPER_POSE, RobotModel
from ditherlab.sim.params import load_params

ROBOT = RobotModel.from_spec("irb140")
#: joint 1's lever for a force along y at the paper's pose [m]
LEVER = abs(ROBOT.jacobian(PAPER_POSE[None])[0][1, 0])
#: the force grid of predict() without dither: 120 points over (0, 200] N
STEP = 200.0 / 120


def one_joint_model(width: float = 10.0) -> TorqueModel:
    """A model whose still band is ``width`` [N·m] wide on joint 1 and so wide elsewhere that
    no other joint ever leaves it; noise 1e-6 N·m (no noise maximum over the push)."""
    lo = np.full(6, -1e4)
    lo[0] = -width / 2
    return TorqueModel(robot="irb140", n=6, regimes={"still": Band(lo, -lo, np.full(6, 1e-6))})


def sensitivity_json(*args: object) -> dict:
    r = run_cli("robot", "irb140", "--q", "paper", "--sensitivity", "--json", *args)
    assert r.code == 0, r.err
    return json.loads(r.out)


@pytest.mark.parametrize("m", [20.0, 30.0])
def test_cli_noise_level_moves_the_one_joint_threshold_as_derived(tmp_path, m):
    """No dither, one joint carrying y: the campaign leaves joint 1 at -+0.85 W/2 (the sliding
    level), a push breaks the link's friction at (0.9 -+ 0.85) W/2 and then carries the whole
    push, so its estimate is P - W/(2l). With the given level m above 0.75 W/(2l) = 8.3 N the
    break-out comes first for both states and every push responds at P = W/(2l) + m: F50 and
    F90 are one step there, up to half the force grid's 1.67 N step, and move with m one to
    one. The predicted level (tiny noise: the 1 N floor) is reported beside it."""
    W = 10.0
    mpath = one_joint_model(W).save(tmp_path / "m.toml")
    d = sensitivity_json("--model", mpath, "--no-dither", "--noise-level", f"{m},{m},{m}")
    (pred,) = d["predictions"]
    assert pred["noise_level"] == {"x": m, "y": m, "z": m}
    assert pred["noise_level_predicted"] == {"x": 1.0, "y": 1.0, "z": 1.0}
    assert pred["noise_level_source"] == "given (--noise-level)"
    step = W / 2 / LEVER + m
    for dn in ("+y", "-y"):
        r = pred["directions"][dn]
        assert r["f50"] == pytest.approx(step, abs=STEP / 2 + 0.01), (dn, r)
        assert step - 0.01 <= r["f90"] <= step + STEP and r["f90"] - r["f50"] < STEP
    own = sensitivity_json("--model", mpath, "--no-dither")["predictions"][0]
    assert own["noise_level_source"] == "predicted" and own["noise_level"]["y"] == 1.0
    assert own["directions"]["+y"]["f50"] < step - 15.0  # the 1 N floor: far lower


def test_dithered_noise_level_divides_by_the_transmission():
    """With dither every joint meets a push at the centre and the extracted signal drops by g
    pk(D) P l (the model's dither_extraction, gain g, lag 0): F50 lies at (W/2 + m l)/(g pk l)
    within the push lengths' spread of pk, so raising m by 4 N raises F50 by 4/(g pk) N."""
    W, g = 4.0, 0.8
    lo = np.full(6, -1e4)
    lo[0] = -W / 2
    b = Bands(lo, -lo, np.full(6, 1e-6), True, "test", np.zeros(6), np.full(6, 20.0))
    b.extraction_gain, b.extraction_lag = np.full(6, g), np.zeros(6)
    durs, _, _, _ = transmission_table(ROBOT, PAPER_POSE, b)
    pk = np.array([extraction_peak(D, 0.0, 20, 250.0) for D in durs])
    f50 = {}
    for m in (1.0, 5.0):
        pred = predict(ROBOT, PAPER_POSE, b, noise_level=[m] * 3, noise_source="measured")
        assert pred["noise_level_source"] == "measured"
        edge = (W / 2 + m * LEVER) / (g * LEVER)
        f50[m] = pred["directions"]["+y"]["f50"]
        assert edge / pk.max() - 0.2 <= f50[m] <= edge / pk.min() + 0.2
    assert 4.0 / (g * pk.max()) - 0.4 <= f50[5.0] - f50[1.0] <= 4.0 / (g * pk.min()) + 0.4


def test_cli_report_noise_level_is_read_from_the_matching_condition(tmp_path):
    """A real report (small simulated campaigns with and without dither at the simulator's
    pose, identified, replayed, reported; its conditions include ``nodither_band (dither on)``,
    which is not the no-dither condition): --report takes dither_band's noise level for the dithered prediction
    and nodither_band's for the other, as they stand in report.json, and gives the same
    thresholds as --noise-level with those numbers; the text names where they come from."""
    recs = [tmp_path / "d.parquet", tmp_path / "n.parquet"]
    ests = [tmp_path / "d-est.parquet", tmp_path / "n-est.parquet"]
    mpath, rep = tmp_path / "m.toml", tmp_path / "rep"
    steps = [
        ("simulate", "push-campaign", "--seed", "5", "--pushes-per-direction", "2", "-o", recs[0]),
        ("simulate", "push-campaign", "--seed", "5", "--no-dither", "--pushes-per-direction", "2",
         "-o", recs[1]),
        ("identify", *recs, "-o", mpath, "--bootstrap", "2"),
        *(("replay", r, "--model", mpath, "-o", e) for r, e in zip(recs, ests, strict=True)),
        ("report", *ests, "-o", rep, "--bootstrap", "5"),
    ]  # fmt: skip
    for args in steps:
        r = run_cli(*args, "-q")
        assert r.code == 0, (args[0], r.err)
    report = json.loads((rep / "report.json").read_text())
    q = ",".join(str(x) for x in load_params()["pose"]["q0"])
    d = sensitivity_json("--q", q, "--model", mpath, "--report", rep / "report.json")
    by = {p["dithered"]: p for p in d["predictions"]}
    for dithered, cond in ((True, "dither_band"), (False, "nodither_band")):
        measured = report["conditions"][cond]["noise_level"]
        assert by[dithered]["noise_level"] == pytest.approx(measured, abs=0)
        assert by[dithered]["noise_level_source"] == (
            f"measured (--report {rep / 'report.json'}, {cond})"
        )
        flag = "--dither" if dithered else "--no-dither"
        nl = ",".join(repr(measured[a]) for a in "xyz")
        given = sensitivity_json("--q", q, "--model", mpath, flag, "--noise-level", nl)
        for dn, v in by[dithered]["directions"].items():
            assert v["f50"] == given["predictions"][0]["directions"][dn]["f50"], (cond, dn)
    assert (
        report["conditions"]["dither_band"]["noise_level"]
        != (report["conditions"]["nodither_band"]["noise_level"])
    )
    r = run_cli("robot", "irb140", "--q", q, "--sensitivity", "--model", mpath, "--dither",
                "--report", rep / "report.json")  # fmt: skip
    assert r.code == 0 and f"noise level measured (--report {rep / 'report.json'}, " in r.out
    assert "(predicted from the bands: x " in r.out


def _report(folder, conditions: dict) -> str:
    """A report.json in ``folder`` holding only ``conditions``; its path."""
    folder.mkdir(exist_ok=True)
    p = folder / "report.json"
    p.write_text(json.dumps({"conditions": conditions}))
    return str(p)


NL = {"x": 1.0, "y": 2.0, "z": 3.0}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["--dither", "--noise-level", "1,2"],
            "--noise-level is '1,2'; expected three numbers X,Y,Z in N (the noise level per axis)",
        ),
        (
            ["--dither", "--noise-level", "1,a,3"],
            "--noise-level is '1,a,3'; expected three numbers X,Y,Z in N (the noise level per "
            "axis)",
        ),
        (
            ["--no-dither", "--noise-level", "1,-2,3"],
            "--noise-level is '1,-2,3'; expected noise levels >= 0 N",
        ),
        (
            ["--noise-level", "1,2,3"],
            "--noise-level 1,2,3 is one condition's noise level; expected --dither or "
            "--no-dither with it",
        ),
        (
            ["--dither", "--noise-level", "1,2,3", "--report", "{rep_ok}"],
            "--noise-level and --report both give the noise level; expected one",
        ),
        (
            ["--noise-level", "1,2,3", "--dither", "--grid", "q2=0:1:2", "--map", "{tmp}/m.csv"],
            "--noise-level gives the noise level measured at one pose; expected no --map (the "
            "map predicts each pose's own)",
        ),
        (
            ["--report", "{tmp}/none.json"],
            "--report {tmp}/none.json: no such file; expected the report.json of ditherlab report",
        ),
        (
            ["--report", "{rep_list}"],
            "--report {rep_list}: no 'conditions'; expected the report.json of ditherlab report",
        ),
        (
            ["--dither", "--report", "{rep_nodither}"],
            "--report {rep_nodither}: no condition dither_band (it has dither_noband, "
            "nodither_band); expected a report of estimates with the dither_band variant (with "
            "dither)",
        ),
        (
            ["--no-dither", "--report", "{rep_nan}"],
            "--report {rep_nan}: condition nodither_band has noise level None along y; expected "
            "a number >= 0 N (rest samples on every axis)",
        ),
    ],
)
def test_bad_noise_input_is_one_line_and_exit_2(tmp_path, args, message):
    """Each mistake: one line on stderr naming the option or file, the value and what was
    expected; exit status 2; nothing on stdout, nothing written."""
    sub = {
        "tmp": str(tmp_path),
        "rep_ok": _report(tmp_path, {"dither_band": {"noise_level": NL}}),
        "rep_list": str(tmp_path / "list.json"),
        "rep_nodither": _report(
            tmp_path / "nd",
            {"nodither_band": {"noise_level": NL}, "dither_noband": {"noise_level": NL}},
        ),
        "rep_nan": _report(tmp_path / "nan", {"nodither_band": {"noise_level": {**NL, "y": None}}}),
    }
    (tmp_path / "list.json").write_text("[1, 2]")
    before = sorted(tmp_path.rglob("*"))

    def fill(s: str) -> str:
        for k, v in sub.items():
            s = s.replace("{" + k + "}", v)
        return s

    r = run_cli("robot", "irb140", "--sensitivity", *(fill(a) for a in args))
    assert (r.code, r.out, r.err) == (2, "", f"error: {fill(message)}\n")
    assert sorted(tmp_path.rglob("*")) == before


def test_not_json_and_without_sensitivity(tmp_path):
    """A report that is not JSON names the file and the parser's complaint; the noise options
    without --sensitivity are refused like the map's."""
    p = tmp_path / "r.json"
    p.write_text("{not json")
    r = run_cli("robot", "irb140", "--sensitivity", "--report", p)
    assert r.code == 2 and r.out == ""
    assert r.err.startswith(f"error: --report {p}: not JSON (Expecting property name ")
    assert r.err.endswith("; expected the report.json of ditherlab report\n")
    assert r.err.count("\n") == 1
    r = run_cli("robot", "irb140", "--noise-level", "1,2,3")
    assert (r.code, r.err) == (
        2,
        "error: robot: --map, --grid, --model, --dither, --noise-level and --report need "
        "--sensitivity\n",
    )


def test_sweep_prediction_given_the_measured_noise_level(tmp_path):
    """A small sweep (one pose away from the paper's, 4 pushes per axis and sign): each point
    carries the noise level measured at rest per condition, the predicted one, and both
    predictions; the threshold rises with the noise level, so the prediction given the measured
    level is above (below, equal to) the model's where the measured level is above (below,
    within 0.05 N of) the predicted, or equal where the rise falls between two of the campaign's
    forces (the report's logistic fit is over them; 4 pushes per axis and sign leave gaps of a
    few newtons), and above on some axis of a condition whose measured level is above. The
    table shows both, labelled."""
    out = tmp_path / "sw"
    r = run_cli(
        "sweep", "--grid", "pose.q0=-0.4:0.35:-0.6:0.5:1.1:0.4", "--grid",
        "push_campaign.magnitude_max=25", "--pushes-per-direction", "4", "--seed", "30",
        "--scheduler", "serial", "--bootstrap", "2", "-q", "-o", out,
    )  # fmt: skip
    assert r.code == 0, r.err
    row = pd.read_parquet(out / "sweep.parquet").iloc[0]
    for c in ("", "nodither_"):
        rose = []
        for a in "xyz":
            meas, pred = row[f"{c}noise_{a}"], row[f"pred_{c}noise_{a}"]
            assert meas >= 1.0 and pred >= 1.0  # the report's floor, both
            f_model, f_meas = row[f"pred_{c}f50_{a}"], row[f"predm_{c}f50_{a}"]
            assert np.isfinite(f_model) and np.isfinite(f_meas)
            if abs(meas - pred) <= 0.05:
                assert f_meas == pytest.approx(f_model, abs=0.3), (c, a)
            elif meas > pred:
                assert f_meas >= f_model, (c, a, meas, pred, f_meas, f_model)
                rose.append(f_meas > f_model)
            else:
                assert f_meas <= f_model, (c, a, meas, pred, f_meas, f_model)
        assert not rose or any(rose), c
    assert "(predicted: model; model + measured noise level)" in r.out
    assert "noise level x / y / z [N] (predicted)" in r.out
