"""Hidden effects: physics the base torque model lacks, injected into the simulated plant.

Each effect is written in the plant's own physical terms (a friction factor from a warming
joint, a cogging torque on the motor rotor, a mass on the flange, a compliant support that
carries part of the push, ...), never with the functions that diagnosis later fits
(``ditherlab.physics.effects`` is not imported here, and this module is not part of the effect library).
The truth of every injected effect goes into ``meta["sim"]["hidden"]``.

| name | SIZE | plant physics |
|---|---|---|
| ``load_friction`` | [-] N·m of band per N·m of gear torque | band and Coulomb level grow with the torque the gear transmits (mesh normal force) |
| ``drive_gain`` | [-] scale | the drives log their torque with a wrong current scale: the logged torque column of joint j is ``1 + share_j (SIZE - 1)`` times the torque the motor delivers (the plant's physics and its servo unchanged) |
| ``joint_offset`` | [rad] | the encoders read ``q - share_j SIZE``: the logged ``q`` carries the offset, the physics and the servo use the true angle |
| ``temperature_friction`` | [°C] warm-up rise | joints warm as ``T = T0 + SIZE (1 - exp(-t/tau))``; friction (band, Coulomb, viscous) falls by ``coefficient`` per °C; ``temp_j`` logged unless ``log_temperature`` is false |
| ``position_ripple`` | [N·m] amplitude | cogging torque ``SIZE sin(Z qm)`` on the motor rotor, ``Z = periods_per_rev`` |
| ``payload`` | [kg] | a point mass at ``com`` in the tool frame that the controller's model lacks |
| ``attenuation_lag`` | [-] share | a compliant support carries ``SIZE`` of the push; the rest reaches the arm through a tool mount with a first-order lag ``time_constant``; the F/T sensor sees the whole push |
| ``stribeck`` | [-] | slipping friction ``Fc (1 + SIZE exp(-(v/vs)^2))`` |
| ``ft_bias`` | [N] | the F/T sensor's force channels carry a constant offset of this magnitude, direction drawn from the seed |
| ``ft_drift`` | [N] | the F/T sensor warms up: its force channels' offset grows as ``SIZE (1 - exp(-t/time_constant))`` from the first sample, direction drawn from the seed |
| ``dynamics`` | [-] | link ``link``'s mass is ``(1 + SIZE)`` times the URDF's (its rotational inertia too) and its centre of mass shifted by ``com_shift`` (link frame): the plant's dynamics differ from the model the controller and diagnosis use |
| ``ft_frame`` | [deg] | the F/T sensor is mounted turned by SIZE degrees about an axis of the tool frame drawn from the seed; its reading, in its own axes, is logged as if in the tool's axes (the arm feels the true push) |
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.core.linalg import vector_norm

#: Name -> unit of SIZE.
EFFECTS: dict[str, str] = {
    "load_friction": "N·m per N·m",
    "drive_gain": "logged / true torque",
    "joint_offset": "rad",
    "temperature_friction": "°C",
    "position_ripple": "N·m",
    "payload": "kg",
    "attenuation_lag": "share",
    "stribeck": "share of Fc",
    "ft_bias": "N",
    "ft_drift": "N",
    "ft_frame": "deg",
    "dynamics": "share of the link's mass",
}


#: largest encoder zero offset the simulator plants [rad] (~5.7°)
MAX_OFFSET = 0.1


@dataclass(frozen=True)
class HiddenSpec:
    """One requested hidden effect: ``name`` and ``size`` (None = the configured default)."""

    name: str
    size: float | None = None


def parse_hidden(items: Iterable[Any]) -> list[HiddenSpec]:
    """Parse ``"NAME[:SIZE]"`` strings, ``(name, size)`` pairs or :class:`HiddenSpec` objects.

    Raises
    ------
    ConfigError
        Unknown effect name, a size that is not a number, a negative size, or a repeated name.
    """
    specs: list[HiddenSpec] = []
    for item in items:
        if isinstance(item, HiddenSpec):
            name, size = item.name, item.size
        elif isinstance(item, str):
            name, _, raw = item.partition(":")
            try:
                size = float(raw) if raw else None
            except ValueError:
                raise ConfigError(
                    f"--hidden {item}: size '{raw}' is not a number; expected NAME[:SIZE]"
                ) from None
        else:
            name, size = item
            size = None if size is None else float(size)
        if name not in EFFECTS:
            known = ", ".join(EFFECTS)
            raise ConfigError(f"--hidden {name}: unknown effect; expected one of {known}")
        if size is not None and (not np.isfinite(size) or size < 0):
            raise ConfigError(
                f"--hidden {name}:{size:g}: negative size; expected a size >= 0 [{EFFECTS[name]}]"
            )
        if size is not None and name == "drive_gain" and size == 0:
            raise ConfigError(
                f"--hidden {name}:0: a drive logging no torque; expected a scale > 0 "
                f"[{EFFECTS[name]}], e.g. 1.1"
            )
        if size is not None and name == "joint_offset" and size > MAX_OFFSET:
            raise ConfigError(
                f"--hidden {name}:{size:g}: an encoder offset above {MAX_OFFSET:g} rad is a wrong "
                "pose, not a zero error; expected a size in [0, 0.1] [rad]"
            )
        if any(s.name == name for s in specs):
            raise ConfigError(f"--hidden {name}: given twice; expected each effect once")
        specs.append(HiddenSpec(name, size))
    return specs


@dataclass
class HiddenPlant:
    """What the hidden effects change in a run (arrays over N samples, n joints)."""

    load: np.ndarray | None = None
    stribeck: np.ndarray | None = None
    stribeck_v: float = 0.02
    ripple_amp: np.ndarray | None = None
    ripple_freq: np.ndarray | None = None
    fscale: np.ndarray | None = None  # (N, n) friction factor
    temp: np.ndarray | None = None  # (N, n) [°C] logged temperature, or None
    payload: dict[str, Any] | None = None
    arm_share: float = 1.0  # share of the push reaching the arm
    lag: float = 0.0  # [s] first-order lag of that share
    ft_bias: np.ndarray = field(default_factory=lambda: np.zeros(6))
    ft_warm: np.ndarray | None = None  # (N, 6) [N, N·m] the F/T sensor's warm-up offset
    ft_mount: np.ndarray | None = None  # (3, 3) the F/T sensor's axes in tool axes
    link_change: dict[str, Any] | None = None  # a link's inertial parameters changed
    tau_scale: np.ndarray | None = None  # (n,) logged / true torque of each drive
    q_offset: np.ndarray | None = None  # (n,) [rad] true angle - encoder reading
    truth: list[dict[str, Any]] = field(default_factory=list)

    def logged(self, q: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The logged ``q`` and ``tau`` (N, n) from the true angle and the drive's torque: the
        encoders read ``q - q_offset``, the drives log ``tau_scale`` times their torque."""
        if self.q_offset is not None:
            q = q - self.q_offset
        if self.tau_scale is not None:
            tau = tau * self.tau_scale
        return q, tau

    def arm_push(self, push: np.ndarray, dt: float) -> np.ndarray:
        """The wrench that reaches the arm, (N, 6), from the push on the tool (N, 6)."""
        out = push * self.arm_share
        if self.lag > 0:
            alpha = dt / (self.lag + dt)
            y = np.zeros(6)
            out = out.copy()
            for k in range(len(out)):
                y = y + alpha * (out[k] - y)
                out[k] = y
        return out

    def plant_robot(self, robot: Any) -> Any:
        """The plant's RobotModel: the controller's ``robot`` with the hidden payload and the
        changed link inertial (a new model; ``robot`` is left as it is)."""
        if self.payload is None and self.link_change is None:
            return robot
        plant = robot.with_payload(self.payload)
        if self.link_change is not None:
            c = self.link_change
            body = plant.model.inertias[c["link"]]  # the link's inertial, its joint frame
            body.mass = body.mass * c["mass_factor"]
            body.inertia = body.inertia * c["mass_factor"]
            body.lever = body.lever + np.asarray(c["com_shift"], dtype=float)
            plant.model.inertias[c["link"]] = body
        return plant

    def logged_wrench(self, wrench: np.ndarray, robot: Any, q_link: np.ndarray) -> np.ndarray:
        """The F/T columns (N, 6), base axes, for the wrench (N, 6) the robot exerts at the tool
        point: the sensor reads it in its own axes (turned by ``ft_mount`` in the tool frame,
        the tool's axes from the plant's link angles ``q_link`` (N, n)), the log turns that
        reading back with the tool's axes; then ``ft_bias`` and the warm-up ``ft_warm`` are
        added. Noise not included."""
        out = np.array(wrench, dtype=float)
        if self.ft_mount is not None:
            tool_axes = robot.tool_pose(q_link)[:, :3, :3]  # in base axes
            sensor_axes = _fixed_sum(np.moveaxis(tool_axes[:, :, :, None] * self.ft_mount, 2, 3))
            for a in (slice(0, 3), slice(3, 6)):
                # sensor components, then taken as the tool's
                reading = _fixed_sum(np.swapaxes(sensor_axes, 1, 2) * out[:, None, a])
                out[:, a] = _fixed_sum(tool_axes * reading[:, None, :])
        out = out + self.ft_bias
        return out if self.ft_warm is None else out + self.ft_warm


def _fixed_sum(x: np.ndarray) -> np.ndarray:
    """``x.sum(axis=-1)`` over a last axis of 3, added in a fixed order: the same bits on every
    CPU (matmul and einsum choose BLAS or SIMD kernels by CPU, which sum in other orders)."""
    return (x[..., 0] + x[..., 1]) + x[..., 2]


class _Run(NamedTuple):
    """What an effect's plant terms may depend on: the run's sample times ``t`` (N,) [s], its
    joint count ``n`` and the hidden effects' random stream ``rng``."""

    t: np.ndarray
    n: int
    rng: np.random.Generator


def build_hidden(
    specs: list[HiddenSpec],
    params: Mapping[str, Any],
    t: np.ndarray,
    n: int,
    rng: np.random.Generator,
) -> HiddenPlant:
    """Turn the requested effects into plant terms for a run at times ``t`` (N,) [s] of ``n``
    joints, drawing from ``rng`` where an effect's direction or axis is random.

    Sizes not given take ``params["hidden"][name]["size"]``; the other constants of each
    effect come from the same table. Each effect's truth goes into ``HiddenPlant.truth``.
    """
    hp = HiddenPlant()
    run = _Run(t, n, rng)
    for spec in specs:
        cfg = dict(params["hidden"][spec.name])
        size = float(cfg["size"] if spec.size is None else spec.size)
        truth: dict[str, Any] = {
            "name": spec.name,
            "size": size,
            "unit": EFFECTS[spec.name],
            "joints": list(range(1, n + 1)),
        }
        truth.update(_PLANT_TERMS[spec.name](hp, size, cfg, run))
        hp.truth.append(truth)
    if hp.fscale is None:
        hp.fscale = np.ones((len(t), n))
    return hp


# One function per effect: it sets the effect's terms on the HiddenPlant from its SIZE and its
# table ``cfg`` and returns what the truth records beyond name, size, unit and joints.
def _load_friction(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    hp.load = np.full(run.n, size)
    return {}


def _drive_gain(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    share = _share(cfg, "drive_gain", run.n)
    hp.tau_scale = 1.0 + share * (size - 1.0)
    return {
        "joints": [int(j) + 1 for j in np.flatnonzero(share)],
        "scale": [float(v) for v in hp.tau_scale],
    }


def _joint_offset(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    share = _share(cfg, "joint_offset", run.n)
    hp.q_offset = share * size
    return {
        "joints": [int(j) + 1 for j in np.flatnonzero(share)],
        "offset": [float(v) for v in hp.q_offset],
    }


def _temperature_friction(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    t = run.t
    temp = cfg["ambient"] + size * (1.0 - np.exp(-(t - t[0]) / cfg["time_constant"]))
    temp = np.tile(temp[:, None], (1, run.n))
    factor = np.clip(1.0 - cfg["coefficient"] * (temp - cfg["ambient"]), 0.05, None)
    hp.fscale = factor if hp.fscale is None else hp.fscale * factor
    hp.temp = temp if cfg["log_temperature"] else None
    return {k: cfg[k] for k in ("coefficient", "time_constant", "ambient", "log_temperature")}


def _position_ripple(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    hp.ripple_amp = np.full(run.n, size)
    hp.ripple_freq = np.full(run.n, float(cfg["periods_per_rev"]))
    return {"periods_per_rev": cfg["periods_per_rev"]}


def _payload(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    hp.payload = {"mass": size, "com": [float(c) for c in cfg["com"]]}
    return {"com": hp.payload["com"]}


def _attenuation_lag(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    hp.arm_share = max(0.0, 1.0 - size)
    hp.lag = float(cfg["time_constant"])
    return {"time_constant": hp.lag}


def _stribeck(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    hp.stribeck = np.full(run.n, size)
    hp.stribeck_v = float(cfg["velocity"])
    return {"velocity": hp.stribeck_v}


def _ft_bias(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    d = run.rng.normal(size=3)
    d /= vector_norm(d)
    hp.ft_bias = np.concatenate([size * d, np.zeros(3)])
    return {"bias": [float(v) for v in hp.ft_bias]}


def _ft_drift(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    d = run.rng.normal(size=3)
    d /= vector_norm(d)
    T = float(cfg["time_constant"])
    warm = size * (1.0 - np.exp(-(run.t - run.t[0]) / T))
    hp.ft_warm = np.zeros((len(run.t), 6))
    hp.ft_warm[:, :3] = warm[:, None] * d
    return {"direction": [float(v) for v in d], "time_constant": T}


def _ft_frame(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    axis = run.rng.normal(size=3)
    axis /= vector_norm(axis)
    a = np.radians(size)
    X = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    XX = _fixed_sum(np.moveaxis(X[:, :, None] * X, 1, 2))  # X @ X
    hp.ft_mount = np.eye(3) + np.sin(a) * X + (1 - np.cos(a)) * XX  # Rodrigues
    return {"axis": [float(v) for v in axis], "rotation": [float(v) for v in a * axis]}


def _dynamics(hp: HiddenPlant, size: float, cfg: dict, run: _Run) -> dict[str, Any]:
    link = int(cfg["link"])
    shift = [float(c) for c in cfg["com_shift"]]
    hp.link_change = {"link": link, "mass_factor": 1.0 + size, "com_shift": shift}
    return {"link": link, "mass_factor": 1.0 + size, "com_shift": shift}


#: Each effect's plant terms, by name (the names of :data:`EFFECTS`).
_PLANT_TERMS: dict[str, Callable[[HiddenPlant, float, dict, _Run], dict[str, Any]]] = {
    "load_friction": _load_friction,
    "drive_gain": _drive_gain,
    "joint_offset": _joint_offset,
    "temperature_friction": _temperature_friction,
    "position_ripple": _position_ripple,
    "payload": _payload,
    "attenuation_lag": _attenuation_lag,
    "stribeck": _stribeck,
    "ft_bias": _ft_bias,
    "ft_drift": _ft_drift,
    "ft_frame": _ft_frame,
    "dynamics": _dynamics,
}


def _share(cfg: Mapping[str, Any], name: str, n: int) -> np.ndarray:
    """(n,) the per-joint ``share`` of a hidden effect's SIZE (0: the joint is not affected)."""
    share = np.asarray(cfg["share"], dtype=float)[:n]
    if len(share) < n or not np.all(np.isfinite(share)) or not np.any(share):
        raise ConfigError(
            f"hidden.{name}.share = {cfg['share']!r}: expected {n} finite values, one non-zero"
        )
    return share
