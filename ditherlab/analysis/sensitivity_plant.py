"""The dithered push transmission of the simulator's plant, for :mod:`ditherlab.analysis.sensitivity`.

With dither a push reaches the estimator through the extracted signal, and how much of a joint's
push torque it shows is decided by the plant: whether the dither's spring torque frees the
link's friction (behind the gear spring) every period, the creep the velocity integral stops
(the joint's only stiffness with Kp = 0), the centre loop and the one-period extraction.
:func:`dither_transmission` simulates that from the plant's equations (:mod:`ditherlab.sim.plant`)
one joint at a time; :func:`extraction_peak` is the model's ``dither_extraction`` law instead;
:func:`transmitted` reads the table at any torque. ``docs/design/analysis-sensitivity.md`` has
the measurements.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ditherlab.physics.dither import PEAK_FACTOR

__all__ = [
    "TRANSMISSION_DURATIONS",
    "TRANSMISSION_TORQUES",
    "dither_transmission",
    "extraction_peak",
    "transmitted",
]


#: push torques [N·m] of :func:`dither_transmission`'s table, as multiples of each joint's Fs
TRANSMISSION_TORQUES = (0.025, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.3, 1.7, 2.2)
#: push lengths of the table: the middles of this many equal strata of the campaign's range
TRANSMISSION_DURATIONS = 4


def _stick_slip_all(
    m: np.ndarray, p: np.ndarray, h: float, fs: np.ndarray, fc: np.ndarray, fv: np.ndarray,
    stuck: np.ndarray, v_old: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The simulator's implicit rigid stick-slip (:mod:`ditherlab.sim.plant`) for arrays of
    bodies: inertia ``m`` [kg m^2], momentum without friction ``p`` [N m s], step ``h`` [s],
    static / Coulomb / viscous friction -> (velocity [rad/s], stuck)."""
    start = stuck | (v_old == 0.0)
    hold = start & (np.abs(p) <= h * fs)
    s = np.where(start, np.where(p > 0.0, 1.0, -1.0), np.where(v_old > 0.0, 1.0, -1.0))
    v = (p - h * fc * s) / (m + h * fv)
    st = hold | (v * s <= 0.0)
    return np.where(st, 0.0, v), st


def _extracted(u: np.ndarray, w: int) -> np.ndarray:
    """The paper's extraction (:func:`ditherlab.physics.dither.extract`) of logged torques ``u``
    (N, B) [N·m]: per sample the mean of the upper and lower means about the mean of the last
    ``w`` samples; NaN before the first whole window."""
    out = np.full(u.shape, np.nan)
    for k in range(w - 1, len(u)):
        x = u[k - w + 1 : k + 1]
        c = x.mean(axis=0)
        up, lo = x > c, x < c
        mu = np.where(up.any(0), (x * up).sum(0) / np.maximum(up.sum(0), 1), c)
        ml = np.where(lo.any(0), (x * lo).sum(0) / np.maximum(lo.sum(0), 1), c)
        out[k] = 0.5 * (mu + ml)
    return out


def dither_transmission(
    p: Mapping[str, Any],
    link_inertia: np.ndarray,
    torques: np.ndarray,
    durations: np.ndarray,
    *,
    settle: float = 2.0,
    lag: float = 0.3,
) -> np.ndarray:
    """How much of a push's joint torque the extracted signal shows with dither, per joint,
    from the plant's own equations (:mod:`ditherlab.sim.plant`) for one joint at a time.

    Per joint: the motor (``joints.motor_inertia``) on the gear spring (``gear_stiffness``,
    ``gear_damping_ratio``) to the link (inertia ``link_inertia``), the friction split by
    ``friction.motor_share`` between the motor and the gear output (rigid stick-slip, static
    ``Fs``, Coulomb ``coulomb_ratio·Fs``, viscous), the servo while dithering (position gain
    0, velocity PI ``kv``, ``ki`` at ``servo_rate_hz``), the dither feedforward (waveform,
    frequency) with its centre and amplitude loops (the logged torque's window mean held at the
    gravity torque, its amplitude at ``amplitude_fraction·Fs``, ``update_every``,
    ``hold_fraction``), logged at ``sample_rate_hz`` and extracted over one dither period as
    the estimator does. The dither runs ``settle`` [s] (the loops settle), then a raised-cosine
    push of peak torque ``torques[i, j]`` [N·m] and length ``durations[d]`` [s] acts on the
    link; the result is the largest drop of the extracted signal against the same run without
    a push, within the push and ``lag`` [s] after it (the report's window). Gravity is balanced
    by the controller's model (the loops work about it), the noise left out.

    What it shows (``docs/design/analysis-sensitivity.md``): a link whose friction the dither's
    spring torque overcomes every period creeps under any push and the velocity integral (the
    joint's only stiffness with Kp = 0) builds the torque that holds it, late for short and
    large pushes; a link the dither does not free (joint 3 at 0.5 Fs) holds a push until it
    exceeds what the dither leaves of the link's band; the centre loop eats part of a long push.

    Parameters
    ----------
    p : simulator parameters (:func:`ditherlab.sim.params.load_params`)
    link_inertia : (n,) [kg m^2] each link's inertia at the pose with the other links held
        (``M_jj`` plus ``joints.output_inertia``)
    torques : (m, n) [N·m] push torques per joint
    durations : (D,) [s] push lengths

    Returns
    -------
    (D, m, n) [N·m] the drop of the extracted signal, >= 0
    """
    torques = np.asarray(torques, float)
    durations = np.asarray(durations, float)
    m, n = torques.shape
    nd = len(durations)
    jj = np.tile(np.arange(n), nd * (m + 1))  # joint of each simulated case
    tq = np.concatenate([np.tile(np.vstack([torques, np.zeros((1, n))]).ravel(), nd)])
    dur = np.repeat(durations, (m + 1) * n)
    pl = _plant(p, n, jj, link_inertia)
    ns = int(round((settle + durations.max() + lag + 0.1) * pl.rate))
    k0 = int(round(settle * pl.rate))
    logged = _logged_torque(pl, tq, dur, ns, k0)
    return _largest_drop(logged, pl, k0, durations, lag, (nd, m + 1, n))


@dataclass(frozen=True)
class _Plant:
    """The simulated cases of :func:`dither_transmission`: per case (B,) the joint's motor,
    spring, link and friction, its servo and dither loops; and the timing.

    Attributes
    ----------
    jm, kg, cg, me : [kg m^2, N·m/rad, N·m·s/rad, kg m^2] motor inertia, gear stiffness and
        damping, link inertia
    fs_m, fs_o, fv : [N·m, N·m, N·m·s/rad] static friction at the motor and at the gear output,
        viscous friction (split by ``ms``)
    ms, cr : [-] the motor's share of the friction, Coulomb over static
    kv, ki : the servo's velocity PI gains
    on : (B,) bool whether the joint dithers
    asp, cap, hold : [N·m] the amplitude loop's set point and cap, the loops' dead band
    rate, nserv, nsub, dts, h : log rate [Hz], servo ticks per sample and plant steps per tick,
        their steps [s]
    omega, per, wave, peak : the dither's frequency [rad/s], period [s], waveform and its peak
        factor [-]
    L, upd, kc, ka : the loops' window [samples], update interval [samples] and gains [1/s]
    """

    jm: np.ndarray
    kg: np.ndarray
    cg: np.ndarray
    me: np.ndarray
    fs_m: np.ndarray
    fs_o: np.ndarray
    fv: np.ndarray
    ms: float
    cr: float
    kv: np.ndarray
    ki: np.ndarray
    on: np.ndarray
    asp: np.ndarray
    cap: np.ndarray
    hold: np.ndarray
    rate: float
    nserv: int
    nsub: int
    dts: float
    h: float
    omega: float
    per: float
    wave: str
    peak: float
    L: int
    upd: int
    kc: float
    ka: float


def _plant(p: Mapping[str, Any], n: int, jj: np.ndarray, link_inertia: np.ndarray) -> _Plant:
    """The cases' plant from simulator parameters ``p``: case ``b`` is joint ``jj[b]`` of ``n``
    (link inertia ``link_inertia`` (n,) [kg m^2])."""
    f, jt, sv, d, tm = p["friction"], p["joints"], p["servo"], p["dither"], p["timing"]

    def per_joint(v: Any) -> np.ndarray:
        return np.broadcast_to(np.asarray(v, float), (n,))[jj]

    fs = per_joint(f["static"])
    ms = float(f["motor_share"])
    jm, kg = per_joint(jt["motor_inertia"]), per_joint(jt["gear_stiffness"])
    on = per_joint(np.asarray(d["joints"], bool).astype(float)) > 0.5
    rate = float(tm["sample_rate_hz"])
    nserv = max(int(round(float(tm["servo_rate_hz"]) / rate)), 1)
    nsub = max(int(tm["plant_substeps"]), 1)
    dts = 1.0 / (rate * nserv)
    omega = float(d["frequency"])
    per = 2.0 * math.pi / omega
    return _Plant(
        jm=jm,
        kg=kg,
        cg=float(jt["gear_damping_ratio"]) * 2.0 * np.sqrt(kg * jm),
        me=np.asarray(link_inertia, float)[jj],
        fs_m=ms * fs,
        fs_o=(1.0 - ms) * fs,
        fv=per_joint(f["viscous"]),
        ms=ms,
        cr=float(f["coulomb_ratio"]),
        kv=per_joint(sv["kv"]),
        ki=per_joint(sv["ki"]),
        on=on,
        asp=np.where(on, per_joint(d["amplitude_fraction"]) * fs, 0.0),
        cap=float(d["amplitude_cap"]) * fs,
        hold=float(d["hold_fraction"]) * 2.0 * fs,
        rate=rate,
        nserv=nserv,
        nsub=nsub,
        dts=dts,
        h=dts / nsub,
        omega=omega,
        per=per,
        wave=str(d["waveform"]),
        peak=PEAK_FACTOR[str(d["waveform"])],
        L=max(int(round(float(d["periods"]) * per * rate)), 1),
        upd=max(int(d["update_every"]), 1),
        kc=float(d["centre_gain"]),
        ka=float(d["amplitude_gain"]),
    )


@dataclass
class _State:
    """The cases' state (B,): motor and link angles [rad] and velocities [rad/s], the velocity
    integral and the centre [N·m], motor and output stuck, the dither amplitude [N·m]."""

    qm: np.ndarray
    vm: np.ndarray
    q: np.ndarray
    v: np.ndarray
    integ: np.ndarray
    c: np.ndarray
    sm: np.ndarray
    so: np.ndarray
    a: np.ndarray


def _logged_torque(pl: _Plant, tq: np.ndarray, dur: np.ndarray, ns: int, k0: int) -> np.ndarray:
    """The logged torque (ns, B) [N·m] of every case: the dither from rest, a raised-cosine
    push of peak ``tq`` (B,) [N·m] and length ``dur`` (B,) [s] from sample ``k0`` on."""
    B = len(tq)
    z = [np.zeros(B) for _ in range(6)]
    s = _State(*z, np.ones(B, bool), np.ones(B, bool), pl.asp.copy())
    logged = np.zeros((ns, B))
    clock = 0.0
    for k in range(ns):
        tk = (k - k0) / pl.rate
        push = np.where(
            (tk >= 0.0) & (tk < dur), 0.5 * (1.0 - np.cos(2.0 * np.pi * max(tk, 0.0) / dur)), 0.0
        ) * tq  # fmt: skip
        for i in range(pl.nserv):
            u = _servo_tick(pl, s, clock)
            if i == 0:
                logged[k] = u
            clock += pl.dts
            for _ in range(pl.nsub):
                _plant_step(pl, s, u, push)
        if k >= pl.L and k % pl.upd == 0:
            _dither_loops(pl, s, logged[k - pl.L + 1 : k + 1])
    return logged


def _servo_tick(pl: _Plant, s: _State, clock: float) -> np.ndarray:
    """One servo tick at dither time ``clock`` [s]: the velocity PI (position gain 0) plus the
    dither's feedforward -> the torque reference (B,) [N·m]."""
    sn = math.sin(pl.omega * clock)
    w = (1.0 if sn >= 0.0 else -1.0) if pl.wave == "square" else sn
    if pl.wave == "triangle":
        w = 2.0 / math.pi * math.asin(sn)
    ev = -s.vm
    s.integ += pl.ki * ev * pl.dts
    return s.c + np.where(pl.on, s.a * w, 0.0) + pl.kv * ev + s.integ


def _plant_step(pl: _Plant, s: _State, u: np.ndarray, push: np.ndarray) -> None:
    """One plant step: the motor under ``u`` and the link under ``push`` (B,) [N·m], coupled by
    the gear spring, each with its rigid stick-slip friction."""
    ts = pl.kg * (s.qm - s.q) + pl.cg * (s.vm - s.v)
    h, ms, cr = pl.h, pl.ms, pl.cr
    s.vm, s.sm = _stick_slip_all(
        pl.jm, pl.jm * s.vm + h * (u - ts), h, pl.fs_m, cr * pl.fs_m, ms * pl.fv, s.sm, s.vm
    )
    s.v, s.so = _stick_slip_all(
        pl.me, pl.me * s.v + h * (ts + push), h, pl.fs_o, cr * pl.fs_o, (1.0 - ms) * pl.fv,
        s.so, s.v,
    )  # fmt: skip
    s.qm += h * s.vm
    s.q += h * s.v


def _dither_loops(pl: _Plant, s: _State, x: np.ndarray) -> None:
    """The centre and amplitude loops on the last window ``x`` (L, B) [N·m] of logged torque:
    the window mean driven to 0, the amplitude to its set point, outside the dead band."""
    cm = x.mean(axis=0)
    up, lo = x > cm, x < cm
    amp = 0.5 * pl.peak * (
        (x * up).sum(0) / np.maximum(up.sum(0), 1)
        - (x * lo).sum(0) / np.maximum(lo.sum(0), 1)
    )  # fmt: skip
    dtl = pl.upd / pl.rate
    s.c = np.where(np.abs(cm) > pl.hold, s.c - pl.kc * cm * dtl, s.c)
    s.a = np.where(
        np.abs(pl.asp - amp) > pl.hold, np.clip(s.a + pl.ka * (pl.asp - amp) * dtl, 0, pl.cap), s.a
    )


def _largest_drop(
    logged: np.ndarray,
    pl: _Plant,
    k0: int,
    durations: np.ndarray,
    lag: float,
    shape: tuple[int, int, int],
) -> np.ndarray:
    """The largest drop (D, m, n) [N·m] of the extracted signal of pushes against the same run
    without a push (the last of the ``m + 1`` torques per length), within each push (pushes
    from sample ``k0``, ``durations`` (D,) [s]) and ``lag`` [s] after it; ``shape`` is
    ``(D, m + 1, n)``, the cases' order."""
    nd, m1, n = shape
    m = m1 - 1
    wx = max(int(round(pl.per * pl.rate)), 1)
    s0 = max(k0 - wx - 1, 0)
    sig = _extracted(logged[s0:], wx)
    sig = sig.reshape(len(sig), nd, m1, n)
    drop = sig[:, :, m : m + 1, :] - sig[:, :, :m, :]  # against the same run without a push
    t = (np.arange(len(sig)) + s0 - k0) / pl.rate
    win = (t[:, None] >= 0.0) & (t[:, None] <= durations[None, :] + lag)  # (T, D)
    drop = np.where(win[:, :, None, None], np.nan_to_num(drop, nan=-np.inf), -np.inf)
    return np.maximum(drop.max(axis=0), 0.0)


def extraction_peak(duration: float, lag: float, window: int, rate: float) -> float:
    """The peak [-] of a unit raised-cosine push of ``duration`` [s] seen through the
    ``dither_extraction`` law: the causal mean over ``window`` samples, then a first-order lag
    of ``lag`` samples (backward Euler, :meth:`ditherlab.physics.effects.sensor.AttenuationLag.delayed`),
    within the push and the report's 0.3 s after it, at ``rate`` [Hz]."""
    t = np.arange(0.0, duration + 0.3, 1.0 / rate)
    e = np.where(t < duration, 0.5 * (1.0 - np.cos(2.0 * np.pi * t / duration)), 0.0)
    y = np.convolve(e, np.ones(window) / window)[: len(e)]
    if lag > 0:
        al, acc = 1.0 / (lag + 1.0), 0.0
        for k in range(len(y)):
            acc += al * (y[k] - acc)
            y[k] = acc
    return float(y.max())


def transmitted(x: np.ndarray, torques: np.ndarray, drop: np.ndarray) -> np.ndarray:
    """The drop [N·m] (D, F, n) of the extracted signal for joint torques ``x`` (F, n) [N·m],
    interpolated in a table's ``torques`` (m, n) [N·m] / ``drop`` (D, m, n) [N·m]
    (:func:`ditherlab.analysis.sensitivity.transmission_table`) from 0 at 0, and continued
    beyond the table along its last slope."""
    nd, _, n = drop.shape
    out = np.empty((nd, x.shape[0], n))
    for j in range(n):
        tj = np.concatenate([[0.0], torques[:, j]])
        for d in range(nd):
            hj = np.concatenate([[0.0], drop[d, :, j]])
            slope = (hj[-1] - hj[-2]) / max(tj[-1] - tj[-2], 1e-12)
            y = np.interp(x[:, j], tj, hj)
            out[d, :, j] = np.where(x[:, j] > tj[-1], hj[-1] + slope * (x[:, j] - tj[-1]), y)
    return np.maximum(out, 0.0)
