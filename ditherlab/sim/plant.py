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
implicit); a slipping side whose update would reverse its velocity sticks. It keeps a sub-band
push out of the logged torque (the paper's Fig. 2, left) and does not depend on the step size;
why this law and not a smooth one: ``docs/design/simulator-friction.md``. On the link side the
joints are coupled through M, so the stuck/slip friction torques are found by projected
Gauss-Seidel on ``W = M^-1`` (a box problem per joint, warm-started).

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

What a step reads and writes comes in four objects: :class:`Params` (the per-joint and scalar
parameters), :class:`Dynamics` (the link-side dynamics of a chunk), :class:`Samples` (the
per-sample inputs of a chunk) and :class:`State` (what carries over from chunk to chunk).

Two implementations of the same step: :func:`run_kernel` (numba, scalar loops) and
:func:`run_reference` (plain numpy over joints, many more Gauss-Seidel sweeps); the tests and
``bench/bench_sim.py`` check they agree. Both use the same stick-slip law, gear-spring, Stribeck
and ripple formulas, window levels and dither mode switch (tested on their own), so the
comparison checks how the servo, the loops and the coupled link-side solve are put together.
How the kernel is laid out for speed: ``docs/design/sim-kernel.md``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

# ------------------------------------------------------------------ rows of the parameter arrays
# Rows of the per-joint parameter array ``jp`` (N_JP, n), arm side of the gearbox, SI.
# the joints
JM = 0  # [kg·m²] reflected motor inertia
KG = 1  # [N·m/rad] gear stiffness
CG = 2  # [N·m·s/rad] gear damping
FS_M = 3  # [N·m] static friction (band half-width) on the motor side
FC_M = 4  # [N·m] Coulomb friction on the motor side
FV_M = 5  # [N·m·s/rad] viscous friction on the motor side
FS_O = 6  # [N·m] static friction on the gear output (link side)
FC_O = 7  # [N·m] Coulomb friction on the gear output
FV_O = 8  # [N·m·s/rad] viscous friction on the gear output
# the servo's gains
KP = 9  # [1/s] position gain
KV = 10  # [N·m·s/rad] velocity gain
KI = 11  # [N·m/rad] velocity integral gain
# the dither loops' settings
AMP_SP = 12  # [N·m] amplitude set-point (peak in the logged torque)
AMP_CAP = 13  # [N·m] largest feedforward amplitude
BAND = 14  # [N·m] band width 2 Fs (the loops' hold is a fraction of it)
DMASK = 15  # [-] 1 where the joint dithers
# hidden plant terms and drive options
LOAD = 16  # [-] band growth per N·m of gear torque, relative to the band
STRIB = 17  # [-] Stribeck excess at zero speed, relative to Fc
STRIB_V = 18  # [rad/s] Stribeck velocity
RIP_A = 19  # [N·m] cogging ripple amplitude on the motor
RIP_F = 20  # [1/rad] ripple angular frequency in the motor angle
LM = 21  # [rad] half-width of the gear's lost motion
LMK = 22  # [-] stiffness inside the lost motion / KG
ILEAK = 23  # [1/s] leak of the velocity integral at standstill
IFRZ = 24  # [-] 1: the velocity integral is frozen at standstill
N_JP = 25
# Entries of the scalar parameter array ``sp`` (N_SP,).
SP_H = 0  # [s] plant integration step
SP_NSERVO = 1  # [-] servo ticks per logged sample
SP_NSUB = 2  # [-] plant steps per servo tick
SP_OMEGA = 3  # [rad/s] dither angular frequency
SP_WIN = 4  # [samples] the loops' window (whole dither periods)
SP_UPD = 5  # [samples] the loops update every this many samples
SP_KC = 6  # [1/s] centre loop gain
SP_KA = 7  # [1/s] amplitude loop gain
SP_HOLD = 8  # [-] the loops hold while the error is below this times BAND
SP_RAMP = 9  # [samples] ramp of the references up and of the feedforward down
SP_DTS = 10  # [s] servo period
SP_SWEEPS = 11  # [-] Gauss-Seidel sweeps of the link-side friction per plant step
SP_WAVE = 12  # [-] the dither waveform (WAVE_*)
SP_PEAK = 13  # [-] the waveform's peak factor (ditherlab.physics.dither.PEAK_FACTOR)
SP_VSTILL = 14  # [rad/s] standstill speed of the integral's freeze / leak
N_SP = 15
#: ``sp[SP_WAVE]`` of each waveform (:data:`ditherlab.physics.dither.WAVEFORMS`, in that order)
WAVE_SQUARE, WAVE_SINE, WAVE_TRIANGLE = range(3)
# Rows of the continuous state ``x`` (N_X, n).
X_QM = 0  # [rad] motor angle (arm side)
X_VM = 1  # [rad/s] motor velocity
X_Q = 2  # [rad] link angle
X_V = 3  # [rad/s] link velocity
X_I = 4  # [N·m] velocity integral
X_OFF = 5  # [rad] bumpless offset of the position reference
X_FO = 6  # [N·m] output-side friction torque (the Gauss-Seidel warm start)
X_KPE = 7  # [1/s] position gain in effect at the last tick
X_C = 8  # [N·m] dither centre feedforward
X_A = 9  # [N·m] dither amplitude feedforward
X_C0 = 10  # [N·m] measured centre when the loops started (the centre ramp's start)
X_CSTOP = 11  # [N·m] centre feedforward when the loops stopped
X_ASTOP = 12  # [N·m] amplitude feedforward when the loops stopped
X_SM = 13  # [-] 1 while the motor side is stuck
X_SO = 14  # [-] 1 while the output side is stuck
X_CM = 15  # [N·m] the loops' measured centre
X_AM = 16  # [N·m] the loops' measured amplitude
X_CR = 17  # [N·m] centre reference
X_AR = 18  # [N·m] amplitude reference
N_X = 19
# integer state ``ist``: ring-buffer position, filled, mode (0 off, 1 ramp up, 2 on, 3 ramp down),
# loop sample counter; float state ``fst``: ramp progress up, ramp progress down, dither clock [s]
I_POS, I_FILL, I_MODE, I_CNT = range(4)
F_R, F_RD, F_CLOCK = range(3)
# rows of the per-sample output ``out`` (N_OUT, N, n): the logged torque, motor angle and
# velocity, link angle, dither feedforward [N·m, rad, rad/s]; the loops' measured and reference
# centre and amplitude, their centre and amplitude feedforward [N·m]; the dither flag [-]
(O_TAU, O_QM, O_VM, O_Q, O_FFW, O_CMEAS, O_AMEAS, O_CREF, O_AREF, O_C, O_A, O_DITHER) = range(12)
N_OUT = 12
# events of the dither mode switch (:func:`_switch_mode`) and what the loops do on a sample
# (:func:`_advance_ramps`)
EV_NONE, EV_START, EV_STOP = range(3)
ACT_NONE, ACT_UPDATE, ACT_RAMP_DOWN = range(3)


# ---------------------------------------------------------------------- what a step reads
class Params(NamedTuple):
    """The plant's, the servo's and the dither loops' parameters.

    Attributes
    ----------
    jp : (N_JP, n) per-joint parameters, one row per name above (``JM`` .. ``IFRZ``)
    sp : (N_SP,) scalar parameters, one entry per name above (``SP_H`` .. ``SP_VSTILL``)
    """

    jp: np.ndarray
    sp: np.ndarray


class Dynamics(NamedTuple):
    """The link-side dynamics of one chunk, evaluated where the chunk starts.

    Attributes
    ----------
    W : (n, n) [1/(kg·m²)] inverse link mass matrix (output inertia on its diagonal)
    gp0, Gp, qp_lin : the plant's gravity ``g(q) ~ gp0 + Gp (q - qp_lin)``: (n,) [N·m],
        (n, n) [N·m/rad], (n,) [rad]
    gc0, Gc, qc_lin : the controller's gravity model, linearised likewise in the motor angle
    JT : (n, 6) [m or 1] transposed tool Jacobian
    Gam : (n, n, n) [kg·m²] Christoffel symbols of the link mass matrix,
        ``Gam[j, a, b] = (dM_ja/dq_b + dM_jb/dq_a - dM_ab/dq_j) / 2``: the Coriolis and
        centrifugal torque is ``c_j = sum_ab Gam[j, a, b] v_a v_b``
    """

    W: np.ndarray
    gp0: np.ndarray
    Gp: np.ndarray
    qp_lin: np.ndarray
    gc0: np.ndarray
    Gc: np.ndarray
    qc_lin: np.ndarray
    JT: np.ndarray
    Gam: np.ndarray


class Samples(NamedTuple):
    """The per-sample inputs of one chunk of K samples, float64 and C-contiguous.

    Attributes
    ----------
    push : (K, 6) [N, N·m] push on the tool point (base axes)
    tau_ext : (K, n) [N·m] external torque at the joints (link side)
    q_ref, dq_ref : (K, n) [rad], [rad/s] motor-angle reference and its rate
    kp_on : (K,) [-] 1 while the position loop is enabled
    dcmd : (K,) [-] 1 while the dither is requested
    noise : (K, n) [N·m] noise added to the logged torque
    fscale : (K, n) [-] friction factor (1 nominal)
    """

    push: np.ndarray
    tau_ext: np.ndarray
    q_ref: np.ndarray
    dq_ref: np.ndarray
    kp_on: np.ndarray
    dcmd: np.ndarray
    noise: np.ndarray
    fscale: np.ndarray


class State(NamedTuple):
    """What carries over from one chunk to the next; updated in place.

    Attributes
    ----------
    x : (N_X, n) continuous state, one row per name above (``X_QM`` .. ``X_AR``)
    ist : (4,) int64 ring-buffer position and fill, dither mode, loop sample counter
    fst : (3,) ramp progress up and down [-], dither clock [s]
    hist : (n, L) [N·m] ring buffer of the logged torque, L samples of whole dither periods
    """

    x: np.ndarray
    ist: np.ndarray
    fst: np.ndarray
    hist: np.ndarray


class Scratch(NamedTuple):
    """The compiled step's work arrays, each (n,): torque reference ``u`` and dither
    feedforward ``ffw`` [N·m] of the servo tick; per plant step the gear torque ``ts`` [N·m],
    the friction factor ``mult`` [-], the motor's new velocity ``vnew`` [rad/s], the link
    velocity without output friction ``vstar`` [rad/s] and ``tnet`` (the net link torque
    [N·m], then the new output stuck flags [-])."""

    u: np.ndarray
    ffw: np.ndarray
    ts: np.ndarray
    mult: np.ndarray
    vnew: np.ndarray
    vstar: np.ndarray
    tnet: np.ndarray


# ---------------------------------------------------------------------- shared by both steps
# The friction law, the plant's small formulas and the dither loops' bookkeeping are written once
# and used by both implementations: the kernel calls them compiled (inlined), the reference calls
# the scalar ones compiled and the array formulas as plain numpy (``.py_func``). What the
# reference still checks is the composition: servo, loops and the coupled link-side solve.
@njit(cache=True)
def _stick_slip(m, p, h, fs, fc, fv, stuck, v_old):
    """Implicit rigid stick-slip for one body over a step of ``h`` [s] -> (v [rad/s], stuck).

    ``m`` [kg·m²] inertia, ``p`` [N·m·s] momentum at the step's end without friction, ``fs``,
    ``fc`` [N·m] static and Coulomb level, ``fv`` [N·m·s/rad] viscous coefficient, ``stuck``
    and ``v_old`` [rad/s] the body's state before the step.
    """
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
    """Centre, upper and lower mean [N·m] of the ``fill`` newest samples of joint j in the ring
    buffer ``hist`` (n, L) [N·m] (the paper's pseudo-code)."""
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
    """Torque of the gear spring with damping [N·m] (scalars or arrays of joints): stiffness
    ``kg`` [N·m/rad], damping ``cg`` [N·m·s/rad], motor and link angle ``qm``, ``q`` [rad] and
    velocity ``vm``, ``v`` [rad/s].

    ``lm`` [rad] is the half-width of the gear's lost motion around zero twist and ``lmk`` [-]
    the stiffness inside it as a fraction of ``kg`` (0: pure backlash); outside, the spring has
    the full stiffness ``kg`` from the edge of the lost motion. ``lm = 0`` is the plain spring
    ``kg (qm - q)``.
    """
    d = qm - q
    inner = np.minimum(np.abs(d), lm)
    return kg * (d - np.sign(d) * (1.0 - lmk) * inner) + cg * (vm - v)


def gear_twist(ts, kg, lm, lmk):
    """The twist ``qm - q`` at which the (undamped) gear spring carries ``ts``: the inverse of
    :func:`_gear_torque` at zero velocity.

    Parameters
    ----------
    ts : (n,) [N·m] gear torque
    kg : (n,) [N·m/rad] gear stiffness
    lm : (n,) [rad] half-width of the lost motion
    lmk : (n,) [-] stiffness inside the lost motion as a fraction of ``kg``

    Returns
    -------
    (n,) [rad]
    """
    ts, kg, lm, lmk = (np.asarray(a, dtype=float) for a in (ts, kg, lm, lmk))
    edge = kg * lmk * lm  # torque at the edge of the lost motion
    with np.errstate(divide="ignore", invalid="ignore"):
        inside = np.where(lmk > 0, ts / (kg * np.where(lmk > 0, lmk, 1.0)), 0.0)
    outside = ts / kg + np.sign(ts) * (1.0 - lmk) * lm
    return np.where(np.abs(ts) <= edge, inside, outside)


@njit(cache=True, inline="always")
def _stribeck(v, strib, strib_v):
    """Factor [-] on the Coulomb level at velocity ``v`` [rad/s]:
    ``1 + strib exp(-(v / strib_v)^2)``, ``strib_v`` [rad/s]."""
    return 1.0 + strib * np.exp(-((v / strib_v) ** 2))


@njit(cache=True, inline="always")
def _ripple(amp, freq, qm):
    """Cogging ripple torque [N·m] of amplitude ``amp`` [N·m] and angular frequency ``freq``
    [1/rad] at motor angle ``qm`` [rad] (scalars or arrays of joints)."""
    return amp * np.sin(freq * qm)


@njit(cache=True, inline="always")
def _dither_wave(omega, clock, shape):
    """The unit-peak dither waveform [-] at the dither clock ``clock`` [s], ``omega`` [rad/s]
    (:func:`ditherlab.physics.dither.wave`): square +1 while ``sin(omega clock) >= 0``, else -1;
    sine; triangle ``(2/pi) asin(sin)``."""
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
    """Gravity of joint j linearised about ``q_lin``: ``g0 + G (x[row] - q_lin)`` [N·m]."""
    g = g0[j]
    for m in range(g0.shape[0]):
        g += G[j, m] * (x[row, m] - q_lin[m])
    return g


@njit(cache=True, inline="always")
def _servo(par, dyn, inp, kk, tau_in, st, w):
    """One servo tick of every joint (paper Fig. 3) -> torque reference ``w.u`` and dither
    feedforward ``w.ffw`` [N·m].

    Position loop (off while the joint dithers; bumpless offset when it comes back on), velocity
    loop with integral, the controller's gravity model and the dither feedforward
    ``c + a w(omega t)``. ``kk`` is the sample in the chunk, ``tau_in`` [s] the time since it,
    for the ramp of ``q_ref``. At standstill (speed reference ``dq_ref`` 0 and
    ``|vm| < sp[SP_VSTILL]``) the integral is frozen where ``jp[IFRZ]`` is set and leaks at
    ``jp[ILEAK]`` [1/s] (both 0 by default).
    """
    jp, sp, x = par.jp, par.sp, st.x
    q_ref, dq_ref = inp.q_ref, inp.dq_ref
    loops_on = st.ist[I_MODE] != 0
    sq = _dither_wave(sp[SP_OMEGA], st.fst[F_CLOCK], int(sp[SP_WAVE]))
    dts = sp[SP_DTS]
    for j in range(jp.shape[1]):
        dith = loops_on and jp[DMASK, j] > 0.5
        kpe = 0.0 if dith else jp[KP, j] * inp.kp_on[kk]
        qr = q_ref[kk, j] + dq_ref[kk, j] * tau_in
        if kpe > 0.0 and x[X_KPE, j] == 0.0:
            x[X_OFF, j] = x[X_QM, j] - qr
        x[X_KPE, j] = kpe
        vref = dq_ref[kk, j] + kpe * (qr + x[X_OFF, j] - x[X_QM, j])
        ev = vref - x[X_VM, j]
        if dq_ref[kk, j] == 0.0 and abs(x[X_VM, j]) < sp[SP_VSTILL]:
            # standstill: the drive freezes the integral or lets it leak (both off by default)
            if jp[IFRZ, j] < 0.5:
                x[X_I, j] += jp[KI, j] * ev * dts
            x[X_I, j] -= jp[ILEAK, j] * x[X_I, j] * dts
        else:
            x[X_I, j] += jp[KI, j] * ev * dts
        g = _linear_gravity(dyn.gc0, dyn.Gc, dyn.qc_lin, x, X_QM, j)
        w.ffw[j] = (x[X_C, j] + x[X_A, j] * sq) if dith else 0.0
        w.u[j] = g + w.ffw[j] + jp[KV, j] * ev + x[X_I, j]


@njit(cache=True, inline="always")
def _log_sample(out, k, kk, inp, st, w):
    """Log sample k (torque reference plus noise, angles, feedforward) and push the logged torque
    into the ring buffer."""
    x, ist, hist = st.x, st.ist, st.hist
    pos = ist[I_POS]
    L = hist.shape[1]
    for j in range(w.u.shape[0]):
        tl = w.u[j] + inp.noise[kk, j]
        out[O_TAU, k, j] = tl
        out[O_QM, k, j] = x[X_QM, j]
        out[O_VM, k, j] = x[X_VM, j]
        out[O_Q, k, j] = x[X_Q, j]
        out[O_FFW, k, j] = w.ffw[j]
        hist[j, pos] = tl
    ist[I_POS] = (pos + 1) % L
    ist[I_FILL] = min(ist[I_FILL] + 1, L)


@njit(cache=True, inline="always")
def _integrate_loops(par, dyn, st, fill, r, dt_loop):
    """The loops' update for every dithering joint: the window's centre and amplitude against
    their references (ramped by ``r`` [-]), integrated into ``c`` and ``a`` outside the hold
    band; ``fill`` is the window's samples so far, ``dt_loop`` [s] the time between updates."""
    jp, sp, x = par.jp, par.sp, st.x
    for j in range(jp.shape[1]):
        if jp[DMASK, j] < 0.5:
            continue
        c, up, lo = _window_levels(st.hist, j, fill)
        amp = 0.5 * (up - lo) * sp[SP_PEAK]
        g = _linear_gravity(dyn.gc0, dyn.Gc, dyn.qc_lin, x, X_QM, j)
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
def _dither_loops(par, dyn, st, cmd):
    """The dither loops on a logged sample, ``cmd`` the dither command: mode switch, ramps, and
    the centre/amplitude update."""
    sp, x, ist, fst = par.sp, st.x, st.ist, st.fst
    n = x.shape[1]
    upd = int(sp[SP_UPD])
    dt_loop = upd * int(sp[SP_NSERVO]) * sp[SP_DTS]
    fill = ist[I_FILL]
    event = _switch_mode(ist, fst, cmd)
    if event == EV_START:
        for j in range(n):
            c, up, lo = _window_levels(st.hist, j, fill)
            x[X_C0, j] = c
    elif event == EV_STOP:
        for j in range(n):
            x[X_CSTOP, j] = x[X_C, j]
            x[X_ASTOP, j] = x[X_A, j]
    action = _advance_ramps(ist, fst, sp[SP_RAMP], upd)
    if action == ACT_UPDATE:
        _integrate_loops(par, dyn, st, fill, fst[F_R], dt_loop)
    elif action == ACT_RAMP_DOWN:
        for j in range(n):
            x[X_C, j] = x[X_CSTOP, j] * (1.0 - fst[F_RD])
            x[X_A, j] = x[X_ASTOP, j] * (1.0 - fst[F_RD])


@njit(cache=True, inline="always")
def _log_loops(out, k, st):
    """Log the loops' measured and reference centre/amplitude, ``c``, ``a`` and the dither flag."""
    x, ist = st.x, st.ist
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
    """Growth of a friction band ``band`` [N·m] with the gear torque ``ts`` [N·m]:
    ``1 + load |ts| / band`` [-]."""
    return 1.0 + load * abs(ts) / band if band > 0.0 else 1.0


@njit(cache=True, inline="always")
def _free_link_velocity(h, dyn, inp, kk, x, w):
    """Link velocities after a plant step of ``h`` [s] without output-side friction:
    ``v + h W tnet`` with ``tnet = ts - g(q) - c(q, v) + tau_ext + J^T P`` (written to
    ``w.tnet`` and ``w.vstar``), the Coriolis and centrifugal torque
    ``c_j = sum_ab Gam[j, a, b] v_a v_b``."""
    W, Gam, JT = dyn.W, dyn.Gam, dyn.JT
    ts, tnet, vstar = w.ts, w.tnet, w.vstar
    n = ts.shape[0]
    for j in range(n):
        g = _linear_gravity(dyn.gp0, dyn.Gp, dyn.qp_lin, x, X_Q, j)
        e = inp.tau_ext[kk, j]
        for c6 in range(6):
            e += JT[j, c6] * inp.push[kk, c6]
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
def _advance_joints(h, W, x, w):
    """End of a plant step of ``h`` [s]: link velocity with the output friction (0 when stuck,
    ``w.tnet`` holding the stuck flags), then both angles advanced with the new velocities
    (semi-implicit Euler)."""
    vstar, stuck, vnew = w.vstar, w.tnet, w.vnew
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
def _motor_side(h, jp, x, u, fscale, kk, w):
    """Motor side of a plant step of ``h`` [s] under the torque reference ``u`` (n,) [N·m]: gear
    torque, friction factor (``fscale`` row ``kk``), implicit stick-slip of the rotor
    (``w.ts``, ``w.mult``, ``w.vnew`` written; the motor's stuck flags in ``x``). A plain
    compiled call, not inlined (docs/design/sim-kernel.md)."""
    ts, mult, vnew = w.ts, w.mult, w.vnew
    n = ts.shape[0]
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
        vnew[j], stuck = _stick_slip(jp[JM, j], p, h, fs, fc, fv, x[X_SM, j] > 0.5, vm)
        x[X_SM, j] = 1.0 if stuck else 0.0


@njit(cache=True)
def _link_side(h, sweeps, jp, W, x, fscale, kk, w):
    """Output side of a plant step of ``h`` [s]: ``sweeps`` projected Gauss-Seidel sweeps on
    ``W = M^-1`` for the coupled friction torques ``x[X_FO]`` (warm-started), a stick-slip box
    problem per joint; ``w.tnet`` is spent once ``w.vstar`` is formed and holds the new stuck
    flags. A plain compiled call, not inlined (docs/design/sim-kernel.md)."""
    vstar, mult, tnet = w.vstar, w.mult, w.tnet
    n = vstar.shape[0]
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
            v, stuck = _stick_slip(me, p, h, fs, fc, fv, x[X_SO, j] > 0.5, vo)
            x[X_FO, j] = (p - me * v) / h
            tnet[j] = 1.0 if stuck else 0.0


def run_kernel(par: Params, dyn: Dynamics, inp: Samples, st: State, out: np.ndarray, k0: int):
    """Advance the plant, servo and dither loops over the K samples of ``inp`` (compiled).

    Parameters
    ----------
    par : the parameters
    dyn : the chunk's link-side dynamics
    inp : the chunk's per-sample inputs
    st : the state, updated in place
    out : (N_OUT, N, n) the run's outputs; rows ``k0 .. k0 + K`` are written
    k0 : the chunk's first sample in the run
    """
    _kernel(*par, *dyn, *inp, *st, out, k0)


# Flat: numba's dispatcher types a NamedTuple argument in Python, field by field, on every call
# from Python; inside, rebuilding the objects is free (docs/design/sim-kernel.md)
@njit(cache=True)
def _kernel(
    jp, sp, W, gp0, Gp, qp_lin, gc0, Gc, qc_lin, JT, Gam,
    push, tau_ext, q_ref, dq_ref, kp_on, dcmd, noise, fscale,
    x, ist, fst, hist, out, k0,
):  # fmt: skip
    """:func:`run_kernel` on the arrays of its four objects, in their order."""
    par = Params(jp, sp)
    dyn = Dynamics(W, gp0, Gp, qp_lin, gc0, Gc, qc_lin, JT, Gam)
    inp = Samples(push, tau_ext, q_ref, dq_ref, kp_on, dcmd, noise, fscale)
    st = State(x, ist, fst, hist)
    _run_chunk(par, dyn, inp, st, out, k0)


@njit(cache=True, inline="always")
def _run_chunk(par, dyn, inp, st, out, k0):
    """The step over the chunk's samples: per sample ``SP_NSERVO`` servo ticks (the first logs
    the sample and runs the dither loops on it), each followed by ``SP_NSUB`` plant steps with
    its torque reference held: the motor side, the link's free velocity, the Gauss-Seidel
    sweeps of the link-side friction, the joints advanced. Inlined into :func:`_kernel`; the
    arrays the loop reads are taken out of the objects before it (docs/design/sim-kernel.md)."""
    jp, sp, W, x, ist, fst = par.jp, par.sp, dyn.W, st.x, st.ist, st.fst
    push, dcmd, fscale = inp.push, inp.dcmd, inp.fscale
    n = jp.shape[1]
    z = np.zeros
    w = Scratch(z(n), z(n), z(n), z(n), z(n), z(n), z(n))
    u = w.u
    h, dts = sp[SP_H], sp[SP_DTS]
    nservo, nsub, sweeps = int(sp[SP_NSERVO]), int(sp[SP_NSUB]), int(sp[SP_SWEEPS])
    for kk in range(push.shape[0]):
        k = k0 + kk
        for i in range(nservo):
            _servo(par, dyn, inp, kk, i * dts, st, w)
            if i == 0:
                # log the sample and run the dither loops on the logged torque
                _log_sample(out, k, kk, inp, st, w)
                _dither_loops(par, dyn, st, dcmd[kk] > 0.5)
                _log_loops(out, k, st)
            if ist[I_MODE] != 0:
                fst[F_CLOCK] += dts
            for _ in range(nsub):
                _motor_side(h, jp, x, u, fscale, kk, w)
                _free_link_velocity(h, dyn, inp, kk, x, w)
                _link_side(h, sweeps, jp, W, x, fscale, kk, w)
                _advance_joints(h, W, x, w)


# ---------------------------------------------------------------------- the numpy reference
def run_reference(
    par: Params,
    dyn: Dynamics,
    inp: Samples,
    st: State,
    out: np.ndarray,
    k0: int,
    sweeps: int = 60,
) -> None:
    """The same step as :func:`run_kernel`, written plainly with numpy over the joints.

    Slow (pure Python per plant step) and meant only as the reference for tests and the
    benchmark; it runs ``sweeps`` Gauss-Seidel sweeps instead of the kernel's few. Same
    arguments and in-place updates as :func:`run_kernel`.
    """
    sp, x, ist, fst, hist = par.sp, st.x, st.ist, st.fst, st.hist
    dts, nservo, nsub = sp[SP_DTS], int(sp[SP_NSERVO]), int(sp[SP_NSUB])
    for kk in range(inp.push.shape[0]):
        k = k0 + kk
        for i in range(nservo):
            u, ffw = _reference_servo(par, dyn, inp, kk, i * dts, st)
            if i == 0:
                tl = u + inp.noise[kk]
                out[O_TAU, k], out[O_QM, k], out[O_VM, k] = tl, x[X_QM], x[X_VM]
                out[O_Q, k], out[O_FFW, k] = x[X_Q], ffw
                hist[:, ist[I_POS]] = tl
                ist[I_POS] = (ist[I_POS] + 1) % hist.shape[1]
                ist[I_FILL] = min(ist[I_FILL] + 1, hist.shape[1])
                _reference_dither_loops(par, dyn, st, inp.dcmd[kk] > 0.5)
                out[O_CMEAS, k], out[O_AMEAS, k] = x[X_CM], x[X_AM]
                out[O_CREF, k], out[O_AREF, k] = x[X_CR], x[X_AR]
                out[O_C, k], out[O_A, k] = x[X_C], x[X_A]
                out[O_DITHER, k] = 1.0 if ist[I_MODE] != 0 else 0.0
            if ist[I_MODE] != 0:
                fst[F_CLOCK] += dts
            for _ in range(nsub):
                _reference_substep(par, dyn, inp, kk, u, x, sweeps)


def _reference_servo(par, dyn, inp, kk, tau_in, st):
    """:func:`_servo` over all joints at once -> (u, ffw), each (n,) [N·m]."""
    jp, sp, x = par.jp, par.sp, st.x
    loops_on = st.ist[I_MODE] != 0
    sq = _dither_wave(sp[SP_OMEGA], st.fst[F_CLOCK], int(sp[SP_WAVE]))
    dq_ref = inp.dq_ref[kk]
    qr = inp.q_ref[kk] + dq_ref * tau_in
    dith = loops_on & (jp[DMASK] > 0.5)
    kpe = np.where(dith, 0.0, jp[KP] * inp.kp_on[kk])
    switch_on = (kpe > 0) & (x[X_KPE] == 0)
    x[X_OFF] = np.where(switch_on, x[X_QM] - qr, x[X_OFF])
    x[X_KPE] = kpe
    ev = dq_ref + kpe * (qr + x[X_OFF] - x[X_QM]) - x[X_VM]
    still = (dq_ref == 0.0) & (np.abs(x[X_VM]) < sp[SP_VSTILL])
    x[X_I] += np.where(still & (jp[IFRZ] > 0.5), 0.0, jp[KI] * ev * sp[SP_DTS])
    x[X_I] -= np.where(still, jp[ILEAK] * x[X_I] * sp[SP_DTS], 0.0)
    gc = dyn.gc0 + dyn.Gc @ (x[X_QM] - dyn.qc_lin)
    ffw = np.where(dith, x[X_C] + x[X_A] * sq, 0.0)
    return gc + ffw + jp[KV] * ev + x[X_I], ffw


def _reference_levels(hist, fill):
    """(centre, upper, lower) of every joint's window, each (n,) [N·m]: :func:`_window_levels`,
    stacked."""
    c, up, lo = np.array([_window_levels(hist, j, fill) for j in range(hist.shape[0])]).T
    return c, up, lo


def _reference_dither_loops(par, dyn, st, cmd):
    """:func:`_dither_loops` with the update written over all joints at once."""
    jp, sp, x, ist, fst, hist = par.jp, par.sp, st.x, st.ist, st.fst, st.hist
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
        cref = (1 - r) * x[X_C0] + r * (dyn.gc0 + dyn.Gc @ (x[X_QM] - dyn.qc_lin))
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


def _reference_substep(par, dyn, inp, kk, u, x, sweeps):
    """One plant step over all joints with the torque reference ``u`` (n,) [N·m] held: motor
    side, link side with matrix products, and the output-side friction by ``sweeps``
    Gauss-Seidel sweeps."""
    jp, h, W = par.jp, par.sp[SP_H], dyn.W
    fscale = inp.fscale[kk]
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
    coriolis = np.einsum("jab,a,b->j", dyn.Gam, x[X_V], x[X_V])
    gp = dyn.gp0 + dyn.Gp @ (x[X_Q] - dyn.qp_lin)
    tnet = ts - gp - coriolis + dyn.JT @ inp.push[kk] + inp.tau_ext[kk]
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
