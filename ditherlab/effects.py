"""The physical effects a torque model is made of: a library of named terms, fitted to residuals.

The base model is ``tau = tau_grav(q) + J(q)^T F + tau_f + e`` (DESIGN.md). Each named effect adds
a torque with a physical form, driven by logged variables, with a few parameters:

=======================  ====================================================  ==================
effect                   torque on joint j (the fitted parameters in bold)     driven by
=======================  ====================================================  ==================
``viscous``              **c** · dq                                            dq
``stribeck``             **(Fs - Fc)** · exp(-(dq / **vs**)²) · sign(dq)        dq (moving)
``load_friction``        **k** · (|L| - L_ref) · sign(dq) while moving, and    L = L0 + **c**(1 +
                         the stick band widened by **k** · (|L| - L_ref)       **g**|L0|/fc)sign(dq);
                                                                               L0 = tau_grav +
                                                                               J^T F (+ M ddq moving)
``temperature_friction`` **a** · (x - x_ref) · sign(dq) while moving, and the   temp_j, or
                         band widened by **a** · (x - x_ref); x = temperature   exp(-t / **T**)
                         or exp(-t / T) (time since start, **T** fitted)
``position_ripple``      **A** sin(2π q / **P**) + **B** cos(2π q / **P**)        q (P by a spectral
                                                                               search)
``payload``              Y(q) · (**m**, **m c**): gravity of a mass at the tool   q (gravity
                                                                               regressor)
``attenuation_lag``      the servo shows **g** · lag_L(J^T F(t - **d**))       J^T F
                         instead of J^T F(t): a delay **d** or a first-order
                         lag of **L** samples
``ft_bias``              the sensor reads F + **b**: the true wrench is F - b    F/T columns
``inertia``              **s** · (M(q) ddq)_j + **Jm** · ddq_j                   ddq
=======================  ====================================================  ==================

Friction-type effects (``stribeck``, ``load_friction``, ``temperature_friction``) act as a
sliding torque only in the ``moving`` regime; while the joint sticks, friction is whatever lies in
the band, so there they can only change the band's width. Parameters in bold are fitted by
least squares on the model's residual (nonlinear ones — vs, T, P, d — by a search over a grid, each
grid point a linear least-squares fit), per joint, except ``payload`` and ``ft_bias`` whose
parameters are shared by all joints.

Fitting is *band-aware*: in the ``still`` and ``dither`` regimes the friction band absorbs
whatever lies inside it, so only the part of the residual outside the band counts; in the
``moving`` regime the band collapses onto the sliding friction line and the whole residual about
that line counts (see :func:`band_loss`).

Three functions apply a model's effects in one place for every consumer:
:func:`effects_torque` (torque terms), :func:`external_torque` (``J^T F`` as the servo shows it)
and :func:`sensor_wrench` (F/T columns corrected for a bias). :func:`add_effect` fits one more
effect and returns the model with ``version + 1``. None of this code is shared with the
simulator, whose hidden effects are written in the plant's own terms.
"""

from __future__ import annotations

import abc
import math
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.signal import lfilter, savgol_filter

from ditherlab.errors import ModelError
from ditherlab.model import REGIMES, EffectSpec, TorqueModel
from ditherlab.recording import DITHER, MOVING, STILL, Recording, regimes

__all__ = [
    "EFFECTS",
    "Effect",
    "Scored",
    "Signals",
    "add_effect",
    "band_loss",
    "effect_names",
    "effects_torque",
    "external_torque",
    "fit_effect",
    "get_effect",
    "hyper_params",
    "model_text",
    "scored",
    "sensor_wrench",
    "signals",
    "widening",
]


# ============================================================== per-recording signals
class Signals:
    """Arrays of one recording that effects are driven by, computed once and cached.

    Attributes (all time-first, SI)
    -------------------------------
    t : (N,) [s] ; ts : (N,) [s] time since the first sample
    q, dq, ddq : (N, n) [rad, rad/s, rad/s²]; ``ddq`` is a Savitzky–Golay derivative of ``dq``
        over ~40 ms (plain double differencing amplifies noise by 1/dt²)
    regime : (N, n) int8 (``STILL``, ``DITHER``, ``MOVING``)
    gravity : (N, n) [N·m] ; jac : (N, 6, n) ; mass : (N, n, n) ; regressor : (N, n, 10)
    """

    def __init__(self, rec: Recording):
        self.rec = rec
        self.n = rec.n
        self.t = rec.t
        self.ts = self.t - self.t[0]
        self.q = rec.q
        self.dq = rec.dq
        self.regime = regimes(rec)
        self._cache: dict[str, np.ndarray] = {}

    def _get(self, key: str, make: Callable[[], np.ndarray]) -> np.ndarray:
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    @property
    def moving(self) -> np.ndarray:
        """(N, n) bool: the joint slides (regime MOVING)."""
        return self.regime == MOVING

    @property
    def ddq(self) -> np.ndarray:
        def make() -> np.ndarray:
            N = len(self.t)
            if N < 7:
                return np.zeros_like(self.dq)
            dt = float(np.median(np.diff(self.t)))
            w = max(5, int(round(0.04 / dt)) | 1)
            w = min(w, N - (1 - N % 2))
            return savgol_filter(self.dq, w, 2, deriv=1, delta=dt, axis=0)

        return self._get("ddq", make)

    @property
    def gravity(self) -> np.ndarray:
        return self._get("gravity", lambda: self.rec.robot().gravity(self.q))

    @property
    def jac(self) -> np.ndarray:
        return self._get("jac", lambda: self.rec.robot().jacobian(self.q))

    @property
    def mass(self) -> np.ndarray:
        return self._get("mass", lambda: self.rec.robot().mass_matrix(self.q))

    @property
    def regressor(self) -> np.ndarray:
        return self._get("regressor", lambda: self.rec.robot().gravity_regressor(self.q))

    @property
    def rigid_load(self) -> np.ndarray:
        """(N, n) [N·m]: ``tau_grav + J^T F`` (F from the F/T columns when present), plus
        ``M(q) ddq`` where the joint moves: the torque the links ask of each gear."""

        def make() -> np.ndarray:
            L = self.gravity.copy()
            if self.rec.has_wrench:
                L += self.jtf(self.rec.wrench)
            Mddq = np.einsum("tjk,tk->tj", self.mass, self.ddq)
            return L + np.where(self.moving, Mddq, 0.0)

        return self._get("rigid_load", make)

    @property
    def torque_regressor(self) -> np.ndarray:
        """(N, n, 10): :meth:`ditherlab.robot.RobotModel.torque_regressor` with ``dq`` and
        ``ddq`` of joints that are not moving set to 0 (standing still: the gravity regressor)."""

        def make() -> np.ndarray:
            mv = self.moving
            return self.rec.robot().torque_regressor(
                self.q, np.where(mv, self.dq, 0.0), np.where(mv, self.ddq, 0.0)
            )

        return self._get("torque_regressor", make)

    def wrench(self, what: str) -> np.ndarray:
        """The raw F/T columns (N, 6); ModelError naming the column when absent."""
        w = self.rec.wrench
        if w is None:
            raise ModelError(
                f"{_where(self.rec)}effect {what!r} needs the F/T sensor column f_x "
                "(f_x..m_z), which the recording lacks"
            )
        return w

    def wrench_lp(self, what: str) -> np.ndarray:
        """The F/T columns low-passed (N, 6): see :func:`smooth_wrench`."""
        w = self.wrench(what)
        return self._get("wrench_lp", lambda: smooth_wrench(w, self.rec.sample_rate))

    def jtf(self, F: np.ndarray) -> np.ndarray:
        """``J^T F`` : (N, n) [N·m] for a wrench F : (N, 6)."""
        return np.einsum("tkn,tk->tn", self.jac, F)


_SIGNALS: weakref.WeakKeyDictionary[Recording, Signals] = weakref.WeakKeyDictionary()


#: low-pass window for the F/T sensor in residuals [s]
WRENCH_SMOOTH_S = 0.1


def smooth_wrench(
    F: np.ndarray, sample_rate: float, window_s: float = WRENCH_SMOOTH_S
) -> np.ndarray:
    """F/T columns ``F`` (N, 6) [N, N·m] low-passed by a quadratic Savitzky–Golay filter over
    ``window_s`` [s] (its noise std falls about 3× for 0.1 s at 250 Hz).

    Why: the sensor's white noise enters the torque residual through ``J^T F``; unfiltered, any
    effect that scales ``J^T F`` (``attenuation_lag`` with a gain below 1) "explains" that noise
    (errors in variables). Pushes and contacts last far longer than the window.
    """
    w = int(round(window_s * sample_rate)) | 1
    if w < 5 or len(F) <= w:
        return np.asarray(F, dtype=float)
    return savgol_filter(np.asarray(F, dtype=float), w, 2, axis=0)


def signals(rec: Recording) -> Signals:
    """The cached :class:`Signals` of a recording (robot quantities computed once)."""
    s = _SIGNALS.get(rec)
    if s is None:
        s = Signals(rec)
        _SIGNALS[rec] = s
    return s


def _where(rec: Recording) -> str:
    return f"{rec.name}: " if rec.name else ""


def _sgn(x: np.ndarray) -> np.ndarray:
    return np.sign(x)


# ============================================================== effect definitions
@dataclass(frozen=True)
class Design:
    """The linear part of an effect on one joint (or all joints, for shared parameters).

    ``shift = centre @ w + offset`` moves the predicted torque; ``widen @ w`` widens the stick
    band's half-width (still/dither regimes only). Shapes: (N, k) per joint, (N, n, k) shared.
    """

    centre: np.ndarray
    widen: np.ndarray | None = None
    offset: np.ndarray | None = None


class Effect(abc.ABC):
    """One named physical effect: its form, driving variables, parameters, fit and predict.

    Subclasses define :meth:`design` (the torque per unit linear parameter for a given value of
    the nonlinear parameter ``h``), :meth:`grid` (the values of ``h`` searched), and how
    parameters are named in the model file.
    """

    name: str = ""
    physics: str = ""
    driven_by: str = ""
    #: True: one parameter vector shared by all joints (payload, ft_bias).
    shared: bool = False
    #: Linear parameter names (per joint when not shared).
    linear: tuple[str, ...] = ()
    #: Name of the searched nonlinear parameter, or None; a tuple names the parts of a
    #: searched tuple (``attenuation_lag``: delay and lag).
    hyper: str | tuple[str, ...] | None = None
    #: The searched parameter is a continuous number, refined after the grid search.
    continuous: bool = False
    #: Which consumer applies it: "torque" (effects_torque), "external", "sensor".
    kind: str = "torque"
    #: Regimes in which the effect can be seen (documentation and diagnosis text).
    shows_in: tuple[str, ...] = REGIMES

    # -- to implement
    @abc.abstractmethod
    def design(self, sig: Signals, j: int | None, h: Any, ref: dict[str, Any]) -> Design:
        """The effect's :class:`Design` on joint j (None: all joints) for nonlinear value h."""

    def grid(self, sig: Sequence[Signals], j: int | None) -> list[Any]:
        return [None]

    def reference(self, sig: Sequence[Signals], j: int | None) -> dict[str, Any]:
        """Fixed reference values of the driving variable (computed from the data, not the
        residual), e.g. the mean load; stored with the parameters."""
        return {}

    def check(self, sig: Signals) -> None:
        """Raise ModelError naming a column the effect needs but the recording lacks."""
        return None

    def shortlist(
        self, sc: Sequence[Scored], j: int | None, grid: list[Any], masks: list[np.ndarray]
    ) -> list[list[Any]]:
        """For each boolean training mask over the stacked samples, the grid values worth a full
        fit (default: the whole grid). Long grids override this with a fast pre-screen."""
        return [list(grid) for _ in masks]

    def signs(self, h: Any) -> tuple[int, ...]:
        """Physical sign of each linear parameter: +1 (>= 0), -1 (<= 0) or 0 (free)."""
        return (0,) * self.k

    def driver(self, sig: Signals, j: int, p: dict[str, Any]) -> tuple[np.ndarray, str]:
        """The driving variable of joint j (N,) and its axis label, for evidence plots."""
        return sig.dq[:, j], f"dq_{j + 1} [rad/s]"

    def term(self, p: dict[str, Any], j: int) -> str:
        """The effect's term in the printed equation of joint j (0-based)."""
        return self.name

    @property
    def k(self) -> int:
        return len(self.linear)


def _mm(W: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``W.T @ X`` for tall skinny matrices without BLAS threads (which oversubscribe a shared
    two-core machine and run ~10x slower than this single-threaded loop)."""
    return np.einsum("mf,mp->fp", W, X)


def _fmt(x: float) -> str:
    return f"{x:.3g}"


class Viscous(Effect):
    name = "viscous"
    physics = "torque proportional to velocity (lubricant shear)"
    driven_by = "dq"
    linear = ("coef",)
    shows_in = ("moving",)

    def design(self, sig, j, h, ref):
        return Design(sig.dq[:, j : j + 1])

    def term(self, p, j):
        return f"{_fmt(p['coef'])}·viscous(dq_{j + 1})"


class Stribeck(Effect):
    name = "stribeck"
    physics = "friction higher near zero speed, decaying with speed (Stribeck curve)"
    driven_by = "dq (moving)"
    linear = ("fs_minus_fc",)
    hyper = "vs"
    shows_in = ("moving",)

    def signs(self, h):
        return (1,)  # friction is *higher* near zero speed

    def design(self, sig, j, h, ref):
        dq = sig.dq[:, j]
        c = np.exp(-((dq / h) ** 2)) * _sgn(dq) * sig.moving[:, j]
        return Design(c[:, None])

    def grid(self, sig, j):
        v = np.concatenate([np.abs(s.dq[s.moving[:, j], j]) for s in sig])
        hi = float(np.quantile(v, 0.9)) if v.size else 1.0
        hi = max(hi, 1e-3)
        return list(np.geomspace(hi / 100, hi, 16))

    def driver(self, sig, j, p):
        return sig.dq[:, j], f"dq_{j + 1} [rad/s]"

    def term(self, p, j):
        return f"{_fmt(p['fs_minus_fc'])}·stribeck(dq_{j + 1}, vs={_fmt(p['vs'])})"


class LoadFriction(Effect):
    """Friction that grows with the torque the gear transmits (the mesh's normal force).

    The gear torque is not logged; it is the torque the links ask of the gear,
    ``L = |L0 + c·(1 + g·|L0|/fc)·sign(dq)|`` with ``L0 = tau_grav + J^T F + M(q) ddq``:
    gravity and the external wrench, the links' inertia torque while moving, and the friction
    on the gear's *output* side (bearings after the gear), which the teeth also carry in the
    direction of motion: ``c`` [N·m] at no load, growing by the relative rate ``g / fc`` per
    N·m of load like the joint's friction itself (``fc`` [N·m]: the joint's sliding friction
    level in the data, the median ``|tau - tau_grav - J^T F|`` while moving). ``c`` and ``g``
    are searched on a grid; while the joint sticks the split of the held friction is unknown and
    ``L = |tau_grav + J^T F|``. All terms are the model's, never the measured torque: a load
    taken from the measured torque contains the residual itself, and then "explains" any
    missing effect (a payload, a ripple) through ``k·|tau|``.

    Measured on the simulator's 3-pose excitation (0.15 N·m of band per N·m of gear torque,
    joint 2 loads up to 170 N·m): after fitting, the rigid-body load ``|tau_grav + J^T F|``
    leaves joint 2 at 2.6x the noise floor, ``+ M ddq + c·sign(dq)`` at 1.26x (and a payload is
    then wrongly suggested), the growing output friction at 0.85x.
    """

    name = "load_friction"
    physics = "Coulomb friction and the stick band grow with the torque the gear transmits"
    driven_by = "|L0 + c·(1 + g·|L0|/fc)·sign(dq)|, L0 = tau_grav + J^T F + M ddq; sign(dq)"
    linear = ("k",)
    hyper = ("output_friction", "output_growth")
    shows_in = ("moving", "still", "dither")

    def signs(self, h):
        return (1,)  # friction grows with load

    @staticmethod
    def load(sig: Signals, j: int, h: Any = None, fc: float = 1.0) -> np.ndarray:
        """(N,) [N·m]: the gear torque of joint j for ``h = (c [N·m], g [-])`` (None: no
        output-side friction) and the friction level ``fc`` [N·m]."""
        c, g = h if h is not None else (0.0, 0.0)
        L = sig.rigid_load[:, j].copy()
        mv = sig.moving[:, j]
        if c:
            grow = 1.0 + (g or 0.0) * np.abs(L[mv]) / max(fc, 1e-9)
            L[mv] += c * grow * _sgn(sig.dq[mv, j])
        return np.abs(L)

    @staticmethod
    def level(sig: Sequence[Signals], j: int) -> float:
        """[N·m]: the joint's sliding friction level, median |tau - tau_grav - J^T F| moving."""
        parts = []
        for s in sig:
            mv = s.moving[:, j]
            r = s.rec.tau[mv, j] - s.gravity[mv, j]
            if s.rec.has_wrench:
                r = r - s.jtf(s.rec.wrench)[mv, j]
            parts.append(np.abs(r))
        v = np.concatenate(parts)
        return float(np.median(v)) if v.size else 0.0

    def grid(self, sig, j):
        fc = self.level(sig, j)
        cs = [float(x) for x in fc * np.linspace(0.0, 1.0, 9)]
        return [(0.0, 0.0)] + [(c, g) for c in cs[1:] for g in (0.0, 0.1, 0.2, 0.3)]

    def reference(self, sig, j):
        return {
            "load_ref": float(np.mean(np.concatenate([self.load(s, j) for s in sig]))),
            "friction_level": self.level(sig, j),
        }

    def design(self, sig, j, h, ref):
        x = self.load(sig, j, h, ref.get("friction_level", 1.0)) - ref["load_ref"]
        mv = sig.moving[:, j]
        return Design((x * _sgn(sig.dq[:, j]) * mv)[:, None], (x * ~mv)[:, None])

    def driver(self, sig, j, p):
        h = (p.get("output_friction"), p.get("output_growth"))
        L = self.load(sig, j, h, p.get("friction_level") or 1.0)
        return L, f"|gear torque| joint {j + 1} [N·m]"

    def term(self, p, j):
        c, g = _fmt(p.get("output_friction") or 0.0), _fmt(p.get("output_growth") or 0.0)
        fc = _fmt(p.get("friction_level") or 0.0)
        return (
            f"{_fmt(p['k'])}·load_friction(|L0 + {c}·(1 + {g}·|L0|/{fc})·sign dq|_{j + 1}, "
            f"sign dq_{j + 1})"
        )


class TemperatureFriction(Effect):
    name = "temperature_friction"
    physics = "friction falls as the joint warms up (lubricant viscosity)"
    driven_by = "temp_j, or time since start when no temperature is logged"
    linear = ("coef",)
    hyper = "time_constant"
    shows_in = ("moving", "still", "dither")

    def signs(self, h):
        # falls as the temperature rises; decays with time since start (higher when cold)
        return (-1,) if h is None else (1,)

    @staticmethod
    def _x(sig: Signals, j: int, h: Any) -> np.ndarray:
        if h is None:
            if sig.rec.temp is None:
                raise ModelError(
                    f"{_where(sig.rec)}effect 'temperature_friction' is driven by column "
                    f"temp_{j + 1}, which the recording lacks"
                )
            return sig.rec.temp[:, j]
        return np.exp(-sig.ts / h)

    def check(self, sig):
        return None

    def grid(self, sig, j):
        if all(s.rec.temp is not None for s in sig):
            return [None]
        T = max(s.ts[-1] for s in sig) or 1.0
        return list(np.geomspace(T / 20, 5 * T, 14))

    def reference(self, sig, j):
        if all(s.rec.temp is not None for s in sig):
            return {"x_ref": float(np.mean(np.concatenate([s.rec.temp[:, j] for s in sig])))}
        return {"x_ref": None}

    def design(self, sig, j, h, ref):
        x = self._x(sig, j, h)
        xr = ref["x_ref"] if ref.get("x_ref") is not None else float(np.mean(x))
        x = x - xr
        mv = sig.moving[:, j]
        return Design((x * _sgn(sig.dq[:, j]) * mv)[:, None], (x * ~mv)[:, None])

    def driver(self, sig, j, p):
        if p.get("time_constant") is None and sig.rec.temp is not None:
            return sig.rec.temp[:, j], f"temp_{j + 1} [°C]"
        return sig.ts, "time since start [s]"

    def term(self, p, j):
        if p.get("time_constant") is None:
            return f"{_fmt(p['coef'])}·temperature_friction(temp_{j + 1})"
        return f"{_fmt(p['coef'])}·temperature_friction(exp(-t/{_fmt(p['time_constant'])} s))"


class PositionRipple(Effect):
    name = "position_ripple"
    physics = "periodic torque in joint angle (gear teeth, cogging)"
    driven_by = "q, period found by a least-squares periodogram"
    linear = ("a_sin", "b_cos", "a2_sin", "b2_cos")
    hyper = "period"
    continuous = True
    shows_in = ("moving",)

    def design(self, sig, j, h, ref):
        # fundamental and second harmonic (tooth meshing is rarely a pure sine)
        ph = 2 * np.pi * sig.q[:, j] / h
        return Design(np.column_stack([np.sin(ph), np.cos(ph), np.sin(2 * ph), np.cos(2 * ph)]))

    def grid(self, sig, j):
        q = np.concatenate([s.q[s.moving[:, j], j] for s in sig])
        if q.size < 10:
            return [2 * np.pi]
        span = float(q.max() - q.min())
        step = float(np.median(np.concatenate([np.abs(np.diff(s.q[:, j])) for s in sig])))
        lo = max(8 * step, span / 400, 1e-3)
        hi = max(span / 1.5, lo * 1.01)
        # periodogram resolution: neighbouring frequencies differ by < 1/4 cycle over the span
        n = int(min(600, max(16, 4 * span / lo)))
        return list(1.0 / np.geomspace(1 / lo, 1 / hi, n))

    def shortlist(self, sc, j, grid, masks, keep: int = 3):
        """Least-squares periodogram (Lomb–Scargle without offset) of the moving samples of each
        training set; the ``keep`` periods with the largest weighted variance reduction."""
        if len(grid) <= keep:
            return [list(grid) for _ in masks]
        e = np.concatenate([s.e[s.use[:, j], j] for s in sc])
        q = np.concatenate([s.sig.q[s.use[:, j], j] for s in sc])
        hh = np.concatenate([s.h[s.use[:, j], j] for s in sc])
        wt = 1.0 / np.concatenate([s.sigma[s.use[:, j], j] for s in sc]) ** 2
        lin = hh == 0  # moving samples: plain least squares
        f = 2 * np.pi / np.asarray(grid, dtype=float)
        out = []
        sums = []
        idx = np.flatnonzero(lin)
        # reduce over samples in chunks of periods to bound memory
        parts = {k: [] for k in ("ss", "sc", "cc", "es", "ec")}
        W = np.column_stack([m[idx] * wt[idx] for m in masks])  # (M, F)
        for c0 in range(0, len(f), 100):
            ph = np.outer(q[idx], f[c0 : c0 + 100])
            S, C = np.sin(ph), np.cos(ph)
            ee = e[idx][:, None]
            parts["ss"].append(_mm(W, S * S))
            parts["sc"].append(_mm(W, S * C))
            parts["cc"].append(_mm(W, C * C))
            parts["es"].append(_mm(W, ee * S))
            parts["ec"].append(_mm(W, ee * C))
        sums = {k: np.concatenate(v, axis=1) for k, v in parts.items()}  # (F, P)
        det = sums["ss"] * sums["cc"] - sums["sc"] ** 2
        det = np.where(det > 1e-12 * (sums["ss"] * sums["cc"] + 1e-300), det, np.inf)
        red = (
            sums["cc"] * sums["es"] ** 2
            - 2 * sums["sc"] * sums["es"] * sums["ec"]
            + sums["ss"] * sums["ec"] ** 2
        ) / det
        for k in range(len(masks)):
            best = np.argsort(-red[k])[:keep]
            out.append([grid[i] for i in best])
        return out

    def driver(self, sig, j, p):
        return np.mod(sig.q[:, j], p["period"]), f"q_{j + 1} mod {_fmt(p['period'])} rad"

    def term(self, p, j):
        amp = math.hypot(p["a_sin"], p["b_cos"])
        return f"{_fmt(amp)}·position_ripple(q_{j + 1}, period={_fmt(p['period'])} rad)"


class Payload(Effect):
    """An unmodelled mass at the tool: its gravity torque, and while moving its inertia and
    Coriolis torques (pinocchio's joint-torque regressor of the tool link, linear in the mass
    and its first moments; the point mass's own rotational inertia, ``m·|c|²``, is neglected).
    Measured on the simulator's 3-pose excitation with a 2 kg payload: gravity alone left a
    residual that load_friction was then suggested for (max 1.13x the floor)."""

    name = "payload"
    physics = (
        "an unmodelled mass at the tool: gravity and inertia torques that change with the pose"
    )
    driven_by = "q, dq, ddq (joint-torque regressor of the last link)"
    shared = True
    linear = ("mass", "mc_x", "mc_y", "mc_z")
    shows_in = ("moving", "still", "dither")

    def signs(self, h):
        return (1, 0, 0, 0)

    def design(self, sig, j, h, ref):
        return Design(sig.torque_regressor[:, :, :4])

    def driver(self, sig, j, p):
        w = np.array([p["mass"], *p["mass_com"]])
        return sig.torque_regressor[:, j, :4] @ w, f"payload torque joint {j + 1} [N·m]"

    def term(self, p, j):
        c = ", ".join(_fmt(x / p["mass"]) if p["mass"] else "0" for x in p["mass_com"])
        return f"payload(m={_fmt(p['mass'])} kg, com=[{c}] m)"


class AttenuationLag(Effect):
    """The servo shows ``gain`` of the external torque, late: ``J^T F`` delayed by ``delay``
    samples (a transport delay: communication, a filter with a flat group delay) and passed
    through a first-order lag of ``lag`` samples (a compliant mount or a force loop: a spring and
    damper in series with the tool), ``gain · lag(J^T F(t - delay))``.

    Both are searched, each on its own grid with the other zero (a pure delay or a pure lag),
    and the one that fits best is kept. Measured on the simulator (70 % of the push reaching the
    arm through a 0.15 s first-order lag, pushes up to 50 N while moving): the best pure delay
    (0.12 s, gain 0.61) leaves joint 2 at 1.33x the noise floor, the first-order lag (0.152 s,
    gain 0.68-0.72) at 0.85x.
    """

    name = "attenuation_lag"
    physics = "the servo shows only part of the external torque, and late"
    driven_by = "J^T F (F/T sensor), delay or first-order lag searched"
    linear = ("gain",)
    hyper = ("delay", "lag")
    kind = "external"
    shows_in = ("still", "dither", "moving")

    def signs(self, h):
        return (1,)

    def check(self, sig):
        sig.wrench(self.name)

    @staticmethod
    def delayed(sig: Signals, X: np.ndarray, h: Any) -> np.ndarray:
        """``X`` (N,) delayed by ``h[0]`` samples and low-passed by a first-order lag of time
        constant ``h[1]`` samples (None in either: 0), started at rest at ``X[0]``."""
        d, lag = int(h[0] or 0), float(h[1] or 0.0)
        out = X
        if d > 0:
            out = np.empty_like(X)
            out[d:] = X[:-d]
            out[:d] = X[:1]
        if lag > 0:
            a = 1.0 / (lag + 1.0)  # backward Euler of T dy/dt = x - y, T = lag samples
            out, _ = lfilter([a], [1.0, a - 1.0], out, zi=[out[0] * (1.0 - a)])
        return out

    def grid(self, sig, j):
        fs = sig[0].rec.sample_rate
        kmax = max(int(round(0.3 * fs)), 2)
        ks = sorted(set(np.unique(np.round(np.geomspace(1, kmax, 20)).astype(int))))
        return [(0, 0)] + [(k, 0) for k in ks] + [(0, k) for k in ks]

    def design(self, sig, j, h, ref):
        X = sig.jtf(sig.wrench_lp(self.name))[:, j]
        return Design(self.delayed(sig, X, h)[:, None], offset=-X)

    def driver(self, sig, j, p):
        return sig.jtf(sig.wrench_lp(self.name))[:, j], f"(J^T F)_{j + 1} [N·m]"

    def term(self, p, j):
        return f"attenuation_lag(gain={_fmt(p['gain'])}, {_late(p)})"


def _late(p: dict[str, Any]) -> str:
    """'delay=D samples' and/or 'lag=L samples' of attenuation_lag parameters ``p``."""
    parts = [f"delay={int(p.get('delay') or 0)} samples"]
    if p.get("lag"):
        parts.append(f"lag={_fmt(p['lag'])} samples")
    return ", ".join(parts)


class FtBias(Effect):
    name = "ft_bias"
    physics = "the reference F/T sensor reads a constant offset"
    driven_by = "J^T (constant in F)"
    shared = True
    linear = ("f_x", "f_y", "f_z", "m_x", "m_y", "m_z")
    kind = "sensor"
    shows_in = ("still", "dither", "moving")

    def check(self, sig):
        sig.wrench(self.name)

    def design(self, sig, j, h, ref):
        sig.wrench(self.name)
        return Design(-sig.jac.transpose(0, 2, 1))

    def driver(self, sig, j, p):
        b = np.array([p[c] for c in self.linear])
        return -(sig.jac[:, :, j] @ b), f"-(J^T bias)_{j + 1} [N·m]"

    def term(self, p, j):
        b = ", ".join(_fmt(p[c]) for c in self.linear)
        return f"ft_bias([{b}])"


class Inertia(Effect):
    name = "inertia"
    physics = "dynamic torque M(q)·ddq of the links plus the reflected motor inertia"
    driven_by = "ddq"
    linear = ("scale", "motor_inertia")
    shows_in = ("moving",)

    def signs(self, h):
        return (1, 1)

    def design(self, sig, j, h, ref):
        Mddq = np.einsum("tk,tk->t", sig.mass[:, j, :], sig.ddq)
        return Design(np.column_stack([Mddq, sig.ddq[:, j]]))

    def driver(self, sig, j, p):
        return sig.ddq[:, j], f"ddq_{j + 1} [rad/s²]"

    def term(self, p, j):
        return f"inertia({_fmt(p['scale'])}·M ddq + {_fmt(p['motor_inertia'])}·ddq_{j + 1})"


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        Viscous(),
        Stribeck(),
        LoadFriction(),
        TemperatureFriction(),
        PositionRipple(),
        Payload(),
        AttenuationLag(),
        FtBias(),
        Inertia(),
    )
}


def effect_names() -> list[str]:
    """The names of the effect library, in the order they are tried."""
    return list(EFFECTS)


def get_effect(name: str) -> Effect:
    """The :class:`Effect` called ``name``; ModelError listing the names for an unknown one."""
    if name not in EFFECTS:
        raise ModelError(f"unknown effect {name!r}, expected one of: {', '.join(EFFECTS)}")
    return EFFECTS[name]


# ============================================================== parameters <-> specs
#: data-derived reference values stored with an effect's parameters
REF_KEYS = ("load_ref", "friction_level", "x_ref")


def _spec_params(e: Effect, j: int, spec: EffectSpec) -> tuple[np.ndarray, Any, dict]:
    """(w, h, ref) of joint j (0-based) from a model's EffectSpec."""
    p = spec.params
    if e.shared:
        if e.name == "payload":
            w = np.array([p["mass"], *p["mass_com"]], dtype=float)
        else:
            w = np.array([p[c] for c in e.linear], dtype=float)
        return w, None, {}
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
        return {name: _plain_h(v) for name, v in zip(e.hyper, h, strict=True)}
    return {e.hyper: _plain_h(h)}


def _joint_params(spec: EffectSpec, j: int) -> dict[str, Any]:
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


def _make_spec(e: Effect, fits: dict[int, FitResult]) -> EffectSpec:
    """An EffectSpec from per-joint fits (0-based joint -> FitResult), lists per joint."""
    if e.shared:
        f = fits[-1]
        if e.name == "payload":
            params: dict[str, Any] = {
                "mass": float(f.w[0]),
                "mass_com": [float(x) for x in f.w[1:]],
            }
        else:
            params = {c: float(v) for c, v in zip(e.linear, f.w, strict=True)}
        return EffectSpec(e.name, [], params)
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


def _plain_h(h: Any) -> Any:
    if h is None:
        return None
    if isinstance(h, int | np.integer):
        return int(h)
    return float(h)


def _clean_none(spec: EffectSpec) -> EffectSpec:
    # TOML has no null: drop parameters that are all None (e.g. time_constant with a temp column)
    p = {
        k: v
        for k, v in spec.params.items()
        if not (v is None or (isinstance(v, list) and all(x is None for x in v)))
    }
    return EffectSpec(spec.name, spec.joints, p)


# ============================================================== applying a model's effects
def _shift(e: Effect, sig: Signals, spec: EffectSpec) -> np.ndarray:
    """(N, n) [N·m]: the torque shift one effect spec predicts on a recording."""
    out = np.zeros((len(sig.t), sig.n))
    if e.shared:
        w, h, ref = _spec_params(e, 0, spec)
        d = e.design(sig, None, h, ref)
        out += d.centre @ w
        if d.offset is not None:
            out += d.offset
        return out
    for jj in spec.joints:
        j = jj - 1
        if j >= sig.n:
            continue
        w, h, ref = _spec_params(e, j, spec)
        d = e.design(sig, j, h, ref)
        out[:, j] += d.centre @ w + (d.offset if d.offset is not None else 0.0)
    return out


def _check_model_effects(model: TorqueModel, rec: Recording) -> None:
    sig = signals(rec)
    for spec in model.effects:
        get_effect(spec.name).check(sig)


def effects_torque(model: TorqueModel, rec: Recording, *, sensor: bool = True) -> np.ndarray:
    """Sum of the model's torque effects (those driven by q, dq, ddq, temperature or time).

    Parameters
    ----------
    model : TorqueModel
    rec : Recording
    sensor : let effects read the F/T columns (``load_friction``'s load ``J^T F``). False for
        the force estimator (replay, the diagnosis's force error): a sensorless estimate must not
        see the sensor, and the load is then the model's ``tau_grav + M ddq`` part alone.

    Returns
    -------
    (N, n) [N·m]; zeros when the model has none.
    """
    full = signals(rec)
    sig = full if sensor or not rec.has_wrench else _without_sensor(full)
    out = np.zeros((len(rec), rec.n))
    for spec in model.effects:
        e = get_effect(spec.name)
        e.check(full)
        if e.kind == "torque":
            out += _shift(e, sig, spec)
    return out


#: Signals cache entries computed from the F/T columns
SENSOR_KEYS = ("wrench_lp", "rigid_load")


class _NoSensor:
    """A recording seen without its F/T columns (everything else delegated)."""

    has_wrench = False
    wrench = None

    def __init__(self, rec: Recording):
        self._rec = rec

    def __getattr__(self, name: str) -> Any:
        return getattr(self._rec, name)


def _without_sensor(sig: Signals) -> Signals:
    """``sig`` with the recording's F/T columns hidden; the robot quantities cached in ``sig``
    (gravity, Jacobian, mass matrix, regressors, ddq: none depends on the wrench) are shared."""
    out = Signals.__new__(Signals)
    out.__dict__.update(sig.__dict__)
    out.rec = _NoSensor(sig.rec)  # type: ignore[assignment]
    out._cache = {k: v for k, v in sig._cache.items() if k not in SENSOR_KEYS}
    return out


def widening(model: TorqueModel, rec: Recording) -> np.ndarray:
    """How much the model's effects widen the stick band's half-width, per sample.

    Non-zero only for ``load_friction`` and ``temperature_friction`` in the still and dither
    regimes: use ``[tau_min - w, tau_max + w]`` as the band there.

    Returns
    -------
    (N, n) [N·m]
    """
    sig = signals(rec)
    out = np.zeros((len(rec), rec.n))
    for spec in model.effects:
        e = get_effect(spec.name)
        if e.shared or e.kind != "torque":
            continue
        for jj in spec.joints:
            j = jj - 1
            w, h, ref = _spec_params(e, j, spec)
            d = e.design(sig, j, h, ref)
            if d.widen is not None:
                out[:, j] += d.widen @ w
    return out


def external_torque(model: TorqueModel, rec: Recording, F: np.ndarray) -> np.ndarray:
    """``J^T F`` as the servo shows it: with the model's ``attenuation_lag`` when present.

    Parameters
    ----------
    model : TorqueModel
    rec : Recording
    F : (N, 6) [N, N·m], wrench at the tool point in base axes

    Returns
    -------
    (N, n) [N·m]: per joint with ``attenuation_lag``, ``gain · lag((J^T F)(t - delay))``; else
    ``J^T F``.
    """
    sig = signals(rec)
    X = sig.jtf(np.asarray(F, dtype=float))
    out = X.copy()
    for spec in model.effects:
        if spec.name != "attenuation_lag":
            continue
        for jj in spec.joints:
            j = jj - 1
            w, h, _ = _spec_params(EFFECTS["attenuation_lag"], j, spec)
            out[:, j] = w[0] * AttenuationLag.delayed(sig, X[:, j], h)
    return out


def sensor_wrench(model: TorqueModel, rec: Recording) -> np.ndarray:
    """The F/T columns corrected by the model's ``ft_bias`` when present.

    Returns
    -------
    (N, 6) [N, N·m]; ModelError when the recording has no F/T columns.
    """
    sig = signals(rec)
    F = sig.wrench("sensor_wrench").copy()
    for spec in model.effects:
        if spec.name == "ft_bias":
            b = np.array([spec.params[c] for c in FtBias.linear], dtype=float)
            F -= b
    return F


# ============================================================== the band-aware residual
@dataclass
class Scored:
    """The band-aware residual of one recording under a model, ready for fitting.

    Attributes
    ----------
    sig : Signals
    e : (N, n) [N·m] residual about the band centre (moving: about the sliding friction line)
    h : (N, n) [N·m] half-width of the band that absorbs it (0 in the moving regime)
    sigma : (N, n) [N·m] noise level of each sample's regime
    use : (N, n) bool, samples that are scored
    tau : (N, n) [N·m] the torque used (the dither-extracted signal in the dither regime)
    """

    sig: Signals
    e: np.ndarray
    h: np.ndarray
    sigma: np.ndarray
    use: np.ndarray
    tau: np.ndarray
    notes: list[str] = field(default_factory=list)
    sigma_hf: np.ndarray | None = None
    #: the model's moving band has (coulomb, viscous): identification re-fits them
    sliding: tuple[bool, bool] = (False, False)

    def excess(
        self, shift: np.ndarray | None = None, widen: np.ndarray | None = None
    ) -> np.ndarray:
        """(N, n) [N·m]: the signed part of ``e - shift`` outside the band (0 inside)."""
        x = self.e if shift is None else self.e - shift
        hh = self.h if widen is None else np.maximum(self.h + widen, 0.0)
        return np.sign(x) * np.maximum(np.abs(x) - hh, 0.0)


def _dither_signal(rec: Recording) -> tuple[np.ndarray, np.ndarray] | None:
    """The paper's extracted dither signal (N, n) and its validity (N,), or None."""
    try:
        from ditherlab.replay import extract_dither
    except ImportError:
        return None
    sig = extract_dither(rec)
    if sig is None:
        return None
    return np.asarray(sig.signal, dtype=float), np.asarray(sig.valid, dtype=bool)


def scored(
    model: TorqueModel, rec: Recording, *, use_sensor: bool = True, min_samples: int = 200
) -> Scored:
    """The band-aware residual ``rho = tau - gravity - effects - J^T F`` of a recording.

    Per regime: in ``still`` and ``dither`` the stick band ``[tau_min, tau_max]`` (widened by the
    model's load/temperature effects) absorbs whatever lies inside it; in ``moving`` the band
    collapses onto the sliding friction ``coulomb·sign(dq) + viscous·dq`` (when the model has
    them) plus one offset in ``[tau_min, tau_max]`` (the data's mean offset, clipped into the
    band), and the whole residual about that line counts. In the dither regime the torque is the
    paper's extracted signal (:func:`ditherlab.replay.extract_dither`); without it dither samples
    are not scored.

    Parameters
    ----------
    model : TorqueModel
    rec : Recording
    use_sensor : subtract ``external_torque(sensor_wrench)`` (needs F/T columns); when False or
        absent, the residual contains the external torque (free-motion logs have none).
    min_samples : a joint's regime with fewer samples in this recording is not scored (as in
        :func:`ditherlab.identify.identify`).

    Raises
    ------
    ModelError
        When the recording contains a regime the model has no band for.
    """
    sig = signals(rec)
    if model.n != rec.n:
        raise ModelError(
            f"{_where(rec)}the recording has {rec.n} joints, the model {model.n}; expected the same robot"
        )
    _check_model_effects(model, rec)
    reg = sig.regime
    names = {STILL: "still", DITHER: "dither", MOVING: "moving"}
    tau = rec.tau.copy()
    notes: list[str] = []
    use = np.ones(tau.shape, dtype=bool)
    if (reg == DITHER).any():
        ext = _dither_signal(rec)
        if ext is None:
            use &= reg != DITHER
            notes.append("dither samples not scored (no dither extraction for this recording)")
        else:
            tau = np.where(reg == DITHER, ext[0], tau)
            # the first dither period has no full window
            use &= (reg != DITHER) | ext[1][:, None]
    near = stick_transitions(reg, rec.sample_rate)
    if near.any():
        use &= ~near
        notes.append(
            f"{int(near.sum())} joint-samples within {STICK_SETTLE_S:g} s of a stick not scored"
        )
    # velocity reversals inside a motion: the joint is at rest for a few samples and its
    # friction passes through the static band, neither on the sliding line nor a stick
    rev = (reg == MOVING) & (np.abs(rec.dq) < REVERSAL_V) & use
    if rev.any():
        use &= ~rev
        notes.append(
            f"{int(rev.sum())} joint-samples of velocity reversals (|dq| < {REVERSAL_V:g} rad/s "
            "while moving) not scored"
        )
    rho = tau - sig.gravity - effects_torque(model, rec)
    if use_sensor and rec.has_wrench:
        rho -= external_torque(
            model, rec, smooth_wrench(sensor_wrench(model, rec), rec.sample_rate)
        )
    e = np.zeros_like(rho)
    h = np.zeros_like(rho)
    sigma = np.ones_like(rho)
    for code, name in names.items():
        m = (reg == code) & use
        if not m.any():
            continue
        few = m.sum(axis=0) < min_samples
        if few.any():
            # a handful of samples (e.g. velocity reversals flagged still) is not a regime:
            # identification fits no band from it either
            use &= ~(m & few)
            m &= ~few
            if not m.any():
                continue
        if name not in model.regimes:
            use &= ~m
            notes.append(f"{int(m.any(axis=1).sum())} {name} samples not scored (no band)")
            continue
        b = model.band(name)
        centre = 0.5 * (b.tau_min + b.tau_max)
        half = 0.5 * (b.tau_max - b.tau_min)
        cen = np.broadcast_to(centre, rho.shape).copy()
        if code == MOVING:
            if b.coulomb is not None:
                cen += b.coulomb * np.sign(sig.dq)
            if b.viscous is not None:
                cen += b.viscous * sig.dq
            # the band collapses to one point in [tau_min, tau_max]: the one the data sit at
            # (mean offset from the sliding line, clipped into the band)
            for j in range(rec.n):
                mj = m[:, j]
                if mj.any():
                    off = float(np.mean((rho - cen + centre)[mj, j] - centre[j]))
                    cen[:, j] += np.clip(centre[j] + off, b.tau_min[j], b.tau_max[j]) - centre[j]
            hh = np.zeros(rho.shape)
        else:
            hh = np.broadcast_to(half, rho.shape)
        e[m] = (rho - cen)[m]
        h[m] = hh[m]
        sigma[m] = np.broadcast_to(b.sigma, rho.shape)[m]
    wid = widening(model, rec)
    h = np.where(reg == MOVING, h, np.maximum(h + wid, 0.0))
    mb = model.regimes.get("moving")
    sliding = (mb is not None and mb.coulomb is not None, mb is not None and mb.viscous is not None)
    hf = white_noise(e, use & (reg != DITHER), reg)
    return Scored(sig, e, h, sigma, use, tau, notes, hf, sliding)


#: a joint stopped for at least this long has stuck [s]
MIN_STICK_S = 0.04
#: moving samples this close to a stick are break-away / stopping transients [s]
STICK_SETTLE_S = 0.2
#: moving samples slower than this are a velocity reversal (the regime threshold) [rad/s]
REVERSAL_V = 5e-3
#: a moving run at least this long is a motion (shorter: a slip) [s]
MIN_MOTION_S = 0.5


def stick_transitions(
    reg: np.ndarray,
    sample_rate: float,
    min_stick_s: float = MIN_STICK_S,
    settle_s: float = STICK_SETTLE_S,
    min_motion_s: float = MIN_MOTION_S,
) -> np.ndarray:
    """(N, n) bool: the first and last ``settle_s`` [s] of every motion that starts or ends in a
    stick.

    A stick is a run of at least ``min_stick_s`` [s] of non-moving samples of one joint
    (``reg`` (N, n) from :func:`ditherlab.recording.regimes`); a motion is a run of at least
    ``min_motion_s`` [s] of moving samples. Where a motion leaves or enters a stick, the
    friction passes between the static level Fs and the sliding level Fc (break-away) while the
    servo and the gear spring settle: a transient that neither the band nor the sliding line
    describes. A velocity reversal of continuous motion (a few non-moving samples) is not a stick.
    A short slip between sticks (shorter than ``min_motion_s``, e.g. a pose giving way under a
    push beyond the band) is break-away and stop with nothing in between: it is marked whole
    (on the simulator such slips of a wrist joint left 0.4-0.6 N·m of residual against a
    0.08 N·m noise floor).
    """
    N, n = reg.shape
    out = np.zeros((N, n), dtype=bool)
    lmin = max(1, int(round(min_stick_s * sample_rate)))
    lmot = max(1, int(round(min_motion_s * sample_rate)))
    g = int(round(settle_s * sample_rate))
    if g <= 0:
        return out
    for j in range(n):
        mv = reg[:, j] == MOVING
        d = np.diff(np.r_[0, mv.astype(np.int8), 0])
        starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        for k, (a, b) in enumerate(zip(starts, ends, strict=True)):
            before = a - (ends[k - 1] if k > 0 else 0)
            after = (starts[k + 1] if k + 1 < len(starts) else N) - b
            if b - a < lmot:
                if a > 0 and b < N and before >= lmin and after >= lmin:
                    out[a:b, j] = True
                continue
            if a > 0 and before >= lmin:
                out[a : min(b, a + g), j] = True
            if b < N and after >= lmin:
                out[max(a, b - g) : b, j] = True
    return out


def white_noise(e: np.ndarray, use: np.ndarray, reg: np.ndarray) -> np.ndarray:
    """Model-free noise level per joint from first differences of the residual.

    Effects are smooth in time; white measurement noise is not: ``diff(e)`` has standard
    deviation ``sqrt(2)·sigma``. A robust scale (1.4826 · median absolute deviation) ignores the
    few jumps at velocity reversals and regime changes. Only consecutive samples that are both
    scored and in the same regime count (dither samples are excluded: the extracted signal is a
    window mean).

    Parameters
    ----------
    e : (N, n) [N·m] ; use : (N, n) bool ; reg : (N, n) regime codes

    Returns
    -------
    (n,) [N·m]; NaN for a joint with fewer than 20 usable pairs
    """
    out = np.full(e.shape[1], np.nan)
    if len(e) < 2:
        return out
    d = np.diff(e, axis=0)
    ok = use[1:] & use[:-1] & (reg[1:] == reg[:-1])
    for j in range(e.shape[1]):
        x = d[ok[:, j], j]
        if x.size >= 20:
            out[j] = 1.4826 * np.median(np.abs(x - np.median(x))) / np.sqrt(2.0)
    return out


def band_loss(x: np.ndarray, h: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Per-sample band-aware loss ``(max(0, |x| - h) / s)²`` [σ² units].

    ``x`` residual about the band centre, ``h`` half-width (0: plain least squares), ``s`` noise.
    """
    return (np.maximum(np.abs(x) - h, 0.0) / s) ** 2


# ============================================================== fitting
def solve_signed(e, h, s, C, W, o, signs: Sequence[int]) -> tuple[np.ndarray, float]:
    """:func:`_solve` with sign constraints on the parameters (+1: >= 0, -1: <= 0, 0: free).

    A parameter whose unconstrained value has the wrong sign is held at 0 and the rest re-fitted
    (an active-set loop; the problem is convex, so this reaches the constrained optimum for the
    one- and two-parameter effects with constraints here).
    """
    k = C.shape[1]
    sg = np.asarray(signs, dtype=float)
    free = np.ones(k, dtype=bool)
    w = np.zeros(k)
    L = float(np.sum((np.maximum(np.abs(e - o) - h, 0.0) / s) ** 2))
    for _ in range(k + 1):
        if not free.any():
            break
        wf, L = _solve(e, h, s, C[:, free], W[:, free], o)
        w = np.zeros(k)
        w[free] = wf
        bad = free & (sg * w < 0)
        if not bad.any():
            return w, L
        free &= ~bad
    w = np.zeros(k)
    if free.any():
        wf, L = _solve(e, h, s, C[:, free], W[:, free], o)
        w[free] = wf
    else:
        L = float(np.sum((np.maximum(np.abs(e - o) - h, 0.0) / s) ** 2))
    return w, L


def _solve(e, h, s, C, W, o, w0=None, iters: int = 40) -> tuple[np.ndarray, float]:
    """Minimise ``sum((max(0, |e - o - C w| - h - W w) / s)²)`` over w (convex).

    Semi-smooth Gauss–Newton on the active set (samples outside the band) with a backtracking
    line search. Shapes: e, h, s, o (M,); C, W (M, k).

    Returns
    -------
    w (k,), loss
    """
    k = C.shape[1]
    base = e - o
    s2 = 1.0 / s**2
    if k == 0:
        return np.zeros(0), float(np.sum(np.maximum(np.abs(base) - h, 0.0) ** 2 * s2))

    def mv(A: np.ndarray, w: np.ndarray) -> np.ndarray:
        # single-threaded matrix-vector product (see _mm)
        return np.einsum("mk,k->m", A, w)

    def loss_of(w: np.ndarray) -> float:
        x = base - mv(C, w)
        return float(np.sum(np.maximum(np.abs(x) - h - mv(W, w), 0.0) ** 2 * s2))

    w = np.zeros(k) if w0 is None else np.asarray(w0, dtype=float).copy()
    L = loss_of(w)
    scale = np.sqrt(np.mean(C**2, axis=0) + np.mean(W**2, axis=0)) + 1e-300
    prev_act = None
    for _ in range(iters):
        x = base - mv(C, w)
        sg = np.sign(x)
        ex = np.abs(x) - h - mv(W, w)
        act = ex > 0
        if not act.any():
            break
        if prev_act is not None and np.array_equal(act, prev_act):
            break  # the last full Gauss-Newton step solved this piece exactly
        Jm = (-(sg[act, None] * C[act]) - W[act]) / (s[act, None] * scale)
        r = ex[act] / s[act]
        # ridge-regularised normal equations (keeps singular designs, e.g. no motion, finite)
        G = _mm(Jm, Jm)
        G[np.diag_indices(k)] += 1e-9 * (np.trace(G) / k + 1e-300)
        try:
            d = -np.linalg.solve(G, np.einsum("mk,m->k", Jm, r)) / scale
        except np.linalg.LinAlgError:
            break
        t = 1.0
        while t > 1e-4:
            wn = w + t * d
            Ln = loss_of(wn)
            if Ln <= L:
                break
            t *= 0.5
        else:
            break
        improve = L - Ln
        w, L = wn, Ln
        prev_act = act if t == 1.0 else None
        if improve <= 1e-12 * max(L, 1e-300) and t == 1.0:
            break
    return w, L


@dataclass
class Stack:
    """Samples of one or several recordings stacked for one joint (or all joints, shared).

    The design ``C`` (and ``W``) holds the effect's ``k`` columns followed by nuisance columns:
    one indicator per (joint, regime) group, and per joint ``sign(dq)`` and ``dq`` in the moving
    regime (when the model has Coulomb / viscous terms). Identification re-fits the bands and
    the sliding line with the effect in place, so they absorb whatever part of an effect is
    constant within a regime or proportional to sign(dq) or dq: an effect is credited only with
    the rest, and the baseline it is compared with gets the same nuisance columns.
    """

    e: np.ndarray
    h: np.ndarray
    s: np.ndarray
    C: np.ndarray
    W: np.ndarray
    o: np.ndarray
    block: np.ndarray  # (M,) time index within the concatenated samples (for folds)
    k: int  # number of effect columns (the rest are intercepts)

    def signs(self, eff: Sequence[int]) -> tuple[int, ...]:
        return tuple(eff) + (0,) * (self.C.shape[1] - self.k)


def stack(e: Effect, sc: Sequence[Scored], j: int | None, h: Any, ref: dict[str, Any]) -> Stack:
    """Flatten the scored samples of joint j (or all joints when the effect is shared)."""
    es, hs, ss, Cs, Ws, os_, bs, gs = [], [], [], [], [], [], [], []
    ns: list[tuple[int, np.ndarray]] = []
    t0 = 0
    for s in sc:
        d = e.design(s.sig, j, h, ref)
        N = len(s.e)
        joints = range(s.sig.n) if j is None else [j]
        for jj in joints:
            if j is None:
                C = d.centre[:, jj, :]
                Wd = d.widen[:, jj, :] if d.widen is not None else None
                o = d.offset[:, jj] if d.offset is not None else None
            else:
                C, Wd, o = d.centre, d.widen, d.offset
            m = s.use[:, jj]
            mv = s.sig.regime[:, jj] == MOVING
            es.append(s.e[m, jj])
            hs.append(s.h[m, jj])
            ss.append(s.sigma[m, jj])
            Cs.append(C[m])
            Ws.append(np.zeros_like(C[m]) if Wd is None else (Wd * ~mv[:, None])[m])
            os_.append(np.zeros(int(m.sum())) if o is None else o[m])
            bs.append(t0 + np.flatnonzero(m))
            gs.append(jj * 3 + s.sig.regime[m, jj].astype(np.int64))
            # sliding-friction nuisance (moving only): joint jj's sign(dq) and dq columns
            dqm = np.where(mv, s.sig.dq[:, jj], 0.0)[m]
            cols = []
            if s.sliding[0]:
                cols.append(np.sign(dqm))
            if s.sliding[1]:
                cols.append(dqm)
            ns.append((jj, np.column_stack(cols) if cols else np.zeros((len(dqm), 0))))
        t0 += N
    e_, h_, s_, C_, W_, o_, b_, g_ = (np.concatenate(a) for a in (es, hs, ss, Cs, Ws, os_, bs, gs))
    _, gi = np.unique(g_, return_inverse=True)
    G = np.zeros((len(g_), int(gi.max()) + 1 if len(g_) else 0))
    G[np.arange(len(g_)), gi] = 1.0
    # sliding columns per joint, block-placed (zeros for the other joints' rows)
    joints_in = sorted({jj for jj, _ in ns})
    width = max((a.shape[1] for _, a in ns), default=0)
    S = np.zeros((len(g_), width * len(joints_in)))
    r0 = 0
    for jj, a in ns:
        c0 = joints_in.index(jj) * width
        S[r0 : r0 + len(a), c0 : c0 + a.shape[1]] = a
        r0 += len(a)
    S = S[:, np.any(S != 0, axis=0)]
    N_ = np.hstack([G, S])
    k = C_.shape[1]
    return Stack(e_, h_, s_, np.hstack([C_, N_]), np.hstack([W_, np.zeros_like(N_)]), o_, b_, k)


#: Smallest :func:`identifiability` for which add_effect accepts a fit.
MIN_IDENTIFIABILITY = 0.02


def identifiability(st: Stack) -> float:
    """How much of the effect's design is left once the nuisance columns are projected out.

    The smallest singular value of the effect columns (weighted by 1/sigma) after removing
    their least-squares projection on the intercept and sliding-friction columns, relative to
    their own norm: 1 = fully distinct, 0 = the bands and the sliding line can take it all (e.g.
    ``ft_bias`` or ``payload`` in one fixed pose), and then its parameters are arbitrary.
    """
    if st.k == 0 or len(st.e) == 0:
        return 0.0
    w = 1.0 / st.s[:, None]
    Ce = st.C[:, : st.k] * w
    N = st.C[:, st.k :] * w
    if N.shape[1]:
        coef, *_ = np.linalg.lstsq(N, Ce, rcond=None)
        Ce = Ce - N @ coef
    norms = np.linalg.norm(st.C[:, : st.k] * w, axis=0)
    if not np.all(norms > 0):
        return 0.0
    return float(np.linalg.svd(Ce / norms, compute_uv=False).min())


def fit_effect(
    e: Effect,
    sc: Sequence[Scored],
    j: int | None,
    train: Callable[[np.ndarray], np.ndarray] | None = None,
) -> FitResult:
    """Fit effect ``e`` on joint ``j`` (None: shared parameters over all joints).

    Every value of the nonlinear parameter on the effect's grid is fitted by band-aware least
    squares (:func:`_solve`); the one with the smallest loss is kept. For an effect whose
    parameter is continuous (``position_ripple``'s period), the final fit (``train`` None)
    refines it between the best value's grid neighbours (bounded Brent search): the grid is
    spaced a quarter cycle over the joint's span, which leaves up to 1/8 cycle of phase error at
    the ends of the span (on the simulator, 1.5x the noise floor on a wrist joint).

    Parameters
    ----------
    e : Effect
    sc : scored residuals (:func:`scored`) of one or more recordings
    j : 0-based joint, or None for a shared effect
    train : optional function of the stack's time index (M,) -> bool mask of training samples

    Returns
    -------
    FitResult (w, h, ref, loss on the training samples)
    """
    sigs = [s.sig for s in sc]
    ref = e.reference(sigs, j)
    best: FitResult | None = None
    grid = full = e.grid(sigs, j)
    if not e.shared and j is not None and len(grid) > 1:
        st0 = stack(e, sc, j, grid[0], ref)
        m0 = train(st0.block) if train is not None else np.ones(len(st0.e), dtype=bool)
        grid = e.shortlist(sc, j, grid, [m0])[0]

    def fit_at(h: Any) -> FitResult:
        st = stack(e, sc, j, h, ref)
        m = train(st.block) if train is not None else slice(None)
        w, L = solve_signed(
            st.e[m], st.h[m], st.s[m], st.C[m], st.W[m], st.o[m], st.signs(e.signs(h))
        )
        return FitResult(w[: st.k], h, ref, L)

    for h in grid:
        f = fit_at(h)
        if best is None or f.loss < best.loss:
            best = f
    assert best is not None
    if e.continuous and train is None and len(full) > 2:
        # the final fit: the grid's best value refined between its grid neighbours
        k = int(np.argmin(np.abs(np.asarray(full, dtype=float) - float(best.h))))
        lo, hi = sorted((float(full[max(k - 1, 0)]), float(full[min(k + 1, len(full) - 1)])))
        r = minimize_scalar(
            lambda h: fit_at(float(h)).loss,
            bounds=(lo, hi),
            method="bounded",
            options={"xatol": 1e-6 * abs(float(best.h))},
        )
        f = fit_at(float(r.x))
        if f.loss < best.loss:
            best = f
    return best


# ============================================================== model-level operations
def add_effect(
    model: TorqueModel,
    recs: Sequence[Recording],
    name: str,
    joints: Sequence[int] | None = None,
    *,
    refit: bool = True,
) -> TorqueModel:
    """Fit one more effect on the current residual and return the new model (version + 1).

    Parameters
    ----------
    model : TorqueModel
    recs : recordings to fit on (with an F/T sensor for ``attenuation_lag`` and ``ft_bias``)
    name : effect name (see :data:`EFFECTS`)
    joints : 1-based joints for a per-joint effect; None chooses the joints where diagnosis finds
        the effect (all joints when none passes the test)
    refit : re-fit the bands and noise with :func:`ditherlab.identify.identify` afterwards,
        when that module is available

    Returns
    -------
    TorqueModel with the effect appended (an existing one of the same name is replaced).

    Raises
    ------
    ModelError
        Unknown effect name, a joint out of range, or a column the effect needs is missing.
    """
    e = get_effect(name)
    recs = list(recs)
    if not recs:
        raise ModelError("add_effect needs at least one recording")
    for r in recs:
        e.check(signals(r))
    if joints is not None:
        bad = [j for j in joints if not 1 <= int(j) <= model.n]
        if bad:
            raise ModelError(
                f"effect {name!r}: joint {bad[0]} is out of range, expected 1..{model.n}"
            )
    base = model.copy()
    base.effects = [s for s in base.effects if s.name != name]
    sc = [scored(base, r) for r in recs]
    if e.shared:
        fits = {-1: fit_effect(e, sc, None)}
    else:
        if joints is None:
            from ditherlab.diagnose import select_joints

            js = select_joints(base, recs, name, scored_recs=sc)
        else:
            js = [int(j) - 1 for j in joints]
        fits = {j: fit_effect(e, sc, j) for j in js}
    for j, f in fits.items():
        st = stack(e, sc, None if j == -1 else j, f.h, f.ref)
        if identifiability(st) < MIN_IDENTIFIABILITY:
            where = "these recordings" if j == -1 else f"joint {j + 1} of these recordings"
            raise ModelError(
                f"effect {name!r} cannot be told apart from the bands in {where}: its torque "
                f"barely changes within a regime ({e.driven_by}); record a varying pose, motion "
                "or force"
            )
    spec = _clean_none(_make_spec(e, fits))
    new = base.copy()
    new.effects.append(spec)
    new.version = model.version + 1
    if refit:
        new = _refit(new, recs)
    return new


def _refit(model: TorqueModel, recs: Sequence[Recording], n_boot: int = 20) -> TorqueModel:
    """Re-fit bands and noise with the effects in place (identify), keeping version/history."""
    try:
        from ditherlab import identify as ident
    except ImportError:
        return model
    fn = getattr(ident, "identify", None)
    if fn is None or not all(r.has_wrench for r in recs):
        return model
    out = fn(list(recs), base=model, n_boot=n_boot)
    out.effects = list(model.effects)
    out.version = model.version
    out.history = list(model.history)
    return out


def model_text(model: TorqueModel) -> str:
    """The model as one readable equation per joint, e.g.

    ``tau_2 = gravity + J^T F + band[-8.1, 7.9] + 3.2·sign(dq_2) + 0.42·viscous(dq_2)``.
    """
    lines = []
    ext = "J^T F"
    for s in model.effects:
        if s.name == "ft_bias":
            ext = "J^T (F - ft_bias)"
    for j in range(model.n):
        parts = ["gravity"]
        xt = ext
        for s in model.effects:
            if s.name == "attenuation_lag" and (j + 1) in s.joints:
                p = _joint_params(s, j)
                xt = f"{_fmt(p['gain'])}·({ext})({_late(p)})"
        parts.append(xt)
        for rname in ("still", "dither", "moving"):
            b = model.regimes.get(rname)
            if b is None:
                continue
            tag = "" if rname == "still" else f"_{rname}"
            parts.append(f"band{tag}[{b.tau_min[j]:.3g}, {b.tau_max[j]:.3g}]")
            if rname == "moving":
                if b.coulomb is not None:
                    parts.append(f"{b.coulomb[j]:.3g}·sign(dq_{j + 1})")
                if b.viscous is not None:
                    parts.append(f"{b.viscous[j]:.3g}·dq_{j + 1}")
        for s in model.effects:
            e = EFFECTS.get(s.name)
            if e is None or s.name in ("attenuation_lag", "ft_bias"):
                continue
            if e.shared or (j + 1) in s.joints:
                parts.append(e.term(_joint_params(s, j), j))
        sig = model.regimes.get("still") or next(iter(model.regimes.values()), None)
        noise = f" + e(σ={sig.sigma[j]:.3g})" if sig is not None else ""
        lines.append(f"tau_{j + 1} = " + " + ".join(parts) + noise)
    head = f"model v{model.version} ({model.robot if isinstance(model.robot, str) else 'urdf'})"
    if model.effects:
        head += ": effects " + ", ".join(f"{s.name}{s.joints or ''}" for s in model.effects)
    return "\n".join([head, *lines])
