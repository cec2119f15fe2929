"""Synthetic push recordings with a known truth, for the identify / replay / thresholds tests.

The joint model is the ideal stick-slip of eq. (1)-(2): at rest the logged torque ``u`` stays
where it is while the friction ``tau_f = u - g - J^T F`` lies in its band ``[a, b]``; when the
push would move ``tau_f`` out of the band, ``u`` follows so that ``tau_f`` stays on the edge. With
dither, ``u = centre + A·square(t)`` and the centre obeys the same rule in the shrunk band
``[a + A, b - A]`` (the paper's Fig. 4); the logged torque gets Gaussian noise ``sigma``.
This is deliberately not the simulator (no servo, no gear): it gives exact truths.
"""

from __future__ import annotations

import numpy as np

from ditherlab.data.recording import Recording, RecordingArrays
from ditherlab.robot import RobotModel

Q0 = np.array([0.0, 0.0, 0.0, 0.0, np.pi / 2, 0.0])
FS = np.array([10.0, 9.0, 8.0, 2.5, 2.5, 1.5])  # [N·m]
BAND_LO = -0.9 * FS
BAND_HI = 1.1 * FS
SIGMA = 0.03 * FS
AXES = ("x", "y", "z")


def push_profile(t: np.ndarray, t0: float, peak: float, ramp: float = 0.3, hold: float = 0.6):
    """Raised-cosine push starting at t0: ramp up, hold, ramp down; (N,) [N]."""
    s = np.zeros_like(t)
    up = (t >= t0) & (t < t0 + ramp)
    s[up] = 0.5 - 0.5 * np.cos(np.pi * (t[up] - t0) / ramp)
    s[(t >= t0 + ramp) & (t < t0 + ramp + hold)] = 1.0
    dn = (t >= t0 + ramp + hold) & (t < t0 + 2 * ramp + hold)
    s[dn] = 0.5 + 0.5 * np.cos(np.pi * (t[dn] - t0 - ramp - hold) / ramp)
    return peak * s


def push_recording(
    seed: int = 0,
    *,
    dither: bool = False,
    magnitudes=(5.0, 10.0, 15.0, 20.0, 30.0, 40.0, 50.0),
    axes=AXES,
    signs=(1.0, -1.0),
    rest: float = 1.5,
    amplitude_frac: float = 0.8,
    period: float = 0.08,
    rate: float = 250.0,
    lead: float = 2.0,
) -> tuple[Recording, dict]:
    """A push campaign on the IRB140 at Q0 with an F/T sensor; returns (recording, truth)."""
    rng = np.random.default_rng(seed)
    pushes = [(ax, sg, m) for ax in axes for sg in signs for m in magnitudes]
    order = rng.permutation(len(pushes))
    pushes = [pushes[i] for i in order]
    dur_push = 1.2
    T = lead + len(pushes) * (dur_push + rest) + rest
    t = np.arange(0.0, T, 1.0 / rate)
    N, n = len(t), 6
    P = np.zeros((N, 3))  # applied force [N]
    starts = []
    for i, (ax, sg, m) in enumerate(pushes):
        t0 = lead + i * (dur_push + rest)
        starts.append(t0)
        P[:, AXES.index(ax)] += sg * push_profile(t, t0, m)
    F = np.zeros((N, 6))
    F[:, :3] = -P  # the wrench the robot exerts (docs/recording-format.md)
    robot = RobotModel.from_spec("irb140")
    q = np.tile(Q0, (N, 1))
    g = robot.gravity(Q0)[0]
    J = robot.jacobian(Q0)[0]
    ext = F @ J  # (N, n) J^T F
    A = amplitude_frac * (BAND_HI - BAND_LO) / 2 if dither else np.zeros(n)
    lo, hi = BAND_LO + A, BAND_HI - A
    # the friction starts anywhere in the (shrunk) band; the dither centres it
    tf = 0.5 * (lo + hi) if dither else rng.uniform(BAND_LO, BAND_HI)
    u = np.empty((N, n))
    centre = g + tf
    for k in range(N):
        f = centre - g - ext[k]
        centre = np.where(f > hi, g + ext[k] + hi, np.where(f < lo, g + ext[k] + lo, centre))
        u[k] = centre
    on = np.zeros(N, bool)
    tau_ffw = None
    if dither:
        on = t >= 1.0
        sq = np.where(np.floor(t / period * 2) % 2 == 0, 1.0, -1.0)
        wave = A[None, :] * sq[:, None] * on[:, None]
        u = u + wave
        tau_ffw = wave + g
    tau = u + rng.normal(0.0, 1.0, (N, n)) * SIGMA
    rec = Recording.from_arrays(
        RecordingArrays(
            t, q, tau, dq=np.zeros((N, n)), wrench=F, dither=on if dither else None, tau_ffw=tau_ffw
        ),
        {"robot": "irb140", "sample_rate_hz": rate, "source": "synthetic"},
        name="synthetic.parquet",
    )
    truth = {
        "still": (BAND_LO, BAND_HI, SIGMA),
        "dither": (lo, hi, SIGMA),
        "pushes": [(s, ax, sg, m) for s, (ax, sg, m) in zip(starts, pushes, strict=True)],
        "amplitude": A,
        "period": period,
    }
    return rec, truth


def moving_recording(seed: int = 0, duration: float = 60.0, rate: float = 250.0):
    """Joints sweeping back and forth: rho = coulomb·sign(dq) + viscous·dq + U[a, b] + noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / rate)
    N, n = len(t), 6
    freq = 0.1 + 0.05 * np.arange(n)
    amp = 0.3
    q = Q0 + amp * np.sin(2 * np.pi * freq * t[:, None] + 0.3)
    dq = amp * 2 * np.pi * freq * np.cos(2 * np.pi * freq * t[:, None] + 0.3)
    coulomb = 0.85 * FS
    viscous = 0.3 * FS
    half = 0.1 * FS
    robot = RobotModel.from_spec("irb140")
    g = robot.gravity(q)
    blocks = np.repeat(rng.uniform(-1, 1, (N // 50 + 1, n)), 50, axis=0)[:N] * half
    tau = g + coulomb * np.sign(dq) + viscous * dq + blocks + rng.normal(0, 1, (N, n)) * SIGMA
    rec = Recording.from_arrays(
        RecordingArrays(t, q, tau, dq=dq, wrench=np.zeros((N, 6))),
        {"robot": "irb140", "sample_rate_hz": rate},
        name="moving.parquet",
    )
    return rec, {"coulomb": coulomb, "viscous": viscous, "band": (-half, half), "sigma": SIGMA}
