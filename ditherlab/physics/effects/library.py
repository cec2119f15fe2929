"""The effect library: the registry of effects by name, and the conversion between fitted
parameters and the model file's :class:`~ditherlab.data.torque_model.EffectSpec`.

Importing this module imports every family module, whose classes register themselves
(:class:`ditherlab.physics.effects.base.Effect`); :data:`EFFECTS` holds one instance of each, in the
order diagnosis tries them (``Effect.order``). An effect defined anywhere else (a user's module,
a test) registers the same way and is tried by diagnosis from then on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ditherlab.core.errors import ModelError, where_prefix
from ditherlab.core.schema import shown
from ditherlab.data.torque_model import EffectSpec
from ditherlab.physics.effects import drive, extraction, friction, rigid, sensor, transmission  # noqa: F401 (registers)
from ditherlab.physics.effects.base import EFFECTS, Effect

__all__ = [
    "EFFECTS",
    "REF_KEYS",
    "FitResult",
    "clean_none",
    "effect_names",
    "get_effect",
    "hyper_params",
    "joint_params",
    "make_spec",
    "spec_params",
]


def effect_names() -> list[str]:
    """The names of the effect library, in the order they are tried."""
    return list(EFFECTS)


def get_effect(name: str) -> Effect:
    """The :class:`Effect` called ``name``; ModelError listing the names for an unknown one."""
    if name not in EFFECTS:
        raise ModelError(f"unknown effect {name!r}, expected one of: {', '.join(EFFECTS)}")
    return EFFECTS[name]


#: data-derived reference values stored with an effect's parameters
REF_KEYS = ("load_ref", "friction_level", "x_ref", "base_columns", "span")


def spec_params(e: Effect, j: int, spec: EffectSpec) -> tuple[np.ndarray, Any, dict]:
    """(w, h, ref) of joint j (0-based) from a model's EffectSpec.

    ModelError naming the model file and the parameter when one the effect reads is missing
    or is not a number (or one number per listed joint).
    """
    try:
        return _spec_params(e, j, spec)
    except KeyError as exc:
        got = "missing"
        bad = f".{exc.args[0]}"
    except (IndexError, TypeError, ValueError):
        got, bad = f"got {shown(spec.params)}", ""
    names = [*e.linear, *((e.hyper,) if isinstance(e.hyper, str) else e.hyper or ())]
    what = f"numbers for {', '.join(names)}" if names else "the parameters the effect fitted"
    per = "" if e.shared else f" (a number or one per joint in {spec.joints})"
    raise ModelError(
        f"{where_prefix(spec.source)}effect {spec.name!r} params{bad}: {got}; expected {what}{per}"
    )


def _spec_params(e: Effect, j: int, spec: EffectSpec) -> tuple[np.ndarray, Any, dict]:
    p = spec.params
    if e.shared:
        h0: Any = p.get(e.hyper) if isinstance(e.hyper, str) else None
        return e.weights(p), h0, {key: p[key] for key in REF_KEYS if key in p}
    k = spec.joints.index(j + 1)

    def at(v: Any) -> Any:
        return v[k] if isinstance(v, list) else v

    w = np.array([at(p[c]) for c in e.linear], dtype=float)
    if isinstance(e.hyper, tuple):
        h: Any = tuple(at(p.get(name)) for name in e.hyper)
    else:
        h = at(p.get(e.hyper)) if e.hyper else None
    ref = {key: at(p[key]) for key in REF_KEYS if key in p}
    return w, h, ref


def hyper_params(e: Effect, h: Any) -> dict[str, Any]:
    """The searched parameter(s) ``h`` of effect ``e`` by name (plain Python numbers)."""
    if not e.hyper:
        return {}
    if isinstance(e.hyper, tuple):
        return {name: plain_h(v) for name, v in zip(e.hyper, h, strict=True)}
    return {e.hyper: plain_h(h)}


def joint_params(spec: EffectSpec, j: int) -> dict[str, Any]:
    """The parameters of joint j (0-based) of an EffectSpec, one value each (a shared
    effect's all)."""
    e = get_effect(spec.name)
    if e.shared:
        return dict(spec.params)
    k = spec.joints.index(j + 1)
    return {key: (v[k] if isinstance(v, list) else v) for key, v in spec.params.items()}


@dataclass
class FitResult:
    """Fitted parameters of one effect on one joint (or all joints when shared)."""

    w: np.ndarray
    h: Any
    ref: dict[str, Any]
    loss: float


def make_spec(e: Effect, fits: dict[int, FitResult]) -> EffectSpec:
    """An EffectSpec from per-joint fits (0-based joint -> FitResult), lists per joint."""
    if e.shared:
        ref = {key: v for key, v in fits[-1].ref.items() if key in REF_KEYS}
        hyper = hyper_params(e, fits[-1].h)
        return EffectSpec(e.name, [], {**e.linear_params(fits[-1].w), **hyper, **ref})
    joints = sorted(fits)
    params = {c: [float(fits[j].w[i]) for j in joints] for i, c in enumerate(e.linear)}
    if e.hyper:
        names = e.hyper if isinstance(e.hyper, tuple) else (e.hyper,)
        for name in names:
            params[name] = [hyper_params(e, fits[j].h)[name] for j in joints]
    for key in REF_KEYS:
        if any(key in fits[j].ref for j in joints):
            vals = [fits[j].ref.get(key) for j in joints]
            if all(v is not None for v in vals):
                params[key] = [float(v) for v in vals]
    return EffectSpec(e.name, [j + 1 for j in joints], params)


def plain_h(h: Any) -> Any:
    """A searched value as a plain Python number (int for a sample count), or None."""
    if h is None:
        return None
    if isinstance(h, int | np.integer):
        return int(h)
    return float(h)


def clean_none(spec: EffectSpec) -> EffectSpec:
    """The spec without the parameters that are all None (TOML has no null), e.g. a
    ``time_constant`` where a temperature column drives the effect."""
    p = {
        k: v
        for k, v in spec.params.items()
        if not (v is None or (isinstance(v, list) and all(x is None for x in v)))
    }
    return EffectSpec(spec.name, spec.joints, p, source=spec.source)
