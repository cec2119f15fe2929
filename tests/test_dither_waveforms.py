"""Dither waveforms (square, sine, triangle): generation, extraction, metadata and simulation.

The paper (§VII) left waveforms other than its square wave to future work. Each waveform is of
unit peak, zero mean over whole periods and positive on the first half period; the extraction's
``signal`` is the window mean for each, and its ``amplitude`` is the peak (the paper's
``(upper - lower) / 2`` times :data:`ditherlab.physics.dither.PEAK_FACTOR`).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from ditherlab.core.errors import ConfigError
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.physics import dither as D
from ditherlab.robot import PAPER_POSE, RobotModel
from ditherlab.sim import simulate
from ditherlab.sim.engine import Engine, Inputs
from ditherlab.sim.params import load_params

FS = 250.0  # [Hz]
OMEGA = 80.0  # [rad/s]
PERIOD = 2 * np.pi / OMEGA  # [s]
WAVES = D.WAVEFORMS


# ------------------------------------------------------------------ generation
@pytest.mark.parametrize("waveform", WAVES)
def test_wave_mean_peak_and_mean_abs_over_whole_periods(waveform):
    """Over whole periods the wave has zero mean, its peak is the amplitude, and its mean
    absolute value is the amplitude over the waveform's peak factor (1, pi/2, 2)."""
    n = 4000  # samples per period
    t = (np.arange(10 * n) + 0.5) * PERIOD / n  # 10 whole periods, midpoints
    A = 2.5
    w = D.wave(t, OMEGA, A, waveform)
    assert abs(w.mean()) < 1e-9 * A
    # the samples straddle the peaks by half a step: within 2 A / n of it
    assert abs(w.max() - A) < 2.01 * A / n and abs(w.min() + A) < 2.01 * A / n
    assert abs(np.abs(w).mean() - A / D.PEAK_FACTOR[waveform]) < 1e-6 * A
    first = t < PERIOD / 2
    assert np.all(w[first] > 0) and np.all(w[~first & (t < PERIOD)] < 0)


@pytest.mark.parametrize("waveform", WAVES)
@pytest.mark.parametrize("omega", [40.0, 80.0, 160.0])
def test_wave_frequency_from_its_zero_crossings(waveform, omega):
    """The sampled wave changes sign twice per period of 2 pi / omega (within one crossing)."""
    t = np.arange(5000) / FS  # 20 s
    w = D.wave(t, omega, 1.0, waveform)
    crossings = np.count_nonzero(np.signbit(w[1:]) != np.signbit(w[:-1]))
    assert abs(crossings - 2 * t[-1] * omega / (2 * np.pi)) <= 1


def test_wave_shapes():
    """Square equals square_wave bit for bit, per joint column too; sine is sin; the triangle is
    linear between its peaks (constant slope 2 A omega / pi)."""
    t = np.arange(3000) / FS
    amp = np.array([1.0, 3.0])
    np.testing.assert_array_equal(D.wave(t, OMEGA, amp, "square"), D.square_wave(t, OMEGA, amp))
    np.testing.assert_array_equal(D.wave(t, OMEGA, 2.0, "sine"), 2.0 * np.sin(OMEGA * t))
    tt = np.linspace(0.3 * PERIOD, 0.7 * PERIOD, 101)  # between the peaks at 1/4 and 3/4
    slope = np.diff(D.wave(tt, OMEGA, 2.0, "triangle")) / np.diff(tt)
    np.testing.assert_allclose(slope, -2 * 2.0 * OMEGA / np.pi, rtol=1e-9)
    assert D.wave(t, OMEGA, amp, "triangle").shape == (3000, 2)


# ------------------------------------------------------------------ extraction
def _dithered(waveform, amp=(3.0, 1.0), step=1.5, t_step=4.0, noise=0.02, N=2500, seed=4):
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    w = D.wave(t, OMEGA, np.array(amp), waveform)
    ext = np.where(t >= t_step, step, 0.0)[:, None] * np.ones(len(amp))
    return t, w + ext + rng.normal(size=w.shape) * noise


@pytest.mark.parametrize("waveform", WAVES)
def test_extract_recovers_step_and_peak_amplitude_for_each_waveform(waveform):
    """On wave + step + noise the signal recovers the step and the amplitude the peak (2 %)."""
    t, tau = _dithered(waveform)
    ds = D.extract(tau, t, period=PERIOD, periods=2, waveform=waveform)
    assert ds.waveform == waveform
    before = (t > 1.0) & (t < 3.9)
    after = t > 4.0 + 2 * PERIOD + 0.05
    for j, amp in enumerate((3.0, 1.0)):
        assert abs(ds.signal[before, j].mean()) < 0.02
        assert abs(ds.signal[after, j].mean() - 1.5) < 0.02
        assert abs(np.median(ds.amplitude[before, j]) - amp) < 0.02 * amp
        # the signal is the window mean: the same on average as the centre
        assert abs(ds.signal[after, j].mean() - ds.centre[after, j].mean()) < 0.01


@pytest.mark.parametrize("waveform", WAVES)
def test_extract_signal_ripple_of_a_non_integer_period_is_small(waveform):
    """A clean wave in 20-sample windows (19.63 samples a period): the square wave's
    ``(upper + lower) / 2`` does not ripple; for a sine or triangle it would by 5-6 % of A, so
    their signal is the mean over exactly whole periods: below 0.4 % of A with one period per
    window and 0.1 % with three. upper, lower and centre do not depend on the waveform
    argument; the amplitude is scaled to the peak."""
    t = np.arange(5000) / FS
    w = D.wave(t, OMEGA, 3.0, waveform)[:, None]
    for periods, bound in ((1, 0.004), (3, 0.001)):
        ds = D.extract(w, t, period=PERIOD, periods=periods, waveform=waveform)
        f = ds.full & (t > 1.0)
        assert np.ptp(ds.signal[f]) / 2 < bound * 3.0, (periods, np.ptp(ds.signal[f]))
        paper = 0.5 * (ds.upper[f] + ds.lower[f])
        if waveform == "square":
            np.testing.assert_array_equal(ds.signal[f], paper)
        else:
            assert np.ptp(paper) / 2 > 0.01 * 3.0  # what the paper's signal would do here
    sq = D.extract(w, t, period=PERIOD, periods=3, waveform="square")
    for k in ("upper", "lower", "centre"):
        np.testing.assert_array_equal(getattr(sq, k), getattr(ds, k))
    np.testing.assert_allclose(ds.amplitude, D.PEAK_FACTOR[waveform] * sq.amplitude, rtol=1e-15)


def test_period_mean_against_a_loop():
    """The exact-period mean: floor(L) newest samples plus the fraction of the one before, over
    L; the samples so far at the start; one whole period of a sine averages to zero."""
    x = np.random.default_rng(0).normal(size=(300, 2))
    L = 19.63
    got = D._period_mean(x, L)
    ref = [(x[i - 18 : i + 1].sum(0) + 0.63 * x[i - 19]) / L for i in range(19, 300)]
    np.testing.assert_allclose(got[19:], ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(got[:19], np.cumsum(x, 0)[:19] / np.arange(1, 20)[:, None])
    t = np.arange(1000) / FS
    s = D._period_mean(np.sin(OMEGA * t)[:, None], PERIOD * FS)
    assert np.max(np.abs(s[20:])) < 0.003


def test_extract_unknown_waveform():
    """An unknown waveform name is a ConfigError naming it and the known ones."""
    t, tau = _dithered("square", N=100)
    with pytest.raises(ConfigError, match=r"dither: waveform = 'saw'; expected one of square, sine, triangle"):  # fmt: skip
        D.extract(tau, t, period=PERIOD, waveform="saw")


def _recording(waveform_meta, waveform="sine", A=2.0):
    t = np.arange(3000) / FS
    n = 6
    w = D.wave(t, OMEGA, A, waveform)
    tau = np.tile(w[:, None], (1, n))
    meta = {"robot": "irb140"}
    if waveform_meta is not None:
        meta["dither"] = {"waveform": waveform_meta}
    return Recording.from_arrays(
        RecordingArrays(t, np.zeros((len(t), n)), tau, tau_ffw=tau, dither=np.ones(len(t), bool)),
        meta,
    )


def test_extract_dither_reads_the_waveform_from_the_metadata():
    """A recording stating ``dither.waveform = sine`` gets the sine's peak as its amplitude (and
    so the band shrunk by the peak) and the exact-period mean as its signal; without the key it
    is square: the amplitude is the mean |w| = 2 A / pi of the same data and the signal the
    paper's, which ripples on a sine."""
    A = 2.0
    sine = D.extract_dither(_recording("sine", A=A))
    plain = D.extract_dither(_recording(None, A=A))
    assert sine.waveform == "sine" and plain.waveform == "square"
    k = slice(100, None)
    assert abs(np.median(sine.amplitude[k]) - A) < 0.02 * A
    assert abs(np.median(plain.amplitude[k]) - 2 * A / np.pi) < 0.02 * A
    # both signals average the wave away; the exact-period mean without the ripple
    assert abs(sine.signal[k].mean()) < 0.01 and abs(plain.signal[k].mean()) < 0.01
    assert np.ptp(sine.signal[k]) / 2 < 0.01 * A < 0.05 * A < np.ptp(plain.signal[k]) / 2
    lo, hi = D.dithered_band(-5.0, 5.0, sine.amplitude[k])
    assert abs(np.median(hi - lo) - (10.0 - 2 * A)) < 0.05 * A


def test_dither_waveform_metadata():
    """The waveform from the metadata: the top-level key, else the simulator's parameters,
    else square; an unknown name is one ConfigError naming the key and the value."""
    assert D.dither_waveform({}) == "square"
    assert D.dither_waveform({"dither": {"period": 0.08}}) == "square"
    assert D.dither_waveform({"dither": {"waveform": "triangle"}}) == "triangle"
    sim = {"sim": {"params": {"dither": {"waveform": "sine"}}}}
    assert D.dither_waveform(sim) == "sine"
    with pytest.raises(ConfigError) as e:
        D.dither_waveform({"dither": {"waveform": "Sine"}})
    assert str(e.value) == (
        "metadata key dither.waveform = 'Sine'; expected one of square, sine, triangle"
    )


# ------------------------------------------------------------------ simulator
def test_params_reject_unknown_waveform_and_wrong_type():
    """The simulator's parameters: one line naming the key, the value and what was expected."""
    with pytest.raises(ConfigError) as e:
        load_params(overrides={"dither": {"waveform": "sawtooth"}})
    assert str(e.value) == (
        "options: dither.waveform: got 'sawtooth'; expected one of 'square', 'sine', 'triangle'"
    )
    with pytest.raises(ConfigError) as e:
        load_params(overrides={"dither": {"waveform": 3}})
    assert str(e.value) == (
        "options: dither.waveform: got 3; expected one of 'square', 'sine', 'triangle'"
    )
    with pytest.raises(ConfigError) as e:
        simulate("push-campaign", config={"dither": {"waveform": "saw"}}, pushes_per_direction=1)
    assert str(e.value) == (
        "config: dither.waveform: got 'saw'; expected one of 'square', 'sine', 'triangle'"
    )


@functools.lru_cache(maxsize=1)
def _robot() -> RobotModel:
    return RobotModel.from_spec("irb140")


@functools.lru_cache(maxsize=16)
def _dither_run(waveform: str, omega: float = 80.0):
    """Joint 2 dithering in the paper's pose for 5 s (t, outputs, engine)."""
    J = 1
    p = load_params(
        overrides={
            "dither": {
                "waveform": waveform,
                "frequency": omega,
                "joints": [i == J for i in range(6)],
                "amplitude_fraction": 0.9,
            }
        }
    )
    eng = Engine(p, _robot())
    N = int(5 * FS)
    q0 = np.asarray(PAPER_POSE, dtype=float)
    inp = Inputs.still(N, q0)
    inp.dither_cmd[125:] = 1.0
    return np.arange(N) / FS, eng.run(inp, eng.initial_state(q0)), eng


@pytest.mark.parametrize("waveform", WAVES)
@pytest.mark.parametrize("omega", [40.0, 160.0])
def test_simulated_dither_has_the_waveform_frequency_and_peak(waveform, omega):
    """The simulator's feedforward is the waveform at omega (period within 0.5 %, shape within
    3 % of its peak), and the loop brings the logged torque's peak amplitude to the set-point
    (0.9 Fs, within the loops' 2 % hold band plus 4 %)."""
    J = 1
    t, o, eng = _dither_run(waveform, omega)
    settled = (t > 3.0) & (t < 5.0)
    ffw = o.tau_ffw[settled, J]
    # frequency: the strongest spectral line of the feedforward, within one bin (0.5 Hz)
    spec = np.abs(np.fft.rfft(ffw - ffw.mean()))
    f_hz = np.fft.rfftfreq(len(ffw), 1 / FS)[np.argmax(spec)]
    assert abs(f_hz - omega / (2 * np.pi)) <= 0.5
    # over the settled stretch c and a barely move: ffw = c + a w(omega t_clock)
    c, a = o.centre_ffw[settled, J], o.amp_ffw[settled, J]
    shape = (ffw - c) / a
    assert np.max(np.abs(shape)) <= 1.0 + 1e-12
    if waveform == "square":
        assert set(np.unique(np.abs(shape).round(12))) == {1.0}
    else:  # a sampled sine/triangle: samples below the peak, mean |w| near 1 / peak factor
        assert abs(np.abs(shape).mean() - 1 / D.PEAK_FACTOR[waveform]) < 0.03
    ex = D.extract(o.tau[:, J], t, period=2 * np.pi / omega, periods=5, waveform=waveform)
    fs = eng.fs[J]
    assert abs(np.mean(ex.amplitude[settled]) - 0.9 * fs) < (0.04 + 0.04) * fs


def test_default_square_simulation_is_unchanged():
    """The default (square) push campaign is pinned: sums and samples of seed 0's dithered
    campaign (4 pushes per direction) on this plant (the friction band behind the gear spring,
    the operator's pace, the links' inverse mass matrix by a Cholesky in compiled loops,
    independent of the BLAS kernel), to 1e-12 relative: re-record only on a deliberate change of
    the plant. Stating ``waveform = "square"`` changes nothing, and the recording says which
    waveform it has."""
    rec = simulate("push-campaign", seed=0, dither=True, pushes_per_direction=4)
    expected = {  # column: (sum, sum of |x|, x[5000], x[12345])
        "tau_2": (-2174065.106836064, 2177102.812517944, -45.81910310280565, -44.76744631861143),
        "tau_ffw_2": (-256420.79570538952, 437773.42179964273, 2.0799640497946283, -7.352667552862199),
        "q_2": (-87.63111509576731, 144.58040988066594, -0.002360169672419422, -0.005126509891827584),
        "tau_5": (-1113.6107304287766, 63914.35247418483, 1.6697532311344916, 1.6147951703443868),
    }  # fmt: skip
    assert len(rec) == 40794
    for col, (s, sa, x0, x1) in expected.items():
        x = rec.data[col].to_numpy()
        np.testing.assert_allclose([np.sum(x), np.sum(np.abs(x)), x[5000], x[12345]],
                                   [s, sa, x0, x1], rtol=1e-12)  # fmt: skip
    assert rec.meta["dither"] == {"waveform": "square", "omega": 80.0}
    assert D.dither_period(rec) == 2 * np.pi / 80.0
    plain = simulate("push-campaign", seed=0, dither=False, pushes_per_direction=1)
    assert "dither" not in plain.meta  # no dither applied, none stated
    same = simulate(
        "push-campaign", seed=0, dither=True, pushes_per_direction=4,
        config={"dither": {"waveform": "square"}},
    )  # fmt: skip
    assert same.data.equals(rec.data)
