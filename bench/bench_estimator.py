"""Estimator speed: the exact batched solver of eq. (3) against the per-sample QP loop, intervals.

Data: an IRB140 standing near the pose of SIMULATOR-NOTES.md (slow drift of q), bands
``+-Fs = (10, 9, 8, 2.5, 2.5, 1.5) N·m``, noise ``0.03 Fs``, the friction held somewhere in the
band and drifting, and pushes (half-sine, 1-2 s, up to 60 N in random directions) every ~4 s,
so that a realistic mix of joints is inside / outside the band. The reference loops (quadprog,
proxsuite through qpsolvers, per sample) run on a subset in the same process and are scaled to
samples per second; quadprog's ``solve_qp`` called directly on QPs built beforehand is compared
with the exact backend in CPU time (timed in alternation, best of five each: on a shared machine
a short run's wall time is the other jobs'), and with its own cost on a one-variable
unconstrained QP (the cost of a call).
"""

from __future__ import annotations

import time

import numpy as np

FS = 250.0  # [Hz]
BAND = np.array([10.0, 9.0, 8.0, 2.5, 2.5, 1.5])  # [N·m]
PRIOR_SIGMA = np.array([20.0, 20.0, 20.0, 0.3, 0.3, 0.3])


def push_data(N: int = 100_000, seed: int = 0) -> tuple[dict, np.ndarray]:
    """Estimator inputs for N samples of a standing robot being pushed; returns (args, F_true)."""
    from ditherlab.robot import RobotModel

    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    q0 = np.array([0.0, 0.0, 0.0, 0.0, np.pi / 2, 0.0])
    q = q0 + 0.05 * np.sin(2 * np.pi * t[:, None] / 300.0 + rng.uniform(0, 6, 6))
    J = RobotModel.from_spec("irb140").jacobian(q)  # (N, 6, n)
    F = np.zeros((N, 6))
    k = int(rng.integers(250, 750))
    while k < N:
        dur = int(rng.uniform(1.0, 2.0) * FS)
        d = rng.normal(size=3)
        mag = rng.uniform(0.0, 80.0)  # [N]
        seg = np.sin(np.pi * np.arange(min(dur, N - k)) / dur)
        F[k : k + len(seg), :3] = mag * seg[:, None] * d / np.linalg.norm(d)
        k += dur + int(rng.uniform(1.0, 3.0) * FS)
    # friction held in the band, drifting slowly; it cannot exceed the band
    held = np.cumsum(rng.normal(size=(N, 6)) * 0.002, axis=0) + rng.uniform(-0.5, 0.5, 6)
    tau_f = np.clip(held, -0.9, 0.9) * BAND
    ext = np.einsum("kin,ki->kn", J, F)
    sigma = 0.03 * BAND
    tau_bar = ext + tau_f + rng.normal(size=(N, 6)) * sigma
    args = dict(
        tau_bar=tau_bar, J=J, tau_min=-BAND, tau_max=BAND, sigma=sigma,
        prior_mean=np.zeros(6), prior_sigma=PRIOR_SIGMA,
    )  # fmt: skip
    return args, F


def _subset(args: dict, rows) -> dict:
    out = dict(args)
    out["tau_bar"] = args["tau_bar"][rows]
    out["J"] = args["J"][rows]
    return out


def _proxsuite_textbook_deviation(args: dict, F_exact: np.ndarray, rows) -> float:
    """Largest |F| error of ProxQP at qpsolvers' default settings on the unscaled QP in (F, tau_f).

    This is the formulation one writes first, and it can be off by up to 20 N. The
    library's reference backend scales the problem and sets eps_abs = 1e-14 instead.
    """
    import qpsolvers

    worst = 0.0
    for k in np.arange(len(args["tau_bar"]))[rows]:
        J, tb = args["J"][k], args["tau_bar"][k]
        w = 1.0 / args["sigma"] ** 2
        p = 1.0 / args["prior_sigma"] ** 2
        n = len(tb)
        Wd = np.diag(w)
        P = 2 * np.block([[J @ Wd @ J.T + np.diag(p), J @ Wd], [Wd @ J.T, Wd]])
        q = -2 * np.concatenate([J @ (w * tb) + p * args["prior_mean"], w * tb])
        lb = np.concatenate([np.full(6, -np.inf), args["tau_min"]])
        ub = np.concatenate([np.full(6, np.inf), args["tau_max"]])
        G = np.vstack([np.hstack([np.zeros((n, 6)), np.eye(n)]),
                       np.hstack([np.zeros((n, 6)), -np.eye(n)])])  # fmt: skip
        h = np.concatenate([ub[6:], -lb[6:]])
        x = qpsolvers.solve_qp(P, q, G, h, solver="proxqp")
        if x is not None:
            worst = max(worst, float(np.abs(x[:6] - F_exact[k]).max()))
    return worst


def _quadprog_direct(args: dict, F_exact: np.ndarray, rows, exact_fn, N: int) -> tuple[float, ...]:
    """quadprog's ``solve_qp`` called directly on the scaled QP of each sample
    (:func:`ditherlab.estimator.qp_matrices`, built beforehand and not timed) and ``exact_fn``
    (``N`` samples), timed in alternation, five rounds, the best CPU time of each (on a shared
    machine a short run's time is the other jobs'; alternating puts both under the same load).
    Returns quadprog's samples/s, ``exact_fn``'s samples/s, and the largest |F| deviation of
    quadprog from the exact backend [N, N·m]."""
    import quadprog

    from ditherlab import estimator as E

    prob = E.problem(**_subset(args, rows))
    qps = []
    for k in range(prob.N):
        P, q, G, h, A, b, c = E.qp_matrices(prob, k)
        C = np.vstack([A, -G]).T.copy()
        qps.append((P, -q, C, np.concatenate([b, -h]), len(b), c))
    best_q = best_e = np.inf
    for _ in range(5):
        t0 = time.thread_time()
        xs = [quadprog.solve_qp(P, a, C, bb, meq)[0] for P, a, C, bb, meq, _ in qps]
        best_q = min(best_q, time.thread_time() - t0)
        t0 = time.thread_time()
        exact_fn()
        best_e = min(best_e, time.thread_time() - t0)
    F = np.array([prob.prior_mean + qp[5] * x[: prob.m] for qp, x in zip(qps, xs, strict=True)])
    dev = float(np.abs(F - F_exact[rows][:, prob.free]).max())
    return prob.N / best_q, N / best_e, dev


def _quadprog_call_cost(M: int) -> float:
    """quadprog's ``solve_qp`` on the one-variable unconstrained QP ``min x^2 / 2``, ``M`` calls:
    samples/s of CPU time, best of five (what a call costs whatever the QP)."""
    import quadprog

    P, a = np.eye(1), np.zeros(1)
    return _cpu_rate(lambda: [quadprog.solve_qp(P, a) for _ in range(M)], M, repeat=5)


def _cpu_rate(fn, N: int, repeat: int = 3) -> float:
    """``N`` over the best CPU time (this thread's) of ``repeat`` calls of ``fn``."""
    best = np.inf
    for _ in range(repeat):
        t0 = time.thread_time()
        fn()
        best = min(best, time.thread_time() - t0)
    return N / best


def _cpu_split(args: dict, prob, qrate: float) -> list[dict]:
    """``estimate`` taken apart, CPU time, best of three each: ``problem()`` (validation,
    weights, broadcasting), the solve with its completion, and one numpy pass over the inputs
    ``tau_bar`` and ``J`` (what reading them once costs: the memory floor of any solver that
    reads them), each as samples/s and as a multiple of quadprog's rate ``qrate``."""
    from ditherlab import estimator as E
    from ditherlab.estimator.backends.exact import solve_exact

    N = prob.N
    parts = (
        ("problem() alone (validation, weights, broadcasting)", lambda: E.problem(**args)),
        ("solve and completion alone", lambda: solve_exact(prob)),
        ("one pass over tau_bar and J (numpy sum: the memory floor)",
         lambda: (args["tau_bar"].sum(), args["J"].sum())),
    )  # fmt: skip
    rows = []
    for name, fn in parts:
        r = _cpu_rate(fn, N)
        rows.append(dict(name=f"  {name}, CPU time", value=r, unit="samples/s", reference=qrate,
                         ratio=r / qrate))  # fmt: skip
    return rows


def _rate(fn, N: int, repeat: int = 3) -> tuple[float, object]:
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return N / best, out


def _square_paths(prob) -> list[dict]:
    """The torque coordinates' kernel alone (``square_block``) with the lockstep passes and one
    sample at a time, alternated, CPU time, best of three each."""
    from ditherlab.estimator.interval_methods import set_membership as S
    from ditherlab.estimator.interval_methods.sm_arrays import Bounds, SMProblem, square_state
    from ditherlab.estimator.interval_methods.sm_square import square_block

    ridge = prob.p_true == 0.0
    kk = S.interval_k(0.95, prob.n, int((~ridge).sum()))
    sig = 1.0 / np.sqrt(prob.w)
    half = np.where(ridge, 0.0, S._halfbox(prob, kk))
    N, m = prob.N, prob.m
    lo, hi, st = np.empty((N, m)), np.empty((N, m)), np.empty(N, np.int64)
    best = {True: np.inf, False: np.inf}
    for _ in range(3):
        for lockstep in (True, False):
            t0 = time.process_time()
            P = SMProblem(prob.tau_bar, prob.J, prob.tau_min, prob.tau_max, sig, kk,
                          prob.prior_mean, half, ridge, S.BIG_BOX)  # fmt: skip
            square_block(P, square_state(m), Bounds(lo, hi, st), lockstep)
            best[lockstep] = min(best[lockstep], time.process_time() - t0)
    return [
        dict(name="  square_block alone, lockstep passes (CPU time)", value=N / best[True],
             unit="samples/s", reference=N / best[False], ratio=best[False] / best[True]),
        dict(name="  square_block alone, one sample at a time (CPU time)",
             value=N / best[False], unit="samples/s"),
    ]  # fmt: skip


def run(quick: bool = False) -> list[dict]:
    from ditherlab import estimator as E
    from ditherlab.estimator.backends.exact import _solve_exact, solve_exact
    from ditherlab.estimator.interval_methods.profile import profile_reference

    N = 20_000 if quick else 100_000
    args, _ = push_data(N)
    E.estimate(**_subset(args, slice(0, 50)))  # compile / load the numba cache
    E.intervals(E.problem(**_subset(args, slice(0, 50))), method="set_membership")
    E.intervals(E.problem(**_subset(args, slice(0, 50))), method="profile")
    p50 = E.problem(**_subset(args, slice(0, 50)))
    profile_reference(p50, E.estimate(**_subset(args, slice(0, 50))).F[:, p50.free])
    rows = []
    rate, sol = _rate(lambda: E.estimate(**args), N)
    active = sol.active.mean()
    rows.append(dict(name=f"estimate exact, {N} samples ({active:.0%} active, {sol.iterations.mean():.2f} it.)",
                     value=rate, unit="samples/s", target=">= 3e6/s; reference: the fastest qpsolvers loop"))  # fmt: skip
    prob = E.problem(**args)
    krate, _ = _rate(lambda: solve_exact(prob), N)
    rows.append(dict(name="  solve and completion alone (no validation)", value=krate,
                     unit="samples/s"))  # fmt: skip
    krate, _ = _rate(lambda: _solve_exact(prob), N)
    rows.append(dict(name="  exact kernel alone (no validation/completion)", value=krate,
                     unit="samples/s"))  # fmt: skip
    # a harder mix: independent random problems (no warm start helps; about half the joints out)
    rng = np.random.default_rng(1)
    Jr = rng.normal(size=(N, 6, 6)) * np.array([1, 1, 1, 0.3, 0.3, 0.3])[None, :, None]
    Fr = rng.normal(size=(N, 6)) * np.array([30, 30, 30, 1, 1, 1])
    tbr = np.einsum("kin,ki->kn", Jr, Fr) + rng.uniform(-BAND, BAND, (N, 6))
    rargs = dict(args, tau_bar=tbr + rng.normal(size=(N, 6)) * 0.03 * BAND, J=Jr)
    rr, rsol = _rate(lambda: E.estimate(**rargs), N)
    rows.append(dict(name=f"estimate exact, iid random problems ({rsol.active.mean():.0%} active, "
                     f"{rsol.iterations.mean():.1f} it.)", value=rr, unit="samples/s"))  # fmt: skip
    best_ref = 0.0
    for backend, M in (
        ("quadprog", 2000 if not quick else 500),
        ("proxsuite", 1000 if not quick else 200),
    ):
        if backend not in E.available_backends():
            continue
        sub = _subset(args, slice(0, N, N // M))
        rref, ref = _rate(lambda sub=sub, backend=backend: E.estimate(**sub, backend=backend),
                          len(sub["tau_bar"]), repeat=1)  # fmt: skip
        ex = E.estimate(**sub)
        dev = float(np.abs(ex.F - ref.F).max())
        rows.append(dict(name=f"estimate {backend} loop (qpsolvers, per sample)", value=rref,
                         unit="samples/s"))  # fmt: skip
        rows.append(dict(name=f"  max |F_exact - F_{backend}| on {len(sub['tau_bar'])} samples",
                         value=dev, unit="N"))  # fmt: skip
        best_ref = max(best_ref, rref)
    if "proxsuite" in E.available_backends():
        M = 100 if quick else 500
        dev = _proxsuite_textbook_deviation(args, sol.F, slice(0, N, N // M))
        rows.append(dict(name=f"  max |F_exact - F_proxsuite| unscaled (F, tau_f), default eps, {M} samples",
                         value=dev, unit="N"))  # fmt: skip
    M = 2000 if not quick else 500
    qrate, crate, qdev = _quadprog_direct(
        args, sol.F, slice(0, N, N // M), lambda: E.estimate(**args), N
    )
    rows.append(dict(name="estimate exact, CPU time", value=crate, unit="samples/s",
                     reference=qrate, ratio=crate / qrate,
                     target=">= 100x quadprog.solve_qp called directly (CPU time)"))  # fmt: skip
    rows.append(dict(name="  quadprog.solve_qp called directly (QPs built, not timed), CPU time",
                     value=qrate, unit="samples/s"))  # fmt: skip
    rows.append(dict(name=f"  max |F_exact - F_quadprog direct| on {M} samples", value=qdev,
                     unit="N"))  # fmt: skip
    rows.append(dict(name="  quadprog.solve_qp on a 1-variable unconstrained QP (a call), CPU time",
                     value=_quadprog_call_cost(M), unit="samples/s"))  # fmt: skip
    rows.extend(_cpu_split(args, prob, qrate))
    if best_ref:
        rows[0]["reference"] = best_ref
        rows[0]["ratio"] = rate / best_ref
    for method in ("set_membership", "profile"):
        r, _ = _rate(lambda method=method: E.intervals(E.problem(**args), F_hat=sol.F,
                                                       method=method), N, repeat=2)  # fmt: skip
        rows.append(dict(name=f"intervals {method}, {N} samples", value=r, unit="samples/s",
                         target=">= 1e6/s"))  # fmt: skip
        if method == "set_membership":
            M = 200 if quick else 400
            prob_sub = E.problem(**_subset(args, slice(0, N, N // M)))
            rref, _ = _rate(lambda ps=prob_sub: E.set_membership_reference(ps), M, repeat=1)
            rows[-1]["name"] += " (reference: linprog per sample)"
        else:  # the reference kernel: the same path, refactored at every segment
            Fm = sol.F[:, prob.free]
            rref, _ = _rate(lambda Fm=Fm: profile_reference(prob, Fm), N, repeat=2)
            rows[-1]["name"] += " (reference: refactor per segment)"
        rows[-1]["reference"] = rref
        rows[-1]["ratio"] = r / rref
        if method == "set_membership":
            rows.extend(_square_paths(prob))
    # the closed form of the no-band variants against numpy's batched inverse
    zargs = dict(args, tau_max=args["tau_min"])
    zsol = E.estimate(**zargs)
    ga = [zargs[k] for k in ("tau_bar", "J", "tau_min", "tau_max", "sigma", "prior_mean",
                             "prior_sigma")]  # fmt: skip
    r, (glo, _) = _rate(lambda: E.gaussian_profile_intervals(E.problem(*ga), zsol.F), N)
    zprob = E.problem(**zargs)

    def numpy_half():
        H = np.einsum("kin,kn,kjn->kij", zprob.J, zprob.w, zprob.J)
        H += np.eye(zprob.m) * zprob.p[:, None, :]
        return np.sqrt(3.841458820694124 * np.diagonal(np.linalg.inv(H), axis1=1, axis2=2))

    rref, half = _rate(numpy_half, N)
    rows.append(dict(name=f"intervals closed form (zero-width bands), {N} samples (reference: "
                     "numpy einsum + inv)", value=r, unit="samples/s", reference=rref,
                     ratio=r / rref))  # fmt: skip
    rows.append(dict(name="  max relative |half-width - numpy's|",
                     value=float(np.abs((zsol.F - glo) / half - 1).max()), unit=""))  # fmt: skip
    from ditherlab.physics import dither as D

    t = np.arange(N) / FS
    tau = args["tau_bar"] + D.square_wave(t, 80.0, 0.8 * BAND)
    r, _ = _rate(lambda: D.extract(tau, t, period=2 * np.pi / 80.0), N)
    rows.append(dict(name=f"dither.extract, {N} x 6 joints", value=r, unit="samples/s"))
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
