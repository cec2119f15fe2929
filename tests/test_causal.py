"""Tests of ditherlab.analysis.causal: the per-sample causal estimate behind ``replay --causal``
and ``live``, against a slow reference written from its definition, and its independence of the
future and of how the stream is cut into blocks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from ditherlab.analysis.causal import (
    DDQ_SPAN,
    MOVING_THRESHOLD,
    CausalEstimator,
    block_of,
    settings_for,
)
from ditherlab.analysis.estimation import ReplayHow, ReplayInputs, variant_estimate
from ditherlab.core.errors import ConfigError
from ditherlab.core.names import DITHER, MOVING, STILL
from ditherlab.core.stamps import wire_time
from ditherlab.core.ticker import Ticker
from ditherlab.data.estimates import COMPONENTS, Estimates
from ditherlab.data.recording import regimes
from ditherlab.data.torque_model import Band, EffectSpec, TorqueModel
from ditherlab.io import read, write
from ditherlab.physics.dither import (
    AMPLITUDE_UP_FRACTION,
    RAMP_MAX_S,
    Extraction,
    band_amplitude,
)
from ditherlab.physics.effects import force_gain

REC = Path(__file__).resolve().parents[1] / "recordings" / "sim-push-dither.parquet"
ROWS = slice(900, 1500)  # the excitation's end (moving), the dither's start, a push


def irb140_model() -> TorqueModel:
    """A model of the simulated IRB140's still, dither and moving bands (round values)."""
    half = np.array([8.0, 8.0, 8.0, 2.0, 2.0, 1.0])
    sigma = np.array([0.5, 0.5, 0.5, 0.1, 0.1, 0.05])
    return TorqueModel(
        "irb140",
        6,
        regimes={
            "still": Band(-half, half, sigma),
            "dither": Band(-0.3 * half, 0.3 * half, sigma / 4),
            "moving": Band(-0.2 * half, 0.2 * half, sigma, coulomb=0.9 * half, viscous=half / 8),
        },
    )


@pytest.fixture(scope="module")
def rec():
    whole = read(REC)
    return whole.with_data(whole.data.iloc[ROWS].reset_index(drop=True))


@pytest.fixture(scope="module")
def model():
    return irb140_model()


def run_blocks(rec, model, size: int, rows: int | None = None) -> dict[str, np.ndarray]:
    """The causal estimate of the first ``rows`` samples, fed in blocks of ``size``."""
    est = CausalEstimator(model, rec.meta, settings_for(rec))
    N = len(rec) if rows is None else rows
    out = [est.update(block_of(rec, slice(a, min(a + size, N)))) for a in range(0, N, size)]
    return {k: np.concatenate([o[k] for o in out]) for k in out[0]}


def reference(rec, model) -> dict[str, np.ndarray]:
    """Every sample's estimate from its own past, written from the definitions one sample at a
    time: backward differences, trailing means, the dither's period means by comparison,
    gravity's mean over the last period, the dither's ramp-in from the last switch-on
    (:func:`_in_ramp`)."""
    s = settings_for(rec)
    W = s.windows()
    t, dq, tau, on = wire_time(rec.t), rec.dq, rec.tau, rec.dither
    Wx = max(2, int(round(s.period / s.dt)))
    robot, gain = rec.robot(), force_gain(model)
    how = ReplayHow(s.level, s.interval, "exact", list(COMPONENTS))
    out: dict[str, list] = {}
    st, db = model.regimes["still"], model.regimes["dither"]
    level = AMPLITUDE_UP_FRACTION * band_amplitude(st.tau_min, st.tau_max, db.tau_min, db.tau_max)
    amps, valids = [], []
    for i in range(len(t)):
        moving = np.abs(dq[max(0, i - W["move"] + 1) : i + 1].mean(axis=0)) > MOVING_THRESHOLD
        reg = np.where(moving, MOVING, DITHER if on[i] else STILL).astype(np.int8)[None, :]
        win = tau[max(0, i - Wx + 1) : i + 1]
        c = win.mean(axis=0)
        up = np.array([_mean_or(win[win[:, j] > c[j], j], c[j]) for j in range(6)])
        low = np.array([_mean_or(win[win[:, j] < c[j], j], c[j]) for j in range(6)])
        p = W["period"]
        valid = i >= p - 1 and bool(on[max(0, i - p + 1) : i + 1].all())
        amps.append(0.5 * (up - low))
        valids.append(valid)
        ramp = _in_ramp(on[: i + 1], np.array(valids), np.array(amps), level, s.dt)
        ext = Extraction(
            up[None], low[None], (0.5 * (up + low))[None], c[None], (0.5 * (up - low))[None],
            on[i : i + 1], np.array([valid]), s.period, ramp=ramp[None],
        )  # fmt: skip
        g, J = robot.gravity_jacobian(rec.q[i : i + 1])
        J = J * gain[None, None, :]
        base = (tau[i : i + 1] - g, *model.sample_bands(reg, dq[i : i + 1]))
        dq_mean = dq[max(0, i - p + 1) : i + 1].mean(axis=0)[None]
        # gravity as the extraction shows it: its mean over the same last period
        seen = robot.gravity(rec.q[max(0, i - p + 1) : i + 1]).mean(axis=0)[None]
        inp = ReplayInputs(g, J, np.zeros_like(g), reg, base, ext, p, dq_mean, seen)
        for v in s.variants:
            F, _, lo, hi = variant_estimate(v, inp, model, how, Ticker(2, None))
            for name, M in ((v, F), (v + "_lo", lo), (v + "_hi", hi)):
                out.setdefault(name, []).append(M[0])
    return {k: np.array(v) for k, v in out.items()}


def _in_ramp(on, valid, amp, level, dt) -> np.ndarray:
    """(n,) bool: the joints in the dither's ramp-in at the last of the samples so far: the
    flag ``on`` switched on at ``r`` (off just before) less than ``RAMP_MAX_S`` ago and stayed
    on, and no sample since ``r`` with a whole window has the joint's amplitude at ``level``."""
    i = len(on) - 1
    starts = [r for r in range(1, i + 1) if on[r] and not on[r - 1]]
    if not starts or not on[starts[-1] : i + 1].all():
        return np.zeros(len(level), bool)
    r = starts[-1]
    if i - r >= int(round(RAMP_MAX_S / dt)):
        return np.zeros(len(level), bool)
    up = (valid[r:, None] & (amp[r:] >= level[None, :])).any(axis=0)
    return ~up & (level > 0)


def _mean_or(x: np.ndarray, empty: float) -> float:
    """The mean of ``x``, or ``empty`` when it holds nothing."""
    return float(x.mean()) if len(x) else empty


def test_causal_matches_the_slow_reference(rec, model):
    """Every variant's estimate and interval at every sample equals the reference computed from
    that sample's past alone (over a motion's end, the dither's start and a push)."""
    got = run_blocks(rec, model, 256)
    ref = reference(rec, model)
    assert len(got["t"]) == len(rec)
    for name, R in ref.items():
        v, suffix = (name[:-3], name[-3:]) if name[-3:] in ("_lo", "_hi") else (name, "")
        G = np.column_stack([got[f"{v}/{c}{suffix}"] for c in COMPONENTS])
        np.testing.assert_allclose(G, R, atol=1e-6, rtol=1e-9, err_msg=name)


def test_the_past_does_not_see_the_future(rec, model):
    """The estimate of the first 300 samples alone equals the first 300 rows of the estimate of
    all 600, bit for bit: no sample reads a later one."""
    whole = run_blocks(rec, model, 600)
    head = run_blocks(rec, model, 300, rows=300)
    for k, v in head.items():
        np.testing.assert_array_equal(v, whole[k][:300], err_msg=k)


def test_blocks_do_not_change_the_estimate(rec, model):
    """Fed one sample at a time or in blocks of 97, every column is the same bit for bit."""
    a = run_blocks(rec, model, 97, rows=200)
    b = run_blocks(rec, model, 1, rows=200)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_regime_and_acceleration_lag_the_offline_ones(rec, model):
    """The causal ddq is the backward difference over DDQ_SPAN, and a joint counts as moving
    until the trailing mean falls below the threshold (after the offline centred mean does)."""
    est = CausalEstimator(model, rec.meta, settings_for(rec))
    b = block_of(rec)
    X = est._joined(b)
    f = est._features(X, len(b.t))
    k = int(round(DDQ_SPAN / rec.dt))
    i = 400
    want = (rec.dq[i] - rec.dq[i - k]) / (b.t[i] - b.t[i - k])
    np.testing.assert_allclose(f["ddq"][i], want, rtol=1e-12)
    off_last = np.flatnonzero((regimes(rec) == MOVING).any(axis=1))[-1]
    causal_last = np.flatnonzero((f["reg"] == MOVING).any(axis=1))[-1]
    assert causal_last > off_last


def test_bad_samples_are_refused(rec, model):
    """A time not after the last one, or a NaN, is one ConfigError naming it."""
    est = CausalEstimator(model, rec.meta, settings_for(rec))
    est.update(block_of(rec, slice(0, 10)))
    with pytest.raises(ConfigError, match="is not after the previous one"):
        est.update(block_of(rec, slice(5, 12)))
    b = block_of(rec, slice(10, 12))
    q = b.q.copy()
    q[1, 2] = np.nan
    with pytest.raises(ConfigError, match="q at t = .* is not finite"):
        est.update(b._replace(q=q))


def test_cli_replay_causal(tmp_path, rec, model, cli):
    """``replay --causal`` writes the offline replay's columns, the causal settings in its
    metadata, and estimates equal to the estimator fed directly."""
    r, m = tmp_path / "r.parquet", tmp_path / "m.toml"
    write(rec.with_data(rec.data.iloc[:300].reset_index(drop=True)), r)
    model.save(m)
    off, cau = tmp_path / "off.parquet", tmp_path / "cau.parquet"
    assert cli("replay", r, "--model", m, "-o", off, "--quiet").code == 0
    res = cli("replay", r, "--model", m, "-o", cau, "--causal", "--quiet")
    assert res.code == 0, res.err
    a, b = pq.read_table(off), pq.read_table(cau)
    assert a.column_names == b.column_names
    direct = run_blocks(rec, model, 300, rows=300)
    for k in ("dither_band/f_x", "nodither_noband/m_z_hi", "t"):
        np.testing.assert_array_equal(b.column(k).to_numpy(), direct[k])
    meta = Estimates.load(cau).meta
    assert meta["causal"]["ddq_span"] == DDQ_SPAN


def test_a_gap_starts_afresh(rec, model):
    """After a 5 s gap the estimate equals a fresh estimator's on the samples after it: no
    window reaches across the gap, and the gap is counted."""
    data = rec.data.iloc[:400].copy()
    data.loc[200:, "t"] += 5.0
    gapped = rec.with_data(data.reset_index(drop=True))
    est = CausalEstimator(model, rec.meta, settings_for(rec))
    whole = est.update(block_of(gapped))
    assert est.gaps == 1
    fresh = CausalEstimator(model, rec.meta, settings_for(rec))
    after = fresh.update(block_of(gapped, slice(200, 400)))
    for k, v in after.items():
        np.testing.assert_array_equal(whole[k][200:], v, err_msg=k)


def extraction_model() -> TorqueModel:
    """:func:`irb140_model` with a ``dither_extraction`` on joints 1-5 (gains and lags in the
    effect's ranges, of the size the demo identifies)."""
    model = irb140_model()
    model.effects = [
        EffectSpec(
            "dither_extraction",
            [1, 2, 3, 4, 5],
            {"gain": [0.84, 0.9, 0.8, 0.7, 0.84], "lag": [16, 10, 0, 5, 16]},
        )
    ]
    return model


def test_extraction_lead_across_blocks_equals_the_whole_stream(monkeypatch):
    """With ``dither_extraction`` the general update's dither variants read the extraction's
    lead over the kept past: fed in blocks of 50 (more than the lead's span of half a period),
    the torque they read equals :func:`extraction_lead` of the whole stream's inputs bit for
    bit, the lead moves it on the dithered rows, and one sample at a time gives the same
    estimate bit for bit."""
    import ditherlab.analysis.estimation as estimation

    whole = read(REC)
    part = whole.with_data(whole.data.iloc[1000:1400].reset_index(drop=True))
    model, s = extraction_model(), settings_for(part)
    calls, lead = [], estimation.extraction_lead

    def spy(tb, model, reg, ext, w, past=None):
        out = lead(tb, model, reg, ext, w, past)
        calls.append((tb, reg, ext, w, out))
        return out

    monkeypatch.setattr(estimation, "extraction_lead", spy)
    est = CausalEstimator(model, part.meta, s, fast=False)
    blocks = [est.update(block_of(part, slice(a, a + 50))) for a in range(0, len(part), 50)]
    mine = calls[:: sum(v.startswith("dither") for v in s.variants)]  # dither_band's
    cat = {f: np.concatenate([getattr(c[2], f) for c in mine]) for f in EXT_ROWS}
    ext = Extraction(**cat, period=s.period, waveform=s.waveform)
    tb, reg = (np.concatenate([c[i] for c in mine]) for i in (0, 1))
    want = lead(tb, model, reg, ext, mine[0][3])
    got = np.concatenate([c[4] for c in mine])
    np.testing.assert_array_equal(got, want)
    assert (np.abs(got - tb).max(axis=1) > 0.05).sum() > 50
    monkeypatch.setattr(estimation, "extraction_lead", lead)
    one = CausalEstimator(model, part.meta, s, fast=False)
    each = [one.update(block_of(part, slice(i, i + 1))) for i in range(200)]
    for k in blocks[0]:
        a = np.concatenate([b[k] for b in blocks])[:200]
        np.testing.assert_array_equal(np.concatenate([e[k] for e in each]), a, err_msg=k)


#: the extraction's per-row fields (:class:`Extraction`)
EXT_ROWS = ("upper", "lower", "signal", "centre", "amplitude", "on", "valid", "ramp")


@pytest.mark.parametrize("fast", [False, True])
def test_extraction_lead_starts_afresh_after_a_gap(fast):
    """With ``dither_extraction``, after a 5 s gap the estimate equals a fresh estimator's on
    the samples after it (the lead reads no row before the gap), in the general update and the
    per-sample path, and the effect moves the dither variants' estimate there."""
    whole = read(REC)
    data = whole.data.iloc[1000:1400].copy()
    data.loc[data.index[200:], "t"] += 5.0
    gapped = whole.with_data(data.reset_index(drop=True))
    model, s = extraction_model(), settings_for(gapped)
    est = CausalEstimator(model, gapped.meta, s, fast=fast)
    assert (est.fast is not None) == fast
    out = est.update(block_of(gapped))
    assert est.gaps == 1
    after = CausalEstimator(model, gapped.meta, s, fast=fast).update(
        block_of(gapped, slice(200, 400))
    )
    for k, v in after.items():
        np.testing.assert_array_equal(out[k][200:], v, err_msg=k)
    plain = CausalEstimator(irb140_model(), gapped.meta, s, fast=fast).update(block_of(gapped))
    assert np.abs(plain["dither_band/f_x"] - out["dither_band/f_x"])[200:].max() > 0.5
