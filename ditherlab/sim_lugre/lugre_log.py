"""What the LuGre plant's controller and sensor log, from the true signals of a run.

- ``tau_j``: the motor current measured by the drive, with AR(1) noise (coloured: lag-1
  coefficient drawn), quantised to the current LSB, times the drive's torque constant as the
  controller believes it (``drive_gain`` planted: a wrong one) [N·m, arm side].
- ``q_j``: the encoder angle (the true angle minus a planted zero error) [rad]; ``dq_j``: the
  encoder difference over the sample step [rad/s].
- ``t``: the nominal sample times plus a time-stamp jitter (the samples are taken on time; the
  stamps are not) [s].
- ``f_x .. m_z``: the F/T sensor: the wrench through a mounting rotation (``ft_frame``), a
  first-order low-pass, a bias (``ft_bias`` planted, a random walk, the sensor's own warm-up
  and a planted one, ``ft_drift``) and white noise [N, N·m], in base axes at the tool point.
- ``temp_j``: the joints' temperatures [°C] (with ``temperature_friction`` planted), quantised
  to 0.1 °C.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ditherlab.data.recording import RecordingArrays
from ditherlab.sim_lugre.lugre_effects import Planted
from ditherlab.sim_lugre.lugre_params import LugreParams
from ditherlab.sim_lugre.lugre_run import TrueRun

__all__ = ["LogStreams", "ar1", "logged_torque", "logged_wrench", "to_arrays", "noise_floor"]

AMBIENT = 25.0  # [°C] the joints' temperature at the start


@dataclass(frozen=True)
class LogStreams:
    """The random streams of the logging (independent of the physics' and the effects')."""

    torque: np.random.Generator
    sensor: np.random.Generator
    stamps: np.random.Generator


def ar1(rng: np.random.Generator, n_samples: int, phi: np.ndarray, std: np.ndarray) -> np.ndarray:
    """(N, n): stationary AR(1) noise ``e_k = phi e_{k-1} + sqrt(1 - phi²) std w_k`` per
    column, lag-1 autocorrelation phi (n,), standard deviation std (n,)."""
    w = rng.standard_normal((n_samples, len(phi))) * std * np.sqrt(1 - phi**2)
    e = np.empty_like(w)
    e[0] = rng.standard_normal(len(phi)) * std
    for k in range(1, n_samples):
        e[k] = phi * e[k - 1] + w[k]
    return e


def logged_torque(run: TrueRun, p: LugreParams, planted: Planted, rng) -> np.ndarray:
    """(N, n) [N·m]: the drives' logged torque (module docstring)."""
    noise = ar1(rng, len(run.tau_m), p.noise_ar, p.noise_std)
    counts = np.round((run.tau_m + noise) / p.lsb)
    return counts * p.lsb * planted.log_gain


def noise_floor(p: LugreParams, planted: Planted) -> np.ndarray:
    """(n,) [N·m]: the logged torque's noise std: the AR(1) noise and the LSB's uniform error."""
    return np.sqrt(p.noise_std**2 + p.lsb**2 / 12) * planted.log_gain


def _lowpass(x: np.ndarray, cutoff: float, dt: float) -> np.ndarray:
    alpha = 1 - np.exp(-2 * np.pi * cutoff * dt)
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, len(x)):
        y[k] = y[k - 1] + alpha * (x[k] - y[k - 1])
    return y


def _mounted(wrench: np.ndarray, rot: np.ndarray, mount: np.ndarray | None) -> np.ndarray:
    """The wrench (N, 6) as a sensor turned by ``mount`` in the tool frame logs it: read in its
    own axes, taken as the tool's, turned back to base axes with the tool's axes rot (N, 3, 3)."""
    if mount is None:
        return wrench
    sensor = rot @ mount  # sensor axes in base axes
    out = wrench.copy()
    for a in (slice(0, 3), slice(3, 6)):
        reading = np.einsum("nji,nj->ni", sensor, wrench[:, a])
        out[:, a] = np.einsum("nij,nj->ni", rot, reading)
    return out


def logged_wrench(run: TrueRun, p: LugreParams, planted: Planted, t: np.ndarray, rng):
    """(N, 6) [N, N·m]: the F/T sensor's columns (module docstring)."""
    ft, dt = p.ft, float(t[1] - t[0])
    w = _lowpass(_mounted(run.wrench, run.tool_rot, planted.ft_mount), ft["cutoff_hz"], dt)
    scale = np.array([1.0, 1.0, 1.0, 0.1, 0.1, 0.1])  # torques: 0.1 m lever of the forces
    walk = np.cumsum(rng.standard_normal((len(t), 6)) * ft["walk"] * np.sqrt(dt), axis=0)
    warm_dir = rng.normal(size=6)
    warm = ft["warmup"] * (1 - np.exp(-(t - t[0]) / ft["warmup_time"]))[:, None] * warm_dir
    noise = rng.standard_normal((len(t), 6)) * ft["force_noise"]
    planted_warm = -np.expm1(-(t - t[0]) / planted.ft_warm_time)[:, None] * planted.ft_warm
    return w + planted.ft_bias + planted_warm + (walk + warm + noise) * scale


def temperatures(t: np.ndarray, planted: Planted) -> np.ndarray:
    """(N, n) [°C]: the joints' temperature: ambient plus the planted warm-up."""
    tau = max(planted.warm_time * (t[-1] - t[0]), 1e-9)
    return AMBIENT + planted.warm * (1 - np.exp(-(t - t[0]) / tau))[:, None]


def friction_scale(temp: np.ndarray, planted: Planted) -> np.ndarray:
    """(N, n) [-]: the friction factor ``exp(-alpha (T - ambient))`` at temperatures temp."""
    return np.exp(-planted.warm_alpha * (temp - AMBIENT))


def to_arrays(run: TrueRun, inputs, streams: LogStreams, log_temperature: bool):
    """The run's RecordingArrays (module docstring); ``inputs`` is the run's RunInputs."""
    p, planted, sc = inputs.params, inputs.planted, inputs.scenario
    t_nom = (np.arange(len(run.q)) + 1) * sc.dt_log
    jitter = np.clip(streams.stamps.normal(0, p.jitter, len(t_nom)), -1.5e-3, 1.5e-3)
    tau = logged_torque(run, p, planted, streams.torque)
    wrench = logged_wrench(run, p, planted, t_nom, streams.sensor) if sc.sensor else None
    temp = None
    if log_temperature and np.any(planted.warm > 0):
        temp = np.round(temperatures(t_nom, planted) * 10) / 10
    return RecordingArrays(
        t=t_nom + jitter, q=run.q - planted.offset, tau=tau, dq=run.dq, tau_ffw=run.tau_ffw,
        wrench=wrench, temp=temp, dither=run.dither.copy(),
    )  # fmt: skip
