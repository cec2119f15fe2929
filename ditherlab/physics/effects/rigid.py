"""Rigid-body effects: an unmodelled payload, the links' and motors' inertia, and the links'
inertial parameters as identified base parameters (``dynamics``)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ditherlab.physics.effects.base import Design, Effect, fmt
from ditherlab.physics.effects.ranges import Bound, effort_scale, payload_limit
from ditherlab.physics.effects.signals import Signals


def _reach(sigs: Sequence[Signals], j: int | None = None) -> float:
    """[m]: the largest distance of the tool point from the base in the recordings."""
    return max(
        float(np.linalg.norm(s.rec.robot().tool_pose(s.q)[:, :3, 3], axis=1).max()) for s in sigs
    )


def _com_distance(p: dict, sigs: Sequence[Signals]) -> float | None:
    """[m]: the payload's centre of mass's distance from the tool point (None: no load at all;
    infinite: a first moment without mass, a torque no load can make)."""
    m = float(p["mass"])
    mc = np.asarray(p["mass_com"], dtype=float)
    if m <= 0:
        return math.inf if np.any(mc != 0) else None
    return float(np.linalg.norm(mc / m))


def _armature_max(sigs: Sequence[Signals], j: int | None) -> float:
    """[kg·m²]: the reflected inertia whose torque at the joint's largest logged acceleration
    equals its effort limit."""
    jj = slice(None) if j is None else slice(j, j + 1)
    a = max(float(np.max(np.abs(s.ddq[:, jj]), initial=0.0)) for s in sigs)
    return effort_scale(sigs, j) / a if a > 0 else np.inf


__all__ = ["Dynamics", "Inertia", "Payload"]


class Payload(Effect):
    """An unmodelled mass at the tool: its gravity torque, and while moving its inertia and
    Coriolis torques (pinocchio's joint-torque regressor of the tool link, linear in the mass
    and its first moments; the point mass's own rotational inertia, ``m·|c|²``, is neglected).
    The inertia and Coriolis terms matter: gravity alone leaves a moving payload's residual for
    another effect to take (``docs/design/physics-effect-models.md``)."""

    name = "payload"
    order = 6
    physics = (
        "an unmodelled mass at the tool: gravity and inertia torques that change with the pose"
    )
    driven_by = "q, dq, ddq (joint-torque regressor of the last link)"
    shared = True
    linear = ("mass", "mc_x", "mc_y", "mc_z")
    tied = {0: (1, 2, 3)}  # no mass, no first moment: a torque no load can make is not fitted
    shows_in = ("moving", "still", "dither")
    bounds = (
        Bound(
            "mass",
            "kg",
            "0 .. the arm's rated payload",
            "a mass is >= 0; the rated payload from the datasheet (irb140 6 kg, ur10e 12.5 kg, "
            "panda 3 kg), for another arm the mass of its moving links (description)",
            0.0,
            lambda sigs, j: payload_limit(sigs)[0],
        ),
        Bound(
            "centre of mass distance",
            "m",
            "0 .. the arm's reach",
            "a load held at the tool lies within the arm's reach (tool point's largest "
            "distance from the base in the recordings)",
            0.0,
            _reach,
            value=_com_distance,
        ),
    )

    def signs(self, h):
        return (1, 0, 0, 0)

    def weights(self, p):
        return np.array([p["mass"], *p["mass_com"]], dtype=float)

    def linear_params(self, w):
        return {"mass": float(w[0]), "mass_com": [float(x) for x in w[1:]]}

    def design(self, sig, j, h, ref):
        return Design(sig.torque_regressor[:, :, :4])

    def driver(self, sig, j, p):
        w = np.array([p["mass"], *p["mass_com"]])
        return sig.torque_regressor[:, j, :4] @ w, f"payload torque joint {j + 1} [N·m]"

    def term(self, p, j):
        c = ", ".join(fmt(x / p["mass"]) if p["mass"] else "0" for x in p["mass_com"])
        return f"payload(m={fmt(p['mass'])} kg, com=[{c}] m)"


class Inertia(Effect):
    """The links' dynamic torque ``M(q) ddq + C(q, dq) dq`` (:attr:`Signals.dynamic_torque`)
    scaled by ``scale`` per joint, plus the reflected motor inertia ``motor_inertia · ddq_j``."""

    name = "inertia"
    order = 9
    physics = "dynamic torque M(q)·ddq + C(q, dq)·dq of the links plus the reflected motor inertia"
    driven_by = "ddq, dq"
    linear = ("scale", "motor_inertia")
    shows_in = ("moving",)
    on_every_joint = True  # every joint has a rotor and moves links
    bounds = (
        Bound(
            "scale",
            "-",
            "0.25 .. 4",
            "a description's link inertias (CAD or datasheet) are right within a factor 4; a "
            "wrist's small links least so",
            0.25,
            4.0,
            nominal=1.0,
        ),
        Bound(
            "motor_inertia",
            "kg·m²",
            "0 .. effort limit / largest logged acceleration",
            "a rotor's reflected inertia is >= 0 and its torque stays within the joint's "
            "effort limit at the log's accelerations",
            0.0,
            _armature_max,
        ),
    )

    def signs(self, h):
        return (1, 1)

    def design(self, sig, j, h, ref):
        return Design(np.column_stack([sig.dynamic_torque[:, j], sig.ddq[:, j]]))

    def driver(self, sig, j, p):
        return sig.ddq[:, j], f"ddq_{j + 1} [rad/s²]"

    def term(self, p, j):
        return f"inertia({fmt(p['scale'])}·(M ddq + C dq) + {fmt(p['motor_inertia'])}·ddq_{j + 1})"


class Dynamics(Effect):
    """The links' rigid-body model identified on the log: the torque
    ``s · (M(q) ddq + C(q, dq) dq) + Y(q, dq, ddq) · Δπ + Ia_j ddq_j``.

    - ``Y · Δπ``: a correction ``Δπ`` of every link's ``(m, m c, I)`` (pinocchio's joint-torque
      regressor, 10 columns per link, in each link's joint frame): gravity and dynamics together.
    - ``s · (M ddq + C dq)``: the URDF's own dynamic torque (:attr:`Signals.dynamic_torque`).
      A model's baseline has gravity only, so on a model without ``inertia`` the fit gives
      ``s ≈ 1``; next to a fitted ``inertia`` ``s ≈ 0``. Without this column ``Y · Δπ`` would have
      to produce the URDF's dynamics together with a second copy of its gravity, which its base
      set cannot do (``docs/design/physics-effect-models.md``).
    - ``Ia_j ddq_j``: each joint's armature (the reflected rotor inertia, on joint j's row alone),
      the standard base-parameter set of rigid-robot identification.

    Only base parameters can be identified: many columns are zero (a link's inertia about an
    axis that never turns) or linear combinations of others (masses of distal links seen only
    together). The base set is chosen on the data (:meth:`reference`): the regressor of every
    ``STEP``-th sample stacked over joints, each column scaled to unit norm, QR with column
    pivoting, and the columns kept whose ``|R_ii|`` is above ``RANK_TOL`` times the largest.
    The pivots fall gradually over the identifiable columns, then by many orders of magnitude
    over the structurally dependent ones; ``RANK_TOL = 1e-3`` sits in that gap (a condition
    number of at most 1000 for the kept columns): a recording that hardly excites a direction
    drops it rather than fit noise along it (``docs/design/physics-effect-models.md``). The dropped columns' parameters fold into the kept ones, so ``delta`` (on
    ``base_columns``) is a change of base parameters, not of the URDF's individual links.
    Physical consistency is not imposed; :meth:`full_correction` gives the smallest change of all
    links' parameters that produces the fitted torque and the masses it implies, so one can check
    that they stay positive (no LMI on the inertias).
    """

    name = "dynamics"
    order = 11
    physics = "the links' masses, centres of mass and inertias differ from the URDF's"
    driven_by = "q, dq, ddq (joint-torque regressor of every link, base parameters)"
    shared = True
    linear = ()  # the base parameters: chosen from the data (reference), stored as `delta`
    shows_in = ("moving", "still", "dither")
    bounds = (
        Bound(
            "s",
            "-",
            "-0.5 .. 2",
            "the URDF's own dynamic torque is kept (s near 1) or left to a fitted inertia "
            "(s near 0); the description's inertias are right within a factor 2",
            -0.5,
            2.0,
            value=lambda p, sigs: Dynamics.urdf_scale(sigs[0], p),
        ),
    )
    STEP = 5
    RANK_TOL = 1e-3

    @staticmethod
    def regressor(sig: Signals) -> np.ndarray:
        """(N, n, 11 n + 1) [N·m per unit parameter]: the links' regressor
        (:attr:`Signals.link_regressor`, 10 columns per link), one armature column per joint
        (``ddq_j`` of :attr:`Signals.motion` on joint j's row alone), and
        the URDF's dynamic torque (:attr:`Signals.dynamic_torque`) as the last column."""

        def make() -> np.ndarray:
            Y = sig.link_regressor
            N, n, _ = Y.shape
            arm = np.zeros((N, n, n))
            idx = np.arange(n)
            arm[:, idx, idx] = sig.motion[1]
            return np.concatenate([Y, arm, sig.dynamic_torque[:, :, None]], axis=2)

        return sig.cached("dynamics_regressor", make)

    def reference(self, sig, j):
        Y = np.concatenate([self._rows(s) for s in sig])
        norms = np.linalg.norm(Y, axis=0)
        live = np.flatnonzero(norms > 1e-9 * norms.max())
        # scipy.linalg (numpy's QR does not pivot) is imported here: at module level it would
        # slow every command's start-up, for diagnose's dynamics candidate alone
        from scipy.linalg import qr

        _, R, piv = qr(Y[:, live] / norms[live], mode="economic", pivoting=True)
        d = np.abs(np.diag(R))
        keep = live[piv[: int(np.sum(d > self.RANK_TOL * d[0]))]]
        return {"base_columns": sorted(int(c) for c in keep)}

    def _rows(self, sig: Signals) -> np.ndarray:
        Y = self.regressor(sig)[:: self.STEP]
        return Y.reshape(-1, Y.shape[2])

    def signs(self, h):
        return ()

    def weights(self, p):
        return np.array(p["delta"], dtype=float)

    def linear_params(self, w):
        return {"delta": [float(x) for x in w]}

    def _base(self, sig: Signals, p: dict) -> list[int]:
        return (
            p["base_columns"]
            if "base_columns" in p
            else self.reference([sig], None)["base_columns"]
        )

    def design(self, sig, j, h, ref):
        return Design(self.regressor(sig)[:, :, self._base(sig, ref)])

    def driver(self, sig, j, p):
        Y = self.regressor(sig)[:, j, self._base(sig, p)]
        return Y @ self.weights(p), f"dynamics torque joint {j + 1} [N·m]"

    @staticmethod
    def urdf_scale(sig: Signals, p: dict) -> float:
        """``s`` [-]: the share of the URDF's dynamic torque the fit added (0 when its column is
        not in the base set)."""
        last = 11 * sig.rec.n
        cols = list(p["base_columns"])
        return float(p["delta"][cols.index(last)]) if last in cols else 0.0

    def full_correction(self, sig: Signals, p: dict) -> tuple[np.ndarray, np.ndarray]:
        """(Δπ (11 n,), corrected link masses (n,) [kg]): the smallest change of every link's
        parameters (10 per link, then one armature [kg·m²] per joint) giving the fitted torque
        on this recording less its ``s`` part, and the URDF's masses plus it."""
        n = sig.rec.n
        Y = self._rows(sig)
        cols = [c for c in p["base_columns"] if c < 11 * n]
        w = self.weights(p)[[list(p["base_columns"]).index(c) for c in cols]]
        tau = Y[:, cols] @ w
        dpi = np.linalg.lstsq(Y[:, : 11 * n], tau, rcond=1e-10)[0]
        return dpi, sig.rec.robot().link_parameters()[::10] + dpi[: 10 * n : 10]

    def term(self, p, j):
        return f"dynamics(s·(M ddq + C dq) + Y(q, dq, ddq)·Δπ + Ia·ddq, {len(p['delta'])} base parameters)"
