"""Simulator parameters: the defaults in ``irb140.toml`` (documented there, in one place),
overridden from a user TOML file or a dict.

The merged parameters are a nested dict with the same tables and keys as ``irb140.toml``; every
run writes it whole into ``meta["sim"]["params"]``. A key that the defaults do not have is a
:class:`~ditherlab.errors.ConfigError` naming the key.
"""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Mapping
from importlib import resources
from math import isfinite
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.errors import ConfigError

DEFAULTS_FILE = "irb140.toml"


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


def _check_value(default: Any, value: Any, key: str, where: str) -> Any:
    """The override ``value`` if its type fits the default's; a list may be given as a scalar."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: key '{key}' = {value!r}; expected true or false")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: key '{key}' = {value!r}; expected an integer")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, int | float) or not isfinite(value):
            raise ConfigError(f"{where}: key '{key}' = {value!r}; expected a finite number")
        return float(value)
    if isinstance(default, list):
        if isinstance(value, int | float | bool) and default and not isinstance(default[0], list):
            value = [value] * len(default)
        if not isinstance(value, list) or len(value) != len(default):
            raise ConfigError(
                f"{where}: key '{key}' = {value!r}; expected a list of {len(default)} values "
                f"or one value"
            )
        return [_check_value(d, v, key, where) for d, v in zip(default, value, strict=True)]
    return value


def _merge(base: dict[str, Any], over: Mapping[str, Any], prefix: str, where: str) -> None:
    for key, value in over.items():
        name = f"{prefix}{key}"
        if key not in base:
            known = ", ".join(sorted(base))
            raise ConfigError(f"{where}: unknown key '{name}' (known here: {known})")
        if isinstance(base[key], dict):
            if not isinstance(value, Mapping):
                raise ConfigError(f"{where}: key '{name}' must be a table, got {value!r}")
            _merge(base[key], value, f"{name}.", where)
        else:
            base[key] = _check_value(base[key], value, name, where)


_NON_NEGATIVE = (
    "joints.motor_inertia",
    "joints.gear_stiffness",
    "joints.gear_damping_ratio",
    "joints.output_inertia",
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


def _get(p: Mapping[str, Any], dotted: str) -> Any:
    for part in dotted.split("."):
        p = p[part]
    return p


def _validate(p: dict[str, Any], where: str) -> None:
    for key in _NON_NEGATIVE:
        v = np.asarray(_get(p, key), dtype=float)
        if np.any(v < 0) or not np.all(np.isfinite(v)):
            raise ConfigError(f"{where}: key '{key}' = {_get(p, key)!r}; expected values >= 0")
    for key in _POSITIVE:
        v = np.asarray(_get(p, key), dtype=float)
        if np.any(v <= 0):
            raise ConfigError(f"{where}: key '{key}' = {_get(p, key)!r}; expected values > 0")
    if p["friction"]["motor_share"] > 1:
        raise ConfigError(
            f"{where}: key 'friction.motor_share' = {p['friction']['motor_share']!r}; "
            "expected a fraction in [0, 1]"
        )
    if p["friction"]["coulomb_ratio"] > 1:
        raise ConfigError(
            f"{where}: key 'friction.coulomb_ratio' = {p['friction']['coulomb_ratio']!r}; "
            "expected Fc/Fs in [0, 1]"
        )
    ratio = p["timing"]["servo_rate_hz"] / p["timing"]["sample_rate_hz"]
    if abs(ratio - round(ratio)) > 1e-9:
        raise ConfigError(
            f"{where}: key 'timing.servo_rate_hz' = {p['timing']['servo_rate_hz']!r}; expected "
            "an integer multiple of timing.sample_rate_hz"
        )
    pc = p["push_campaign"]
    for lo, hi in (
        ("magnitude_min", "magnitude_max"),
        ("duration_min", "duration_max"),
        ("rest_min", "rest_max"),
    ):
        if pc[lo] > pc[hi]:
            raise ConfigError(
                f"{where}: key 'push_campaign.{lo}' = {pc[lo]!r} exceeds push_campaign.{hi} = "
                f"{pc[hi]!r}"
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
    if config is not None:
        over, where = _read_config(config)
        _merge(p, over, "", where)
    else:
        where = "config"
    if overrides:
        _merge(p, overrides, "", "options")
    _validate(p, where)
    return p


def joint_array(p: Mapping[str, Any], dotted: str, n: int = 6) -> np.ndarray:
    """A per-joint parameter as a float array of shape (n,) (scalars are broadcast)."""
    v = np.asarray(_get(p, dotted), dtype=float)
    return np.broadcast_to(v, (n,)).copy() if v.ndim == 0 else v[:n].copy()
