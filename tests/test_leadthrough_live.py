"""Tests of the lead-through driven by an external estimate: the simulator's hook (what it hands
the estimate, what the admittance does with it), ``ditherlab live`` in closed loop across two
processes over DDS on the loopback interface (equal to the same estimate in one process), and
the estimator process dying (one line, exit status 2, nothing written)."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_causal import irb140_model

from ditherlab.analysis.lead_metrics import lead_metrics, tool_path
from ditherlab.app.leadthrough_dds import dds_source
from ditherlab.app.leadthrough_live import causal_source, link_settings
from ditherlab.core.errors import ConfigError
from ditherlab.io.dds import LOOPBACK_URI as LOOPBACK
from ditherlab.sim import simulate
from ditherlab.sim.guidance import LoggedChunk

REPO = Path(__file__).resolve().parents[1]
os.environ["CYCLONEDDS_URI"] = LOOPBACK
#: a domain of this test run's own
DOMAIN = 100 + (os.getpid() + 50) % 100


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("lead") / "model.toml"
    irb140_model().save(path)
    return path


def test_the_hook_hands_the_logged_samples_and_follows_the_estimate():
    """The external estimate gets every update's samples as the recording logs them, in
    order; a push of 20 N along +y for 3 s through the 10 N dead zone moves the tool along +y
    at the admittance's speed (0.004 m/s/N x 10 N) and not across; then it stands."""
    seen: list[LoggedChunk] = []

    def source(chunk: LoggedChunk):
        seen.append(chunk)
        push = 20.0 if chunk.t[-1] < 3.0 else 0.0
        return np.array([0.0, push, 0.0]), np.full(3, np.nan), np.full(3, np.nan)

    rec = simulate("lead-through", seed=3, dither=False, estimate=source)
    t = np.concatenate([c.t for c in seen])
    np.testing.assert_array_equal(t, rec.t)
    for name in ("q", "dq", "tau", "tau_ffw"):
        np.testing.assert_array_equal(
            np.concatenate([getattr(c, name) for c in seen]), getattr(rec, name)
        )
    np.testing.assert_array_equal(np.concatenate([c.dither for c in seen]), rec.dither)
    np.testing.assert_array_equal(rec.data["fhat_y"].to_numpy()[rec.t < 2.99], 20.0)
    x = tool_path(rec)
    a, b = np.searchsorted(rec.t, [1.5, 3.0])  # the smoothing (0.3 s) has settled by 1.5 s
    v = (x[b] - x[a]) / (rec.t[b] - rec.t[a])
    assert v[1] == pytest.approx(0.004 * 10.0, rel=0.05)
    assert abs(v[0]) < 1e-3 and abs(v[2]) < 1e-3
    c = np.searchsorted(rec.t, 6.0)
    assert np.abs(x[c:] - x[c]).max() < 1e-3


def test_no_external_estimate_for_other_scenarios():
    with pytest.raises(ConfigError, match="takes no external estimate"):
        simulate("push-campaign", estimate=lambda chunk: None)


def test_closed_loop_over_dds_equals_one_process(model_file):
    """The dithered lead-through (dead zone) driven by a ``ditherlab live`` process over DDS in
    lock-step is the same run as with the same estimate in this process: the tool's path and
    every metric equal, float for float."""
    model = irb140_model()
    link = link_settings(model, "dead-zone", True)
    here = simulate("lead-through", seed=1, dither=True, estimate=causal_source(model, link))
    ns = f"lead_test_{os.getpid()}"
    with dds_source(model_file, link, namespace=ns, domain=DOMAIN) as source:
        live = simulate("lead-through", seed=1, dither=True, estimate=source)
    np.testing.assert_array_equal(tool_path(live), tool_path(here))
    a, b = lead_metrics(live)["summary"], lead_metrics(here)["summary"]
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_equal(a[key], b[key], err_msg=key)
    # the estimate moved the arm: the pushes were followed, not a still arm compared with itself
    assert a["along_share"] > 0.1 and a["missed_pushes"] < 4


def test_one_update_late_changes_the_path_a_little():
    """The same estimate applied one update (20 ms) late, as a transport delay would apply it:
    the path differs (the dead zone's crossings move by an update), by a fraction of its extent
    (about an eighth on this seed)."""
    model = irb140_model()
    link = link_settings(model, "dead-zone", False)
    now = simulate("lead-through", seed=1, dither=False, estimate=causal_source(model, link))
    late = simulate("lead-through", seed=1, dither=False, estimate=causal_source(model, link, 1))
    a, b = tool_path(now), tool_path(late)
    span = np.ptp(a, axis=0).max()
    d = np.abs(a - b).max()
    assert 0.01 * span < d < 0.25 * span


def _estimators(pid: int) -> list[int]:
    """The children of ``pid`` that run ``ditherlab live`` (not a helper an import starts and
    ends, such as ``ldconfig -p`` from ``ctypes.util.find_library``)."""
    path = Path(f"/proc/{pid}/task/{pid}/children")
    kids = [int(c) for c in path.read_text().split()] if path.exists() else []
    found = []
    for kid in kids:
        try:
            argv = Path(f"/proc/{kid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"ditherlab" in argv and b"live" in argv:
            found.append(kid)
    return found


def test_the_estimator_dying_is_one_line(model_file, tmp_path):
    """The ``ditherlab live`` process killed mid-run: the command says so in one line naming
    it, exit status 2, no traceback, no output folder."""
    out = tmp_path / "lt"
    cmd = [
        sys.executable, "-m", "ditherlab", "leadthrough", "--model", str(model_file), "--live",
        "--repeats", "1", "--dither", "off", "--domain", str(DOMAIN), "-o", str(out), "-q",
    ]  # fmt: skip
    env = dict(os.environ, CYCLONEDDS_URI=LOOPBACK, PYTHONPATH=str(REPO))
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    end = time.monotonic() + 60
    kids: list[int] = []
    while not kids and time.monotonic() < end and p.poll() is None:
        kids = _estimators(p.pid)
        time.sleep(0.05)
    assert kids, "no estimator process started"
    time.sleep(4.0)  # running: subscribed and estimating
    os.kill(kids[0], 9)
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == 2, stderr
    assert "Traceback" not in stderr and stderr.count("\n") == 1, stderr
    assert f"the estimator process (ditherlab live, pid {kids[0]}) ended with status -9" in stderr
    assert not out.exists()


def test_bad_options_are_one_line(model_file, tmp_path, cli):
    """--live without --model, and a model of another robot, are one line each, exit 2."""
    r = cli("leadthrough", "--live", "-o", tmp_path / "a")
    assert r.code == 2 and "--live needs --model FILE" in r.err and r.err.count("\n") == 1
    other = dataclasses.replace(irb140_model(), robot="ur5e")
    path = tmp_path / "ur5e.toml"
    other.save(path)
    r = cli("leadthrough", "--model", path, "-o", tmp_path / "b")
    assert r.code == 2 and "--model: its robot 'ur5e' is not the simulated arm" in r.err, r.err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
