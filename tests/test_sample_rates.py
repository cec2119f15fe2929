"""Every command's defaults at any sample rate from 50 Hz to 5 kHz: one simulated push campaign,
resampled, read through the commands' API paths (``ditherlab.app``) with default options.

The extremes (50 Hz, and a 9 s log at 5 kHz, shorter than diagnosis's four 12 s contexts) run in
``make test``; the whole grid (50 Hz, 250 Hz, 1 kHz, 5 kHz) is ``@pytest.mark.study``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import ditherlab.io as dio
from ditherlab.app import convert, diagnose, identify, info, replay, report, view
from ditherlab.core.errors import ConfigError
from ditherlab.data.estimates import Estimates
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.io.stream import open_source
from ditherlab.sim import simulate

#: [s] the campaign's stretch that is resampled: a still start, dither and pushes
SPAN_S = 40.0


def resample(rec: Recording, rate: float, duration: float | None = None) -> Recording:
    """``rec`` logged at ``rate`` [Hz] over its first ``duration`` [s] (None: all): the numeric
    columns interpolated linearly in time, the flags and the feedforward (a square wave) held
    from the last sample, ``sample_rate_hz`` set."""
    t = rec.t
    end = t[-1] if duration is None else min(t[-1], t[0] + duration)
    tn = t[0] + np.arange(int(np.floor((end - t[0]) * rate)) + 1) / rate
    held = np.clip(np.searchsorted(t, tn, side="right") - 1, 0, len(t) - 1)
    cols = {}
    for c in rec.data.columns:
        v = rec.data[c].to_numpy()
        if c == "t":
            cols[c] = tn
        elif v.dtype == bool or str(c).startswith("tau_ffw") or c == "push":
            cols[c] = v[held]
        else:
            cols[c] = np.interp(tn, t, v.astype(float))
    meta = {**rec.meta, "sample_rate_hz": float(rate)}
    return Recording(pd.DataFrame(cols), meta, name=f"{rate:g} Hz")


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> tuple[Recording, Path, dict]:
    """A dithered push campaign of the built-in simulator at 250 Hz (one push per axis and sign,
    its first :data:`SPAN_S` seconds), the model ``identify`` fits on it with default options,
    and what ``diagnose`` finds with that model at 250 Hz."""
    d = tmp_path_factory.mktemp("rates")
    rec = simulate("push-campaign", seed=1, dither=True, pushes_per_direction=1)
    rec = rec.slice(t1=rec.t[0] + SPAN_S)
    src = dio.write(rec, d / "rec.parquet")
    identify.run(identify.IdentifyOptions(recordings=(src,), out=d / "model.toml"))
    ref = diagnose.run(diagnose.DiagnoseOptions(recordings=(src,), model=d / "model.toml"))
    return rec, d / "model.toml", ref.diagnosis.to_dict()["residual"]


def _reading_commands(src: Path, model: Path, d: Path) -> dict:
    """info, convert, replay, diagnose and view of the recording ``src`` with the model
    ``model``, default options; what each found."""
    found = {"info": info.run(info.InfoOptions(file=src)).summary}
    convert.run(convert.ConvertOptions(src=src, dst=d / "rec.csv"))
    assert dio.read(d / "rec.csv").equals(dio.read(src))
    replay.run(replay.ReplayOptions(recording=src, model=model, out=d / "e.parquet"))
    found["estimates"] = Estimates.load(d / "e.parquet")
    diag = diagnose.run(diagnose.DiagnoseOptions(recordings=(src,), model=model, out=d / "diag"))
    found["residual"] = diag.diagnosis.to_dict()["residual"]
    view.run(
        view.ViewOptions(recording=src, estimates=d / "e.parquet", model=model, save=d / "v.rrd")
    )
    found["view"] = (d / "v.rrd").stat().st_size
    return found


def _fitting_commands(src: Path, model: Path, d: Path) -> dict:
    """identify on the recording ``src``, and report on its estimates with ``model``, default
    options; what each found."""
    own = identify.run(identify.IdentifyOptions(recordings=(src,), out=d / "own.toml")).model
    replay.run(replay.ReplayOptions(recording=src, model=model, out=d / "est.parquet"))
    report.run(report.ReportOptions(estimates=(d / "est.parquet",), out=d / "report"))
    return {"model": own, "report": json.loads((d / "report" / "report.json").read_text())}


def _check(found: dict, rec: Recording, rate: float, ref: dict) -> None:
    """What the commands found at ``rate`` [Hz] is the recording's. Above 250 Hz the resampled
    log carries the 250 Hz noise (interpolated: smoothed by up to 1.2): diagnosis's floor is that
    of 250 Hz within a factor 1.6 (one-sample differences find a twentieth of it at 5 kHz).
    Below, the log holds every k-th sample of a torque whose noise is not white at 250 Hz, and
    only the counts are checked."""
    s = found["info"]
    assert s["samples"] == len(rec) and abs(s["sample_rate_hz"] / rate - 1) < 1e-6
    assert s["regimes"]["dither"] > 0.2
    assert len(found["estimates"].data) == len(rec) and found["view"] > 0
    if rate > 250.0:
        floor, ref_floor = np.array(found["residual"]["noise_floor"]), np.array(ref["noise_floor"])
        assert np.all(np.abs(np.log(floor / ref_floor)) < np.log(1.6)), (floor, ref_floor)


@pytest.mark.parametrize(("rate", "duration"), [(50.0, None), (5000.0, 9.0)])
def test_reading_commands_run_with_defaults_at_the_extreme_rates(
    campaign, tmp_path, rate, duration
):
    """At 50 Hz, and on a 9 s log at 5 kHz (shorter than diagnosis's four 12 s contexts), info,
    convert, replay, diagnose and view run with their default options, see the recording's
    samples and regimes, and diagnosis finds the noise floor of 250 Hz."""
    rec250, model, ref = campaign
    rec = resample(rec250, rate, duration)
    src = dio.write(rec, tmp_path / "rec.parquet")
    _check(_reading_commands(src, model, tmp_path), rec, rate, ref)


def test_fitting_commands_run_with_defaults_at_50_hz(campaign, tmp_path):
    """At 50 Hz (a dither period of 3.9 samples) identify fits the dither band of every joint and
    report writes the paper's statistics, with default options."""
    rec = resample(campaign[0], 50.0)
    found = _fitting_commands(dio.write(rec, tmp_path / "rec.parquet"), campaign[1], tmp_path)
    band = found["model"].band("dither")
    assert np.all(np.isfinite(band.tau_min)) and np.all(band.tau_min < band.tau_max)
    assert found["report"]


@pytest.mark.study
@pytest.mark.parametrize("rate", [50.0, 250.0, 1000.0, 5000.0])
def test_every_command_runs_with_defaults_at_every_rate(campaign, tmp_path, rate):
    """At 50 Hz, 250 Hz, 1 kHz and 5 kHz every command runs with its default options."""
    rec250, model, ref = campaign
    rec = resample(rec250, rate)
    src = dio.write(rec, tmp_path / "rec.parquet")
    _check(_reading_commands(src, model, tmp_path), rec, rate, ref)
    found = _fitting_commands(src, model, tmp_path)
    assert found["model"].n == 6 and found["report"]


def test_a_chunk_below_the_context_runs_a_log_that_fits_in_it(tmp_path):
    """A chunk smaller than four 12 s contexts but longer than the whole log reads it as one
    piece; a chunk shorter than the log is refused, naming the file and the least chunk in rows
    and seconds."""
    n = 45_001  # 9 s at 5 kHz
    t = np.arange(n) / 5000.0
    q = np.tile([0.0, 0.3, 0.2, 0.0, 1.0, 0.0], (n, 1))
    rec = Recording.from_arrays(RecordingArrays(t, q, np.zeros((n, 6))), {"robot": "irb140"})
    src = open_source(dio.write(rec, tmp_path / "short.parquet"))
    (piece,) = src.pieces(50_000, halo_s=12.0)
    assert piece.owned == (0, n)
    with pytest.raises(
        ConfigError,
        match=r"short\.parquet: chunk size 20000 rows .* at least "
        r"240004 rows \(48 s of this recording\), or no --chunk",
    ):
        next(src.pieces(20_000, halo_s=12.0))
