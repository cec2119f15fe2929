"""Logging a one-hour 250 Hz recording with estimates (four variants) to a Rerun .rrd file.

Measures the wall time of ``save_view`` (target < 30 s) and the file size (bound: 900 MB for
one hour with four variants).
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ditherlab.core.names import WRENCH_COLUMNS
from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.data.torque_model import Band, TorqueModel

FS = 250.0
VARIANTS = ("nodither_band", "nodither_noband", "dither_band", "dither_noband")


def campaign(duration: float, seed: int = 0) -> Recording:
    """A push-campaign-like recording: noisy torques and encoder, pushes every 10 s, dither half the time."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration * FS)) / FS
    N, n = len(t), 6
    # Every sample a distinct configuration (slow drift + encoder noise): no repeats to dedup.
    q = (
        np.array([0.0, 0.0, 0.0, 0.0, np.pi / 2, 0.0])
        + 0.05 * np.sin(2 * np.pi * t / 600.0)[:, None]
        + 1e-5 * rng.standard_normal((N, n))
    )
    tau = rng.standard_normal((N, n))
    w = 0.3 * rng.standard_normal((N, 6))
    phase = t % 10.0
    push = np.where(phase < 1.0, np.sin(np.pi * phase) ** 2, 0.0) * 20.0
    w[:, 0] -= push
    dither = (t % 600.0) >= 300.0
    ffw = np.where(dither[:, None], 3.0 * np.sign(np.sin(80 * t))[:, None], 0.0) * np.ones(n)
    return Recording.from_arrays(
        RecordingArrays(t, q, tau, wrench=w, dither=dither, tau_ffw=ffw),
        {"robot": "irb140", "source": "bench", "sample_rate_hz": FS},
        name="bench.parquet",
    )


def estimates_file(rec: Recording, path: Path, seed: int = 1) -> Path:
    """An estimates file in the agreed format with all four variants and the extraction."""
    rng = np.random.default_rng(seed)
    N = len(rec)
    cols: dict[str, np.ndarray] = {"t": rec.t}
    for k, c in enumerate(WRENCH_COLUMNS):
        cols[c] = rec.wrench[:, k]
    cols["dither"] = rec.dither
    for v in VARIANTS:
        F = np.where(np.abs(rec.wrench) > 5, 0.7 * rec.wrench, 0.0)
        for k, c in enumerate(WRENCH_COLUMNS):
            cols[f"{v}/{c}"] = F[:, k]
            cols[f"{v}/{c}_lo"] = F[:, k] - 4.0 - rng.random(N)
            cols[f"{v}/{c}_hi"] = F[:, k] + 4.0 + rng.random(N)
        cols[f"{v}/active"] = (np.abs(F[:, :3]).sum(axis=1) > 0).astype(np.int64)
    period = np.arange(N) // 20
    for j in range(1, rec.n + 1):
        lvl = rng.standard_normal(period.max() + 1)[period]
        cols[f"extract/upper_{j}"] = lvl + 2.5
        cols[f"extract/lower_{j}"] = lvl - 2.5
        cols[f"extract/signal_{j}"] = lvl
    meta = {
        "schema": "ditherlab.estimates/1",
        "recording": rec.meta,
        "recording_name": rec.name,
        "model": {},
        "variants": list(VARIANTS),
        "interval": {"method": "set_membership", "level": 0.95},
        "components": list(WRENCH_COLUMNS),
    }
    pq.write_table(pa.table(cols).replace_schema_metadata({"ditherlab": json.dumps(meta)}), path)
    return path


def model() -> TorqueModel:
    """Bands of the IRB140 order of magnitude (SIMULATOR-NOTES), dither band 10 % of them."""
    fs = np.array([10.0, 9.5, 8.4, 1.6, 2.2, 1.0])
    return TorqueModel(
        robot="irb140",
        n=6,
        regimes={"still": Band(-fs, fs, 0.1 * fs), "dither": Band(-0.1 * fs, 0.1 * fs, 0.1 * fs)},
    )


def run(quick: bool = False) -> list[dict]:
    from ditherlab.output.rerun.rerun_log import load_estimates, save_view

    duration = 120.0 if quick else 3600.0
    rec = campaign(duration)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        est = load_estimates(estimates_file(rec, Path(d) / "est.parquet"))
        for extra, mdl in (("", None), (" + model residuals", model())):
            out = Path(d) / "view.rrd"
            t0 = time.perf_counter()
            summary = save_view(rec, out, estimates=est, model=mdl)
            elapsed = time.perf_counter() - t0
            label = f"{duration / 60:.0f} min at 250 Hz, 4 variants{extra}"
            rows += [
                {
                    "name": f"view: log {label}",
                    "value": elapsed,
                    "unit": "s",
                    "target": "< 30 s for 1 h",
                },
                {
                    "name": f"view: .rrd size, {label}",
                    "value": out.stat().st_size / 1e6,
                    "unit": "MB",
                    "target": "< 900 MB for 1 h" if not extra else None,
                },
                {
                    "name": f"view: rows sent, {label}",
                    "value": float(sum(summary.rows.values())),
                    "unit": "rows",
                },
            ]
    return rows
