"""The compiled inner loop: joints (motor, gear spring, link), friction, servo and dither loops.

Per joint j (arm-side units, SI)::

    Jm dvm/dt = u - ts - r(qm) - f_m          motor (reflected inertia Jm)
    ts        = k (qm - q) + c (vm - v)        gear spring with damping
    M(q) dv/dt = ts - g(q) + J^T P - f_o       links, coupled through the mass matrix

``f_m`` and ``f_o`` are the friction on the motor side and on the gear output; ``motor_share``
splits the band between them. ``P`` is the push on the tool (the wrench the robot exerts is
``F = -P``). ``r(qm)`` is an optional cogging ripple (hidden effect).

Friction model: **rigid stick-slip, solved implicitly at velocity level** (no velocity threshold,
no bristles). A stuck side holds any friction ``|f| <= Fs`` with ``v = 0`` exactly; when the
torque needed to stay stuck exceeds Fs it slips with ``f = Fc sign(v) + Fv v`` (viscous part
implicit); a slipping side whose update would reverse its velocity sticks. Why: the regularised
alternatives (tanh, LuGre, presliding springs) let the servo's velocity integral creep through
the band, so a sub-band push shows fully in the torque (the paper's Fig. 2 left is lost), and a
velocity threshold (Karnopp) chatters and depends on the step size (SIMULATOR-NOTES.md;
``tests/test_sim_paper.py`` checks step independence and the flat torque below the band). On the
link side the joints are coupled through M, so the stuck/slip friction torques are found by
projected Gauss-Seidel on ``W = M^-1`` (a box problem per joint, warm-started).

Servo (paper Fig. 3), at ``servo_rate_hz``::

    vref = dq_ref + Kp (q_ref + offset - qm)       Kp = 0 while the joint dithers
    I   += Ki (vref - vm) dt
    u    = g_ctrl(qm) + c + a sq(w t) + Kv (vref - vm) + I

``u`` is the torque reference; it is what gets logged (plus noise). When Kp is switched back on,
``offset`` is set so that the joint holds where it is (bumpless transfer).

Dither loops (paper §III-B), once per sample with the logged torque: a ring buffer of the last
``periods`` whole dither periods; every ``update_every`` samples the centre (window mean) and the
amplitude ((upper mean - lower mean)/2 of the samples above/below the centre, the paper's
pseudo-code) are compared with their references and integrated into ``c`` and ``a`` unless the
error is within ``hold`` of the band width. References ramp up over ``ramp`` samples (centre from
the measured centre to the gravity torque, amplitude from 0); at stop ``c`` and ``a`` ramp to 0.

Two implementations of the same step: :func:`run_kernel` (numba, scalar loops) and
:func:`run_reference` (plain numpy over joints, many more Gauss-Seidel sweeps); the tests and
``bench/bench_sim.py`` check they agree.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# rows of the per-joint parameter array ``jp`` (shape (N_JP, n))
(
    JM,
    KG,
    CG,
    FS_M,
    FC_M,
    FV_M,
    FS_O,
    FC_O,
    FV_O,
    KP,
    KV,
    KI,
    AMP_SP,
    AMP_CAP,
    BAND,
    DMASK,
    LOAD,
    STRIB,
    STRIB_V,
    RIP_A,
    RIP_F,
) = range(21)
N_JP = 21
# entries of the scalar parameter array ``sp``
(
    SP_H,
    SP_NSERVO,
    SP_NSUB,
    SP_OMEGA,
    SP_WIN,
    SP_UPD,
    SP_KC,
    SP_KA,
    SP_HOLD,
    SP_RAMP,
    SP_DTS,
    SP_SWEEPS,
) = range(12)
N_SP = 12
# rows of the continuous state ``x`` (shape (N_X, n))
(
    X_QM,
    X_VM,
    X_Q,
    X_V,
    X_I,
    X_OFF,
    X_FO,
    X_KPE,
    X_C,
    X_A,
    X_C0,
    X_CSTOP,
    X_ASTOP,
    X_SM,
    X_SO,
    X_CM,
    X_AM,
    X_CR,
    X_AR,
) = range(19)
N_X = 19
# integer state ``ist``: ring-buffer position, filled, mode (0 off, 1 ramp up, 2 on, 3 ramp down),
# loop sample counter; float state ``fst``: ramp progress up, ramp progress down, dither clock
I_POS, I_FILL, I_MODE, I_CNT = range(4)
F_R, F_RD, F_CLOCK = range(3)
# rows of the per-sample output ``out`` (shape (N_OUT, N, n))
(O_TAU, O_QM, O_VM, O_Q, O_FFW, O_CMEAS, O_AMEAS, O_CREF, O_AREF, O_C, O_A, O_DITHER) = range(12)
N_OUT = 12


@njit(cache=True)
def _stick_slip(m, p, h, fs, fc, fv, stuck, v_old):
    """Implicit rigid stick-slip for one body: momentum ``p`` without friction -> (v, stuck)."""
    if stuck or v_old == 0.0:
        if abs(p) <= h * fs:
            return 0.0, True
        s = 1.0 if p > 0.0 else -1.0
    else:
        s = 1.0 if v_old > 0.0 else -1.0
    v = (p - h * fc * s) / (m + h * fv)
    if v * s <= 0.0:
        return 0.0, True
    return v, False


@njit(cache=True)
def _window_levels(hist, j, fill):
    """Centre, upper and lower mean of the ``fill`` newest samples of joint j (pseudo-code)."""
    s = 0.0
    for i in range(fill):
        s += hist[j, i]
    c = s / fill
    su = 0.0
    nu = 0
    sl = 0.0
    nl = 0
    for i in range(fill):
        x = hist[j, i]
        if x > c:
            su += x
            nu += 1
        elif x < c:
            sl += x
            nl += 1
    up = su / nu if nu > 0 else c
    lo = sl / nl if nl > 0 else c
    return c, up, lo


@njit(cache=True)
def run_kernel(
    jp,
    sp,
    W,
    gp0,
    Gp,
    qp_lin,
    gc0,
    Gc,
    qc_lin,
    JT,
    push,
    tau_ext,
    q_ref,
    dq_ref,
    kp_on,
    dcmd,
    noise,
    fscale,
    x,
    ist,
    fst,
    hist,
    out,
    k0,
):
    """Advance the plant, servo and dither loops over ``push.shape[0]`` samples (compiled).

    Parameters
    ----------
    jp : (N_JP, n) per-joint parameters; sp : (N_SP,) scalars (see module constants)
    W : (n, n) [1/(kg m^2)] inverse link mass matrix for this chunk
    gp0, Gp, qp_lin : plant gravity g(q) ~ gp0 + Gp (q - qp_lin) [N m], (n,), (n, n), (n,)
    gc0, Gc, qc_lin : the controller's gravity model, linearised likewise in the motor angle
    JT : (n, 6) [m or 1] transposed tool Jacobian
    push, tau_ext, q_ref, dq_ref, kp_on, dcmd, noise, fscale : per-sample inputs (K, 6) [N, N m]
        push on the tool, (K, n) [N m] external joint torque, (K, n) [rad], (K, n) [rad/s],
        (K,), (K,), (K, n) [N m], (K, n) friction factor
    x, ist, fst, hist : state, updated in place
    out : (N_OUT, N, n) outputs, rows k0 .. k0 + K written
    """
    n = jp.shape[1]
    K = push.shape[0]
    h = sp[SP_H]
    nservo = int(sp[SP_NSERVO])
    nsub = int(sp[SP_NSUB])
    dts = sp[SP_DTS]
    omega = sp[SP_OMEGA]
    L = hist.shape[1]
    upd = int(sp[SP_UPD])
    dt_loop = upd * nservo * dts
    sweeps = int(sp[SP_SWEEPS])
    u = np.zeros(n)
    ts = np.zeros(n)
    tnet = np.zeros(n)
    vstar = np.zeros(n)
    vnew = np.zeros(n)
    mult = np.zeros(n)
    ffw = np.zeros(n)
    for kk in range(K):
        k = k0 + kk
        for i in range(nservo):
            tau_in = i * dts
            mode = ist[I_MODE]
            sq = 1.0 if math.sin(omega * fst[F_CLOCK]) >= 0.0 else -1.0
            for j in range(n):
                dith = mode != 0 and jp[DMASK, j] > 0.5
                kpe = 0.0 if dith else jp[KP, j] * kp_on[kk]
                qr = q_ref[kk, j] + dq_ref[kk, j] * tau_in
                if kpe > 0.0 and x[X_KPE, j] == 0.0:
                    x[X_OFF, j] = x[X_QM, j] - qr
                x[X_KPE, j] = kpe
                vref = dq_ref[kk, j] + kpe * (qr + x[X_OFF, j] - x[X_QM, j])
                ev = vref - x[X_VM, j]
                x[X_I, j] += jp[KI, j] * ev * dts
                g = gc0[j]
                for m in range(n):
                    g += Gc[j, m] * (x[X_QM, m] - qc_lin[m])
                ffw[j] = (x[X_C, j] + x[X_A, j] * sq) if dith else 0.0
                u[j] = g + ffw[j] + jp[KV, j] * ev + x[X_I, j]
            if i == 0:
                # ---- log the sample and run the dither loops on the logged torque
                pos = ist[I_POS]
                for j in range(n):
                    tl = u[j] + noise[kk, j]
                    out[O_TAU, k, j] = tl
                    out[O_QM, k, j] = x[X_QM, j]
                    out[O_VM, k, j] = x[X_VM, j]
                    out[O_Q, k, j] = x[X_Q, j]
                    out[O_FFW, k, j] = ffw[j]
                    hist[j, pos] = tl
                ist[I_POS] = (pos + 1) % L
                ist[I_FILL] = min(ist[I_FILL] + 1, L)
                fill = ist[I_FILL]
                cmd = dcmd[kk] > 0.5
                if mode == 0 and cmd or mode == 3 and cmd:
                    if mode == 0:
                        fst[F_CLOCK] = 0.0
                    ist[I_MODE] = 1
                    ist[I_CNT] = 0
                    fst[F_R] = 0.0
                    for j in range(n):
                        c, up, lo = _window_levels(hist, j, fill)
                        x[X_C0, j] = c
                elif (mode == 1 or mode == 2) and not cmd:
                    ist[I_MODE] = 3
                    fst[F_RD] = 0.0
                    for j in range(n):
                        x[X_CSTOP, j] = x[X_C, j]
                        x[X_ASTOP, j] = x[X_A, j]
                mode = ist[I_MODE]
                if mode == 1:
                    fst[F_R] = min(1.0, fst[F_R] + 1.0 / sp[SP_RAMP])
                    if fst[F_R] >= 1.0:
                        ist[I_MODE] = 2
                if mode == 1 or mode == 2:
                    ist[I_CNT] += 1
                    if ist[I_CNT] % upd == 0:
                        r = fst[F_R]
                        for j in range(n):
                            if jp[DMASK, j] < 0.5:
                                continue
                            c, up, lo = _window_levels(hist, j, fill)
                            amp = 0.5 * (up - lo)
                            g = gc0[j]
                            for m in range(n):
                                g += Gc[j, m] * (x[X_QM, m] - qc_lin[m])
                            cref = (1.0 - r) * x[X_C0, j] + r * g
                            aref = r * jp[AMP_SP, j]
                            hold = sp[SP_HOLD] * jp[BAND, j]
                            if abs(cref - c) > hold:
                                x[X_C, j] += sp[SP_KC] * (cref - c) * dt_loop
                            if abs(aref - amp) > hold:
                                a = x[X_A, j] + sp[SP_KA] * (aref - amp) * dt_loop
                                x[X_A, j] = min(max(a, 0.0), jp[AMP_CAP, j])
                            x[X_CM, j] = c
                            x[X_AM, j] = amp
                            x[X_CR, j] = cref
                            x[X_AR, j] = aref
                elif mode == 3:
                    fst[F_RD] = min(1.0, fst[F_RD] + 1.0 / sp[SP_RAMP])
                    for j in range(n):
                        x[X_C, j] = x[X_CSTOP, j] * (1.0 - fst[F_RD])
                        x[X_A, j] = x[X_ASTOP, j] * (1.0 - fst[F_RD])
                    if fst[F_RD] >= 1.0:
                        ist[I_MODE] = 0
                for j in range(n):
                    out[O_CMEAS, k, j] = x[X_CM, j]
                    out[O_AMEAS, k, j] = x[X_AM, j]
                    out[O_CREF, k, j] = x[X_CR, j]
                    out[O_AREF, k, j] = x[X_AR, j]
                    out[O_C, k, j] = x[X_C, j]
                    out[O_A, k, j] = x[X_A, j]
                    out[O_DITHER, k, j] = 1.0 if ist[I_MODE] != 0 else 0.0
            if ist[I_MODE] != 0:
                fst[F_CLOCK] += dts
            # ---- plant substeps with the torque reference u held
            for _ in range(nsub):
                for j in range(n):
                    ts[j] = jp[KG, j] * (x[X_QM, j] - x[X_Q, j]) + jp[CG, j] * (
                        x[X_VM, j] - x[X_V, j]
                    )
                    band = jp[FS_M, j] + jp[FS_O, j]
                    lm = 1.0 + jp[LOAD, j] * abs(ts[j]) / band if band > 0.0 else 1.0
                    mult[j] = lm * fscale[kk, j]
                    ripple = jp[RIP_A, j] * math.sin(jp[RIP_F, j] * x[X_QM, j])
                    vm = x[X_VM, j]
                    fc = (
                        jp[FC_M, j]
                        * mult[j]
                        * (1.0 + jp[STRIB, j] * math.exp(-((vm / jp[STRIB_V, j]) ** 2)))
                    )
                    p = jp[JM, j] * vm + h * (u[j] - ts[j] - ripple)
                    v, st = _stick_slip(
                        jp[JM, j],
                        p,
                        h,
                        jp[FS_M, j] * mult[j],
                        fc,
                        jp[FV_M, j] * fscale[kk, j],
                        x[X_SM, j] > 0.5,
                        vm,
                    )
                    vnew[j] = v
                    x[X_SM, j] = 1.0 if st else 0.0
                for j in range(n):
                    g = gp0[j]
                    for m in range(n):
                        g += Gp[j, m] * (x[X_Q, m] - qp_lin[m])
                    e = tau_ext[kk, j]
                    for c6 in range(6):
                        e += JT[j, c6] * push[kk, c6]
                    tnet[j] = ts[j] - g + e
                for j in range(n):
                    acc = 0.0
                    for m in range(n):
                        acc += W[j, m] * tnet[m]
                    vstar[j] = x[X_V, j] + h * acc
                # projected Gauss-Seidel for the coupled output-side friction
                for _sw in range(sweeps):
                    for j in range(n):
                        a = vstar[j]
                        for m in range(n):
                            if m != j:
                                a -= h * W[j, m] * x[X_FO, m]
                        me = 1.0 / W[j, j]
                        p = me * a
                        vo = x[X_V, j]
                        fc = (
                            jp[FC_O, j]
                            * mult[j]
                            * (1.0 + jp[STRIB, j] * math.exp(-((vo / jp[STRIB_V, j]) ** 2)))
                        )
                        v, st = _stick_slip(
                            me,
                            p,
                            h,
                            jp[FS_O, j] * mult[j],
                            fc,
                            jp[FV_O, j] * fscale[kk, j],
                            x[X_SO, j] > 0.5,
                            vo,
                        )
                        x[X_FO, j] = (p - me * v) / h
                        tnet[j] = 1.0 if st else 0.0  # reuse as the new stuck flag
                for j in range(n):
                    acc = 0.0
                    for m in range(n):
                        acc += W[j, m] * x[X_FO, m]
                    v = vstar[j] - h * acc
                    if tnet[j] > 0.5:
                        v = 0.0
                    x[X_SO, j] = tnet[j]
                    x[X_QM, j] += h * vnew[j]
                    x[X_VM, j] = vnew[j]
                    x[X_Q, j] += h * v
                    x[X_V, j] = v


def run_reference(
    jp,
    sp,
    W,
    gp0,
    Gp,
    qp_lin,
    gc0,
    Gc,
    qc_lin,
    JT,
    push,
    tau_ext,
    q_ref,
    dq_ref,
    kp_on,
    dcmd,
    noise,
    fscale,
    x,
    ist,
    fst,
    hist,
    out,
    k0,
    sweeps=60,
):
    """The same step as :func:`run_kernel`, written plainly with numpy over the joints.

    Slow (pure Python per substep) and meant only as the reference for tests and the
    benchmark; it runs ``sweeps`` Gauss-Seidel sweeps instead of the kernel's few. Same
    arguments and in-place updates as :func:`run_kernel`.
    """
    n = jp.shape[1]
    h, dts, omega = sp[SP_H], sp[SP_DTS], sp[SP_OMEGA]
    nservo, nsub, upd = int(sp[SP_NSERVO]), int(sp[SP_NSUB]), int(sp[SP_UPD])
    dt_loop = upd * nservo * dts
    L = hist.shape[1]
    dm = jp[DMASK] > 0.5

    def levels(fill):
        # the paper's pseudo-code over the ring buffer's newest `fill` samples
        w = hist[:, :fill]
        c = w.mean(axis=1)
        above, below = w > c[:, None], w < c[:, None]
        up = np.where(above.any(1), (w * above).sum(1) / np.maximum(above.sum(1), 1), c)
        lo = np.where(below.any(1), (w * below).sum(1) / np.maximum(below.sum(1), 1), c)
        return c, up, lo

    def stick_slip(m, p, fs, fc, fv, stuck, v_old):
        fresh = stuck | (v_old == 0.0)
        s = np.where(fresh, np.where(p > 0, 1.0, -1.0), np.where(v_old > 0, 1.0, -1.0))
        v = (p - h * fc * s) / (m + h * fv)
        hold = (fresh & (np.abs(p) <= h * fs)) | (v * s <= 0.0)
        return np.where(hold, 0.0, v), hold

    for kk in range(push.shape[0]):
        k = k0 + kk
        for i in range(nservo):
            mode = ist[I_MODE]
            sq = 1.0 if np.sin(omega * fst[F_CLOCK]) >= 0.0 else -1.0
            dith = (mode != 0) & dm
            kpe = np.where(dith, 0.0, jp[KP] * kp_on[kk])
            qr = q_ref[kk] + dq_ref[kk] * (i * dts)
            switch_on = (kpe > 0) & (x[X_KPE] == 0)
            x[X_OFF] = np.where(switch_on, x[X_QM] - qr, x[X_OFF])
            x[X_KPE] = kpe
            ev = dq_ref[kk] + kpe * (qr + x[X_OFF] - x[X_QM]) - x[X_VM]
            x[X_I] += jp[KI] * ev * dts
            gc = gc0 + Gc @ (x[X_QM] - qc_lin)
            ffw = np.where(dith, x[X_C] + x[X_A] * sq, 0.0)
            u = gc + ffw + jp[KV] * ev + x[X_I]
            if i == 0:
                tl = u + noise[kk]
                out[O_TAU, k], out[O_QM, k], out[O_VM, k] = tl, x[X_QM], x[X_VM]
                out[O_Q, k], out[O_FFW, k] = x[X_Q], ffw
                hist[:, ist[I_POS]] = tl
                ist[I_POS] = (ist[I_POS] + 1) % L
                ist[I_FILL] = min(ist[I_FILL] + 1, L)
                cmd = dcmd[kk] > 0.5
                if cmd and mode in (0, 3):
                    if mode == 0:
                        fst[F_CLOCK] = 0.0
                    ist[I_MODE], ist[I_CNT], fst[F_R] = 1, 0, 0.0
                    x[X_C0] = levels(ist[I_FILL])[0]
                elif not cmd and mode in (1, 2):
                    ist[I_MODE], fst[F_RD] = 3, 0.0
                    x[X_CSTOP], x[X_ASTOP] = x[X_C], x[X_A]
                mode = ist[I_MODE]
                if mode == 1:
                    fst[F_R] = min(1.0, fst[F_R] + 1.0 / sp[SP_RAMP])
                    if fst[F_R] >= 1.0:
                        ist[I_MODE] = 2
                if mode in (1, 2):
                    ist[I_CNT] += 1
                    if ist[I_CNT] % upd == 0:
                        r = fst[F_R]
                        c, up, lo = levels(ist[I_FILL])
                        amp = 0.5 * (up - lo)
                        cref = (1 - r) * x[X_C0] + r * (gc0 + Gc @ (x[X_QM] - qc_lin))
                        aref = r * jp[AMP_SP]
                        hold = sp[SP_HOLD] * jp[BAND]
                        dc = np.where(np.abs(cref - c) > hold, sp[SP_KC] * (cref - c) * dt_loop, 0)
                        da = np.where(
                            np.abs(aref - amp) > hold, sp[SP_KA] * (aref - amp) * dt_loop, 0
                        )
                        x[X_C] = np.where(dm, x[X_C] + dc, x[X_C])
                        x[X_A] = np.where(dm, np.clip(x[X_A] + da, 0.0, jp[AMP_CAP]), x[X_A])
                        for row, val in ((X_CM, c), (X_AM, amp), (X_CR, cref), (X_AR, aref)):
                            x[row] = np.where(dm, val, x[row])
                elif mode == 3:
                    fst[F_RD] = min(1.0, fst[F_RD] + 1.0 / sp[SP_RAMP])
                    x[X_C] = x[X_CSTOP] * (1 - fst[F_RD])
                    x[X_A] = x[X_ASTOP] * (1 - fst[F_RD])
                    if fst[F_RD] >= 1.0:
                        ist[I_MODE] = 0
                out[O_CMEAS, k], out[O_AMEAS, k] = x[X_CM], x[X_AM]
                out[O_CREF, k], out[O_AREF, k] = x[X_CR], x[X_AR]
                out[O_C, k], out[O_A, k] = x[X_C], x[X_A]
                out[O_DITHER, k] = 1.0 if ist[I_MODE] != 0 else 0.0
            if ist[I_MODE] != 0:
                fst[F_CLOCK] += dts
            for _ in range(nsub):
                ts = jp[KG] * (x[X_QM] - x[X_Q]) + jp[CG] * (x[X_VM] - x[X_V])
                band = jp[FS_M] + jp[FS_O]
                mult = (
                    np.where(band > 0, 1 + jp[LOAD] * np.abs(ts) / np.where(band > 0, band, 1), 1.0)
                    * fscale[kk]
                )

                def strib(v):
                    return 1 + jp[STRIB] * np.exp(-((v / jp[STRIB_V]) ** 2))

                ripple = jp[RIP_A] * np.sin(jp[RIP_F] * x[X_QM])
                p = jp[JM] * x[X_VM] + h * (u - ts - ripple)
                vm, sm = stick_slip(
                    jp[JM],
                    p,
                    jp[FS_M] * mult,
                    jp[FC_M] * mult * strib(x[X_VM]),
                    jp[FV_M] * fscale[kk],
                    x[X_SM] > 0.5,
                    x[X_VM],
                )
                tnet = ts - (gp0 + Gp @ (x[X_Q] - qp_lin)) + JT @ push[kk] + tau_ext[kk]
                vstar = x[X_V] + h * (W @ tnet)
                fo = x[X_FO].copy()
                so = np.zeros(n, dtype=bool)
                fc_o = jp[FC_O] * mult * strib(x[X_V])
                for _sw in range(sweeps):
                    for j in range(n):
                        a = vstar[j] - h * (W[j] @ fo - W[j, j] * fo[j])
                        me = 1.0 / W[j, j]
                        v1, s1 = stick_slip(
                            np.array([me]),
                            np.array([me * a]),
                            np.array([jp[FS_O, j] * mult[j]]),
                            np.array([fc_o[j]]),
                            np.array([jp[FV_O, j] * fscale[kk, j]]),
                            np.array([x[X_SO, j] > 0.5]),
                            np.array([x[X_V, j]]),
                        )
                        fo[j] = (me * a - me * v1[0]) / h
                        so[j] = s1[0]
                v = np.where(so, 0.0, vstar - h * (W @ fo))
                x[X_FO], x[X_SO], x[X_SM] = fo, so.astype(float), sm.astype(float)
                x[X_QM] += h * vm
                x[X_VM] = vm
                x[X_Q] += h * v
                x[X_V] = v
