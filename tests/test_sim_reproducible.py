"""The simulator gives the same bits on every CPU.

The plant is a chaotic stick-slip system: a difference in the last bit of one link's inverse
mass matrix becomes, over a 945 s push campaign, up to 18 N·m in the logged torque and moves the
paper's table by single pushes (README "The built-in simulator", session 17). Until session 17
that inverse came from LAPACK, whose OpenBLAS build picks its kernels by CPU at run time, so the
same seed gave other recordings on other machines. These tests run the simulator with two of
OpenBLAS's kernels (``OPENBLAS_CORETYPE``) in fresh processes and compare every column bit for
bit.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ditherlab.linalg import min_norm_solve, spd_inverse, spd_solve, vector_norm
from ditherlab.robot import RobotModel

#: A generic x86-64 kernel that any CPU can run; this machine's own is chosen by default.
GENERIC = "Prescott"


def _corename(env: dict[str, str]) -> str | None:
    """The OpenBLAS kernel numpy uses under ``env`` (None where it cannot be asked)."""
    code = (
        "import ctypes, glob, os, numpy as np\n"
        "libs = glob.glob(os.path.join(os.path.dirname(np.__file__), os.pardir, 'numpy.libs', "
        "'*openblas*'))\n"
        "f = getattr(ctypes.CDLL(libs[0]), 'scipy_openblas_get_corename64_', None) if libs else None\n"
        "if f is not None:\n"
        "    f.restype = ctypes.c_char_p\n"
        "    print(f().decode())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    return out.stdout.strip() or None


def _simulate(tmp: Path, name: str, args: list[str], coretype: str | None) -> pd.DataFrame:
    env = dict(os.environ)
    env.pop("OPENBLAS_CORETYPE", None)
    if coretype:
        env["OPENBLAS_CORETYPE"] = coretype
    path = tmp / f"{name}.parquet"
    cmd = [sys.executable, "-m", "ditherlab", "simulate", *args, "-o", str(path), "-q"]
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return pd.read_parquet(path)


def test_spd_inverse_is_the_inverse():
    """On random symmetric positive definite matrices and the IRB140's link mass matrices at
    random poses: the inverse to 1e-12 relative, exactly symmetric."""
    rng = np.random.default_rng(3)
    robot = RobotModel.from_spec("irb140")
    mats = []
    for n in (1, 2, 6, 7):
        A = rng.normal(size=(n, n))
        mats.append(A @ A.T + n * np.eye(n))
    q = rng.uniform(-1.5, 1.5, size=(5, 6))
    mats += list(
        robot.evaluate(q, ["mass_matrix"], reference=True)["mass_matrix"] + 0.01 * np.eye(6)
    )
    for M in mats:
        W = spd_inverse(np.ascontiguousarray(M))
        np.testing.assert_array_equal(W, W.T)
        ref = np.linalg.inv(M)
        assert np.max(np.abs(W - ref)) <= 1e-12 * np.max(np.abs(ref))


def test_solves_and_norm_agree_with_lapack():
    """``spd_solve`` and ``min_norm_solve`` (the lead-through's joint rates) against numpy's
    solve and pseudo-inverse to 1e-11 relative on random problems and the IRB140's Jacobians;
    None for a matrix that is not positive definite / a Jacobian that lost rank;
    ``vector_norm`` equals ``np.linalg.norm`` to the last bits."""
    rng = np.random.default_rng(5)
    robot = RobotModel.from_spec("irb140")
    A = rng.normal(size=(6, 6))
    G = A @ A.T + np.eye(6)
    b = rng.normal(size=6)
    x = spd_solve(G, b)
    np.testing.assert_allclose(x, np.linalg.solve(G, b), rtol=1e-11, atol=1e-12)
    assert spd_solve(np.diag([1.0, -1.0]), np.ones(2)) is None
    Js = list(robot.evaluate(rng.uniform(-1.2, 1.2, size=(5, 6)), ["jacobian"])["jacobian"])
    for J in [*Js, rng.normal(size=(3, 6))]:
        t = rng.normal(size=J.shape[0])
        ref = np.linalg.pinv(J) @ t
        got = min_norm_solve(np.ascontiguousarray(J), t)
        assert np.max(np.abs(got - ref)) <= 1e-11 * max(1.0, np.max(np.abs(ref)))
    J = Js[0].copy()
    J[1] = J[0]
    assert min_norm_solve(J, np.ones(6)) is None
    for v in (rng.normal(size=3), rng.normal(size=7), np.zeros(3)):
        assert vector_norm(v) == pytest.approx(np.linalg.norm(v), rel=1e-15, abs=0.0)


@pytest.mark.slow
def test_the_same_recording_on_every_blas_kernel(tmp_path):
    """A dithered push campaign, an excitation with a turned F/T sensor (whose logged wrench is
    rotated) and a lead-through (closed loop through the estimator) are the same bits with this
    machine's OpenBLAS kernel and a generic one."""
    base = dict(os.environ)
    base.pop("OPENBLAS_CORETYPE", None)
    own, generic = _corename(base), _corename({**base, "OPENBLAS_CORETYPE": GENERIC})
    if own is None or generic is None or own == generic:
        pytest.skip(f"cannot choose another OpenBLAS kernel here ({own} / {generic})")
    runs = {
        "campaign": ["push-campaign", "--seed", "2", "--dither", "--pushes-per-direction", "2"],
        "excitation": ["excitation", "--seed", "5", "--no-dither", "--hidden", "ft_frame"],
        # the controller runs the estimator and solves for the joint rates in the loop
        "lead-through": ["lead-through", "--seed", "1"],
    }
    for name, args in runs.items():
        a = _simulate(tmp_path, f"{name}_own", args, None)
        b = _simulate(tmp_path, f"{name}_generic", args, GENERIC)
        assert list(a.columns) == list(b.columns)
        for c in a.columns:
            np.testing.assert_array_equal(a[c].to_numpy(), b[c].to_numpy(), err_msg=f"{name} {c}")
