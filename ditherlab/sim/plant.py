"""The compiled inner loop: joints (motor, gear spring, link), friction, servo and dither loops.

Per joint j (arm-side units, SI)::

    Jm dvm/dt = u - ts - r(qm) - f_m          motor (reflected inertia Jm)
    ts        = k (qm - q) + c (vm - v)        gear spring with damping
    M(q) dv/dt = ts - g(q) + J^T P - f_o       links, coupled through the mass matrix

``f_m`` and ``f_o`` are the friction on the motor side and on the gear output; ``motor_share``
splits the band between them. ``P`` is the push on the tool (the wrench the robot exerts is
``F = -P``). ``r(qm)`` is an optional cogging ripple (hidden effect). With ``joints.lost_motion``
(off by default) the spring has a gap of that width around zero twist, of
``lost_motion_stiffness`` times ``k`` inside (:func:`_gear_torque`).

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
    u    = g_ctrl(qm) + c + a w(omega t) + Kv (vref - vm) + I

Off by default (``servo.standstill_freeze``, ``standstill_leak``): at standstill (speed reference 0
and ``|vm| < servo.standstill_velocity``) the integral ``I`` is frozen and/or leaks towards 0.

``u`` is the torque reference; it is what gets logged (plus noise). When Kp is switched back on,
``offset`` is set so that the joint holds where it is (bumpless transfer).

``w`` is the unit-peak dither waveform (square, sine or triangle: ``sp[SP_WAVE]``).

Dither loops (paper §III-B), once per sample with the logged torque: a ring buffer of the last
``periods`` whole dither periods; every ``update_every`` samples the centre (window mean) and the
amplitude ((upper mean - lower mean)/2 of the samples above/below the centre, the paper's
pseudo-code, times the waveform's peak factor ``sp[SP_PEAK]``, 1 for the square wave) are
compared with their references and integrated into ``c`` and ``a`` unless the error is within
``hold`` of the band width. References ramp up over ``ramp`` samples (centre from
the measured centre to the gravity torque, amplitude from 0); at stop ``c`` and ``a`` ramp to 0.

Two implementations of the same step: :func:`run_kernel` (numba, scalar loops) and
:func:`run_reference` (plain numpy over joints, many more Gauss-Seidel sweeps); the tests and
``bench/bench_sim.py`` check they agree. Both use the same stick-slip law, gear-spring, Stribeck
and ripple formulas, window levels and dither mode switch (tested on their own), so the
comparison checks how the servo, the loops and the coupled link-side solve are put together.
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
    LM,
    LMK,
    ILEAK,
    IFRZ,
) = range(25)
N_JP = 25
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
    SP_WAVE,
    SP_PEAK,
    SP_VSTILL,
) = range(15)
N_SP = 15
#: ``sp[SP_WAVE]`` of each waveform (:data:`ditherlab.physics.dither.WAVEFORMS`, in that order)
WAVE_SQUARE, WAVE_SINE, WAVE_TRIANGLE = range(3)
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
# events of the dither mode switch (:func:`_switch_mode`) and what the loops do on a sample
# (:func:`_advance_ramps`)
EV_NONE, EV_START, EV_STOP = range(3)
ACT_NONE, ACT_UPDATE, ACT_RAMP_DOWN = range(3)


# ---------------------------------------------------------------------- shared by both steps
# The friction law, the plant's small formulas and the dither loops' bookkeeping are written once
# and used by both implementations: the kernel calls them compiled (inlined), the reference calls
# the scalar ones compiled and the array formulas as plain numpy (``.py_func``). What the
# reference still checks is the composition: servo, loops and the coupled link-side solve.
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


@njit(cache=True, inline="always")
def _gear_torque(kg, cg, qm, q, vm, v, lm, lmk):
    """Torque of the gear spring with damping [N m] (scalars or arrays of joints).

    ``lm`` [rad] is the half-width of the gear's lost motion around zero twist and ``lmk`` [-]
    the stiffness inside it as a fraction of ``kg`` (0: pure backlash); outside, the spring has
    the full stiffness ``kg`` from the edge of the lost motion. ``lm = 0`` is the plain spring
    ``kg (qm - q)``.
    """
    d = qm - q
    inner = np.minimum(np.abs(d), lm)
    return kg * (d - np.sign(d) * (1.0 - lmk) * inner) + cg * (vm - v)


def gear_twist(ts, kg, lm, lmk):
    """The twist ``qm - q`` [rad] at which the (undamped) gear spring carries ``ts`` [N m]:
    the inverse of :func:`_gear_torque` at zero velocity (arrays of joints)."""
    ts, kg, lm, lmk = (np.asarray(a, dtype=float) for a in (ts, kg, lm, lmk))
    edge = kg * lmk * lm  # torque at the edge of the lost motion
    with np.errstate(divide="ignore", invalid="ignore"):
        inside = np.where(lmk > 0, ts / (kg * np.where(lmk > 0, lmk, 1.0)), 0.0)
    outside = ts / kg + np.sign(ts) * (1.0 - lmk) * lm
    return np.where(np.abs(ts) <= edge, inside, outside)


@njit(cache=True, inline="always")
def _stribeck(v, strib, strib_v):
    """Factor on the Coulomb level at velocity ``v``: ``1 + strib exp(-(v / strib_v)^2)``."""
    return 1.0 + strib * np.exp(-((v / strib_v) ** 2))


@njit(cache=True, inline="always")
def _ripple(amp, freq, qm):
    """Cogging ripple torque [N m] at motor angle ``qm`` (scalars or arrays of joints)."""
    return amp * np.sin(freq * qm)


@njit(cache=True, inline="always")
def _dither_wave(omega, clock, shape):
    """The unit-peak dither waveform at the dither clock (:func:`ditherlab.physics.dither.wave`):
    square +1 while ``sin(omega clock) >= 0``, else -1; sine; triangle ``(2/pi) asin(sin)``."""
    s = math.sin(omega * clock)
    if shape == WAVE_SQUARE:
        return 1.0 if s >= 0.0 else -1.0
    if shape == WAVE_SINE:
        return s
    return (2.0 / math.pi) * math.asin(s)


@njit(cache=True, inline="always")
def _switch_mode(ist, fst, cmd):
    """Follow the dither command: start the loops (from off or during the ramp-down) or stop them.

    Updates the mode, counters and ramp progress in ``ist``/``fst``; returns EV_START (the
    caller stores the measured centre as the ramp's start), EV_STOP (the caller stores ``c``
    and ``a`` to ramp them down) or EV_NONE.
    """
    mode = ist[I_MODE]
    if mode == 0 and cmd or mode == 3 and cmd:
        if mode == 0:
            fst[F_CLOCK] = 0.0
        ist[I_MODE] = 1
        ist[I_CNT] = 0
        fst[F_R] = 0.0
        return EV_START
    if (mode == 1 or mode == 2) and not cmd:
        ist[I_MODE] = 3
        fst[F_RD] = 0.0
        return EV_STOP
    return EV_NONE


@njit(cache=True, inline="always")
def _advance_ramps(ist, fst, ramp, upd):
    """One sample of the ramps and the loop counter; returns what the loops do on this sample.

    ACT_UPDATE: compare and integrate (every ``upd``-th sample while ramping up or on, with the
    reference ramp at ``fst[F_R]``); ACT_RAMP_DOWN: scale the stored ``c`` and ``a`` by
    ``1 - fst[F_RD]``; ACT_NONE otherwise. The mode moves on when a ramp completes.
    """
    mode = ist[I_MODE]
    if mode == 1:
        fst[F_R] = min(1.0, fst[F_R] + 1.0 / ramp)
        if fst[F_R] >= 1.0:
            ist[I_MODE] = 2
    if mode == 1 or mode == 2:
        ist[I_CNT] += 1
        return ACT_UPDATE if ist[I_CNT] % upd == 0 else ACT_NONE
    if mode == 3:
        fst[F_RD] = min(1.0, fst[F_RD] + 1.0 / ramp)
        if fst[F_RD] >= 1.0:
            ist[I_MODE] = 0
        return ACT_RAMP_DOWN
    return ACT_NONE


# ---------------------------------------------------------------------- the compiled step
@njit(cache=True, inline="always")
def _linear_gravity(g0, G, q_lin, x, row, j):
    """Gravity of joint j linearised about ``q_lin``: ``g0 + G (x[row] - q_lin)`` [N m]."""
    g = g0[j]
    for m in range(g0.shape[0]):
        g += G[j, m] * (x[row, m] - q_lin[m])
    return g


@njit(cache=True, inline="always")
def _servo(
    jp, x, q_ref, dq_ref, kp_on, kk, tau_in, dts, loops_on, sq, gc0, Gc, qc_lin, u, ffw, sp_vstill
):
    """One servo tick of every joint (paper Fig. 3) -> torque reference ``u``, feedforward ``ffw``.

    Position loop (off while the joint dithers; bumpless offset when it comes back on), velocity
    loop with integral, the controller's gravity model and the dither feedforward
    ``c + a sq``. ``tau_in`` [s] is the time since the sample, for the ramp of ``q_ref``.
    At standstill (speed reference ``dq_ref`` 0 and ``|vm| < sp_vstill`` [rad/s]) the integral
    is frozen where ``jp[IFRZ]`` is set and leaks at ``jp[ILEAK]`` [1/s] (both 0 by default).
    """
    for j in range(jp.shape[1]):
        dith = loops_on and jp[DMASK, j] > 0.5
        kpe = 0.0 if dith else jp[KP, j] * kp_on[kk]
        qr = q_ref[kk, j] + dq_ref[kk, j] * tau_in
        if kpe > 0.0 and x[X_KPE, j] == 0.0:
            x[X_OFF, j] = x[X_QM, j] - qr
        x[X_KPE, j] = kpe
        vref = dq_ref[kk, j] + kpe * (qr + x[X_OFF, j] - x[X_QM, j])
        ev = vref - x[X_VM, j]
        if dq_ref[kk, j] == 0.0 and abs(x[X_VM, j]) < sp_vstill:
            # standstill: the drive freezes the integral or lets it leak (both off by default)
            if jp[IFRZ, j] < 0.5:
                x[X_I, j] += jp[KI, j] * ev * dts
            x[X_I, j] -= jp[ILEAK, j] * x[X_I, j] * dts
        else:
            x[X_I, j] += jp[KI, j] * ev * dts
        g = _linear_gravity(gc0, Gc, qc_lin, x, X_QM, j)
        ffw[j] = (x[X_C, j] + x[X_A, j] * sq) if dith else 0.0
        u[j] = g + ffw[j] + jp[KV, j] * ev + x[X_I, j]


@njit(cache=True, inline="always")
def _log_sample(out, k, kk, u, ffw, noise, x, ist, hist):
    """Log sample k (torque reference plus noise, angles, feedforward) and push the logged torque
    into the ring buffer."""
    pos = ist[I_POS]
    L = hist.shape[1]
    for j in range(u.shape[0]):
        tl = u[j] + noise[kk, j]
        out[O_TAU, k, j] = tl
        out[O_QM, k, j] = x[X_QM, j]
        out[O_VM, k, j] = x[X_VM, j]
        out[O_Q, k, j] = x[X_Q, j]
        out[O_FFW, k, j] = ffw[j]
        hist[j, pos] = tl
    ist[I_POS] = (pos + 1) % L
    ist[I_FILL] = min(ist[I_FILL] + 1, L)


@njit(cache=True, inline="always")
def _integrate_loops(jp, sp, x, hist, fill, r, gc0, Gc, qc_lin, dt_loop):
    """The loops' update for every dithering joint: the window's centre and amplitude against
    their references (ramped by ``r``), integrated into ``c`` and ``a`` outside the hold band."""
    for j in range(jp.shape[1]):
        if jp[DMASK, j] < 0.5:
            continue
        c, up, lo = _window_levels(hist, j, fill)
        amp = 0.5 * (up - lo) * sp[SP_PEAK]
        g = _linear_gravity(gc0, Gc, qc_lin, x, X_QM, j)
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


@njit(cache=True, inline="always")
def _dither_loops(jp, sp, x, ist, fst, hist, cmd, upd, gc0, Gc, qc_lin, dt_loop):
    """The dither loops on a logged sample: mode switch, ramps, and the centre/amplitude update."""
    n = jp.shape[1]
    fill = ist[I_FILL]
    event = _switch_mode(ist, fst, cmd)
    if event == EV_START:
        for j in range(n):
            c, up, lo = _window_levels(hist, j, fill)
            x[X_C0, j] = c
    elif event == EV_STOP:
        for j in range(n):
            x[X_CSTOP, j] = x[X_C, j]
            x[X_ASTOP, j] = x[X_A, j]
    action = _advance_ramps(ist, fst, sp[SP_RAMP], upd)
    if action == ACT_UPDATE:
        _integrate_loops(jp, sp, x, hist, fill, fst[F_R], gc0, Gc, qc_lin, dt_loop)
    elif action == ACT_RAMP_DOWN:
        for j in range(n):
            x[X_C, j] = x[X_CSTOP, j] * (1.0 - fst[F_RD])
            x[X_A, j] = x[X_ASTOP, j] * (1.0 - fst[F_RD])


@njit(cache=True, inline="always")
def _log_loops(out, k, x, ist):
    """Log the loops' measured and reference centre/amplitude, ``c``, ``a`` and the dither flag."""
    for j in range(x.shape[1]):
        out[O_CMEAS, k, j] = x[X_CM, j]
        out[O_AMEAS, k, j] = x[X_AM, j]
        out[O_CREF, k, j] = x[X_CR, j]
        out[O_AREF, k, j] = x[X_AR, j]
        out[O_C, k, j] = x[X_C, j]
        out[O_A, k, j] = x[X_A, j]
        out[O_DITHER, k, j] = 1.0 if ist[I_MODE] != 0 else 0.0


@njit(cache=True, inline="always")
def _load_factor(load, band, ts):
    """Growth of a friction band ``band`` with the gear torque ``ts``: ``1 + load |ts| / band``."""
    return 1.0 + load * abs(ts) / band if band > 0.0 else 1.0


@njit(cache=True, inline="always")
def _free_link_velocity(h, W, gp0, Gp, qp_lin, JT, Gam, push, tau_ext, kk, x, ts, tnet, vstar):
    """Link velocities after the substep without output-side friction: ``v + h W tnet`` with
    ``tnet = ts - g(q) - c(q, v) + tau_ext + J^T P`` (written to ``tnet`` and ``vstar``), the
    Coriolis and centrifugal torque ``c_j = sum_ab Gam[j, a, b] v_a v_b``."""
    n = ts.shape[0]
    for j in range(n):
        g = _linear_gravity(gp0, Gp, qp_lin, x, X_Q, j)
        e = tau_ext[kk, j]
        for c6 in range(6):
            e += JT[j, c6] * push[kk, c6]
        c = 0.0
        for a in range(n):
            va = x[X_V, a]
            if va != 0.0:
                for b in range(n):
                    c += Gam[j, a, b] * va * x[X_V, b]
        tnet[j] = ts[j] - g - c + e
    for j in range(n):
        acc = 0.0
        for m in range(n):
            acc += W[j, m] * tnet[m]
        vstar[j] = x[X_V, j] + h * acc


@njit(cache=True, inline="always")
def _advance_joints(h, W, x, vstar, stuck, vnew):
    """End of the substep: link velocity with the output friction (0 when stuck), then both
    angles advanced with the new velocities (semi-implicit Euler)."""
    n = vstar.shape[0]
    for j in range(n):
        acc = 0.0
        for m in range(n):
            acc += W[j, m] * x[X_FO, m]
        v = vstar[j] - h * acc
        if stuck[j] > 0.5:
            v = 0.0
        x[X_SO, j] = stuck[j]
        x[X_QM, j] += h * vnew[j]
        x[X_VM, j] = vnew[j]
        x[X_Q, j] += h * v
        x[X_V, j] = v


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
    Gam,
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
    Gam : (n, n, n) [kg m^2] Christoffel symbols of the link mass matrix for this chunk,
        ``Gam[j, a, b] = (dM_ja/dq_b + dM_jb/dq_a - dM_ab/dq_j) / 2``: the Coriolis and
        centrifugal torque is ``c_j = sum_ab Gam[j, a, b] v_a v_b``
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
    shape = int(sp[SP_WAVE])
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
            loops_on = ist[I_MODE] != 0
            sq = _dither_wave(omega, fst[F_CLOCK], shape)
            tau_in = i * dts
            _servo(
                jp,
                x,
                q_ref,
                dq_ref,
                kp_on,
                kk,
                tau_in,
                dts,
                loops_on,
                sq,
                gc0,
                Gc,
                qc_lin,
                u,
                ffw,
                sp[SP_VSTILL],
            )
            if i == 0:
                # log the sample and run the dither loops on the logged torque
                _log_sample(out, k, kk, u, ffw, noise, x, ist, hist)
                _dither_loops(
                    jp, sp, x, ist, fst, hist, dcmd[kk] > 0.5, upd, gc0, Gc, qc_lin, dt_loop
                )
                _log_loops(out, k, x, ist)
            if ist[I_MODE] != 0:
                fst[F_CLOCK] += dts
            # plant substeps with the torque reference u held. The motor side and the
            # Gauss-Seidel sweeps stay written out here: as inlined helpers they cost 3-10 % of
            # the kernel's speed (A/B-measured in one process; numba's inlining adds reference
            # counting of the helpers' array arguments to the compiled loop).
            for _ in range(nsub):
                # motor side: gear torque, friction factor, implicit stick-slip of the rotor
                for j in range(n):
                    ts[j] = _gear_torque(
                        jp[KG, j],
                        jp[CG, j],
                        x[X_QM, j],
                        x[X_Q, j],
                        x[X_VM, j],
                        x[X_V, j],
                        jp[LM, j],
                        jp[LMK, j],
                    )
                    band = jp[FS_M, j] + jp[FS_O, j]
                    mult[j] = _load_factor(jp[LOAD, j], band, ts[j]) * fscale[kk, j]
                    ripple = _ripple(jp[RIP_A, j], jp[RIP_F, j], x[X_QM, j])
                    vm = x[X_VM, j]
                    fc = jp[FC_M, j] * mult[j] * _stribeck(vm, jp[STRIB, j], jp[STRIB_V, j])
                    p = jp[JM, j] * vm + h * (u[j] - ts[j] - ripple)
                    fs, fv = jp[FS_M, j] * mult[j], jp[FV_M, j] * fscale[kk, j]
                    vnew[j], st = _stick_slip(jp[JM, j], p, h, fs, fc, fv, x[X_SM, j] > 0.5, vm)
                    x[X_SM, j] = 1.0 if st else 0.0
                _free_link_velocity(
                    h, W, gp0, Gp, qp_lin, JT, Gam, push, tau_ext, kk, x, ts, tnet, vstar
                )
                # output side: projected Gauss-Seidel on W = M^-1 for the coupled friction
                # torques x[X_FO] (warm-started), a stick-slip box problem per joint; tnet is
                # spent once vstar is formed and holds the new stuck flags
                for _sw in range(sweeps):
                    for j in range(n):
                        a = vstar[j]
                        for m in range(n):
                            if m != j:
                                a -= h * W[j, m] * x[X_FO, m]
                        me = 1.0 / W[j, j]
                        p = me * a
                        vo = x[X_V, j]
                        fc = jp[FC_O, j] * mult[j] * _stribeck(vo, jp[STRIB, j], jp[STRIB_V, j])
                        fs, fv = jp[FS_O, j] * mult[j], jp[FV_O, j] * fscale[kk, j]
                        v, st = _stick_slip(me, p, h, fs, fc, fv, x[X_SO, j] > 0.5, vo)
                        x[X_FO, j] = (p - me * v) / h
                        tnet[j] = 1.0 if st else 0.0
                _advance_joints(h, W, x, vstar, tnet, vnew)


# ---------------------------------------------------------------------- the numpy reference
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
    Gam,
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
    h, dts, omega, shape = sp[SP_H], sp[SP_DTS], sp[SP_OMEGA], int(sp[SP_WAVE])
    nservo, nsub = int(sp[SP_NSERVO]), int(sp[SP_NSUB])
    for kk in range(push.shape[0]):
        k = k0 + kk
        for i in range(nservo):
            loops_on = ist[I_MODE] != 0
            sq = _dither_wave(omega, fst[F_CLOCK], shape)
            u, ffw = _reference_servo(
                jp,
                x,
                q_ref[kk] + dq_ref[kk] * (i * dts),
                dq_ref[kk],
                kp_on[kk],
                dts,
                loops_on,
                sq,
                gc0,
                Gc,
                qc_lin,
                sp[SP_VSTILL],
            )
            if i == 0:
                tl = u + noise[kk]
                out[O_TAU, k], out[O_QM, k], out[O_VM, k] = tl, x[X_QM], x[X_VM]
                out[O_Q, k], out[O_FFW, k] = x[X_Q], ffw
                hist[:, ist[I_POS]] = tl
                ist[I_POS] = (ist[I_POS] + 1) % hist.shape[1]
                ist[I_FILL] = min(ist[I_FILL] + 1, hist.shape[1])
                _reference_dither_loops(jp, sp, x, ist, fst, hist, dcmd[kk] > 0.5, gc0, Gc, qc_lin)
                out[O_CMEAS, k], out[O_AMEAS, k] = x[X_CM], x[X_AM]
                out[O_CREF, k], out[O_AREF, k] = x[X_CR], x[X_AR]
                out[O_C, k], out[O_A, k] = x[X_C], x[X_A]
                out[O_DITHER, k] = 1.0 if ist[I_MODE] != 0 else 0.0
            if ist[I_MODE] != 0:
                fst[F_CLOCK] += dts
            for _ in range(nsub):
                _reference_substep(
                    jp,
                    h,
                    sweeps,
                    W,
                    gp0,
                    Gp,
                    qp_lin,
                    JT,
                    Gam,
                    push[kk],
                    tau_ext[kk],
                    fscale[kk],
                    u,
                    x,
                )


def _reference_servo(jp, x, qr, dq_ref, kp_on, dts, loops_on, sq, gc0, Gc, qc_lin, vstill):
    """:func:`_servo` over all joints at once -> (u, ffw); ``qr`` is the ramped position ref,
    ``vstill`` [rad/s] the standstill speed of the integral's freeze / leak."""
    dith = loops_on & (jp[DMASK] > 0.5)
    kpe = np.where(dith, 0.0, jp[KP] * kp_on)
    switch_on = (kpe > 0) & (x[X_KPE] == 0)
    x[X_OFF] = np.where(switch_on, x[X_QM] - qr, x[X_OFF])
    x[X_KPE] = kpe
    ev = dq_ref + kpe * (qr + x[X_OFF] - x[X_QM]) - x[X_VM]
    still = (dq_ref == 0.0) & (np.abs(x[X_VM]) < vstill)
    x[X_I] += np.where(still & (jp[IFRZ] > 0.5), 0.0, jp[KI] * ev * dts)
    x[X_I] -= np.where(still, jp[ILEAK] * x[X_I] * dts, 0.0)
    gc = gc0 + Gc @ (x[X_QM] - qc_lin)
    ffw = np.where(dith, x[X_C] + x[X_A] * sq, 0.0)
    return gc + ffw + jp[KV] * ev + x[X_I], ffw


def _reference_levels(hist, fill):
    """(centre, upper, lower) of every joint's window: :func:`_window_levels`, stacked."""
    c, up, lo = np.array([_window_levels(hist, j, fill) for j in range(hist.shape[0])]).T
    return c, up, lo


def _reference_dither_loops(jp, sp, x, ist, fst, hist, cmd, gc0, Gc, qc_lin):
    """:func:`_dither_loops` with the update written over all joints at once."""
    dm = jp[DMASK] > 0.5
    upd = int(sp[SP_UPD])
    dt_loop = upd * int(sp[SP_NSERVO]) * sp[SP_DTS]
    fill = ist[I_FILL]
    event = _switch_mode(ist, fst, cmd)
    if event == EV_START:
        x[X_C0] = _reference_levels(hist, fill)[0]
    elif event == EV_STOP:
        x[X_CSTOP], x[X_ASTOP] = x[X_C], x[X_A]
    action = _advance_ramps(ist, fst, sp[SP_RAMP], upd)
    if action == ACT_UPDATE:
        r = fst[F_R]
        c, up, lo = _reference_levels(hist, fill)
        amp = 0.5 * (up - lo) * sp[SP_PEAK]
        cref = (1 - r) * x[X_C0] + r * (gc0 + Gc @ (x[X_QM] - qc_lin))
        aref = r * jp[AMP_SP]
        hold = sp[SP_HOLD] * jp[BAND]
        dc = np.where(np.abs(cref - c) > hold, sp[SP_KC] * (cref - c) * dt_loop, 0)
        da = np.where(np.abs(aref - amp) > hold, sp[SP_KA] * (aref - amp) * dt_loop, 0)
        x[X_C] = np.where(dm, x[X_C] + dc, x[X_C])
        x[X_A] = np.where(dm, np.clip(x[X_A] + da, 0.0, jp[AMP_CAP]), x[X_A])
        for row, val in ((X_CM, c), (X_AM, amp), (X_CR, cref), (X_AR, aref)):
            x[row] = np.where(dm, val, x[row])
    elif action == ACT_RAMP_DOWN:
        x[X_C] = x[X_CSTOP] * (1 - fst[F_RD])
        x[X_A] = x[X_ASTOP] * (1 - fst[F_RD])


def _reference_substep(jp, h, sweeps, W, gp0, Gp, qp_lin, JT, Gam, push, tau_ext, fscale, u, x):
    """One plant substep over all joints: motor side, link side with matrix products, and the
    output-side friction by ``sweeps`` Gauss-Seidel sweeps; ``push``, ``tau_ext`` and ``fscale``
    are this sample's rows."""
    n = jp.shape[1]
    ts = _gear_torque.py_func(jp[KG], jp[CG], x[X_QM], x[X_Q], x[X_VM], x[X_V], jp[LM], jp[LMK])
    band = jp[FS_M] + jp[FS_O]
    load = np.where(band > 0, 1 + jp[LOAD] * np.abs(ts) / np.where(band > 0, band, 1), 1.0)
    mult = load * fscale
    ripple = _ripple.py_func(jp[RIP_A], jp[RIP_F], x[X_QM])
    p = jp[JM] * x[X_VM] + h * (u - ts - ripple)
    fc_m = jp[FC_M] * mult * _stribeck.py_func(x[X_VM], jp[STRIB], jp[STRIB_V])
    vm, sm = np.zeros(n), np.zeros(n, dtype=bool)
    for j in range(n):
        vm[j], sm[j] = _stick_slip(
            jp[JM, j],
            p[j],
            h,
            jp[FS_M, j] * mult[j],
            fc_m[j],
            jp[FV_M, j] * fscale[j],
            x[X_SM, j] > 0.5,
            x[X_VM, j],
        )
    coriolis = np.einsum("jab,a,b->j", Gam, x[X_V], x[X_V])
    tnet = ts - (gp0 + Gp @ (x[X_Q] - qp_lin)) - coriolis + JT @ push + tau_ext
    vstar = x[X_V] + h * (W @ tnet)
    fo = x[X_FO].copy()
    so = np.zeros(n, dtype=bool)
    fc_o = jp[FC_O] * mult * _stribeck.py_func(x[X_V], jp[STRIB], jp[STRIB_V])
    for _sw in range(sweeps):
        for j in range(n):
            a = vstar[j] - h * (W[j] @ fo - W[j, j] * fo[j])
            me = 1.0 / W[j, j]
            v1, so[j] = _stick_slip(
                me,
                me * a,
                h,
                jp[FS_O, j] * mult[j],
                fc_o[j],
                jp[FV_O, j] * fscale[j],
                x[X_SO, j] > 0.5,
                x[X_V, j],
            )
            fo[j] = (me * a - me * v1) / h
    v = np.where(so, 0.0, vstar - h * (W @ fo))
    x[X_FO], x[X_SO], x[X_SM] = fo, so.astype(float), sm.astype(float)
    x[X_QM] += h * vm
    x[X_VM] = vm
    x[X_Q] += h * v
    x[X_V] = v
