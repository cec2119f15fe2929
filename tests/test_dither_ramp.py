"""Tests of the dither's ramp-in (ditherlab.physics.dither.ramp_in) and of its gate in the three
estimate paths: the offline replay (analysis/estimation.py), the causal general update and the
causal per-sample path. Right after the dither switches on, the extracted amplitude has not
reached its working level; a joint read with the narrow dither band then reports a force nobody
applies. The shipped simulated push campaign switches its dither on at 4.5 s with nobody pushing
(the sensor reads below 1.5 N for the next second)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import ditherlab.analysis.causal as causal_mod
import ditherlab.analysis.causal_fast as fast_mod
import ditherlab.analysis.estimation as estimation
from ditherlab.analysis.causal import CausalEstimator, block_of, settings_for
from ditherlab.analysis.estimation import RampCarry, replay
from ditherlab.data.torque_model import Band, TorqueModel
from ditherlab.io import read
from ditherlab.physics.dither import ramp_in, ramp_state

REC = Path(__file__).resolve().parents[1] / "recordings" / "sim-push-dither.parquet"
#: rows 700-1700: standing, the dither's switch-on at row 425 of the slice (4.5 s), no push
ROWS = slice(700, 1700)


def reference(flag, valid, amp, level, longest):
    """The rule read directly, switch-on by switch-on: after each false-to-true step of
    ``flag``, each joint up to its first sample with a whole window whose amplitude reaches its
    level, at most ``longest`` samples and while the flag stays on."""
    out = np.zeros(amp.shape, dtype=bool)
    for r in np.flatnonzero(~flag[:-1] & flag[1:]) + 1:
        hi = min(r + longest, len(flag))
        off = np.flatnonzero(~flag[r:hi])
        hi = r + off[0] if len(off) else hi
        for j in range(amp.shape[1]):
            if level[j] <= 0:
                continue
            up = np.flatnonzero(valid[r:hi] & (np.nan_to_num(amp[r:hi, j]) >= level[j]))
            out[r : r + (up[0] if len(up) else hi - r), j] = True
    return out


def _random_stream(seed: int, N: int = 4000, n: int = 3):
    rng = np.random.default_rng(seed)
    flag = np.repeat(rng.random(N // 200) < 0.6, 200)[:N]
    flag[rng.integers(0, N, 30)] ^= True  # short flickers
    valid = flag & (rng.random(N) < 0.9)
    amp = np.cumsum(rng.normal(0.02, 0.1, (N, n)), axis=0) % 3.0
    amp[rng.integers(0, N, 20), 0] = np.nan
    level = np.array([1.5, 2.5, 0.0])
    return flag, valid, amp, level


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ramp_in_is_the_rule_and_pieces_give_the_whole(seed):
    flag, valid, amp, level = _random_stream(seed)
    whole = ramp_in(flag, valid, amp, level, 150)
    np.testing.assert_array_equal(whole, reference(flag, valid, amp, level, 150))
    assert whole[:, 0].any() and whole[:, 1].any() and not whole[:, 2].any()
    # a stream in blocks, the state carried: the whole's marks
    st, parts = ramp_state(3), []
    for a in range(0, len(flag), 333):
        b = slice(a, a + 333)
        parts.append(ramp_in(flag[b], valid[b], amp[b], level, 150, st))
    np.testing.assert_array_equal(np.concatenate(parts), whole)
    assert not ramp_in(flag, valid, amp, None, 150).any()


def test_ramp_carry_across_overlapping_pieces():
    """Pieces with a context (halo) shorter than a ramp-in: the carried marks are the whole's
    on every row of every piece, the leading context included."""
    flag, valid, amp, level = _random_stream(3)
    longest, halo, rows = 400, 50, 300
    whole = ramp_in(flag, valid, amp, level, longest)
    carry = RampCarry()
    for a in range(0, len(flag), rows):
        lo, hi = max(a - halo, 0), min(a + rows + halo, len(flag))
        carry.at(lo, slice(a - lo, min(a + rows, len(flag)) - lo))
        got = carry.marks(flag[lo:hi], valid[lo:hi], amp[lo:hi], level, longest)
        np.testing.assert_array_equal(got, whole[lo:hi], err_msg=f"piece at {a}")
    assert (np.diff(np.flatnonzero(np.diff(whole[:, 0].astype(int)))) > halo).any()


def plant_model() -> TorqueModel:
    """Round values of the bands ``identify`` finds on the shipped push campaigns: still band
    about the static friction, dither band shrunk by the plant's dither amplitude."""
    half = np.array([9.8, 9.9, 8.2, 2.3, 2.2, 1.2])
    amp = np.array([9.0, 8.7, 7.2, 1.75, 1.75, 1.05])
    sigma = np.array([0.33, 0.32, 0.28, 0.076, 0.077, 0.046])
    return TorqueModel(
        "irb140",
        6,
        regimes={
            "still": Band(-half, half, sigma),
            "dither": Band(-(half - amp), half - amp, sigma / 2),
            "moving": Band(-half, half, sigma, coulomb=0.5 * half, viscous=half / 8),
        },
        prior_sigma=np.array([20.0, 20.0, 20.0, 0.3, 0.3, 0.3]),
    )


@pytest.fixture(scope="module")
def rec():
    whole = read(REC)
    return whole.with_data(whole.data.iloc[ROWS].reset_index(drop=True))


def _force(cols, v="dither_band") -> np.ndarray:
    """|F| (N,) [N] of a variant's estimate."""
    return np.linalg.norm(np.c_[cols[f"{v}/f_x"], cols[f"{v}/f_y"], cols[f"{v}/f_z"]], axis=1)


def _ramp_rows(rec) -> slice:
    """From the dither's switch-on to 0.9 s after it (the plant's ramp-in)."""
    r = int(np.flatnonzero(~rec.dither[:-1] & rec.dither[1:])[0]) + 1
    return slice(r, r + int(0.9 * rec.sample_rate))


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def test_offline_gate_keeps_the_standing_ramp_in_near_zero(rec, monkeypatch):
    """Nobody pushes during the ramp-in: with the gate the estimate stays near zero, without
    it (no level: nothing marked) the narrow dither band reads the growing dither as force."""
    model = plant_model()
    ramp = _ramp_rows(rec)
    assert np.linalg.norm(rec.wrench[ramp, :3], axis=1).max() < 1.5  # no push
    gated = replay(rec, model, variants=["dither_band"]).data
    monkeypatch.setattr(estimation, "ramp_level", lambda model: None)
    ungated = replay(rec, model, variants=["dither_band"]).data
    g, u = _force(gated), _force(ungated)
    assert _rms(g[ramp]) < 3.0
    assert _rms(u[ramp]) > 10.0
    # outside the ramp-in the gate changes nothing
    np.testing.assert_array_equal(g[: ramp.start], u[: ramp.start])
    np.testing.assert_array_equal(g[ramp.stop + 60 :], u[ramp.stop + 60 :])


@pytest.mark.parametrize("fast", [False, True])
def test_causal_gate_keeps_the_standing_ramp_in_near_zero(rec, fast, monkeypatch):
    """The same from the past alone, in both causal paths, in blocks."""
    model = plant_model()
    ramp = _ramp_rows(rec)
    s = settings_for(rec, variants=["dither_band"])

    def run():
        est = CausalEstimator(model, rec.meta, s, fast=fast)
        assert (est.fast is not None) == fast
        out = [est.update(block_of(rec, slice(a, a + 128))) for a in range(0, len(rec), 128)]
        return _force({k: np.concatenate([o[k] for o in out]) for k in out[0]})

    gated = run()
    monkeypatch.setattr(causal_mod, "ramp_level", lambda model: None)
    monkeypatch.setattr(fast_mod, "ramp_level", lambda model: None)
    ungated = run()
    assert _rms(gated[ramp]) < 3.0
    assert _rms(ungated[ramp]) > 10.0
    np.testing.assert_array_equal(gated[: ramp.start], ungated[: ramp.start])
