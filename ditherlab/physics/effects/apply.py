"""Applying a model's effects, in one place for every consumer.

:func:`effects_torque` (the torque terms), :func:`widening` (how much they widen the stick band),
:func:`external_torque` (``J^T F`` as the servo shows it), :func:`sensor_wrench` (the F/T
columns corrected), :func:`model_text` (the model as one equation per joint). Each asks the
effect what it does (``Effect.kind`` and its methods), never its name.
"""

from __future__ import annotations

import numpy as np

from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import REGIMES, EffectSpec, TorqueModel
from ditherlab.physics.effects.base import Effect
from ditherlab.physics.effects.library import EFFECTS, get_effect, joint_params, spec_params
from ditherlab.physics.effects.signals import Signals, signals

__all__ = [
    "check_model_effects",
    "effects_torque",
    "external_torque",
    "force_gain",
    "model_text",
    "sensor_wrench",
    "widening",
]


def _shift(e: Effect, sig: Signals, spec: EffectSpec) -> np.ndarray:
    """(N, n) [N·m]: the torque shift one effect spec predicts on a recording."""
    out = np.zeros((len(sig.t), sig.n))
    if e.shared:
        w, h, ref = spec_params(e, 0, spec)
        d = e.design(sig, None, h, ref)
        out += d.centre @ w
        if d.offset is not None:
            out += d.offset
        return out
    for jj in spec.joints:
        j = jj - 1
        if j >= sig.n:
            continue
        w, h, ref = spec_params(e, j, spec)
        d = e.design(sig, j, h, ref)
        out[:, j] += d.centre @ w + (d.offset if d.offset is not None else 0.0)
    return out


def check_model_effects(model: TorqueModel, rec: Recording) -> None:
    """ModelError naming a column one of the model's effects needs and the recording lacks."""
    sig = signals(rec)
    for spec in model.effects:
        get_effect(spec.name).check(sig)


def effects_torque(model: TorqueModel, rec: Recording, *, sensor: bool = True) -> np.ndarray:
    """Sum of the model's torque effects (those driven by q, dq, ddq, temperature or time).

    Parameters
    ----------
    model : TorqueModel
    rec : Recording
    sensor : let effects read the F/T columns (``load_friction``'s load ``J^T F``). False for
        the force estimator (replay, the diagnosis's force error): a sensorless estimate must not
        see the sensor, and the load is then the model's ``tau_grav + M ddq + C dq`` part alone.

    Returns
    -------
    (N, n) [N·m]; zeros when the model has none.
    """
    full = signals(rec)
    sig = signals(rec, sensor=sensor)
    out = np.zeros((len(rec), rec.n))
    for spec in model.effects:
        e = get_effect(spec.name)
        e.check(full)
        if e.kind == "torque":
            out += _shift(e, sig, spec)
    return out


def widening(model: TorqueModel, rec: Recording) -> np.ndarray:
    """How much the model's effects widen the stick band's half-width, per sample.

    Non-zero only for ``load_friction`` and ``temperature_friction`` in the still and dither
    regimes: use ``[tau_min - w, tau_max + w]`` as the band there.

    Returns
    -------
    (N, n) [N·m]
    """
    sig = signals(rec)
    out = np.zeros((len(rec), rec.n))
    for spec in model.effects:
        e = get_effect(spec.name)
        if e.shared or e.kind != "torque":
            continue
        for jj in spec.joints:
            j = jj - 1
            w, h, ref = spec_params(e, j, spec)
            d = e.design(sig, j, h, ref)
            if d.widen is not None:
                out[:, j] += d.widen @ w
    return out


def external_torque(model: TorqueModel, rec: Recording, F: np.ndarray) -> np.ndarray:
    """``J^T F`` as the servo shows it: through the model's external effects
    (``attenuation_lag``) when present.

    Parameters
    ----------
    model : TorqueModel
    rec : Recording
    F : (N, 6) [N, N·m], wrench at the tool point in base axes

    Returns
    -------
    (N, n) [N·m]: per joint with ``attenuation_lag``, ``gain · lag((J^T F)(t - delay))``; else
    ``J^T F``.
    """
    sig = signals(rec)
    X = sig.jtf(np.asarray(F, dtype=float))
    out = X.copy()
    for spec in model.effects:
        e = get_effect(spec.name)
        if e.kind != "external":
            continue
        for jj in spec.joints:
            j = jj - 1
            w, h, _ = spec_params(e, j, spec)
            out[:, j] = e.external(sig, j, X[:, j], w, h)
    return out


def force_gain(model: TorqueModel) -> np.ndarray:
    """(n,) [-]: how the model's torque effects scale each joint's external torque ``J^T F`` in
    the logged torque (``drive_gain``'s k; 1 without such an effect). The sensorless estimator
    uses ``J^T`` with row j multiplied by it: ``J * force_gain(model)[None, None, :]``."""
    out = np.ones(model.n)
    for spec in model.effects:
        e = get_effect(spec.name)
        if e.shared or e.kind != "torque":
            continue
        for jj in spec.joints:
            if jj - 1 < model.n:
                out[jj - 1] *= e.force_gain(joint_params(spec, jj - 1))
    return out


def sensor_wrench(model: TorqueModel, rec: Recording) -> np.ndarray:
    """The F/T columns corrected by the model's sensor effects (``ft_bias``) when present.

    Returns
    -------
    (N, 6) [N, N·m]; ModelError when the recording has no F/T columns.
    """
    sig = signals(rec)
    F = sig.wrench("sensor_wrench").copy()
    for spec in model.effects:
        e = get_effect(spec.name)
        if e.kind == "sensor":
            F = e.correct_wrench(F, spec.params, sig)
    return F


def model_text(model: TorqueModel) -> str:
    """The model as one readable equation per joint, e.g.

    ``tau_2 = gravity + J^T F + band[-8.1, 7.9] + 3.2·sign(dq_2) + 0.42·viscous(dq_2)``.
    """
    lines = []
    ext = "J^T F"
    for s in model.effects:
        e = get_effect(s.name)
        if e.kind == "sensor":
            ext = e.sensor_text(ext)
    for j in range(model.n):
        parts = ["gravity"]
        xt = ext
        for s in model.effects:
            e = get_effect(s.name)
            if e.kind == "external" and (j + 1) in s.joints:
                xt = e.external_text(joint_params(s, j), ext)
        parts.append(xt)
        for rname in REGIMES:
            b = model.regimes.get(rname)
            if b is None:
                continue
            tag = "" if rname == "still" else f"_{rname}"
            parts.append(f"band{tag}[{b.tau_min[j]:.3g}, {b.tau_max[j]:.3g}]")
            if rname == "moving":
                if b.coulomb is not None:
                    parts.append(f"{b.coulomb[j]:.3g}·sign(dq_{j + 1})")
                if b.viscous is not None:
                    parts.append(f"{b.viscous[j]:.3g}·dq_{j + 1}")
        for s in model.effects:
            e = EFFECTS.get(s.name)
            if e is None or e.kind != "torque":
                continue
            if e.shared or (j + 1) in s.joints:
                parts.append(e.term(joint_params(s, j), j))
        sig = model.regimes.get("still") or next(iter(model.regimes.values()), None)
        noise = f" + e(σ={sig.sigma[j]:.3g})" if sig is not None else ""
        lines.append(f"tau_{j + 1} = " + " + ".join(parts) + noise)
    head = f"model v{model.version} ({model.robot if isinstance(model.robot, str) else 'urdf'})"
    if model.effects:
        head += ": effects " + ", ".join(f"{s.name}{s.joints or ''}" for s in model.effects)
    return "\n".join([head, *lines])
