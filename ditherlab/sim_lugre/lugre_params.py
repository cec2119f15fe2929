"""The LuGre plant's parameters, drawn per seed from stated physical ranges.

Every physical parameter is drawn uniformly from a range (never one tuned value); the ranges and
where they come from:

- **Static friction** ``Fs`` [N·m]: the IRB140 from the per-joint set of
  ``/work/shared/SIMULATOR-NOTES.md`` (10 / 9 / 8 / 2.5 / 2.5 / 1.5 N·m), times 0.7..1.3; any
  other arm 2..5 % of the description's rated joint torque (``effort``; the UR10e's datasheet
  torques 330 / 330 / 150 / 54 / 54 / 54 N·m), the span of that IRB140 set's ratios Fs / effort
  (2.3..5 %).
- **Coulomb** ``Fc = (0.6..0.9) Fs`` and **Stribeck velocity** ``vs`` 0.005..0.05 rad/s arm side
  (Armstrong-Hélouvry, Dupont, Canudas de Wit, Automatica 30(7) 1994: static friction 10..60 %
  above Coulomb, Stribeck velocities of 0.5..5 rad/s on the motor, /100 through the gear).
- **Viscous** ``sigma2 = (0.15..0.45) Fs`` [N·m·s/rad] around the notes' ``Fv = 0.3 Fs``.
- **Bristle stiffness** ``sigma0 = Fs / x_b``, ``x_b`` the presliding displacement scale
  1e-5..1e-4 rad arm side: LuGre moves a joint by ``x_b ln((1 + a) / (1 - a))`` peak to peak
  under a dither of ``a Fs`` (below 0.81), at most about 2e-4 rad, the order of the paper's
  measured vibration (1e-4 arm rad, SIMULATOR-NOTES.md); **bristle damping** ``sigma1 = 2 zeta sqrt(sigma0 J)``, zeta 0.3..1
  (Canudas de Wit, Olsson, Åström, Lischinsky, IEEE TAC 40(3) 1995: sigma1 near critical damping
  of the presliding resonance).
- **Reflected motor inertia** ``Jm`` [kg m²]: the IRB140 from the notes' set (1.3 / 1.3 / 0.6 /
  0.08 / 0.08 / 0.04) times 0.7..1.3; the UR10e 0.8..1.6 on joints 1-2, 0.3..0.6 on joint 3,
  0.05..0.12 on the wrist (rotor inertias of about 1e-4 / 4e-5 / 1e-5 kg m² behind 101:1
  harmonic gears); any other arm ``(0.5..1.5) * 3e-3 * effort`` (the IRB140 set's Jm / effort).
- **Servo**: a PID on the joint angle tuned to a drawn closed-loop bandwidth ``wc`` 2π·(4..10)
  rad/s (industrial position loops), damping 0.7..1: ``Kp = J wc²``, ``Kd = 2 zeta J wc``,
  ``Ki = Kp wc / (5..10)``, J the joint's motor plus link inertia at the home pose; the integral
  is clamped to 30 % of the rated torque. Gravity feedforward from the controller's model.
- **Dither**: a square wave at 78.54 rad/s (20 samples a period at 250 Hz) of amplitude
  0.5..0.9 Fc per joint: the paper's 50-90 % (§III-B) of the level the joint holds under a
  vibration. Above Fc a LuGre joint slides under the dither (no band holds a torque between Fc
  and Fs for long), vibrating far beyond the paper's 1e-4 rad.
- **Logged torque**: AR(1) current noise of std (0.01..0.08) Fs and lag-1 coefficient 0.2..0.7
  at 250 Hz; a current LSB of 2 effort / 2^b, b in {12, 13, 14} (12-14 bit current measurement
  over the drive's range); time-stamp jitter of std 20..700 µs (clipped at ±1.5 ms). The notes
  give 0.03 Fs for the IRB140; the real UR10e log ``/work/shared/data/ur10e/ur-static.csv``
  (100 Hz) reads at rest 0.44 / 0.42 / 0.21 / 0.11 / 0.10 / 0.13 N·m (current × the drive gains
  of its README), 0.03..0.1 of this plant's UR10e Fs, with lag-1 autocorrelations of -0.08..0.13
  at 100 Hz (an AR(1) of 0.2..0.7 at 250 Hz has 0.02..0.41 there), and steps of 10 ms with a
  spread of 0.94 ms (stamps jittering by about 0.67 ms).
- **F/T sensor**: first-order low-pass of 20..100 Hz cutoff; force noise 0.05..0.3 N (torques
  0.005..0.03 N·m), resolutions of 6-axis strain-gauge sensors of the ATI Mini45 / Axia class;
  bias drift as a random walk of 0.005..0.05 N/√s plus a warm-up of 0.2..1.5 N over 60..600 s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ditherlab.core.errors import ConfigError
from ditherlab.robot import RobotModel

__all__ = ["LugreParams", "draw_params", "home_pose", "SAMPLE_RATE", "SUBSTEPS", "OMEGA"]

SAMPLE_RATE = 250.0  # [Hz] the logged rate
SUBSTEPS = 20  # substeps per logged sample: 5 kHz inside
OMEGA = 2 * np.pi / 0.08  # [rad/s] the dither's angular frequency: 20 samples a period

#: the IRB140's Fs [N·m] and Jm [kg m²] per joint (SIMULATOR-NOTES.md)
IRB140_FS = np.array([10.0, 9.0, 8.0, 2.5, 2.5, 1.5])
IRB140_JM = np.array([1.3, 1.3, 0.6, 0.08, 0.08, 0.04])
#: the UR10e's reflected motor inertia ranges [kg m²], joints 1..6
UR10E_JM = np.array([[0.8, 1.6], [0.8, 1.6], [0.3, 0.6], [0.05, 0.12], [0.05, 0.12], [0.05, 0.12]])
#: the poses each arm stands in [rad] (IRB140: the paper's Fig. 1; UR10e: tool down, elbow up)
HOME = {
    "irb140": [0.0, 0.0, 0.0, 0.0, np.pi / 2, 0.0],
    "ur10e": [0.0, -1.2, 1.5, -1.87, -np.pi / 2, 0.0],
}


@dataclass
class LugreParams:
    """The drawn plant: per joint arrays (n,) and scalars, units as in the module docstring."""

    fs: np.ndarray
    fc: np.ndarray
    vs: np.ndarray
    sigma0: np.ndarray
    sigma1: np.ndarray
    sigma2: np.ndarray
    jm: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    ki: np.ndarray
    tau_max: np.ndarray
    dither_amp: np.ndarray
    noise_std: np.ndarray
    noise_ar: np.ndarray
    lsb: np.ndarray
    jitter: float
    ft: dict[str, float]

    def as_meta(self) -> dict[str, Any]:
        """Every parameter as plain lists and numbers, for ``meta["sim"]["params"]``."""
        out: dict[str, Any] = {}
        for k, v in self.__dict__.items():
            out[k] = [float(x) for x in v] if isinstance(v, np.ndarray) else v
        return out


def home_pose(robot: RobotModel) -> np.ndarray:
    """(n,) [rad]: the arm's standing pose (HOME, else the middle of its joint ranges)."""
    if robot.name in HOME and robot.n == 6:
        return np.array(HOME[robot.name], dtype=float)
    lo, hi = np.nan_to_num(robot.q_lower, nan=-np.pi), np.nan_to_num(robot.q_upper, nan=np.pi)
    return np.clip(0.5 * (lo + hi), -np.pi / 2, np.pi / 2)


def _friction_and_inertia(robot: RobotModel, rng: np.random.Generator) -> tuple:
    n, effort = robot.n, np.asarray(robot.effort_limit, dtype=float)
    if not np.all(np.isfinite(effort) & (effort > 0)):
        raise ConfigError(
            f"--robot {robot.name}: joint effort limits {effort.tolist()}; expected a rated "
            "torque > 0 [N·m] per joint in the description (the plant's friction scales with it)"
        )
    if robot.name == "irb140" and n == 6:
        fs = IRB140_FS * rng.uniform(0.7, 1.3, n)
        jm = IRB140_JM * rng.uniform(0.7, 1.3, n)
    elif robot.name == "ur10e" and n == 6:
        fs = effort * rng.uniform(0.02, 0.05, n)
        jm = rng.uniform(UR10E_JM[:, 0], UR10E_JM[:, 1])
    else:
        fs = effort * rng.uniform(0.02, 0.05, n)
        jm = 3e-3 * effort * rng.uniform(0.5, 1.5, n)
    return fs, jm, effort


def draw_params(robot: RobotModel, rng: np.random.Generator) -> LugreParams:
    """Draw every parameter of the plant for ``robot`` from ``rng`` (module docstring)."""
    n = robot.n
    fs, jm, effort = _friction_and_inertia(robot, rng)
    fc = fs * rng.uniform(0.6, 0.9, n)
    vs = rng.uniform(0.005, 0.05, n)
    sigma2 = fs * rng.uniform(0.15, 0.45, n)
    sigma0 = fs / rng.uniform(1e-5, 1e-4, n)
    m_home = np.diag(robot.mass_matrix(home_pose(robot)[None])[0])
    j_total = jm + m_home
    sigma1 = 2 * rng.uniform(0.3, 1.0, n) * np.sqrt(sigma0 * j_total)
    wc = 2 * np.pi * rng.uniform(4.0, 10.0, n)
    kp = j_total * wc**2
    kd = 2 * rng.uniform(0.7, 1.0, n) * j_total * wc
    ki = kp * wc / rng.uniform(5.0, 10.0, n)
    ft = {
        "cutoff_hz": float(rng.uniform(20.0, 100.0)),
        "force_noise": float(rng.uniform(0.05, 0.3)),
        "walk": float(rng.uniform(0.005, 0.05)),
        "warmup": float(rng.uniform(0.2, 1.5)),
        "warmup_time": float(rng.uniform(60.0, 600.0)),
    }
    return LugreParams(
        fs=fs, fc=fc, vs=vs, sigma0=sigma0, sigma1=sigma1, sigma2=sigma2, jm=jm,
        kp=kp, kd=kd, ki=ki, tau_max=effort.copy(),
        dither_amp=fc * rng.uniform(0.5, 0.9, n),
        noise_std=fs * rng.uniform(0.01, 0.08, n),
        noise_ar=rng.uniform(0.2, 0.7, n),
        lsb=2 * effort / 2.0 ** rng.integers(12, 15, n),
        jitter=float(rng.uniform(20e-6, 700e-6)),
        ft=ft,
    )  # fmt: skip
