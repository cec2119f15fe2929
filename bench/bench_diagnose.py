"""Diagnosis speed: whole ``diagnose`` runs at two lengths (linear?), the candidates' designs at
the scored rows against at every row, the compiled band-aware fit against its numpy reference,
and the periodogram shortlist against the full grid.

Data: a moving IRB140 (three sines per joint, 0.05-0.75 Hz), gravity from pinocchio, Coulomb and
viscous friction, sensor noise, smooth random wrenches with an F/T sensor, and a position ripple
of 1.5 N·m with a period of 0.05 rad on joint 2. The model is the plant's base (bands collapsed on
the sliding line), so diagnosis has one effect to find among nine.
"""

from __future__ import annotations

import time

import numpy as np

FS = 250.0  # [Hz]
FC = np.array([8.0, 7.5, 6.5, 2.0, 2.0, 1.2])  # [N·m]
SIGMA = np.array([0.25, 0.25, 0.2, 0.05, 0.05, 0.04])  # [N·m]


def recording(duration: float, seed: int = 0):
    """A synthetic moving recording (N = duration·250 samples) with a ripple on joint 2."""
    from ditherlab.data.recording import Recording, RecordingArrays
    from ditherlab.robot import RobotModel

    rng = np.random.default_rng(seed)
    t = np.arange(int(duration * FS)) / FS
    q = np.tile([0.0, 0.2, 0.1, 0.0, np.pi / 2, 0.0], (len(t), 1))
    dq = np.zeros_like(q)
    for j in range(6):
        for k in range(3):
            A, w, ph = (
                rng.uniform(0.1, 0.35) / (k + 1),
                2 * np.pi * rng.uniform(0.05, 0.25) * (k + 1),
                rng.uniform(0, 6),
            )
            q[:, j] += A * np.sin(w * t + ph)
            dq[:, j] += A * w * np.cos(w * t + ph)
    robot = RobotModel.from_spec("irb140")
    F = np.zeros((len(t), 6))
    for c in range(6):
        F[:, c] = (15.0 if c < 3 else 0.8) * np.sin(
            2 * np.pi * rng.uniform(0.1, 0.6) * t + rng.uniform(0, 6)
        )
    tau = robot.gravity(q) + FC * np.tanh(dq / 0.003) + 0.3 * FC * dq
    tau += np.einsum("tkn,tk->tn", robot.jacobian(q), F) + rng.normal(size=q.shape) * SIGMA
    tau[:, 1] += 1.5 * np.sin(2 * np.pi * q[:, 1] / 0.05)
    return Recording.from_arrays(RecordingArrays(t, q, tau, dq=dq, wrench=F), {"robot": "irb140"})


def _model():
    from ditherlab.data.torque_model import Band, TorqueModel

    z = np.zeros(6)
    return TorqueModel("irb140", 6, regimes={"moving": Band(z, z, SIGMA, coulomb=FC, viscous=0.3 * FC),
                                             "still": Band(-FC, FC, SIGMA)})  # fmt: skip


def _long(quick: bool) -> list[dict]:
    """diagnose on 2 and 8 minutes (samples/s at each: flat = linear); on the longer one the
    candidates' designs at the scored rows against at every row (every effect treated as a
    time filter: computed on the whole recording, then taken; same diagnosis), and the numba
    band-aware fit against the numpy iteration on the stacks of that run."""
    from ditherlab.analysis.diagnosis import diagnose
    from ditherlab.physics import effect_fit as fit
    from ditherlab.physics.effects import EFFECTS

    m = _model()
    out = []
    speeds = []
    for minutes in (0.5, 2.0) if quick else (2.0, 8.0):
        rec = recording(60 * minutes, seed=1)
        t0 = time.perf_counter()
        diagnose([rec], m)
        dt = time.perf_counter() - t0
        speeds.append(len(rec) / dt)
    out.append(dict(name=f"diagnose, {len(rec)} samples (synthetic, moving, F/T)", value=speeds[1],
                    unit="samples/s", reference=speeds[0], ratio=speeds[1] / speeds[0],
                    target="ratio ~1 (linear; reference = a log 4x shorter); 50 k samples/s"))  # fmt: skip
    calls: list[tuple] = []
    solve = fit._solve

    def record(*a, **k):
        if len(calls) < 300:
            calls.append((a, k))
        return solve(*a, **k)

    old = {n: e.pointwise for n, e in EFFECTS.items()}
    try:
        for e in EFFECTS.values():
            type(e).pointwise = False
        t0 = time.perf_counter()
        ref = diagnose([rec], m)
        slow = time.perf_counter() - t0
    finally:
        for n, e in EFFECTS.items():
            type(e).pointwise = old[n]
    fit._solve = record
    try:
        t0 = time.perf_counter()
        new = diagnose([rec], m)
        fast = time.perf_counter() - t0
    finally:
        fit._solve = solve
    same = [c.to_dict() for c in new.candidates] == [c.to_dict() for c in ref.candidates]
    out.append(dict(name=f"diagnose {len(rec)} samples: designs at the scored rows ({'same' if same else 'DIFFERENT'} candidates)",
                    value=len(rec) / fast, unit="samples/s", reference=len(rec) / slow,
                    ratio=slow / fast, target="reference = every design at every row"))  # fmt: skip
    t0 = time.perf_counter()
    for a, k in calls:
        fit._solve(*a, **k)
    fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    for a, k in calls:
        fit._solve_reference(*a, **k)
    slow = time.perf_counter() - t0
    M = int(np.median([a[3].shape[0] for a, _ in calls]))
    out.append(dict(name=f"band-aware fit, {len(calls)} stacks of that run (median {M} rows)",
                    value=len(calls) / fast, unit="fits/s", reference=len(calls) / slow,
                    ratio=slow / fast, target="reference = the same iteration in numpy"))  # fmt: skip
    return out


def run(quick: bool = False) -> list[dict]:
    from ditherlab.analysis.diagnosis import diagnose
    from ditherlab.physics.effect_fit import _solve, stack
    from ditherlab.physics.effects import EFFECTS
    from ditherlab.physics.residual import scored

    rows = []
    rec = recording(8.0 if quick else 20.0)
    m = _model()
    t0 = time.perf_counter()
    d = diagnose([rec], m)
    dt = time.perf_counter() - t0
    top = d.suggested[0].effect if d.suggested else "none"
    n_cand = len(d.candidates) + len(d.skipped)
    rows.append(dict(name=f"diagnose, {len(rec)} samples x 6 joints, {n_cand} candidates (found: {top})",
                     value=len(rec) / dt, unit="samples/s"))  # fmt: skip
    rows += _long(quick)
    e = EFFECTS["position_ripple"]
    sc = [scored(m, rec)]
    grid = e.grid([sc[0].sig], 1)
    t0 = time.perf_counter()
    st0 = stack(e, sc, 1, grid[0], {})
    e.shortlist(sc, 1, grid, [np.ones(len(st0.e), dtype=bool)])
    fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    for h in grid:
        st = stack(e, sc, 1, h, {})
        _solve(st.e, st.h, st.s, st.C, st.W, st.o)
    slow = time.perf_counter() - t0
    rows.append(dict(name=f"ripple period search, {len(grid)} periods: periodogram shortlist",
                     value=len(grid) / fast, unit="periods/s", reference=len(grid) / slow,
                     ratio=slow / fast, target="reference = a full band-aware fit per period"))  # fmt: skip
    return rows
