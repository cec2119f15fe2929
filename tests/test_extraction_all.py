"""``dither_extraction`` on every dithering joint a push loads (``Effect.on_every_joint``).

The extraction is a property of the measurement pipeline: it acts on every joint that dithers
and is pushed, not only where one recording's diagnosis evidence passed. Fitted only there (the
joints ``select_joints`` picks from the identification log's evidence), the other joints would
keep it in their residual and diagnose on the next clean log would suggest ``attenuation_lag``
for them: a false discovery (seeds 977 -> 978). Also: identification's dither residual windows
the model torque once (the effect's term is already the one-period mean).
"""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest
from conftest import run_cli

from ditherlab.analysis.identification import identify
from ditherlab.analysis.scoring import ACTS_SNR, acting_joints
from ditherlab.core.names import DITHER
from ditherlab.core.timeseries import causal_mean, jtf
from ditherlab.data.recording import regimes
from ditherlab.data.torque_model import EffectSpec
from ditherlab.io import read
from ditherlab.physics.effects import get_effect, signals
from ditherlab.physics.effects.extraction import extraction_window
from ditherlab.physics.residual import scored
from ditherlab.sim import simulate

#: the clean control's seeds (identification, evaluation)
ID_SEED, EV_SEED = 977, 978
PUSHES = 4  # per axis and sign: a 155 s campaign instead of 1 880 s


@pytest.fixture(scope="module")
def control(tmp_path_factory):
    """Dithered clean campaigns on seeds 977 and 978 (nothing hidden), and the model identified
    on 977 with what the plant has and the base model lacks: inertia and the extraction."""
    d = tmp_path_factory.mktemp("control")
    paths = {}
    for s in (ID_SEED, EV_SEED):
        p = d / f"c{s}.parquet"
        r = run_cli("simulate", "push-campaign", "--seed", str(s), "--dither",
                    "--pushes-per-direction", str(PUSHES), "-o", str(p), "-q")  # fmt: skip
        assert r.code == 0, r.err
        paths[s] = p
    r = run_cli(
        "identify", str(paths[ID_SEED]), "--bootstrap", "0", "-o", str(d / "base.toml"), "-q"
    )
    assert r.code == 0, r.err
    paths["base"] = d / "base.toml"
    model = d / "m.toml"
    r = run_cli("identify", str(paths[ID_SEED]), "--add", "inertia", "--add", "dither_extraction",
                "--bootstrap", "0", "-o", str(model), "-q")  # fmt: skip
    assert r.code == 0, r.err
    return paths, model


@pytest.mark.slow
@pytest.mark.study
def test_dithered_clean_control_suggests_nothing(control):
    """identify on the dithered clean campaign of seed 977 with ``--add inertia --add
    dither_extraction``, diagnose on seed 978's: nothing is suggested. (With the extraction on
    977's evidence joints only, joints 2 and 3 here, diagnose suggests attenuation_lag on
    joints 1 and 5: 41 % of the residual.)"""
    paths, model = control
    r = run_cli("diagnose", str(paths[EV_SEED]), "--model", str(model), "--json",
                "--no-history", "-q")  # fmt: skip
    assert r.code == 0, r.err
    assert "warning" not in r.err, r.err
    cands = json.loads(r.out)["candidates"]
    sug = [(c["effect"], c["joints"], c["explained_fraction"]) for c in cands if c["suggested"]]
    assert sug == [], sug
    best = {c["effect"]: c["explained_fraction"] for c in cands}
    assert best["attenuation_lag"] < 0.05, best


@pytest.mark.slow
@pytest.mark.study
def test_found_where_the_model_lacks_it_and_only_with_dither(tmp_path):
    """Diagnose still suggests dither_extraction on a dithered evaluation campaign when the
    model lacks it (the base model identified on the identification pair, seed 1, as
    ``make demo``), and not on the same campaign without dither, where its design is zero.
    (On the 4-push control of seed 977 alone it explains 3.7 %, below the 5 % rule: the campaign
    is too short. With joint 4's dithered band by the paper's rule alone, [-0.80, -0.04] N·m
    beside the rest at 0, it would be suggested there through that band.)"""
    paths = {}
    for s, d in ((1, "--no-dither"), (1, "--dither"), (0, "--dither"), (0, "--no-dither")):
        p = tmp_path / f"c{s}{d}.parquet"
        r = run_cli("simulate", "push-campaign", "--seed", str(s), d,
                    "--pushes-per-direction", "25", "-o", str(p), "-q")  # fmt: skip
        assert r.code == 0, r.err
        paths[s, d] = p
    base = tmp_path / "base.toml"
    r = run_cli("identify", str(paths[1, "--no-dither"]), str(paths[1, "--dither"]),
                "--bootstrap", "0", "-o", str(base), "-q")  # fmt: skip
    assert r.code == 0, r.err
    for rec, want in ((paths[0, "--dither"], True), (paths[0, "--no-dither"], False)):
        r = run_cli("diagnose", str(rec), "--model", str(base), "--json",
                    "--no-history", "-q")  # fmt: skip
        assert r.code == 0, r.err
        ext = [c for c in json.loads(r.out)["candidates"] if c["effect"] == "dither_extraction"]
        assert len(ext) == 1 and ext[0]["suggested"] is want, (rec, ext)


@pytest.mark.slow
def test_extraction_is_fitted_on_every_joint_a_push_loads(control):
    """The identified model has dither_extraction on every joint whose push torque (the
    one-period mean of J^T F while dithering, from the recording and the robot's Jacobian)
    exceeds 3x its dither noise: joints 1-5 of the IRB140 (all six dither); not joint 6, which a
    force at the tool point does not load (below its noise). Each gain is a part of the push
    (0.6-1.05: the extraction shows it in part), not fitted to noise."""
    paths, model = control
    m = tomllib.loads(model.read_text())
    spec = [e for e in m["effects"] if e["name"] == "dither_extraction"]
    assert len(spec) == 1
    joints = spec[0]["joints"]
    rec = read(paths[ID_SEED])
    X = jtf(rec.robot().jacobian(rec.q), rec.wrench)  # (N, n) [N·m]
    w = int(round(2 * np.pi / 80.0 * rec.sample_rate))  # the simulator's 80 rad/s dither
    dith = regimes(rec) == DITHER
    sigma = np.array(m["regimes"]["dither"]["sigma"])
    peak = np.array([np.max(np.abs(causal_mean(X, w)[:, j])[dith[:, j]]) for j in range(rec.n)])
    loaded = [j + 1 for j in range(rec.n) if peak[j] >= ACTS_SNR * sigma[j]]
    assert loaded == [1, 2, 3, 4, 5], (peak, sigma)
    assert peak[5] < sigma[5]  # joint 6: a force at the tool point does not load it
    assert joints == loaded
    gains = np.array(spec[0]["params"]["gain"])
    assert np.all((gains > 0.6) & (gains < 1.05)), gains


def test_acting_joints_needs_a_dithered_push():
    """acting_joints: every joint a push loads on a dithered campaign (1-5 of the IRB140); none
    on the same campaign without dither, where the extraction's design is zero."""
    e = get_effect("dither_extraction")
    for dither, want in ((True, [0, 1, 2, 3, 4]), (False, [])):
        rec = simulate("push-campaign", seed=5, pushes_per_direction=2, dither=dither)
        base = identify([rec], n_boot=0)
        assert acting_joints(e, [scored(base, rec)]) == want


def test_identify_reads_each_regime_through_its_own_torque():
    """Identification with the extraction in the model. The dither regime reads the extracted
    signal: with an extraction that shows the push exactly (gain 1, no lag: the one-period mean
    of J^T F) its residual equals the base model's, whose J^T F it passes through the same
    window; the effect's term is not windowed a second time (windowed twice, the dither noise of
    joint 2 moves from 0.13768 to 0.13775 N·m on this campaign). The still and moving regimes
    read the logged torque, which the extraction's view does not describe: with a realistic
    extraction (gain 0.8, lag 42 samples) their bands and sliding friction are the base model's
    (read through the extraction's view, joint 3's Coulomb friction falls from 5.8 to 0.6 N·m
    on seed 979's campaign)."""
    rec = simulate("push-campaign", seed=5, pushes_per_direction=2)
    assert extraction_window(signals(rec)) == 20  # samples: 2π / 80 rad/s at 250 Hz
    base = identify([rec], n_boot=0)

    def with_extraction(gain: float, lag: int):
        m = base.copy()
        m.effects = [
            EffectSpec(
                "dither_extraction", list(range(1, 7)), {"gain": [gain] * 6, "lag": [lag] * 6}
            )
        ]
        return identify([rec], base=m, n_boot=0)

    a = identify([rec], base=base, n_boot=0)
    exact = with_extraction(1.0, 0)
    np.testing.assert_allclose(exact.regimes["dither"].sigma, a.regimes["dither"].sigma, rtol=1e-9)
    real = with_extraction(0.8, 42)
    for name in ("still", "moving"):
        for k in ("tau_min", "tau_max", "sigma", "coulomb", "viscous"):
            got, want = getattr(real.regimes[name], k), getattr(a.regimes[name], k)
            if want is not None:
                np.testing.assert_allclose(got, want, rtol=1e-9, err_msg=f"{name}.{k}")
