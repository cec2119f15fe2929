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

    What it shows (``docs/design/analysis-sensitivity.md``): a link whose friction the dither's spring torque
    overcomes every period creeps under any push and the velocity integral (the joint's only
    stiffness with Kp = 0) builds the torque that holds it, late for short and large pushes; a
    link the dither does not free (joint 3 at 0.5 Fs) holds a push until it exceeds what the
    dither leaves of the link's band; the centre loop eats part of a long push.

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
    f, jt, sv, d, tm = p["friction"], p["joints"], p["servo"], p["dither"], p["timing"]
    torques = np.asarray(torques, float)
    durations = np.asarray(durations, float)
    m, n = torques.shape
    nd = len(durations)
    jj = np.tile(np.arange(n), nd * (m + 1))  # joint of each simulated case
    tq = np.concatenate([np.tile(np.vstack([torques, np.zeros((1, n))]).ravel(), nd)])
    dur = np.repeat(durations, (m + 1) * n)

    def per_joint(v: Any) -> np.ndarray:
        return np.broadcast_to(np.asarray(v, float), (n,))[jj]

    fs = per_joint(f["static"])
    ms, cr = float(f["motor_share"]), float(f["coulomb_ratio"])
    fv = per_joint(f["viscous"])
    jm, kg = per_joint(jt["motor_inertia"]), per_joint(jt["gear_stiffness"])
    cg = float(jt["gear_damping_ratio"]) * 2.0 * np.sqrt(kg * jm)
    kv, ki = per_joint(sv["kv"]), per_joint(sv["ki"])
    on = per_joint(np.asarray(d["joints"], bool).astype(float)) > 0.5
    asp = np.where(on, per_joint(d["amplitude_fraction"]) * fs, 0.0)
    cap = float(d["amplitude_cap"]) * fs
    me = np.asarray(link_inertia, float)[jj]
    fs_m, fs_o = ms * fs, (1.0 - ms) * fs
    rate = float(tm["sample_rate_hz"])
    nserv = max(int(round(float(tm["servo_rate_hz"]) / rate)), 1)
    nsub = max(int(tm["plant_substeps"]), 1)
    dts = 1.0 / (rate * nserv)
    h = dts / nsub
    omega = float(d["frequency"])
    per = 2.0 * math.pi / omega
    L = max(int(round(float(d["periods"]) * per * rate)), 1)
    upd = max(int(d["update_every"]), 1)
    kc, ka = float(d["centre_gain"]), float(d["amplitude_gain"])
    hold = float(d["hold_fraction"]) * 2.0 * fs
    wave, peak = str(d["waveform"]), PEAK_FACTOR[str(d["waveform"])]
    B = len(jj)
    qm, vm, q, v, integ, c = (np.zeros(B) for _ in range(6))
    sm, so = np.ones(B, bool), np.ones(B, bool)
    a = asp.copy()
    ns = int(round((settle + durations.max() + lag + 0.1) * rate))
    k0 = int(round(settle * rate))
    logged = np.zeros((ns, B))
    clock = 0.0
    for k in range(ns):
        tk = (k - k0) / rate
        push = np.where(
            (tk >= 0.0) & (tk < dur), 0.5 * (1.0 - np.cos(2.0 * np.pi * max(tk, 0.0) / dur)), 0.0
        ) * tq  # fmt: skip
        for i in range(nserv):
            sn = math.sin(omega * clock)
            w = (1.0 if sn >= 0.0 else -1.0) if wave == "square" else sn
            if wave == "triangle":
                w = 2.0 / math.pi * math.asin(sn)
            ev = -vm
            integ += ki * ev * dts
            u = c + np.where(on, a * w, 0.0) + kv * ev + integ
            if i == 0:
                logged[k] = u
            clock += dts
            for _ in range(nsub):
                ts = kg * (qm - q) + cg * (vm - v)
                vm, sm = _stick_slip_all(
                    jm, jm * vm + h * (u - ts), h, fs_m, cr * fs_m, ms * fv, sm, vm
                )
                v, so = _stick_slip_all(
                    me, me * v + h * (ts + push), h, fs_o, cr * fs_o, (1.0 - ms) * fv, so, v
                )
                qm += h * vm
                q += h * v
        if k >= L and k % upd == 0:  # the centre and amplitude loops
            x = logged[k - L + 1 : k + 1]
            cm = x.mean(axis=0)
            up, lo = x > cm, x < cm
            amp = 0.5 * peak * (
                (x * up).sum(0) / np.maximum(up.sum(0), 1)
                - (x * lo).sum(0) / np.maximum(lo.sum(0), 1)
            )  # fmt: skip
            dtl = upd / rate
            c = np.where(np.abs(cm) > hold, c - kc * cm * dtl, c)
            a = np.where(np.abs(asp - amp) > hold, np.clip(a + ka * (asp - amp) * dtl, 0, cap), a)
    wx = max(int(round(per * rate)), 1)
    s0 = max(k0 - wx - 1, 0)
    sig = _extracted(logged[s0:], wx)
    sig = sig.reshape(len(sig), nd, m + 1, n)
    drop = sig[:, :, m : m + 1, :] - sig[:, :, :m, :]  # against the same run without a push
    t = (np.arange(len(sig)) + s0 - k0) / rate
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
