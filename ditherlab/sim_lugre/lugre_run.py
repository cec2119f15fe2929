"""The LuGre plant's time loop: pinocchio's arm held over each logged sample, the compiled
substeps (:mod:`ditherlab.sim_lugre.lugre_kernel`) inside.

Two models of the arm: the **controller's** (the description as it is: the servo's gravity
feedforward) and the **plant's** (the description with a planted payload or changed links: the
physics). The loop returns the true signals; noise, quantisation, the sensor and the time stamps
are added afterwards (:mod:`ditherlab.sim_lugre.lugre_log`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ditherlab.robot import TOOL_POINT_FRAME, RobotModel
from ditherlab.sim_lugre.lugre_effects import Planted
from ditherlab.sim_lugre.lugre_kernel import lugre_block
from ditherlab.sim_lugre.lugre_loads import Loads
from ditherlab.sim_lugre.lugre_params import OMEGA, LugreParams
from ditherlab.sim_lugre.lugre_scenarios import Scenario

__all__ = ["TrueRun", "Plant", "run_plant"]


@dataclass
class TrueRun:
    """The true signals at the logged samples (N): q, dq [rad, rad/s], tau_m [N·m] (the
    torque the motors deliver), tau_ffw [N·m] (the feedforward sent), wrench (N, 6) [N, N·m]
    (what the robot exerts on its environment at the tool point, base axes), push (N, 6) the
    person's push, tool_rot (N, 3, 3) the tool's axes, dither (N,) bool, friction scale (N, n)."""

    q: np.ndarray
    dq: np.ndarray
    tau_m: np.ndarray
    tau_ffw: np.ndarray
    wrench: np.ndarray
    tool_rot: np.ndarray
    dither: np.ndarray
    scale: np.ndarray


def _plant_model(robot: RobotModel, planted: Planted) -> pin.Model:
    """The plant's pinocchio model: the controller's with the planted payload and links."""
    model = robot.with_payload(planted.payload).model if planted.payload else robot.model.copy()
    for joint, change in planted.links.items():
        body = model.inertias[joint]
        f = change["mass_factor"]
        lever = body.lever + np.asarray(change["com_shift"], dtype=float)
        model.inertias[joint] = pin.Inertia(body.mass * f, lever, body.inertia * f)
    return model


class Plant:
    """The arm's two models and their evaluation at one pose."""

    def __init__(self, robot: RobotModel, planted: Planted) -> None:
        self.robot = robot
        self.ctrl = robot.model
        self.ctrl_data = self.ctrl.createData()
        self.model = _plant_model(robot, planted)
        self.data = self.model.createData()
        self.tool = self.model.getFrameId(TOOL_POINT_FRAME)
        self._plain = robot.model.nq == robot.n

    def config(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio's configuration of the angles q (n,) [rad]."""
        return q if self._plain else self.robot.pin_configuration(q[None])[0]

    def at(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, ...]:
        """M (n, n) [kg m²] (its upper triangle), h = C v + g (n,) [N·m], J (6, n), the tool
        pose (R (3, 3), p (3,))."""
        m, d, x = self.model, self.data, self.config(q)
        mass = pin.crba(m, d, x).copy()
        h = pin.nonLinearEffects(m, d, x, v).copy()
        jac = pin.computeFrameJacobian(m, d, x, self.tool, pin.LOCAL_WORLD_ALIGNED)
        pin.updateFramePlacement(m, d, self.tool)
        pose = d.oMf[self.tool]
        return mass, h, jac, pose.rotation.copy(), pose.translation.copy()

    def gravity_ffw(self, q_enc: np.ndarray) -> np.ndarray:
        """(n,) [N·m]: the controller's gravity at the encoder angles q_enc (n,) [rad]."""
        return pin.computeGeneralizedGravity(self.ctrl, self.ctrl_data, self.config(q_enc)).copy()


def _static_rows(p: LugreParams, planted: Planted) -> tuple[np.ndarray, np.ndarray]:
    fric = np.array([p.sigma0, p.sigma1, p.sigma2 + planted.sigma2_add, p.fc,
                     p.fs + planted.hump_add * p.fc, p.vs, planted.k_load, np.ones_like(p.fs)])  # fmt: skip
    servo = np.array([p.kp, p.kd, p.ki, p.tau_max, 0.3 * p.tau_max / p.ki,
                      p.dither_amp * planted.dither_pass, planted.offset, *planted.ripple,
                      p.jm + planted.jm_add])  # fmt: skip
    return fric, servo


def _square(t: np.ndarray) -> np.ndarray:
    """The dither's square wave in [-1, 1] at times t (N,) [s]."""
    return np.where(np.sin(OMEGA * t) >= 0, 1.0, -1.0)


def _arm_push(push: np.ndarray, planted: Planted, dt: float) -> np.ndarray:
    """(N, 6): the part of the person's push that reaches the arm (attenuation_lag)."""
    out = push * planted.arm_share
    if planted.lag > 0:
        alpha = 1 - np.exp(-dt / planted.lag)
        y = np.zeros(6)
        out = out.copy()
        for k in range(len(out)):
            y = y + alpha * (out[k] - y)
            out[k] = y
    return out


@dataclass(frozen=True)
class RunInputs:
    """A run's inputs: the drawn plant, the planted effects, the scenario, the loads."""

    params: LugreParams
    planted: Planted
    scenario: Scenario
    loads: Loads
    dither: bool
    scale: np.ndarray  # (N, n) friction factor (temperature)


def _start(inp: RunInputs, n: int) -> np.ndarray:
    state = np.zeros((5, n))
    state[0] = inp.scenario.q_ref[0] + inp.planted.offset
    return state


def run_plant(
    robot: RobotModel, inp: RunInputs, progress: Callable[[int, int], None] | None = None
) -> TrueRun:
    """Run the scenario on the plant; the true signals at the logged samples (:class:`TrueRun`)."""
    sc, p, planted = inp.scenario, inp.params, inp.planted
    n, N, nsub = robot.n, sc.n_samples, sc.nsub
    dt = sc.dt_log / nsub
    plant, (fric, servo) = Plant(robot, planted), _static_rows(p, planted)
    out = TrueRun(*(np.zeros((N, n)) for _ in range(4)), np.zeros((N, 6)),
                  np.zeros((N, 3, 3)), sc.still & inp.dither, inp.scale)  # fmt: skip
    arm_push = _arm_push(sc.push, planted, sc.dt_log)
    state, block = _start(inp, n), np.zeros((3, n))
    ref = np.empty((2, nsub, n))
    t_sub = np.arange(N * nsub).reshape(N, nsub) * dt
    waves = _square(t_sub) * out.dither[:, None]
    for k in range(N):
        mass, block[0], jac, rot, pos = plant.at(state[0], state[1])
        load = inp.loads.force(k, pos)
        block[1] = jac[:3].T @ (arm_push[k, :3] + load)  # forces at the tool point
        block[2] = plant.gravity_ffw(state[0] - planted.offset)
        fric[7] = inp.scale[k]
        ref[0], ref[1] = sc.q_ref[k * nsub : (k + 1) * nsub], sc.dq_ref[k * nsub : (k + 1) * nsub]
        wave = waves[k]
        out.dq[k] = lugre_block(state, ref, fric, servo, block, mass, wave, dt)
        out.q[k], out.tau_m[k] = state[0], state[4]
        out.tau_ffw[k] = block[2] + wave[-1] * p.dither_amp
        out.wrench[k, :3], out.tool_rot[k] = -(sc.push[k, :3] + load), rot
        if progress is not None and (k % 500 == 0 or k == N - 1):
            progress(k + 1, N)
    return out
