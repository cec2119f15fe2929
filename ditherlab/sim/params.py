"""Simulator parameters: the defaults in ``irb140.toml`` (documented there, in one place),
overridden from a user TOML file or a dict.

The merged parameters are a nested dict with the same tables and keys as ``irb140.toml``; every
run writes it whole into ``meta["sim"]["params"]``. A config is checked against
:func:`config_schema`, derived from the defaults: a key that the defaults do not have, a value
of another kind than the default's, a list of another length or a number out of the key's range
is a :class:`~ditherlab.core.errors.ConfigError` naming the file and the key
(``cfg.toml: servo.kp: got '30'; expected a number >= 0``).
"""

from __future__ import annotations

import copy
import functools
import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.core.schema import Either, Flag, Integer, ListOf, Node, Number, Table, Text, check
from ditherlab.estimator import INTERVAL_METHODS
from ditherlab.physics.dither import WAVEFORMS

DEFAULTS_FILE = "irb140.toml"

#: The lead-through's admittance laws (ditherlab.sim.guidance): the paper's 10 N dead zone on
#: the estimate's magnitude, or its §V alternative driven by the confidence interval.
LEAD_THROUGH_LAWS = ("dead-zone", "interval")
#: The push campaign's orders (ditherlab.sim.scenarios): every push of every direction
#: shuffled; one experiment per axis (its pushes of both signs shuffled, the axes one after the
#: other); one per direction (axis and sign).
PUSH_ORDERS = ("shuffled", "per-axis", "per-direction")
#: The text keys and their choices.
_TEXT_CHOICES = {
    "dither.waveform": WAVEFORMS,
    "push_campaign.order": PUSH_ORDERS,
    "lead_through.law": LEAD_THROUGH_LAWS,
    "lead_through.interval": INTERVAL_METHODS,
}


def default_params() -> dict[str, Any]:
    """The built-in IRB140-like parameter set (a fresh nested dict)."""
    text = resources.files("ditherlab.sim").joinpath(DEFAULTS_FILE).read_text(encoding="utf-8")
    return tomllib.loads(text)


def _read_config(config: str | Path | Mapping[str, Any]) -> tuple[dict[str, Any], str]:
    if isinstance(config, Mapping):
        return copy.deepcopy(dict(config)), "config"
    path = Path(config)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the simulator config ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not valid TOML (not UTF-8 text)") from None
    try:
        return tomllib.loads(text), str(path)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None


_NON_NEGATIVE = (
    "joints.motor_inertia",
    "joints.gear_stiffness",
    "joints.gear_damping_ratio",
    "joints.output_inertia",
    "joints.lost_motion",
    "joints.lost_motion_stiffness",
    "servo.standstill_leak",
    "servo.standstill_velocity",
    "friction.static",
    "friction.coulomb_ratio",
    "friction.viscous",
    "friction.motor_share",
    "servo.kp",
    "servo.kv",
    "servo.ki",
    "dither.frequency",
    "dither.amplitude_fraction",
    "dither.amplitude_cap",
    "dither.centre_gain",
    "dither.amplitude_gain",
    "dither.hold_fraction",
    "dither.ramp_s",
    "noise.tau_sigma_fraction",
    "noise.force_sigma",
    "noise.moment_sigma",
    "push_campaign.magnitude_min",
    "push_campaign.magnitude_max",
    "push_campaign.duration_min",
    "push_campaign.duration_max",
    "push_campaign.rest_min",
    "push_campaign.rest_max",
    "push_campaign.excitation_amplitude",
    "push_campaign.excitation_periods",
    "push_campaign.settle_s",
    "push_campaign.pushes_per_direction",
    "excitation.blocks",
    "excitation.move_s",
    "excitation.sweeps",
    "excitation.sweep_amplitude",
    "excitation.wrist_amplitude",
    "excitation.stroke_min_s",
    "excitation.stroke_max_s",
    "excitation.settle_s",
    "excitation.ramp_s",
    "excitation.pushes_per_block",
    "excitation.moving_pushes",
    "excitation.magnitude_min",
    "excitation.magnitude_max",
    "excitation.duration_min",
    "excitation.duration_max",
    "excitation.rest_min",
    "excitation.rest_max",
    "lead_through.dead_zone",
    "lead_through.admittance",
    "lead_through.max_speed",
)
_POSITIVE = (
    "timing.sample_rate_hz",
    "timing.servo_rate_hz",
    "timing.plant_substeps",
    "timing.dynamics_update_samples",
    "timing.gauss_seidel_sweeps",
    "joints.motor_inertia",
    "joints.gear_stiffness",
    "dither.frequency",
    "dither.periods",
    "dither.update_every",
    "excitation.move_s",
    "excitation.stroke_min_s",
    "excitation.stroke_max_s",
    "excitation.duration_min",
    "excitation.duration_max",
)


#: Fractions in [0, 1].
_FRACTION = (
    "friction.motor_share",
    "friction.coulomb_ratio",
    "joints.lost_motion_stiffness",
    "push_campaign.release_fraction",
)
#: (min, max) pairs of the scenario tables: min <= max.
_PAIRS = (
    ("magnitude_min", "magnitude_max"),
    ("duration_min", "duration_max"),
    ("rest_min", "rest_max"),
    ("stroke_min_s", "stroke_max_s"),
)


def _get(p: Mapping[str, Any], dotted: str) -> Any:
    for part in dotted.split("."):
        p = p[part]
    return p


def _scalar(default: Any, key: str) -> Node:
    """The node of one value: the default's kind (true/false, integer, number) in the key's
    range (:data:`_NON_NEGATIVE`, :data:`_POSITIVE`, :data:`_FRACTION`)."""
    if isinstance(default, bool):
        return Flag()
    if isinstance(default, str):  # the dither's waveform, the lead-through's law and interval
        return Text(choices=_TEXT_CHOICES.get(key, ()))
    if key == "lead_through.level":  # a confidence level a controller may act on
        return Number(0.5, 0.999)
    lo, hi, lo_open = None, None, False
    if key in _NON_NEGATIVE:
        lo = 0
    if key in _POSITIVE:
        lo, lo_open = 0, True
    if key in _FRACTION:
        lo, hi = 0, 1
    if isinstance(default, int):
        return Integer(None if lo is None else lo + lo_open, hi)
    return Number(lo, hi, lo_open=lo_open)


def _node(default: Any, key: str) -> Node:
    if isinstance(default, Mapping):
        return Table(keys={k: _node(v, f"{key}.{k}" if key else k) for k, v in default.items()})
    if isinstance(default, list) and default and isinstance(default[0], list):
        return ListOf(item=_node(default[0], key), length=len(default))
    if isinstance(default, list):
        item = _scalar(default[0], key)
        return Either(
            options=(item, ListOf(item=item, length=len(default))),
            what=f"{item.expected({})} or a list of {len(default)} of them",
        )
    return _scalar(default, key)


@functools.cache
def config_schema() -> Node:
    """The schema of a simulator config, derived from the defaults (``irb140.toml``): its
    tables and keys only, each value of the default's kind (a list of the default's length, or
    one value for all) and in the key's range."""
    return _node(default_params(), "")


def _coerce(default: Any, value: Any) -> Any:
    """A checked value in the default's form: one value spread over a list, ints as floats."""
    if isinstance(default, list):
        if not isinstance(value, list):
            value = [value] * len(default)
        return [_coerce(d, v) for d, v in zip(default, value, strict=True)]
    if isinstance(default, float):
        return float(value)
    return value


def _merge(base: dict[str, Any], over: Mapping[str, Any]) -> None:
    for key, value in over.items():
        if isinstance(base[key], dict):
            _merge(base[key], value)
        else:
            base[key] = _coerce(base[key], value)


def _validate(p: dict[str, Any], where: str) -> None:
    """The checks that involve two keys (each key's own range is the schema's)."""
    sr, servo = p["timing"]["sample_rate_hz"], p["timing"]["servo_rate_hz"]
    ratio = servo / sr
    if abs(ratio - round(ratio)) > 1e-9:
        raise ConfigError(
            f"{where}: timing.servo_rate_hz: got {servo!r}; expected an integer multiple of "
            f"timing.sample_rate_hz ({sr:g})"
        )
    for table in ("push_campaign", "excitation"):
        t = p[table]
        for lo, hi in _PAIRS:
            if lo in t and t[lo] > t[hi]:
                raise ConfigError(
                    f"{where}: {table}.{lo}: got {t[lo]!r}; expected at most {table}.{hi} "
                    f"({t[hi]!r})"
                )


def load_params(
    config: str | Path | Mapping[str, Any] | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Defaults merged with a user config (TOML path or dict) and then ``overrides`` (dict).

    Parameters
    ----------
    config : path of a TOML file or a nested dict with tables/keys of ``irb140.toml``
    overrides : nested dict applied after ``config`` (used by tests and scenario options)

    Returns
    -------
    dict
        The merged, validated parameters.

    Raises
    ------
    ConfigError
        Unknown key, a value of the wrong type or length, or a negative value where none is
        allowed; the message names the file and the key.
    """
    p = default_params()
    where = "config"
    if config is not None:
        over, where = _read_config(config)
        check(over, config_schema(), where, ConfigError)
        _merge(p, over)
    if overrides:
        check(overrides, config_schema(), "options", ConfigError)
        _merge(p, overrides)
    _validate(p, where)
    return p


def joint_array(p: Mapping[str, Any], dotted: str, n: int = 6) -> np.ndarray:
    """A per-joint parameter ``dotted`` (e.g. ``"friction.static"``) as a float array (n,) in
    the key's unit (``irb140.toml``); a scalar is broadcast to every joint."""
    v = np.asarray(_get(p, dotted), dtype=float)
    return np.broadcast_to(v, (n,)).copy() if v.ndim == 0 else v[:n].copy()
