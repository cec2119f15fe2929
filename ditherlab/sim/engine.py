"""Drive the compiled joint loop over a whole run: pinocchio dynamics in chunks, state, outputs.

:class:`Engine` turns the parameter dict into the kernel's arrays, holds the state, and runs
per-sample inputs through :func:`ditherlab.sim.plant.run_kernel` in chunks. Between chunks the
link-side dynamics (inverse mass matrix, gravity and its gradient, tool Jacobian) are
re-evaluated with pinocchio when the arm has moved more than ``timing.relinearise_tolerance``;
within a chunk gravity is linearised in q.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ditherlab.core.linalg import spd_inverse
from ditherlab.physics.dither import PEAK_FACTOR, WAVEFORMS
from ditherlab.sim import plant as K
from ditherlab.sim.params import joint_array


@dataclass
class Inputs:
    """Per-sample inputs of a run (N samples, n joints).

    Attributes
    ----------
    push : (N, 6) [N, N·m] wrench applied TO the tool point by the environment (base axes)
    tau_ext : (N, n) [N·m] external torque applied directly at the joints (link side)
    q_ref, dq_ref : (N, n) [rad], [rad/s] motor-angle reference (arm side) and its rate
    kp_on : (N,) [-] 1 while the position loop is enabled (Kp is 0 for dithering joints
        regardless)
    dither_cmd : (N,) [-] 1 while the dither is requested
    fscale : (N, n) [-] friction factor (1 = nominal), e.g. from joint temperature
    noise : (N, n) [N·m] measurement noise added to the logged torque
    """

    push: np.ndarray
    tau_ext: np.ndarray
    q_ref: np.ndarray
    dq_ref: np.ndarray
    kp_on: np.ndarray
    dither_cmd: np.ndarray
    fscale: np.ndarray
    noise: np.ndarray

    @classmethod
    def still(cls, n_samples: int, q0: np.ndarray) -> Inputs:
        """``n_samples`` standing still at ``q0`` (n,) [rad], no push, no dither, no noise."""
        n = len(q0)
        return cls(
            np.zeros((n_samples, 6)),
            np.zeros((n_samples, n)),
            np.tile(q0, (n_samples, 1)),
            np.zeros((n_samples, n)),
            np.ones(n_samples),
            np.zeros(n_samples),
            np.ones((n_samples, n)),
            np.zeros((n_samples, n)),
        )


@dataclass
class PlantExtras:
    """Plant terms beyond the base model (set by hidden effects).

    Attributes
    ----------
    load : (n,) [-] band growth per N·m of gear torque, relative to the band; None: 0
    stribeck : (n,) [-] excess friction at zero speed, relative to Coulomb; None: 0
    stribeck_v : [rad/s] Stribeck velocity
    ripple_amp : (n,) [N·m] cogging ripple amplitude on the motor; None: 0
    ripple_freq : (n,) [1/rad] its periods per arm radian times 2 pi; None: 0
    """

    load: np.ndarray | None = None
    stribeck: np.ndarray | None = None
    stribeck_v: float = 0.02
    ripple_amp: np.ndarray | None = None
    ripple_freq: np.ndarray | None = None


@dataclass
class Outputs:
    """Per-sample outputs of a run (N samples, n joints; :mod:`ditherlab.sim.plant`).

    Attributes
    ----------
    tau : (N, n) [N·m] the logged torque (torque reference plus noise)
    q_motor, dq_motor : (N, n) [rad], [rad/s] motor angle (arm side) and velocity
    q_link : (N, n) [rad] link angle behind the gear spring
    tau_ffw : (N, n) [N·m] dither feedforward (centre plus the wave)
    centre_meas, amp_meas : (N, n) [N·m] the dither loops' measured centre and peak amplitude
    centre_ref, amp_ref : (N, n) [N·m] their references
    centre_ffw, amp_ffw : (N, n) [N·m] the centre and amplitude feedforward
    dither : (N,) bool, the dither loops on
    """

    tau: np.ndarray
    q_motor: np.ndarray
    dq_motor: np.ndarray
    q_link: np.ndarray
    tau_ffw: np.ndarray
    centre_meas: np.ndarray
    amp_meas: np.ndarray
    centre_ref: np.ndarray
    amp_ref: np.ndarray
    centre_ffw: np.ndarray
    amp_ffw: np.ndarray
    dither: np.ndarray


@dataclass
class Engine:
    """The simulator for one robot and parameter set.

    Parameters
    ----------
    params : merged parameter dict (:func:`ditherlab.sim.params.load_params`)
    robot : RobotModel the controller uses (gravity feedforward)
    plant_robot : RobotModel of the true plant (differs with a hidden payload); default robot
    extras : hidden plant terms

    Attributes
    ----------
    jp, sp : the compiled step's parameter arrays (:class:`ditherlab.sim.plant.Params`)
    fs, fc, fv : (n,) [N·m, N·m, N·m·s/rad] static, Coulomb and viscous friction
    window : [samples] the dither loops' window
    sample_rate : [Hz]
    """

    params: dict[str, Any]
    robot: Any
    plant_robot: Any = None
    extras: PlantExtras = field(default_factory=PlantExtras)

    def __post_init__(self) -> None:
        if self.plant_robot is None:
            self.plant_robot = self.robot
        p, n = self.params, self.robot.n
        self.n = n
        self.fs = joint_array(p, "friction.static", n)
        self.fc = self.fs * p["friction"]["coulomb_ratio"]
        self.fv = joint_array(p, "friction.viscous", n)
        self.jp = self._joint_parameters()
        t = p["timing"]
        self.sample_rate = float(t["sample_rate_hz"])
        period = 2 * np.pi / p["dither"]["frequency"]
        self.window = max(1, round(p["dither"]["periods"] * period * self.sample_rate))
        self.sp = self._scalar_parameters()
        self.output_inertia = joint_array(p, "joints.output_inertia", n)

    def _joint_parameters(self) -> np.ndarray:
        """The per-joint parameter array ``jp`` (N_JP, n) of :class:`ditherlab.sim.plant.Params`."""
        p, n, fs, fc, fv = self.params, self.n, self.fs, self.fc, self.fv
        share = float(p["friction"]["motor_share"])
        jm = joint_array(p, "joints.motor_inertia", n)
        kg = joint_array(p, "joints.gear_stiffness", n)
        jp = np.zeros((K.N_JP, n))
        jp[K.JM], jp[K.KG] = jm, kg
        jp[K.CG] = 2.0 * p["joints"]["gear_damping_ratio"] * np.sqrt(kg * jm)
        jp[K.FS_M], jp[K.FC_M], jp[K.FV_M] = share * fs, share * fc, share * fv
        jp[K.FS_O], jp[K.FC_O], jp[K.FV_O] = (1 - share) * fs, (1 - share) * fc, (1 - share) * fv
        jp[K.KP] = p["servo"]["kp"]
        jp[K.KV], jp[K.KI] = joint_array(p, "servo.kv", n), joint_array(p, "servo.ki", n)
        jp[K.ILEAK] = joint_array(p, "servo.standstill_leak", n)
        jp[K.IFRZ] = float(p["servo"]["standstill_freeze"])
        jp[K.LM] = 0.5 * joint_array(p, "joints.lost_motion", n)
        jp[K.LMK] = p["joints"]["lost_motion_stiffness"]
        d = p["dither"]
        jp[K.AMP_SP] = joint_array(p, "dither.amplitude_fraction", n) * fs
        jp[K.AMP_CAP] = d["amplitude_cap"] * fs
        jp[K.BAND] = 2.0 * fs
        jp[K.DMASK] = np.asarray(d["joints"][:n], dtype=float)
        ex = self.extras
        jp[K.LOAD] = 0.0 if ex.load is None else ex.load
        jp[K.STRIB] = 0.0 if ex.stribeck is None else ex.stribeck
        jp[K.STRIB_V] = ex.stribeck_v
        jp[K.RIP_A] = 0.0 if ex.ripple_amp is None else ex.ripple_amp
        jp[K.RIP_F] = 0.0 if ex.ripple_freq is None else ex.ripple_freq
        return jp

    def _scalar_parameters(self) -> np.ndarray:
        """The scalar parameter array ``sp`` (N_SP,) of :class:`ditherlab.sim.plant.Params`."""
        p, t, d = self.params, self.params["timing"], self.params["dither"]
        servo_hz = float(t["servo_rate_hz"])
        sp = np.zeros(K.N_SP)
        sp[K.SP_DTS] = 1.0 / servo_hz
        sp[K.SP_H] = sp[K.SP_DTS] / t["plant_substeps"]
        sp[K.SP_NSERVO], sp[K.SP_NSUB] = round(servo_hz / self.sample_rate), t["plant_substeps"]
        sp[K.SP_OMEGA] = d["frequency"]
        sp[K.SP_WAVE] = WAVEFORMS.index(d["waveform"])
        sp[K.SP_PEAK] = PEAK_FACTOR[d["waveform"]]
        sp[K.SP_WIN] = self.window
        sp[K.SP_UPD] = d["update_every"]
        sp[K.SP_KC], sp[K.SP_KA] = d["centre_gain"], d["amplitude_gain"]
        sp[K.SP_HOLD] = d["hold_fraction"]
        sp[K.SP_RAMP] = max(1.0, d["ramp_s"] * self.sample_rate)
        sp[K.SP_SWEEPS] = t["gauss_seidel_sweeps"]
        sp[K.SP_VSTILL] = p["servo"]["standstill_velocity"]
        return sp

    # ------------------------------------------------------------------ state
    def initial_state(self, q0: np.ndarray) -> dict[str, np.ndarray]:
        """Standing still at motor angle ``q0`` (n,) [rad], the gear spring carrying gravity,
        all friction stuck and unloaded: the arrays of :class:`ditherlab.sim.plant.State` by
        name (``x``, ``ist``, ``fst``, ``hist``)."""
        n = self.n
        x = np.zeros((K.N_X, n))
        # reference=True here and below: pinocchio's own functions, the simulator's ground truth
        g = self.plant_robot.evaluate(q0, ["gravity"], reference=True)["gravity"][0]
        x[K.X_QM] = q0
        jp = self.jp
        x[K.X_Q] = q0 - K.gear_twist(g, jp[K.KG], jp[K.LM], jp[K.LMK])
        # the velocity integral carries what the controller's gravity model misses
        x[K.X_I] = g - self.robot.evaluate(q0, ["gravity"], reference=True)["gravity"][0]
        x[K.X_SM] = x[K.X_SO] = 1.0
        return {
            "x": x,
            "ist": np.zeros(4, dtype=np.int64),
            "fst": np.zeros(3),
            "hist": np.zeros((n, self.window)),
        }

    def _dynamics(self, q_link: np.ndarray, q_motor: np.ndarray) -> K.Dynamics:
        """The link-side dynamics at link angle ``q_link`` and motor angle ``q_motor`` (n,)
        [rad]: pinocchio's, gravity and the mass matrix differentiated by forward differences."""
        n, eps = self.n, 1e-6
        qs = np.vstack([q_link, q_link + eps * np.eye(n)])
        pl = self.plant_robot.evaluate(qs, ["gravity", "mass_matrix", "jacobian"], reference=True)
        M = pl["mass_matrix"]
        W = spd_inverse(M[0] + np.diag(self.output_inertia))
        gp = pl["gravity"]
        Gp = ((gp[1:] - gp[0]) / eps).T  # dg_i/dq_k at [i, k]
        dM = np.moveaxis((M[1:] - M[0]) / eps, 0, 2)  # dM_ij/dq_k at [i, j, k]
        Gam = 0.5 * (dM + np.swapaxes(dM, 1, 2) - np.moveaxis(dM, 2, 0))
        qs = np.vstack([q_motor, q_motor + eps * np.eye(n)])
        gc = self.robot.evaluate(qs, ["gravity"], reference=True)["gravity"]
        Gc = ((gc[1:] - gc[0]) / eps).T
        JT = pl["jacobian"][0].T.copy()
        return K.Dynamics(
            W, gp[0].copy(), Gp, q_link.copy(), gc[0].copy(), Gc, q_motor.copy(), JT, Gam
        )

    # ------------------------------------------------------------------ run
    def run(
        self,
        inputs: Inputs,
        state: dict[str, np.ndarray],
        *,
        progress: Callable[[int, int], None] | None = None,
        reference: bool = False,
        chunk_callback: Callable[[int, int, dict[str, np.ndarray], np.ndarray], None] | None = None,
    ) -> Outputs:
        """Run all samples of ``inputs`` from ``state`` (updated in place).

        Parameters
        ----------
        inputs : per-sample inputs (N samples)
        state : from :meth:`initial_state`, updated in place
        progress : ``progress(done, total)`` in samples
        reference : use the plain numpy step instead of the compiled kernel
        chunk_callback : ``f(k0, k1, state, out)`` after every chunk with the raw output array
            ``out`` (N_OUT, N, n); closed-loop scenarios may modify the inputs of later samples in
            place (the input arrays must then be float64 and C-contiguous, so they are not copied)

        Returns
        -------
        Outputs
        """
        N, n = inputs.push.shape[0], self.n
        out = np.zeros((K.N_OUT, N, n))
        step = K.run_reference if reference else K.run_kernel
        tol = float(self.params["timing"]["relinearise_tolerance"])
        every = int(self.params["timing"]["dynamics_update_samples"])
        par = K.Params(self.jp, self.sp)
        st = K.State(state["x"], state["ist"], state["fst"], state["hist"])
        x = st.x
        dyn = self._dynamics(x[K.X_Q].copy(), x[K.X_QM].copy())
        samples = K.Samples(
            *(
                np.ascontiguousarray(a, dtype=float)
                for a in (
                    inputs.push,
                    inputs.tau_ext,
                    inputs.q_ref,
                    inputs.dq_ref,
                    inputs.kp_on,
                    inputs.dither_cmd,
                    inputs.noise,
                    inputs.fscale,
                )
            )
        )
        k0 = 0
        last_report = 0
        while k0 < N:
            k1 = min(N, k0 + every)
            moved = np.max(np.abs(x[K.X_Q] - dyn.qp_lin)) > tol
            if moved or np.max(np.abs(x[K.X_QM] - dyn.qc_lin)) > tol:
                dyn = self._dynamics(x[K.X_Q].copy(), x[K.X_QM].copy())
            step(par, dyn, K.Samples(*(a[k0:k1] for a in samples)), st, out, k0)
            if chunk_callback is not None:
                chunk_callback(k0, k1, state, out)
            k0 = k1
            if progress is not None and (k0 - last_report >= 2500 or k0 == N):
                progress(k0, N)
                last_report = k0
        return Outputs(*(out[i] for i in range(K.O_DITHER)), out[K.O_DITHER, :, 0] > 0.5)
