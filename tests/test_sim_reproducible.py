"""The simulator gives the same bits whichever BLAS kernel or numpy SIMD path the CPU selects.

The plant is a chaotic stick-slip system: a difference in the last bit of one link's inverse
mass matrix becomes, over a 945 s push campaign, up to 18 N·m in the logged torque and moves the
paper's table by single pushes (docs/design/reproducible-plant.md). LAPACK's OpenBLAS build picks
its kernels by CPU at run time, so an inverse from LAPACK would give the same seed other
recordings on other machines; the plant inverts with its own compiled Cholesky instead
(``ditherlab.core.linalg``). These tests run the simulator with two of OpenBLAS's kernels
(``OPENBLAS_CORETYPE``) and with numpy's AVX2/FMA paths off (``NPY_DISABLE_CPU_FEATURES``), in
fresh processes, and compare every column bit for bit. What they cannot reach from one machine:
glibc's CPU-dispatched ``libm`` and numpy's AVX-512 paths.
The solvers themselves are tested in ``tests/test_linalg.py``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

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


#: numpy's SIMD features to switch off in the third configuration (AVX2 and FMA paths)
NPY_OFF = "AVX2 FMA3 AVX F16C"

#: LAPACK's inverse of the IRB140's mass matrix at 50 poses, hashed: it differs between two
#: kernels where the switch changes LAPACK's rounding (which a plant inverting with LAPACK
#: would inherit)
CANARY = (
    "import hashlib, numpy as np\n"
    "from ditherlab.robot import RobotModel\n"
    "q = np.random.default_rng(0).uniform(-1.5, 1.5, size=(50, 6))\n"
    "M = RobotModel.from_spec('irb140').evaluate(q, ['mass_matrix'], reference=True)['mass_matrix']\n"
    "print(hashlib.sha256(np.linalg.inv(M + 0.01 * np.eye(6)).tobytes()).hexdigest())\n"
)


def _env(**set_: str) -> dict[str, str]:
    env = dict(os.environ)
    env.pop("OPENBLAS_CORETYPE", None)
    env.pop("NPY_DISABLE_CPU_FEATURES", None)
    env.update(set_)
    return env


def _simulate(tmp: Path, name: str, args: list[str], env: dict[str, str]) -> pd.DataFrame:
    path = tmp / f"{name}.parquet"
    cmd = [sys.executable, "-m", "ditherlab", "simulate", *args, "-o", str(path), "-q"]
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return pd.read_parquet(path)


@pytest.mark.slow
def test_the_same_recording_on_every_blas_kernel(tmp_path):
    """A dithered push campaign, an excitation with a turned F/T sensor (whose logged wrench is
    rotated) and a lead-through (closed loop through the estimator) are the same bits with this
    machine's OpenBLAS kernel and a generic one, which round LAPACK's inverse of the mass matrix
    differently here (the canary: a plant that inverted with LAPACK would fail this test); the push
    campaign also with numpy's AVX2/FMA paths off."""
    own_env, generic_env = _env(), _env(OPENBLAS_CORETYPE=GENERIC)
    own, generic = _corename(own_env), _corename(generic_env)
    if own is None or generic is None or own == generic:
        pytest.skip(f"cannot choose another OpenBLAS kernel here ({own} / {generic})")

    def canary(env: dict[str, str]) -> str:
        r = subprocess.run([sys.executable, "-c", CANARY], env=env, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        return r.stdout.strip()

    if canary(own_env) == canary(generic_env):
        pytest.skip(f"the kernels {own} and {generic} round LAPACK's inverse alike here")
    runs = {
        "campaign": ["push-campaign", "--seed", "2", "--dither", "--pushes-per-direction", "2"],
        "excitation": ["excitation", "--seed", "5", "--no-dither", "--hidden", "ft_frame"],
        # the controller runs the estimator and solves for the joint rates in the loop
        "lead-through": ["lead-through", "--seed", "1"],
    }
    for name, args in runs.items():
        a = _simulate(tmp_path, f"{name}_own", args, own_env)
        others = {"generic": generic_env}
        if name == "campaign":
            others["no-avx2"] = _env(NPY_DISABLE_CPU_FEATURES=NPY_OFF)
        for label, env in others.items():
            b = _simulate(tmp_path, f"{name}_{label}", args, env)
            assert list(a.columns) == list(b.columns)
            for c in a.columns:
                np.testing.assert_array_equal(
                    a[c].to_numpy(), b[c].to_numpy(), err_msg=f"{name} {label} {c}"
                )
