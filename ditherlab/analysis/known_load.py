"""A known load at the tool as the ground truth of the force estimate.

A run with a known mass at the tool, replayed with a model identified without it, is a run with
a known external wrench: the wrench the arm exerts on the load, at the tool point in base axes
with the recording's sign (the wrench the robot exerts, ``docs/recording-format.md``):

``f = m (a_c - g)``, ``moment = r × f``

with ``a_c`` [m/s²] the classical acceleration of the load's centre of mass, ``g`` the gravity
vector (base axes), ``r`` [m] the lever from the tool point to the centre of mass. Standing
still it is the weight held up, ``(0, 0, m·9.81)`` with the moment of its lever; moving, its
inertia adds ``m a_c``. The point mass's own rotational inertia is neglected, as the
``payload`` effect neglects it.

The load is declared in one place, the recording's metadata ``known_load`` (``{"mass": kg,
"com": [x, y, z] m}``, tool frame), written by ``ditherlab convert --known-load MASS[@X,Y,Z]``
(:func:`parse_known_load`) and read by :func:`known_load_of`. ``replay`` writes the known
wrench as the estimates file's ``known/f_x .. known/m_z`` columns (:func:`known_columns`);
``replay`` and ``report`` compare the estimate with them by :class:`ReferenceSums`, the same
sums (error RMS and bias per axis, interval coverage) that compare it with an F/T sensor.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ditherlab.core.errors import ConfigError, RecordingError
from ditherlab.core.names import VENDOR, WRENCH_COLUMNS
from ditherlab.core.schema import check
from ditherlab.data.recording import PAYLOAD_NODE, Recording
from ditherlab.physics.effects.signals import Signals
from ditherlab.robot.load_point import tool_point_motion

__all__ = [
    "KNOWN_LOAD",
    "KNOWN_PREFIX",
    "ReferenceSums",
    "known_columns",
    "known_load_analysis",
    "known_load_of",
    "known_load_text",
    "known_wrench",
    "parse_known_load",
]

#: the recording's metadata key of the known load
KNOWN_LOAD = "known_load"
#: the estimates file's columns of the known wrench: ``known/f_x .. known/m_z``
KNOWN_PREFIX = "known/"


def parse_known_load(text: str, where: str = "--known-load") -> dict[str, Any]:
    """``"MASS[@X,Y,Z]"`` (kg; m in the tool frame) -> ``{"mass": kg, "com": [x, y, z] m}``.

    Raises
    ------
    ConfigError
        Not a number, a mass that is not positive, a centre of mass without three numbers; a
        value outside the recording format's range for a payload.
    """
    mass_txt, _, com_txt = str(text).partition("@")
    try:
        mass = float(mass_txt)
        com = [float(c) for c in com_txt.split(",")] if com_txt else [0.0, 0.0, 0.0]
    except ValueError:
        raise ConfigError(
            f"{where} {text}: expected MASS[@X,Y,Z], a mass [kg] and its centre of mass "
            "[m, tool frame], e.g. 2.0@0,0,0.05"
        ) from None
    if len(com) != 3:
        raise ConfigError(f"{where} {text}: the centre of mass has {len(com)} numbers; expected 3")
    if not np.isfinite(mass) or mass <= 0:
        raise ConfigError(f"{where} {text}: mass {mass:g} kg; expected a mass > 0 [kg]")
    load = {"mass": mass, "com": com}
    check(load, PAYLOAD_NODE, where, ConfigError)
    return load


def known_load_of(meta: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """The known load a recording's metadata declares (``known_load``), as ``{"mass": kg,
    "com": [x, y, z] m}`` in the tool frame, or None: the one place every command reads it."""
    load = (meta or {}).get(KNOWN_LOAD)
    if load is None:
        return None
    check(load, PAYLOAD_NODE, "recording metadata known_load", RecordingError)
    return {"mass": float(load["mass"]), "com": [float(c) for c in load.get("com", (0, 0, 0))]}


def known_load_text(load: Mapping[str, Any]) -> str:
    """``2 kg at [0, 0, 0.05] m``: the load in words."""
    c = ", ".join(f"{x:.3g}" for x in load["com"])
    return f"{load['mass']:.3g} kg at [{c}] m"


def known_wrench(rec: Recording, load: Mapping[str, Any]) -> np.ndarray:
    """The wrench the arm exerts on a known load, at the tool point in base axes.

    Parameters
    ----------
    rec : the recording (its robot and tool point; ``q``, and the motion every rigid-body
        quantity uses, :attr:`ditherlab.physics.effects.signals.Signals.motion`: the logged
        velocity and acceleration where the arm moves, 0 where it stands)
    load : ``{"mass": kg, "com": [x, y, z] m}`` in the tool frame

    Returns
    -------
    (N, 6) [N, N·m]: ``f = m (a_c - g)`` and the moment ``r × f`` about the tool point
    """
    dq, ddq = Signals(rec, sensor=False).motion
    pm = tool_point_motion(rec.robot(), rec.q, dq, ddq, np.asarray(load["com"], dtype=float))
    f = float(load["mass"]) * (pm.acceleration - pm.gravity[None, :])
    return np.concatenate([f, np.cross(pm.lever, f)], axis=1)


def known_columns(rec: Recording) -> dict[str, np.ndarray]:
    """The estimates file's ``known/f_x .. known/m_z`` columns, each (N,) [N, N·m], for a
    recording that declares a known load; empty without one."""
    load = known_load_of(rec.meta)
    if load is None:
        return {}
    W = known_wrench(rec, load)
    return {
        f"{KNOWN_PREFIX}{c}": np.ascontiguousarray(W[:, k]) for k, c in enumerate(WRENCH_COLUMNS)
    }


class ReferenceSums:
    """Running error of the estimate against a reference wrench, per estimator variant, over
    blocks of an estimates file's columns: the error's RMS and mean (bias) per axis and the
    share of samples whose interval holds the reference.

    ``prefix`` names the reference columns: ``""`` the F/T sensor's ``f_x .. m_z``,
    :data:`KNOWN_PREFIX` the known load's. ``plus_sensor``: the reference is the known load's
    wrench plus the F/T sensor's where the columns hold one (the contact the sensor measures
    beside the load, which it does not).
    """

    def __init__(self, prefix: str = "", plus_sensor: bool = False) -> None:
        self.prefix = prefix
        self.plus_sensor = plus_sensor
        self.n = 0
        self.variants: list[str] = []
        self.sum: dict[str, np.ndarray] = {}
        self.sse: dict[str, np.ndarray] = {}
        self.covered: dict[str, np.ndarray] = {}
        self.ref_sum = np.zeros(6)

    def add(self, cols: Mapping[str, Any], variants: Sequence[str]) -> None:
        """Count the rows of ``cols`` (a DataFrame or a dict of (N,) arrays) of ``variants``,
        and of the vendor's own estimate (:data:`~ditherlab.core.names.VENDOR`, no interval)
        when ``cols`` holds it; nothing when the reference columns are missing."""
        vendor = f"{VENDOR}/f_x" in cols
        self.variants = [*variants, VENDOR] if vendor else list(variants)
        if f"{self.prefix}f_x" not in cols:
            return

        def stack(names: list[str]) -> np.ndarray:
            return np.stack([np.asarray(cols[c], dtype=float) for c in names], axis=1)

        R = stack([self.prefix + c for c in WRENCH_COLUMNS])
        if self.plus_sensor and "f_x" in cols:
            R = R + np.nan_to_num(stack(list(WRENCH_COLUMNS)))
        self.n += len(R)
        self.ref_sum += R.sum(axis=0)
        for v in self.variants:
            E = stack([f"{v}/{c}" for c in WRENCH_COLUMNS]) - R
            self.sum[v] = self.sum.get(v, 0.0) + E.sum(axis=0)
            self.sse[v] = self.sse.get(v, 0.0) + (E**2).sum(axis=0)
            if v == VENDOR:
                continue
            lo = stack([f"{v}/{c}_lo" for c in WRENCH_COLUMNS])
            hi = stack([f"{v}/{c}_hi" for c in WRENCH_COLUMNS])
            inside = ((lo <= R) & (R <= hi)).sum(axis=0)
            self.covered[v] = self.covered.get(v, 0) + inside

    def result(self) -> dict[str, Any] | None:
        """``{"samples", "reference_mean": (6,), "variants": {V: {"rms", "bias", "coverage"}}}``
        (each (6,) [N, N·m]; coverage a share per axis, None for the vendor's estimate, which
        has no interval), or None without reference rows."""
        if self.n == 0:
            return None
        n = float(self.n)
        per = {
            v: {
                "rms": np.sqrt(self.sse[v] / n).tolist(),
                "bias": (self.sum[v] / n).tolist(),
                "coverage": (self.covered[v] / n).tolist() if v in self.covered else None,
            }
            for v in self.variants
            if v in self.sse
        }
        return {"samples": self.n, "reference_mean": (self.ref_sum / n).tolist(), "variants": per}


def known_load_analysis(ests: Sequence[Any], chunk_rows: int) -> dict[str, Any] | None:
    """The estimate against the known load in each estimates file that holds its wrench: the
    load's wrench, plus the F/T sensor's where the file has one (a push beside the load).

    Parameters
    ----------
    ests : :class:`ditherlab.data.estimates.EstimatesSource` of the files
    chunk_rows : rows read at a time

    Returns
    -------
    ``{"files": [{"file", "load": {"mass", "com"}, "samples", "reference_mean": (6,),
    "variants": {V: {"rms", "bias", "coverage"}}}]}`` (:meth:`ReferenceSums.result`), or None
    when no file declares a known load.
    """
    files = []
    cols = [KNOWN_PREFIX + c for c in WRENCH_COLUMNS]
    for e in ests:
        load = known_load_of(e.meta.get("recording"))
        if load is None or cols[0] not in e.columns:
            continue
        sums = ReferenceSums(KNOWN_PREFIX, plus_sensor=True)
        for block in e.blocks(chunk_rows):
            sums.add(block, e.variants)
        res = sums.result()
        if res is not None:
            files.append({"file": e.name, "load": load, **res})
    return {"files": files} if files else None
