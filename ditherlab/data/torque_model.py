"""The torque model: the base model of the paper plus a list of named effects, as a TOML file.

``tau = tau_grav(q) + J(q)^T F + tau_f + e + sum(effects)``, per joint, with ``tau_f`` a uniform
band ``[tau_min, tau_max]`` and ``e ~ N(0, sigma^2)`` identified per regime (``still``, ``dither``,
``moving``), and a Gaussian prior ``F ~ N(prior_mean, diag(prior_sigma^2))`` on the wrench.

The file is meant to be read and edited by a person::

    schema = "ditherlab.model/1"
    robot = "irb140"
    version = 1
    [prior]
    mean = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]      # [N, N, N, N·m, N·m, N·m]
    sigma = [20.0, 20.0, 20.0, 0.3, 0.3, 0.3]
    [regimes.still]
    tau_min = [...]   # [N·m], one per joint
    tau_max = [...]
    sigma = [...]     # [N·m]
    [[effects]]
    name = "viscous"
    joints = [2, 3]
    params = { coef = [1.2, 0.8] }

Effects are stored as plain specs here; their physics lives in :mod:`ditherlab.physics.effects`.
"""

from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import tomli_w

from ditherlab.core.errors import ModelError
from ditherlab.core.files import atomic_write_text, plain
from ditherlab.core.names import DITHER, MOVING, REGIME_NAMES, STILL, Regime
from ditherlab.core.schema import (
    Either,
    Integer,
    ListOf,
    MapOf,
    Number,
    Table,
    Text,
    check,
    count,
    join_key,
)
from ditherlab.data.recording import PAYLOAD_NODE, ROBOT_NODE, TOOL_OFFSET_NODE
from ditherlab.robot import builtin_robots, builtin_urdf

if TYPE_CHECKING:  # pragma: no cover
    from ditherlab.data.recording import Recording

SCHEMA = "ditherlab.model/1"
#: the regimes a model can have a band for (:class:`ditherlab.core.names.Regime`)
REGIMES = REGIME_NAMES
__all__ = [
    "DITHER",
    "MOVING",
    "PAPER_PRIOR_SIGMA",
    "REGIMES",
    "STILL",
    "Band",
    "EffectSpec",
    "MODEL_SCHEMA",
    "Regime",
    "TorqueModel",
]
#: The paper's prior (§V): F_bar = 0, R_F = diag(20, 20, 20, 0.3, 0.3, 0.3)^2.
PAPER_PRIOR_SIGMA = (20.0, 20.0, 20.0, 0.3, 0.3, 0.3)

#: Largest band edge, sliding friction or prior value a model file may hold [N·m, N]: beyond
#: any robot, and small enough that squares and sums of them stay finite.
MAX_TORQUE = 1e6
#: Smallest noise level [N·m]: below it 1/sigma^2 overflows in the estimator's sums.
MIN_SIGMA = 1e-9
MAX_JOINTS = 64
_PER_JOINT = {"length": "n", "per": "joint"}
_BAND = Table(
    keys={
        "tau_min": ListOf(item=Number(-MAX_TORQUE, MAX_TORQUE, "N·m"), **_PER_JOINT),
        "tau_max": ListOf(item=Number(-MAX_TORQUE, MAX_TORQUE, "N·m"), **_PER_JOINT),
        # positive and >= MIN_SIGMA: TorqueModel.validate, for files and in-memory models
        "sigma": ListOf(item=Number(None, MAX_TORQUE, "N·m"), **_PER_JOINT),
        "coulomb": ListOf(item=Number(-MAX_TORQUE, MAX_TORQUE, "N·m"), **_PER_JOINT),
        "viscous": ListOf(item=Number(-MAX_TORQUE, MAX_TORQUE, "N·m·s/rad"), **_PER_JOINT),
        # standard errors, only printed; -1 where none was estimated
        "stderr": MapOf(value=ListOf(item=Number(-1.0, 1e12), **_PER_JOINT)),
    },
    required=("tau_min", "tau_max", "sigma"),
)
_PARAM = Number(-1e9, 1e9)
#: The model file (see the module docstring); ``n_joints`` gives the lengths of the per-joint
#: lists and the range of ``effects.joints``.
MODEL_SCHEMA = Table(
    keys={
        "schema": Text(choices=(SCHEMA,)),
        "robot": ROBOT_NODE,
        "n_joints": Integer(1, MAX_JOINTS, bind="n"),
        "version": Integer(1),
        "notes": Text(),
        "tool_offset": TOOL_OFFSET_NODE,
        "payload": PAYLOAD_NODE,
        "prior": Table(
            keys={
                "mean": ListOf(item=Number(-MAX_TORQUE, MAX_TORQUE, "N, N·m"), length=6),
                "sigma": ListOf(item=Number(0.0, MAX_TORQUE, "N, N·m", inf=True), length=6),
            }
        ),
        "regimes": Table(keys={name: _BAND for name in REGIME_NAMES}),
        "effects": ListOf(
            item=Table(
                keys={
                    "name": Text(nonempty=True, what="an effect name"),
                    "joints": ListOf(item=Integer(1, "n")),
                    "params": MapOf(
                        value=Either(options=(_PARAM, ListOf(item=_PARAM))),
                        what="a table of parameters (numbers or lists of numbers)",
                    ),
                },
                required=("name",),
            )
        ),
        "history": ListOf(item=MapOf(what="a table (one diagnose run)")),
    },
    required=("schema", "robot", "n_joints"),
)


@dataclass
class Band:
    """The disturbance model of one regime: a uniform band plus Gaussian noise, per joint.

    Attributes
    ----------
    tau_min, tau_max : (n,) [N·m]
        Edges of the uniform friction band (``tau_min <= tau_max``).
    sigma : (n,) [N·m]
        Standard deviation of the Gaussian noise (> 0).
    coulomb, viscous : (n,) [N·m], [N·m·s/rad], optional
        Sliding friction ``coulomb·sign(dq) + viscous·dq`` (used in the ``moving`` regime,
        where the band is centred on it).
    stderr : dict of name -> (n,), optional
        Standard errors of the fitted parameters (e.g. from a bootstrap over pushes).
    """

    tau_min: np.ndarray
    tau_max: np.ndarray
    sigma: np.ndarray
    coulomb: np.ndarray | None = None
    viscous: np.ndarray | None = None
    stderr: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for k in ("tau_min", "tau_max", "sigma", "coulomb", "viscous"):
            v = getattr(self, k)
            if v is not None:
                setattr(self, k, np.asarray(v, dtype=float).reshape(-1))
        self.stderr = {k: np.asarray(v, dtype=float).reshape(-1) for k, v in self.stderr.items()}

    @property
    def n(self) -> int:
        """The number of joints."""
        return len(self.sigma)

    def sliding(self, dq: np.ndarray) -> np.ndarray:
        """The sliding friction line ``coulomb·sign(dq) + viscous·dq`` (N, n) [N·m] for ``dq``
        (N, n) [rad/s]; zeros where the band has neither term."""
        out = np.zeros(np.shape(dq))
        if self.coulomb is not None:
            out += self.coulomb * np.sign(dq)
        if self.viscous is not None:
            out += self.viscous * dq
        return out

    def to_dict(self) -> dict[str, Any]:
        """The band as the model file's ``[regimes.NAME]`` table (lists per joint, N·m)."""
        d: dict[str, Any] = {
            "tau_min": self.tau_min.tolist(),
            "tau_max": self.tau_max.tolist(),
            "sigma": self.sigma.tolist(),
        }
        if self.coulomb is not None:
            d["coulomb"] = self.coulomb.tolist()
        if self.viscous is not None:
            d["viscous"] = self.viscous.tolist()
        if self.stderr:
            d["stderr"] = {k: v.tolist() for k, v in self.stderr.items()}
        return d


@dataclass
class EffectSpec:
    """One named effect of the model: which joints it acts on and its fitted parameters.

    ``params`` maps a parameter name to a number or a list with one value per listed joint.
    """

    name: str
    joints: list[int]
    params: dict[str, Any] = field(default_factory=dict)
    #: the model file it was read from, for messages
    source: str | None = field(default=None, compare=False, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The effect as one ``[[effects]]`` entry of the model file."""
        return {"name": self.name, "joints": list(self.joints), "params": plain(self.params)}


@dataclass
class TorqueModel:
    """A fitted torque model (see the module docstring for the file layout).

    Attributes
    ----------
    robot : built-in name or ``{"urdf": ..., "tool_frame": ...}`` (as in a recording's metadata)
    n : number of joints
    regimes : regime name -> :class:`Band`
    prior_mean : (6,) [N, N·m]
    prior_sigma : (6,) [N, N·m]; ``inf`` leaves a component free, ``0`` holds it at the mean
    effects : the effects added to the base model, in order
    history : one dict per diagnose run (version, effects, RMS figures)
    version : incremented each time an effect is added and the model re-fitted
    """

    robot: str | dict
    n: int
    regimes: dict[str, Band] = field(default_factory=dict)
    prior_mean: np.ndarray = field(default_factory=lambda: np.zeros(6))
    prior_sigma: np.ndarray = field(default_factory=lambda: np.array(PAPER_PRIOR_SIGMA))
    effects: list[EffectSpec] = field(default_factory=list)
    history: list[dict[str, Any]] = field(default_factory=list)
    version: int = 1
    tool_offset: list[float] | None = None
    payload: dict[str, Any] | None = None
    notes: str = ""
    source: str | None = None

    def __post_init__(self) -> None:
        self.prior_mean = np.asarray(self.prior_mean, dtype=float).reshape(6)
        self.prior_sigma = np.asarray(self.prior_sigma, dtype=float).reshape(6)
        self.validate()

    # -------------------------------------------------------------- checks
    def validate(self) -> None:
        """Raise ModelError for inverted bands, noise below :data:`MIN_SIGMA` or wrong lengths."""
        where = f"{self.source}: " if self.source else ""
        if np.any(self.prior_sigma < 0) or np.any(np.isnan(self.prior_sigma)):
            raise ModelError(f"{where}prior.sigma is {self.prior_sigma.tolist()}, expected >= 0")
        for name, b in self.regimes.items():
            if name not in REGIMES:
                raise ModelError(
                    f"{where}unknown regime [regimes.{name}], expected one of {REGIMES}"
                )
            for k in ("tau_min", "tau_max", "sigma", "coulomb", "viscous"):
                v = getattr(b, k)
                if v is not None and len(v) != self.n:
                    raise ModelError(
                        f"{where}regimes.{name}.{k} has {len(v)} values, expected {self.n} (one per joint)"
                    )
                if v is not None and not np.all(np.isfinite(v)):
                    raise ModelError(
                        f"{where}regimes.{name}.{k} is {v.tolist()}, expected finite numbers"
                    )
            inv = np.flatnonzero(b.tau_min > b.tau_max)
            if inv.size:
                j = int(inv[0])
                raise ModelError(
                    f"{where}regimes.{name} band of joint {j + 1} is inverted: "
                    f"tau_min={b.tau_min[j]:g} > tau_max={b.tau_max[j]:g} N·m"
                )
            bad = np.flatnonzero(~(b.sigma >= MIN_SIGMA))
            if bad.size:
                j = int(bad[0])
                raise ModelError(
                    f"{where}regimes.{name}.sigma of joint {j + 1} is {b.sigma[j]:g} N·m, "
                    f"expected a positive noise level (at least {MIN_SIGMA:g} N·m)"
                )
        for e in self.effects:
            badj = [j for j in e.joints if not 1 <= int(j) <= self.n]
            if badj:
                raise ModelError(
                    f"{where}effect {e.name!r} names joint {badj[0]}, expected 1..{self.n}"
                )

    def band(self, regime: str) -> Band:
        """The :class:`Band` of a regime; ModelError when the model has none for it."""
        if regime not in self.regimes:
            where = f"{self.source}: " if self.source else ""
            raise ModelError(
                f"{where}the model has no [regimes.{regime}] (it has "
                f"{', '.join(self.regimes) or 'none'}); identify it from a recording with that regime"
            )
        return self.regimes[regime]

    def effect_names(self) -> list[str]:
        """The names of the model's effects, in order."""
        return [e.name for e in self.effects]

    def copy(self) -> TorqueModel:
        """A deep copy."""
        return copy.deepcopy(self)

    def same_robot(self, spec: str | dict) -> bool:
        """Whether a recording's ``robot`` metadata entry is this model's robot: the same
        built-in name, or the same URDF text (a built-in name stands for its URDF, so a
        recording that embeds the unchanged built-in URDF is that robot)."""
        m = self.robot
        if isinstance(m, str) and isinstance(spec, str):
            return m == spec
        a, b = _urdf_text(m), _urdf_text(spec)
        return a is not None and b is not None and a.strip() == b.strip()

    def check_robot(self, rec: Recording) -> None:
        """Raise ModelError when the recording's robot is not the model's (name/URDF or joint
        count)."""
        spec_m, spec_r = self.robot, rec.meta["robot"]
        if self.n == rec.n and self.same_robot(spec_r):
            return
        mlabel = spec_m if isinstance(spec_m, str) else spec_m.get("name", "urdf")
        where = f"{rec.name}: " if rec.name else ""
        model = f"the model {self.source}" if self.source else "the model"
        if self.n == rec.n and mlabel == rec.robot_label:
            raise ModelError(
                f"{where}the recording's robot {rec.robot_label} ({_kind(spec_r)}) is not "
                f"{model}'s {mlabel} ({_kind(spec_m)}): their URDF texts differ"
            )
        raise ModelError(
            f"{where}the recording's robot is {rec.robot_label} with {rec.n} joints but "
            f"{model} is for {mlabel} with {self.n} joints"
        )

    def sample_bands(
        self, reg: np.ndarray, dq: np.ndarray, *, dither: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The band and noise of every sample: the one per-sample band assembly.

        The ``still`` band everywhere; where a joint moves (and the model has a ``moving`` band)
        the moving band about the sliding line ``coulomb·sign(dq) + viscous·dq``
        (:meth:`Band.sliding`); with ``dither`` the ``dither`` band where a joint stands still with
        the dither on (the torque there being the extracted signal). Samples of a regime the model
        has no band for (and, without a ``still`` band, every sample not covered) get an empty
        band ``[0, 0]`` with unit noise: callers leave them out.

        Parameters
        ----------
        reg : (N, n) regime codes (:func:`ditherlab.data.recording.regimes`)
        dq : (N, n) [rad/s]
        dither : use the dither band on DITHER samples (the estimator's dither variants decide
            this themselves: :func:`ditherlab.analysis.estimation.variant_inputs`)

        Returns
        -------
        tau_min, tau_max, sigma : each (N, n) [N·m]
        """
        N, n = reg.shape
        still = self.regimes.get("still")
        if still is not None:
            lo = np.broadcast_to(still.tau_min, (N, n)).copy()
            hi = np.broadcast_to(still.tau_max, (N, n)).copy()
            sig = np.broadcast_to(still.sigma, (N, n)).copy()
        else:
            lo, hi, sig = np.zeros((N, n)), np.zeros((N, n)), np.ones((N, n))
        mv = reg == MOVING
        if mv.any() and "moving" in self.regimes:
            b = self.regimes["moving"]
            slide = b.sliding(dq)
            lo = np.where(mv, b.tau_min + slide, lo)
            hi = np.where(mv, b.tau_max + slide, hi)
            sig = np.where(mv, b.sigma, sig)
        dm = reg == DITHER
        if dither and dm.any() and "dither" in self.regimes:
            b = self.regimes["dither"]
            lo = np.where(dm, b.tau_min, lo)
            hi = np.where(dm, b.tau_max, hi)
            sig = np.where(dm, b.sigma, sig)
        return lo, hi, sig

    def __str__(self) -> str:
        """A one-line summary; :func:`ditherlab.physics.effects.model_text` prints the equations."""
        robot = self.robot if isinstance(self.robot, str) else "urdf"
        eff = ", ".join(f"{s.name}{s.joints or ''}" for s in self.effects) or "none"
        return (
            f"model v{self.version} ({robot}, {self.n} joints): regimes "
            f"{', '.join(self.regimes) or 'none'}; effects {eff}"
        )

    # -------------------------------------------------------------- file I/O
    def to_dict(self) -> dict[str, Any]:
        """The model as the model file's tables (``docs/recording-format.md``)."""
        d: dict[str, Any] = {
            "schema": SCHEMA,
            "robot": self.robot,
            "n_joints": self.n,
            "version": self.version,
        }
        if self.notes:
            d["notes"] = self.notes
        if self.tool_offset is not None:
            d["tool_offset"] = list(map(float, self.tool_offset))
        if self.payload is not None:
            d["payload"] = plain(self.payload)
        d["prior"] = {"mean": self.prior_mean.tolist(), "sigma": _inf_safe(self.prior_sigma)}
        d["regimes"] = {k: b.to_dict() for k, b in self.regimes.items()}
        d["effects"] = [e.to_dict() for e in self.effects]
        if self.history:
            d["history"] = plain(self.history)
        return d

    def dumps(self) -> str:
        """The model as TOML text."""
        return tomli_w.dumps(self.to_dict())

    def save(self, path: str | Path) -> Path:
        """Write the model as TOML, atomically (temporary file + rename)."""
        return atomic_write_text(Path(path), self.dumps())

    @classmethod
    def from_dict(cls, d: Any, source: str | None = None) -> TorqueModel:
        """A model from a parsed model file, checked against :data:`MODEL_SCHEMA` first.

        Raises ModelError naming ``source``, the key, the value and what was expected.
        """
        n = check(d, MODEL_SCHEMA, source, ModelError)["n"]
        where = f"{source}: " if source else ""
        regimes = {
            name: Band(
                tau_min=b["tau_min"],
                tau_max=b["tau_max"],
                sigma=b["sigma"],
                coulomb=b.get("coulomb"),
                viscous=b.get("viscous"),
                stderr=b.get("stderr", {}),
            )
            for name, b in (d.get("regimes") or {}).items()
        }
        prior = d.get("prior", {})
        effects = []
        for i, e in enumerate(d.get("effects", [])):
            joints, params = list(e.get("joints", [])), dict(e.get("params", {}))
            for k, v in params.items():
                # per-joint lists have one value per listed joint (shared effects list none)
                if joints and isinstance(v, list) and len(v) != len(joints):
                    raise ModelError(
                        f"{where}{join_key(f'effects[{i + 1}].params', k)}: got {count(v)}; "
                        f"expected {len(joints)} (one per joint in effects[{i + 1}].joints)"
                    )
            effects.append(EffectSpec(e["name"], joints, params, source=source))
        return cls(
            robot=d["robot"],
            n=n,
            regimes=regimes,
            prior_mean=prior.get("mean", [0.0] * 6),
            prior_sigma=prior.get("sigma", PAPER_PRIOR_SIGMA),
            effects=effects,
            history=list(d.get("history", [])),
            version=d.get("version", 1),
            tool_offset=d.get("tool_offset"),
            payload=d.get("payload"),
            notes=d.get("notes", ""),
            source=source,
        )

    @classmethod
    def load(cls, path: str | Path) -> TorqueModel:
        """Read a model file; ModelError names the file and the key for any problem."""
        p = Path(path)
        if not p.is_file():
            raise ModelError(f"{p}: no such model file")
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as exc:
            raise ModelError(f"{p}: cannot read the model file ({exc.strerror})") from None
        except UnicodeDecodeError:
            raise ModelError(f"{p}: not a valid TOML file (not UTF-8 text)") from None
        try:
            d = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ModelError(f"{p}: not a valid TOML file ({exc})") from None
        return cls.from_dict(d, source=str(p))


def _urdf_text(spec: str | dict) -> str | None:
    """The URDF text a ``robot`` entry stands for (a built-in's file), or None."""
    if isinstance(spec, str):
        return builtin_urdf(spec) if spec in builtin_robots() else None
    return spec.get("urdf")


def _kind(spec: str | dict) -> str:
    return "built-in" if isinstance(spec, str) else "URDF in the metadata"


def _inf_safe(v: np.ndarray) -> list[float]:
    # TOML has inf natively; tomli_w writes it as `inf`.
    return [float(x) for x in v]
