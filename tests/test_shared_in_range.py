"""A shared fit just outside a range of several parameters is held at its edge where the data
allow it (:func:`ditherlab.physics.effect_fit.shared_in_range`), as a per-joint fit is
(``bounded_fit``); one the data insist on is refused.

The second plant's sensor turned by 20° about a drawn axis (``--hidden ft_frame:20``, the edge
of the effect's range 0..20°) fits 20.2°: without the hold, diagnose called it "fits only with
an unphysical value" and ``identify --add ft_frame`` refused it. Turned by 30°, the data reject
the edge: refused, one line, exit 2, nothing written.
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import pytest
from conftest import run_cli

SEED = 85833  # draw 15 of bench_power --plant lugre


@pytest.mark.slow
def test_a_sensor_turned_to_the_edge_is_held_there_and_beyond_it_refused(tmp_path):
    clean, m = tmp_path / "clean.parquet", tmp_path / "m.toml"
    r = run_cli("simulate", "excitation", "--plant", "lugre", "--robot", "irb140", "--seed",
                str(SEED), "--no-dither", "-o", str(clean), "-q")  # fmt: skip
    assert r.code == 0, r.err
    r = run_cli("identify", str(clean), "--add", "inertia", "--add", "stribeck",
                "--bootstrap", "0", "-o", str(m), "-q")  # fmt: skip
    assert r.code == 0, r.err
    for angle, held in ((20.0, True), (30.0, False)):
        rec, out = tmp_path / f"f{angle:g}.parquet", tmp_path / f"m{angle:g}.toml"
        r = run_cli("simulate", "excitation", "--plant", "lugre", "--robot", "irb140", "--seed",
                    str(SEED), "--no-dither", "--hidden", f"ft_frame:{angle:g}", "-o", str(rec),
                    "-q")  # fmt: skip
        assert r.code == 0, r.err
        r = run_cli("diagnose", str(rec), "--model", str(m), "--json", "--no-history", "-q")
        assert r.code == 0, r.err
        cand = next(c for c in json.loads(r.out)["candidates"] if c["effect"] == "ft_frame")
        assert cand["suggested"] is held and bool(cand["unphysical"]) is not held, cand
        r = run_cli("identify", str(rec), "--model", str(m), "--add", "ft_frame",
                    "--bootstrap", "0", "-o", str(out), "-q")  # fmt: skip
        if held:
            assert r.code == 0, r.err
            assert "ft_frame: rotation angle held at 20 °, the edge of its range 0..20" in r.err
            spec = next(e for e in tomllib.loads(out.read_text())["effects"]
                        if e["name"] == "ft_frame")  # fmt: skip
            turn = math.degrees(math.sqrt(sum(x * x for x in spec["params"]["rotation"])))
            assert turn == pytest.approx(20.0, abs=1e-9), turn
        else:
            assert r.code == 2 and not out.exists(), r.err
            line = r.err.strip()
            assert "\n" not in line and "rotation angle" in line and "0..20" in line, line


def test_each_axis_of_a_sensor_bias_is_clipped_to_its_own_range():
    """A shared fit whose parameters are each bounded on their own (``ft_bias``, ``ft_drift``:
    within ± the largest reading of the axis) is moved to the nearest point inside by clipping
    each axis; the axes inside are kept, and an effect without such ranges has no such point."""
    import numpy as np

    from ditherlab import read
    from ditherlab.physics.effect_fit import _clipped
    from ditherlab.physics.effects import EFFECTS, Signals

    sig = [Signals(read(Path(__file__).parents[1] / "recordings" / "sim-push-dither.parquet"))]
    top = np.abs(sig[0].wrench("test")).max(axis=0)
    w = top * [0.5, -2.0, 0.1, 1.5, 0.0, -0.2]
    for name in ("ft_bias", "ft_drift"):
        got = _clipped(EFFECTS[name], sig, w)
        want = top * [0.5, -1.0, 0.1, 1.0, 0.0, -0.2]
        np.testing.assert_allclose(got, want, rtol=1e-12)
    assert _clipped(EFFECTS["ft_frame"], sig, w) is None  # its ranges are of several parameters
