"""Lead-through (paper §V): an operator guides the tool; the robot follows the *estimated* force.

The operator pushes the tool along z, then y, then x, then several directions at once (like the
paper's Fig. 7), each push a smooth profile with a flat top, released between pushes. Every
``timing.dynamics_update_samples`` samples the controller estimates the push from the logged
torques with eq. (3) (:func:`ditherlab.estimator.estimate`, forces only):

- still and dithering: the dither signal extracted over the last period (mean of the upper and
  lower means), band shrunk by the measured dither amplitude;
- moving: Coulomb + viscous friction subtracted (known when moving), no band;
- still without dither: the full band.

Zero-stiffness impedance (admittance) control in task space, linear motions only: the commanded
tool velocity is ``admittance * P_cmd`` (limited to ``max_speed``), mapped to joint velocities
through the pseudo-inverse of the Jacobian with zero angular velocity. ``lead_through.law``
chooses the force ``P_cmd`` that drives it:

``"dead-zone"`` (the paper's experiment, the default)
    ``P_cmd = (|P| - dead_zone) P/|P|`` beyond the 10 N dead zone, else 0.
``"interval"`` (the paper's §V alternative)
    per base axis, 0 when the confidence interval of the estimated push contains 0, else the
    bound nearest 0 (:func:`interval_command`); the interval is eq. (3)'s of the same sample,
    ``lead_through.interval`` (set membership or profile) at ``lead_through.level``. Per axis
    because the estimator's intervals are per component: the confidence region is the box of the
    three intervals, and the per-axis rule returns the point of that box nearest the origin, the
    smallest push the data cannot rule out (a per-direction rule would need the interval of the
    projection on a data-chosen direction, which the box does not give). Extra columns
    ``flo_x..z, fhi_x..z`` [N] hold the interval of the push the controller acted on.

The dither is ramped off as soon as the commanded speed exceeds ``dither_off_speed``, and back on
after ``still_s`` without motion.

An external estimate (``estimate``, an :data:`EstimateSource`) replaces eq. (3) above: at every
update it is handed the update's samples as the robot logs them (:class:`LoggedChunk`) and
returns the push and its interval; the law, the admittance and the dither switch are the same.
``ditherlab leadthrough --live`` drives the arm this way by ``ditherlab live`` over DDS.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ditherlab.core.linalg import lu_solve, vector_norm
from ditherlab.data.recording import RecordingArrays
from ditherlab.estimator import estimate, intervals, problem, solve
from ditherlab.sim import plant as K
from ditherlab.sim.engine import Engine, Inputs
from ditherlab.sim.hidden import HiddenSpec, build_hidden
from ditherlab.sim.scenarios import scenario_columns, scenario_rngs, wrench_noise

#: (direction in base axes, magnitude [N], flat-top duration [s]); release 2.5 s after each.
OPERATOR_PLAN = (
    ((0.0, 0.0, -1.0), 30.0, 2.5),
    ((0.0, 1.0, 0.0), 28.0, 2.5),
    ((1.0, 0.0, 0.0), 32.0, 2.5),
    ((-1.0, -1.0, 1.0), 35.0, 3.0),
)
EDGE_S, RELEASE_S, START_S = 0.4, 2.5, 4.0


def operator_segments(rng: np.random.Generator) -> tuple[list[dict[str, Any]], float]:
    """The operator's pushes (:data:`OPERATOR_PLAN`, magnitudes drawn +-10 % from ``rng``).

    Returns (segments, end time [s]); each segment has ``t0`` [s] (onset), ``direction`` (unit,
    base axes), ``magnitude`` [N] and ``flat`` [s] (flat-top duration); the push rises and falls
    over :data:`EDGE_S` and is followed by :data:`RELEASE_S` of rest.
    """
    segments = []
    t = START_S
    for direction, mag, flat in OPERATOR_PLAN:
        d = np.asarray(direction, dtype=float) / vector_norm(direction)
        m = mag * rng.uniform(0.9, 1.1)
        segments.append(
            {"t0": t, "direction": [float(v) for v in d], "magnitude": float(m), "flat": flat}
        )
        t += 2 * EDGE_S + flat + RELEASE_S
    return segments, t


def operator_push(tt: np.ndarray, segments: list[dict[str, Any]]) -> np.ndarray:
    """The operator's push on the tool, ``(N, 3)`` [N, base axes], at times ``tt (N,)`` [s]:
    each segment a raised-cosine rise over :data:`EDGE_S`, a flat top, a raised-cosine fall."""
    push = np.zeros((len(tt), 3))
    for s in segments:
        u = tt - s["t0"]
        total = 2 * EDGE_S + s["flat"]
        rise = 0.5 * (1 - np.cos(np.pi * np.clip(u / EDGE_S, 0, 1)))
        fall = 0.5 * (1 - np.cos(np.pi * np.clip((total - u) / EDGE_S, 0, 1)))
        shape = np.where((u >= 0) & (u <= total), np.minimum(rise, fall), 0.0)
        push += s["magnitude"] * shape[:, None] * np.asarray(s["direction"])
    return push


def interval_command(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The interval law's force: per component 0 when ``lo <= 0 <= hi``, else the bound nearest
    0 (``lo`` when the interval lies above 0, ``hi`` when below) -- the point of the box
    ``[lo, hi]`` nearest the origin. A NaN bound (no force consistent with the data, the set
    membership's verdict on data the model cannot explain) commands 0.

    Parameters
    ----------
    lo, hi : (..., 3) [N] interval bounds of the push, ``lo <= hi``

    Returns
    -------
    (..., 3) [N]
    """
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    out = np.where(lo > 0, lo, np.where(hi < 0, hi, 0.0))
    return np.where(np.isnan(lo) | np.isnan(hi), 0.0, out)


@dataclass(frozen=True)
class LoggedChunk:
    """The samples of one controller update as the robot logs them (the recording's columns).

    Attributes
    ----------
    t : (m,) [s] ; q : (m, n) [rad] ; dq : (m, n) [rad/s] ; tau : (m, n) [N·m]
    tau_ffw : (m, n) [N·m] the dither feedforward ; dither : (m,) bool the dither loops on
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    tau_ffw: np.ndarray
    dither: np.ndarray


#: An external estimate of the push: called once per controller update with its
#: :class:`LoggedChunk`, returns the push on the tool at the chunk's last sample ``p_hat`` (3,)
#: [N, base axes] and its interval ``p_lo``, ``p_hi`` (3,) [N] (NaN: none).
EstimateSource = Callable[[LoggedChunk], tuple[np.ndarray, np.ndarray, np.ndarray]]


def lead_through(
    engine_for: Callable[[Any], Engine],
    params: dict[str, Any],
    *,
    seed: int,
    dither: bool,
    hidden: list[HiddenSpec],
    progress: Callable[[int, int], None] | None,
    robot: Any,
    estimate: EstimateSource | None = None,
) -> tuple[RecordingArrays, dict[str, Any]]:
    """Simulate lead-through; returns (the recording's arrays, meta["sim"] part).

    Same parameters as :func:`ditherlab.sim.scenarios.push_campaign`; ``estimate`` an external
    estimate of the push (module docstring; None: eq. (3) in the controller). Extra columns
    ``fhat_x, fhat_y, fhat_z`` [N] hold the push the controller estimated (on the tool); with
    ``lead_through.law = "interval"`` also ``flo_x..z, fhi_x..z`` [N], its interval.
    """
    lt = params["lead_through"]
    fs_hz = float(params["timing"]["sample_rate_hz"])
    dt = 1.0 / fs_hz
    n = robot.n
    plan_rng, noise_rng, hidden_rng = scenario_rngs(seed)
    segments, t = operator_segments(plan_rng)
    N = int(np.ceil(t * fs_hz))
    tt = np.arange(N) * dt
    push = np.zeros((N, 6))
    push[:, :3] = operator_push(tt, segments)
    hp = build_hidden(hidden, params, tt, n, hidden_rng)
    eng = engine_for(hp)
    ctl = Admittance.start(params, eng, robot, hp.arm_push(push, dt), hp.fscale, noise_rng, dither)
    if estimate is not None:
        ctl.source = _LoggedSource(estimate, tt, hp.logged)
    ft_noise = wrench_noise(params, noise_rng, N)
    state = eng.initial_state(ctl.q0)
    if dither:  # the first second settles without dither
        ctl.inputs.dither_cmd[int(1.0 * fs_hz) :] = 1.0
    out = eng.run(ctl.inputs, state, progress=progress, chunk_callback=ctl.control)
    wrench = hp.logged_wrench(-push, robot, out.q_link) + ft_noise
    extra = {"fhat_x": ctl.fhat[:, 0], "fhat_y": ctl.fhat[:, 1], "fhat_z": ctl.fhat[:, 2]}
    if ctl.interval_law:
        for i, a in enumerate("xyz"):
            extra[f"flo_{a}"] = ctl.flo[:, i]
            extra[f"fhi_{a}"] = ctl.fhi[:, i]
    arrays = scenario_columns(tt, out, wrench, hp, extra)
    sim_meta = {
        "operator": segments,
        "timeline": {"end": float(tt[-1])},
        "lead_through": dict(lt),
        "dither_amplitudes": {
            "set_point": [float(v) for v in eng.jp[K.AMP_SP]],
            "unit": "N·m (amplitude of the logged torque)",
        },
        "hidden": hp.truth,
    }
    return arrays, sim_meta


@dataclass(frozen=True)
class _LoggedSource:
    """An external estimate (:data:`EstimateSource`) fed from the engine's raw outputs: the
    times ``tt`` (N,) [s] and how the robot logs its angle and torque (``logged``,
    :meth:`ditherlab.sim.hidden.HiddenPlant.logged`)."""

    estimate: EstimateSource
    tt: np.ndarray
    logged: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]

    def __call__(self, out: np.ndarray, k0: int, k1: int) -> tuple[np.ndarray, ...]:
        """The push (3,) [N] and its interval (3,), (3,) [N] at sample ``k1 - 1``, from the
        logged samples ``k0 .. k1`` of ``out`` (N_OUT, N, n)."""
        q, tau = self.logged(out[K.O_QM, k0:k1].copy(), out[K.O_TAU, k0:k1].copy())
        chunk = LoggedChunk(
            t=self.tt[k0:k1].copy(),
            q=q,
            dq=out[K.O_VM, k0:k1].copy(),
            tau=tau,
            tau_ffw=out[K.O_FFW, k0:k1].copy(),
            dither=out[K.O_DITHER, k0:k1, 0] > 0.5,
        )
        return tuple(np.asarray(a, dtype=float).reshape(3) for a in self.estimate(chunk))


#: [N, N, N, N·m, N·m, N·m] the controller's prior on the wrench (eq. (3)'s R_F, square roots)
PRIOR_SIGMA = (100.0, 100.0, 100.0, 10.0, 10.0, 10.0)


@dataclass
class Admittance:
    """The lead-through controller: every chunk it estimates the push from the logged torques
    and commands the joints to follow it (module docstring); its state carries over.

    Attributes
    ----------
    lt : the ``lead_through`` parameter table
    eng, robot : the Engine (its friction) and the controller's RobotModel
    inputs : the run's Inputs, written ahead of the engine
    q0 : (n,) [rad] the starting pose
    sigma : (n,) [N·m] the logged torque's noise
    dt : [s] the sample step
    period, still_after, ramp_n : [samples] one dither period, the stillness before the dither
        comes back on, the dither's ramp
    dither : the dither is used at all
    fhat, flo, fhi : (N, 3) [N] the estimated push on the tool and its interval (NaN without
        the interval law)
    v : (3,) [m/s] the commanded tool velocity, smoothed
    q_ref : (n,) [rad] the motor-angle reference where the next chunk begins
    still : [samples] how long the commanded speed has been below ``dither_off_speed``
    source : an external estimate of the push (None: eq. (3) from the logged torques)
    """

    lt: dict[str, Any]
    eng: Engine
    robot: Any
    inputs: Inputs
    q0: np.ndarray
    sigma: np.ndarray
    dt: float
    period: int
    still_after: int
    ramp_n: int
    dither: bool
    fhat: np.ndarray
    flo: np.ndarray
    fhi: np.ndarray
    v: np.ndarray
    q_ref: np.ndarray
    still: int
    source: _LoggedSource | None = None

    @classmethod
    def start(
        cls,
        params: dict[str, Any],
        eng: Engine,
        robot: Any,
        arm_push: np.ndarray,
        fscale: np.ndarray,
        noise_rng: np.random.Generator,
        dither: bool,
    ) -> Admittance:
        """The controller at the start of a run: standing at the pose ``pose.q0``, no dither
        for the first second; ``arm_push`` (N, 6) [N, N·m] is the wrench reaching the arm,
        ``fscale`` (N, n) [-] the friction factor, the torque noise drawn from ``noise_rng``."""
        lt = params["lead_through"]
        fs_hz = float(params["timing"]["sample_rate_hz"])
        N, n = len(arm_push), robot.n
        sigma = params["noise"]["tau_sigma_fraction"] * eng.fs
        q0 = np.asarray(params["pose"]["q0"], dtype=float)[:n]
        inputs = Inputs(
            push=np.ascontiguousarray(arm_push),
            tau_ext=np.zeros((N, n)),
            q_ref=np.tile(q0, (N, 1)),
            dq_ref=np.zeros((N, n)),
            kp_on=np.ones(N),
            dither_cmd=np.zeros(N),
            fscale=np.ascontiguousarray(fscale),
            noise=noise_rng.normal(size=(N, n)) * sigma,
        )
        still_after = int(lt["still_s"] * fs_hz)
        return cls(
            lt=lt,
            eng=eng,
            robot=robot,
            inputs=inputs,
            q0=q0,
            sigma=sigma,
            dt=1.0 / fs_hz,
            period=max(1, round(2 * np.pi / params["dither"]["frequency"] * fs_hz)),
            still_after=still_after,
            ramp_n=int(round(float(params["dither"]["ramp_s"]) * fs_hz)),
            dither=dither,
            fhat=np.zeros((N, 3)),
            flo=np.full((N, 3), np.nan),
            fhi=np.full((N, 3), np.nan),
            v=np.zeros(3),
            q_ref=q0.copy(),
            still=still_after if dither else 0,
        )

    @property
    def interval_law(self) -> bool:
        """The interval law drives the admittance (else the dead zone)."""
        return self.lt["law"] == "interval"

    def control(self, k0: int, k1: int, state: dict[str, np.ndarray], out: np.ndarray) -> None:
        """The engine's chunk callback after samples ``k0 .. k1`` (``out`` (N_OUT, N, n), the
        run's raw outputs; ``state`` the engine's): estimate the push at the chunk's last sample
        (eq. (3), or the external :attr:`source`), command the next chunk's joint rates, switch
        the dither."""
        k = k1 - 1
        if self.source is None:
            tau_bar, half, J = self._residual(out, k)
            p_hat, p_lo, p_hi = self._estimate(tau_bar, half, J)
        else:
            p_hat, p_lo, p_hi = self.source(out, k0, k1)
            J = self.robot.evaluate(out[K.O_QM, k], ["jacobian"], reference=True)["jacobian"]
        v = self._tool_velocity(p_hat, p_lo, p_hi, k0, k1)
        self._command_joints(v, J, k0, k1)
        if self.dither:
            self._switch_dither(v, k0, k1)

    def _residual(self, out: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At sample ``k``: the torque less gravity (and less the sliding friction of moving
        joints) (n,) [N·m], the friction band's half-width (n,) [N·m] (0 moving) and the
        Jacobian (1, 6, n)."""
        fs = self.eng.fs
        q, dq = out[K.O_QM, k], out[K.O_VM, k]
        lo = max(0, k - self.period + 1)
        # the extraction once the dither has ramped in: on for its ramp and a whole period (while
        # it ramps the centre term moves the extracted signal, which would read as a push)
        settled = max(0, k - self.ramp_n - self.period + 1)
        whole = k - settled + 1 == self.ramp_n + self.period
        if whole and (out[K.O_DITHER, settled : k + 1, 0] > 0.5).all():
            w = out[K.O_TAU, lo : k + 1]
            c = w.mean(axis=0)
            up = np.where(w > c, w, 0).sum(0) / np.maximum((w > c).sum(0), 1)
            low = np.where(w < c, w, 0).sum(0) / np.maximum((w < c).sum(0), 1)
            tau = 0.5 * (up + low)
            half = np.clip(fs - out[K.O_AMEAS, k], 0.05 * fs, fs)
        else:
            tau = out[K.O_TAU, k]
            half = fs.copy()
        # moving: the mean velocity over the last dither period (the dither's vibration averages
        # out) or the commanded velocity
        moving = (np.abs(out[K.O_VM, lo : k + 1].mean(axis=0)) > 0.005) | (
            np.abs(self.inputs.dq_ref[k]) > 0.002
        )
        dq = np.where(moving, dq, 0.0)
        geo = self.robot.evaluate(q, ["gravity", "jacobian"], reference=True)  # as the plant's
        tau_bar = tau - geo["gravity"][0]
        tau_bar = tau_bar - np.where(moving, self.eng.fc * np.sign(dq) + self.eng.fv * dq, 0.0)
        return tau_bar, np.where(moving, 0.0, half), geo["jacobian"]

    def _estimate(
        self, tau_bar: np.ndarray, half: np.ndarray, J: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The push on the tool (3,) [N] estimated by eq. (3) from the residual torque
        ``tau_bar`` (n,) [N·m], the band's half-width ``half`` (n,) [N·m] and the Jacobian ``J``
        (1, 6, n), and with the interval law its interval (3,), (3,) [N] (else None, None)."""
        lt = self.lt
        args = (tau_bar[None], J, -half, half, self.sigma, np.zeros(6), np.array(PRIOR_SIGMA))
        if not self.interval_law:
            sol = estimate(*args, components=("f_x", "f_y", "f_z"))
            return -sol.F[0, :3], None, None  # the push on the tool
        prob = problem(*args, components=("f_x", "f_y", "f_z"))
        sol = solve(prob)
        lo, hi = intervals(prob, sol.F, lt["interval"], lt["level"])
        return -sol.F[0, :3], -hi[0, :3], -lo[0, :3]  # the push and its interval

    def _tool_velocity(
        self,
        p_hat: np.ndarray,
        p_lo: np.ndarray | None,
        p_hi: np.ndarray | None,
        k0: int,
        k1: int,
    ) -> np.ndarray:
        """The commanded tool velocity (3,) [m/s] from the estimated push ``p_hat`` (3,) [N]
        (and its interval ``p_lo``, ``p_hi`` (3,) [N] for the interval law), recorded for
        samples ``k0 .. k1``, through the admittance law, limited to ``max_speed`` and
        smoothed by the impedance's first-order filter."""
        lt = self.lt
        v = np.zeros(3)
        if self.interval_law:
            self.flo[k0:k1], self.fhi[k0:k1] = p_lo, p_hi
            v = lt["admittance"] * interval_command(p_lo, p_hi)
        else:
            mag = vector_norm(p_hat)
            if mag > lt["dead_zone"]:
                v = lt["admittance"] * (mag - lt["dead_zone"]) * p_hat / mag
        self.fhat[k0:k1] = p_hat
        speed = vector_norm(v)
        if speed > lt["max_speed"]:
            v *= lt["max_speed"] / speed
        # the impedance's own first-order smoothing (time constant `smoothing_s`) keeps the
        # accelerations, which the static estimator reads as force, small
        a = min(1.0, (k1 - k0) * self.dt / max(lt["smoothing_s"], 1e-9))
        self.v = self.v + a * (v - self.v)
        return self.v

    def _command_joints(self, v: np.ndarray, J: np.ndarray, k0: int, k1: int) -> None:
        """The next chunk (as long as this one) follows the tool velocity ``v`` (3,) [m/s]
        without turning: joint rates and the ramped motor-angle reference from sample ``k1``."""
        # the joint rates of the tool velocity in compiled loops, independent of the BLAS kernel
        # (J⁻¹: the pseudo-inverse's answer for a square J of full rank; LAPACK's pinv where the
        # Jacobian is not square or the pose is singular)
        target = np.r_[v, 0.0, 0.0, 0.0]
        Jq = np.ascontiguousarray(J[0])
        dq_ref = lu_solve(Jq, target) if Jq.shape[0] == Jq.shape[1] else None
        if dq_ref is None:
            dq_ref = np.linalg.pinv(Jq) @ target
        inputs, dt = self.inputs, self.dt
        N = len(inputs.q_ref)
        k2 = min(N, k1 + (k1 - k0))
        for kk in range(k1, k2):
            inputs.q_ref[kk] = self.q_ref + dq_ref * dt * (kk - k1)
            inputs.dq_ref[kk] = dq_ref
        self.q_ref = self.q_ref + dq_ref * dt * (k2 - k1)
        if k2 < N:
            inputs.q_ref[k2:] = self.q_ref

    def _switch_dither(self, v: np.ndarray, k0: int, k1: int) -> None:
        """The dither off from sample ``k1`` while the tool is commanded to move faster than
        ``dither_off_speed``, back on after ``still_s`` without such motion."""
        if vector_norm(v) > self.lt["dither_off_speed"]:
            self.still = 0
        else:
            self.still += k1 - k0
        on = self.still >= self.still_after
        self.inputs.dither_cmd[k1:] = 1.0 if on else 0.0
