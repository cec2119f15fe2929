"""Effects planted in the LuGre plant, each as its physical cause in the plant's own terms.

``--hidden NAME[:SIZE][@J1,J2,...]``: the joints (1-based) of a per-joint effect (default joints
2 and 3); a shared effect (payload, attenuation_lag, ft_bias, ft_drift, ft_frame) takes no joints. What
each plants, and the unit of SIZE:

| name | SIZE | the physical cause planted |
|---|---|---|
| ``viscous`` | N·m·s/rad | a seal's viscous drag added to the LuGre ``sigma2`` |
| ``stribeck`` | share of Fc | a lubricant starving at low speed: the static level ``Fs`` raised by SIZE·Fc (the Stribeck hump of ``g(v)``) |
| ``load_friction`` | N·m per N·m | Coulomb and static levels grow by SIZE·\\|tau_m\\| (mesh normal force) |
| ``temperature_friction`` | °C | the joint warms by SIZE (time constant 0.3..1 of the log); its friction scales by ``exp(-alpha ΔT)``, alpha 0.005..0.012 /°C (Bittencourt, Gunnarsson, J. Dyn. Sys. Meas. Control 134, 2012: friction of robot joints falls with temperature) |
| ``position_ripple`` | N·m | a torque ripple ``SIZE sin(Z q + phi)`` on the joint, Z 20..60 periods per revolution (gear teeth, cogging), phi drawn |
| ``payload`` | kg | a point mass on the flange, its centre drawn in the tool frame (x, y ±3 cm, z 2..10 cm), absent from the controller's model |
| ``attenuation_lag`` | share | a compliant support carries SIZE of each push; the rest reaches the arm through a tool mount with a first-order lag of 0.05..0.2 s; the F/T sensor sees the whole push |
| ``ft_bias`` | N | a constant force offset of the F/T sensor, direction drawn |
| ``ft_drift`` | N | the F/T sensor switched on as the log starts: a further warm-up of its force channels towards an offset of SIZE (direction drawn), time constant 60..600 s |
| ``inertia`` | kg m² | a heavier rotor (motor and brake): reflected inertia added, absent from the servo's tuning |
| ``drive_gain`` | logged / true | the drive's current-to-torque constant is off: the logged torque is SIZE times the delivered one |
| ``ft_frame`` | deg | the F/T sensor mounted turned by SIZE about a drawn axis of the tool frame |
| ``dynamics`` | share of mass | each chosen joint's link is (1 + SIZE) times heavier (inertia too), its centre of mass moved by up to 5 cm |
| ``joint_offset`` | rad | encoder zero errors: the servo holds the encoder angle, the arm sits at encoder + SIZE |
| ``dither_extraction`` | share | the drive passes only (1 - SIZE) of the dither's feedforward to the motor (its current loop attenuates it): pushes below ``Fs - A`` stick and show in part |

Draws of an effect (axes, phases, time constants) come from its own random stream of the seed,
so that planting one effect changes nothing else in the run.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ditherlab.core.errors import ConfigError

__all__ = ["EFFECTS", "SHARED", "Planted", "PlantSpec", "parse_planted", "plant", "effect_rng"]

#: name -> (unit of SIZE, default SIZE)
EFFECTS: dict[str, tuple[str, float]] = {
    "viscous": ("N·m·s/rad", 5.0),
    "stribeck": ("share of Fc", 0.5),
    "load_friction": ("N·m per N·m", 0.1),
    "temperature_friction": ("°C", 25.0),
    "position_ripple": ("N·m", 1.0),
    "payload": ("kg", 2.0),
    "attenuation_lag": ("share", 0.3),
    "ft_bias": ("N", 3.0),
    "ft_drift": ("N", 3.0),
    "inertia": ("kg m²", 1.0),
    "drive_gain": ("logged / true torque", 1.1),
    "ft_frame": ("deg", 5.0),
    "dynamics": ("share of the link's mass", 0.3),
    "joint_offset": ("rad", 0.02),
    "dither_extraction": ("share of the dither lost", 0.5),
}
#: effects of the whole arm or sensor: no @JOINTS
SHARED = {"payload", "attenuation_lag", "ft_bias", "ft_drift", "ft_frame"}
DEFAULT_JOINTS = (2, 3)
#: upper bounds of SIZE where a larger value is not the effect any more
MAX_SIZE = {"joint_offset": 0.1, "attenuation_lag": 1.0, "dither_extraction": 1.0}


@dataclass(frozen=True)
class PlantSpec:
    """One planted effect: name, SIZE (unit of :data:`EFFECTS`) and joints (1-based)."""

    name: str
    size: float
    joints: tuple[int, ...]


def _size(name: str, raw: str, item: str) -> float:
    if not raw:
        return EFFECTS[name][1]
    try:
        size = float(raw)
    except ValueError:
        raise ConfigError(
            f"--hidden {item}: size '{raw}' is not a number; expected NAME[:SIZE][@J1,J2]"
        ) from None
    unit = EFFECTS[name][0]
    if not np.isfinite(size) or size < 0 or (name == "drive_gain" and size == 0):
        raise ConfigError(f"--hidden {item}: size {raw}; expected a finite size > 0 [{unit}]")
    if size > MAX_SIZE.get(name, np.inf):
        raise ConfigError(
            f"--hidden {item}: size {raw}; expected at most {MAX_SIZE[name]:g} [{unit}]"
        )
    return size


def _joints(name: str, raw: str | None, item: str, n: int) -> tuple[int, ...]:
    if raw is None:
        return tuple(range(1, n + 1)) if name in SHARED else DEFAULT_JOINTS
    if name in SHARED:
        raise ConfigError(f"--hidden {item}: {name} acts on the whole arm; expected no @JOINTS")
    try:
        joints = tuple(sorted({int(j) for j in raw.split(",")}))
    except ValueError:
        joints = ()
    if not joints or joints[0] < 1 or joints[-1] > n:
        raise ConfigError(
            f"--hidden {item}: joints '{raw}'; expected joint numbers 1..{n} separated by commas"
        )
    return joints


def parse_planted(items: Iterable[str], n: int) -> list[PlantSpec]:
    """``NAME[:SIZE][@J1,J2]`` strings -> specs, for an arm of ``n`` joints.

    Raises
    ------
    ConfigError
        Unknown name, a size that is not a number or out of range, joints out of 1..n, an effect
        given twice.
    """
    specs: list[PlantSpec] = []
    for item in items:
        head, at, raw_joints = item.partition("@")
        name, _, raw = head.partition(":")
        if name not in EFFECTS:
            raise ConfigError(
                f"--hidden {item}: unknown effect '{name}'; expected one of {', '.join(EFFECTS)}"
            )
        if any(s.name == name for s in specs):
            raise ConfigError(f"--hidden {name}: given twice; expected each effect once")
        joints = _joints(name, raw_joints if at else None, item, n)
        specs.append(PlantSpec(name, _size(name, raw, item), joints))
    return specs


def effect_rng(seed: int, name: str) -> np.random.Generator:
    """The random stream of one effect's draws: a function of the seed and the name only."""
    return np.random.default_rng([int(seed), zlib.crc32(name.encode())])


@dataclass
class Planted:
    """What the planted effects change in the plant; per joint arrays (n,), neutral defaults."""

    n: int
    sigma2_add: np.ndarray = field(init=False)
    hump_add: np.ndarray = field(init=False)  # [share of Fc] added to Fs
    k_load: np.ndarray = field(init=False)
    warm: np.ndarray = field(init=False)  # [°C] temperature rise per joint
    warm_alpha: np.ndarray = field(init=False)  # [1/°C]
    warm_time: float = 0.0  # [share of the log] time constant of the warm-up
    ripple: np.ndarray = field(init=False)  # (3, n) amplitude [N·m], periods, phase [rad]
    jm_add: np.ndarray = field(init=False)
    log_gain: np.ndarray = field(init=False)
    offset: np.ndarray = field(init=False)
    dither_pass: np.ndarray = field(init=False)
    payload: dict[str, Any] | None = None
    links: dict[int, dict[str, Any]] = field(default_factory=dict)  # joint -> mass change
    arm_share: float = 1.0
    lag: float = 0.0
    ft_bias: np.ndarray = field(default_factory=lambda: np.zeros(6))
    ft_warm: np.ndarray = field(default_factory=lambda: np.zeros(6))  # [N] planted warm-up offset
    ft_warm_time: float = 1.0  # [s] its time constant
    ft_mount: np.ndarray | None = None
    truth: list[dict[str, Any]] = field(default_factory=list)

    def __post_init__(self) -> None:
        z = np.zeros(self.n)
        self.sigma2_add, self.hump_add, self.k_load = z.copy(), z.copy(), z.copy()
        self.warm, self.warm_alpha, self.jm_add, self.offset = (
            z.copy(),
            z.copy(),
            z.copy(),
            z.copy(),
        )
        self.ripple = np.zeros((3, self.n))
        self.log_gain, self.dither_pass = np.ones(self.n), np.ones(self.n)


def _mask(p: Planted, joints: tuple[int, ...]) -> np.ndarray:
    m = np.zeros(p.n, dtype=bool)
    m[np.asarray(joints) - 1] = True
    return m


def _friction(p: Planted, s: PlantSpec, rng: np.random.Generator) -> dict[str, Any]:
    m = _mask(p, s.joints)
    target = {"viscous": p.sigma2_add, "stribeck": p.hump_add, "load_friction": p.k_load}
    target[s.name][m] += s.size
    return {}


def _temperature(p: Planted, s: PlantSpec, rng: np.random.Generator) -> dict[str, Any]:
    m = _mask(p, s.joints)
    p.warm[m] = s.size
    p.warm_alpha[:] = rng.uniform(0.005, 0.012, p.n)
    p.warm_time = float(rng.uniform(0.3, 1.0))
    return {"alpha": p.warm_alpha.tolist(), "time_constant_share": p.warm_time}


def _ripple(p: Planted, s: PlantSpec, rng: np.random.Generator) -> dict[str, Any]:
    m = _mask(p, s.joints)
    p.ripple[0, m] = s.size
    p.ripple[1] = rng.integers(20, 61, p.n).astype(float)
    p.ripple[2] = rng.uniform(0, 2 * np.pi, p.n)
    return {"periods_per_rev": p.ripple[1, m].tolist(), "phase": p.ripple[2, m].tolist()}


def _payload(p: Planted, s: PlantSpec, rng: np.random.Generator) -> dict[str, Any]:
    com = [float(rng.uniform(-0.03, 0.03)), float(rng.uniform(-0.03, 0.03))]
    com.append(float(rng.uniform(0.02, 0.10)))
    p.payload = {"mass": s.size, "com": com}
    return {"com": com}


def _attenuation(p: Planted, s: PlantSpec, rng: np.random.Generator) -> dict[str, Any]:
    p.arm_share = 1.0 - s.size
    p.lag = float(rng.uniform(0.05, 0.2))
    return {"time_constant": p.lag}


def _ft_bias(p: Planted, s: PlantSpec, rng: np.random.Generator) -> dict[str, Any]:
    d = rng.normal(size=3)
    p.ft_bias = np.concatenate([s.size * d / np.sqrt(d @ d), np.zeros(3)])
    return {"bias": p.ft_bias.tolist()}


def _ft_drift(p: Planted, s: PlantSpec, rng: np.random.Generator) -> dict[str, Any]:
    d = rng.normal(size=3)
    p.ft_warm = np.concatenate([s.size * d / np.sqrt(d @ d), np.zeros(3)])
    p.ft_warm_time = float(rng.uniform(60.0, 600.0))
    return {"offset": p.ft_warm.tolist(), "time_constant": p.ft_warm_time}


def _ft_frame(p: Planted, s: PlantSpec, rng: np.random.Generator) -> dict[str, Any]:
    axis = rng.normal(size=3)
    axis /= np.sqrt(axis @ axis)
    a = np.radians(s.size)
    x = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    p.ft_mount = np.eye(3) + np.sin(a) * x + (1 - np.cos(a)) * (x @ x)  # Rodrigues
    return {"axis": axis.tolist(), "rotation": (a * axis).tolist()}


def _per_joint(p: Planted, s: PlantSpec, rng: np.random.Generator) -> dict[str, Any]:
    m = _mask(p, s.joints)
    if s.name == "inertia":
        p.jm_add[m] = s.size
    elif s.name == "drive_gain":
        p.log_gain[m] = s.size
    elif s.name == "joint_offset":
        p.offset[m] = s.size
    else:  # dither_extraction
        p.dither_pass[m] = 1.0 - s.size
    return {}


def _dynamics(p: Planted, s: PlantSpec, rng: np.random.Generator) -> dict[str, Any]:
    for j in s.joints:
        shift = rng.uniform(-0.05, 0.05, 3).tolist()
        p.links[j] = {"mass_factor": 1.0 + s.size, "com_shift": shift}
    return {"links": {str(j): v for j, v in p.links.items()}}


_TERMS: dict[str, Callable[[Planted, PlantSpec, np.random.Generator], dict[str, Any]]] = {
    "viscous": _friction,
    "stribeck": _friction,
    "load_friction": _friction,
    "temperature_friction": _temperature,
    "position_ripple": _ripple,
    "payload": _payload,
    "attenuation_lag": _attenuation,
    "ft_bias": _ft_bias,
    "ft_drift": _ft_drift,
    "inertia": _per_joint,
    "drive_gain": _per_joint,
    "ft_frame": _ft_frame,
    "dynamics": _dynamics,
    "joint_offset": _per_joint,
    "dither_extraction": _per_joint,
}


def plant(specs: list[PlantSpec], n: int, seed: int) -> Planted:
    """The plant terms of ``specs`` on an arm of ``n`` joints; the truth of each in
    ``Planted.truth`` (name, size, unit, joints and what was drawn)."""
    p = Planted(n)
    for s in specs:
        truth: dict[str, Any] = {
            "name": s.name,
            "size": s.size,
            "unit": EFFECTS[s.name][0],
            "joints": list(s.joints),
        }
        truth.update(_TERMS[s.name](p, s, effect_rng(seed, s.name)))
        p.truth.append(truth)
    return p
