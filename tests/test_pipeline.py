"""The demo's pipeline on small simulated campaigns: simulate -> identify -> replay -> report."""

from __future__ import annotations

import numpy as np

from ditherlab.app.demo import pipeline_text, run_pipeline
from ditherlab.data.estimates import Estimates
from ditherlab.data.torque_model import TorqueModel


def test_pipeline_small_campaign(tmp_path):
    """Every step writes its file, and with dither more pushes get a response than without."""
    res = run_pipeline(tmp_path, pushes_per_direction=4, n_boot=0, report_boot=10, quiet=True)
    model = TorqueModel.load(res.model)
    assert {"still", "dither"} <= set(model.regimes)
    ests = [Estimates.load(p) for p in res.estimates]
    assert ests[0].variants == ["nodither_band", "nodither_noband"]
    assert "dither_band" in ests[1].variants
    assert (res.report / "report.md").is_file() and (res.report / "fig6_estimates.png").is_file()
    c = res.analysis["conditions"]
    detected = {
        k: sum(c[k]["directions"][a]["detected"] for a in "xyz")
        for k in ("nodither_band", "dither_band")
    }
    assert detected["dither_band"] > detected["nodither_band"]
    n = len(res.analysis["recordings"][0]["pushes"])
    assert n == 4 * 2 * 3  # every simulated push found once
    text = pipeline_text(res)
    assert "32 N / 40 N" in text and "seconds:" in text
    # the estimate follows the sensor during the larger pushes with dither
    F = ests[1].wrench[:, :3]
    Fh = ests[1].F("dither_band")[:, :3]
    big = np.abs(F).max(axis=1) > 30
    k = np.abs(F[big]).argmax(axis=1)
    on_axis = np.take_along_axis(F[big], k[:, None], 1)[:, 0]
    est_axis = np.take_along_axis(Fh[big], k[:, None], 1)[:, 0]
    assert np.corrcoef(on_axis, est_axis)[0, 1] > 0.8
