"""Replay the force estimator of eq. (3) over a recording, in up to four variants side by side.

Variants (each only where the recording allows it):

``nodither_band``
    The paper's estimator [10]: ``tau_bar = tau - gravity - effects_torque`` with the ``still``
    band (``moving`` band centred on ``coulomb·sign(dq) + viscous·dq`` where a joint moves).
``nodither_noband``
    The same without the uniform term: ``tau_f`` is fixed at the band centre and the band's
    variance ``(b - a)^2 / 12`` is added to ``sigma^2`` (§IV-C).
``dither_band``
    Needs a ``dither`` column or ``tau_ffw``. Where a joint stands still with the dither on, the
    torque signal is first extracted (§IV-A: per dither period the means of the samples above
    and below the period mean, averaged; :func:`extract_dither`), and the band is the model's
    ``dither`` band — identified on that same extracted signal (:mod:`ditherlab.identify`). A
    model without a ``dither`` band falls back to the paper's rule: the ``still`` band shrunk by
    the extracted dither amplitude on each side (Fig. 4). Samples without dither (before the
    ramp, while moving, the first dither period) are treated as in ``nodither_band``.
``dither_noband``
    ``dither_band`` without the uniform term, as in the paper's Fig. 6 (right column).

The result is an :class:`Estimates` table in the estimates format (brief: Parquet with ``t``,
the sensor columns and ``dither`` copied, per variant ``V/f_x .. V/m_z``, ``V/<c>_lo``,
``V/<c>_hi``, ``V/active`` as a joint bitmask; for dither variants ``extract/upper_j``,
``extract/lower_j``, ``extract/signal_j``; key-value metadata ``ditherlab`` = JSON).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ditherlab.errors import ConfigError, FormatError, ModelError
from ditherlab.estimator.intervals.gaussian import gaussian_profile_intervals
from ditherlab.identify import check_robot
from ditherlab.model import TorqueModel, _plain
from ditherlab.recording import DITHER, MOVING, WRENCH_COLUMNS, Recording, regimes

SCHEMA = "ditherlab.estimates/1"
META_KEY = b"ditherlab"
VARIANTS = ("nodither_band", "nodither_noband", "dither_band", "dither_noband")
COMPONENTS = WRENCH_COLUMNS
INTERVAL_METHODS = ("profile", "set_membership")
#: ``--components`` shorthands.
COMPONENT_SETS = {"all": COMPONENTS, "fxyz": COMPONENTS[:3], "force": COMPONENTS[:3]}


# ------------------------------------------------------------------------------- Estimates
@dataclass
class Estimates:
    """Estimator output per sample (see the module docstring for the columns).

    Attributes
    ----------
    data : DataFrame, one row per sample
    meta : dict with ``schema``, ``recording``, ``recording_name``, ``model``, ``variants``,
        ``interval`` (``method``, ``level``), ``components``, and ``moving_spans`` (the time spans
    in which some joint moved, [s], so that the report can tell rest from motion)
    name : where it was read from (for messages)
    """

    data: pd.DataFrame
    meta: dict[str, Any]
    name: str | None = field(default=None)

    @property
    def variants(self) -> list[str]:
        return list(self.meta.get("variants", []))

    @property
    def t(self) -> np.ndarray:
        """(N,) [s]"""
        return self.data["t"].to_numpy(dtype=float)

    @property
    def has_wrench(self) -> bool:
        return "f_x" in self.data.columns

    @property
    def wrench(self) -> np.ndarray | None:
        """F/T sensor wrench (N, 6) [N, N·m] or None."""
        if not self.has_wrench:
            return None
        return self.data[list(COMPONENTS)].to_numpy(dtype=float)

    @property
    def dither(self) -> np.ndarray | None:
        return self.data["dither"].to_numpy(dtype=bool) if "dither" in self.data.columns else None

    def F(self, variant: str) -> np.ndarray:
        """Estimated wrench of a variant, (N, 6) [N, N·m]."""
        self._check_variant(variant)
        return self.data[[f"{variant}/{c}" for c in COMPONENTS]].to_numpy(dtype=float)

    def interval(self, variant: str) -> tuple[np.ndarray, np.ndarray]:
        """Interval bounds ``(lo, hi)`` of a variant, each (N, 6) [N, N·m]."""
        self._check_variant(variant)
        lo = self.data[[f"{variant}/{c}_lo" for c in COMPONENTS]].to_numpy(dtype=float)
        hi = self.data[[f"{variant}/{c}_hi" for c in COMPONENTS]].to_numpy(dtype=float)
        return lo, hi

    def active(self, variant: str) -> np.ndarray:
        """Joints outside their band, (N, n) bool (decoded from the ``V/active`` bitmask)."""
        self._check_variant(variant)
        mask = self.data[f"{variant}/active"].to_numpy(dtype=np.int64)
        n = int(self.meta.get("n_joints") or _n_from_meta(self.meta))
        return ((mask[:, None] >> np.arange(n)) & 1).astype(bool)

    def _check_variant(self, variant: str) -> None:
        if variant not in self.variants:
            raise ConfigError(
                f"{self.name or 'estimates'}: variant {variant!r} is not in the file "
                f"(it has {', '.join(self.variants) or 'none'})"
            )

    def save(self, path: str | Path) -> Path:
        """Write the estimates as Parquet atomically (zstd; metadata JSON under ``ditherlab``)."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        from ditherlab.io.atomic import atomic_path

        table = pa.Table.from_pandas(self.data, preserve_index=False)
        kv = dict(table.schema.metadata or {})
        kv[META_KEY] = json.dumps(self.meta, sort_keys=True, allow_nan=True).encode("utf-8")
        table = table.replace_schema_metadata(kv)
        with atomic_path(path) as tmp:
            pq.write_table(table, tmp, compression="zstd")
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> Estimates:
        """Read an estimates file; FormatError for anything that is not one."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        p = Path(path)
        if not p.is_file():
            raise FormatError(f"{p}: no such estimates file")
        try:
            table = pq.read_table(p)
        except (pa.ArrowException, OSError) as exc:
            raise FormatError(f"{p}: not a readable Parquet file ({exc})") from None
        kv = table.schema.metadata or {}
        if META_KEY not in kv:
            raise FormatError(
                f"{p}: key-value metadata 'ditherlab' is missing, expected an estimates file "
                "written by `ditherlab replay`"
            )
        try:
            meta = json.loads(kv[META_KEY].decode("utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            raise FormatError(f"{p}: metadata 'ditherlab' is not valid JSON ({exc})") from None
        if meta.get("schema") != SCHEMA:
            raise FormatError(
                f"{p}: metadata key 'schema' is {meta.get('schema')!r}, expected {SCHEMA!r} "
                "(a recording, not estimates? run `ditherlab replay` first)"
            )
        return cls(table.to_pandas(), meta, name=str(p))


def _n_from_meta(meta: dict[str, Any]) -> int:
    model = meta.get("model") or {}
    return int(model.get("n_joints", 0))


# ------------------------------------------------------------------------------- dither
@dataclass
class Extraction:
    """The dither signal extracted from one recording (paper §IV-A).

    Attributes
    ----------
    upper, lower, signal, centre, amplitude : (N, n) [N·m]
        One-period means of the samples above / below the period mean, their average (the new
        torque signal), the period mean, and half their difference (the dither amplitude).
    on : (N,) bool
        Dither active.
    valid : (N,) bool
        Dither active over the whole one-period window ending at the sample.
    period : [s]
    """

    upper: np.ndarray
    lower: np.ndarray
    signal: np.ndarray
    centre: np.ndarray
    amplitude: np.ndarray
    on: np.ndarray
    valid: np.ndarray
    period: float


def dither_on(rec: Recording) -> np.ndarray | None:
    """Where the dither is active, (N,) bool: the ``dither`` column, else where the ``tau_ffw``
    square wave has a non-zero amplitude; None when the recording has neither."""
    if rec.dither is not None:
        return rec.dither
    ffw = rec.tau_ffw
    if ffw is None:
        return None
    period = dither_period(rec)
    w = max(int(round(period * rec.sample_rate)), 2)
    hi = pd.DataFrame(ffw).rolling(w, min_periods=1, center=True).max().to_numpy()
    lo = pd.DataFrame(ffw).rolling(w, min_periods=1, center=True).min().to_numpy()
    return ((hi - lo) > 1e-6).any(axis=1)


def meta_dither_period(meta: Mapping[str, Any]) -> float | None:
    """The dither period [s] a recording's metadata states, or None.

    ``dither.period`` [s] or ``dither.omega`` [rad/s], at the top level or under ``sim``.
    """
    for d in (meta.get("dither"), (meta.get("sim") or {}).get("dither")):
        if isinstance(d, Mapping):
            if d.get("period"):
                return float(d["period"])
            if d.get("omega"):
                return float(2 * np.pi / float(d["omega"]))
    return None


def dither_period(rec: Recording) -> float:
    """The dither period [s].

    From the metadata when it states it (``dither.omega`` [rad/s] or ``dither.period`` [s], also
    under ``sim``), else from the zero crossings of ``tau_ffw``
    (:func:`ditherlab.dither.period_from_feedforward`), else the strongest spectral line above
    2 Hz of ``tau`` over the longest stretch with the dither on.
    """
    stated = meta_dither_period(rec.meta)
    if stated is not None:
        return stated
    if rec.tau_ffw is not None:
        from ditherlab.dither import period_from_feedforward

        ffw = rec.tau_ffw
        if rec.dither is not None and rec.dither.sum() > 8:
            ffw, tt = ffw[rec.dither], rec.t[rec.dither]
        else:
            tt = rec.t
        try:
            return period_from_feedforward(ffw, tt)
        except ConfigError:
            pass
    x = rec.tau
    on = rec.dither if rec.dither is not None else np.ones(len(rec), bool)
    starts, ends = runs(on)  # the longest run of dither-on samples
    if len(starts) == 0:
        raise ConfigError(f"{rec.name or 'recording'}: the dither is never on; no period to find")
    k = int(np.argmax(ends - starts))
    seg = x[starts[k] : ends[k]]
    seg = seg[: min(len(seg), 16384)]
    fs = rec.sample_rate
    if len(seg) < 32:
        raise ConfigError(
            f"{rec.name or 'recording'}: only {len(seg)} samples with the dither on; "
            "cannot find its period"
        )
    seg = seg - seg.mean(axis=0)
    spec = (np.abs(np.fft.rfft(seg * np.hanning(len(seg))[:, None], axis=0)) ** 2).sum(axis=1)
    f = np.fft.rfftfreq(len(seg), 1.0 / fs)
    spec[f < 2.0] = 0.0
    i = int(np.argmax(spec))
    if 0 < i < len(spec) - 1:  # parabolic refinement of the peak
        y0, y1, y2 = np.log(spec[i - 1 : i + 2] + 1e-300)
        den = y0 - 2 * y1 + y2
        delta = 0.5 * (y0 - y2) / den if den != 0 else 0.0
        fpk = f[i] + delta * (f[1] - f[0])
    else:
        fpk = f[i]
    if fpk <= 0:
        raise ConfigError(f"{rec.name or 'recording'}: no dither line found in the spectrum")
    return float(1.0 / fpk)


def extract_dither(rec: Recording, tau: np.ndarray | None = None) -> Extraction | None:
    """Extract the torque signal of a dithered recording (paper §IV-A), or None without dither.

    Parameters
    ----------
    rec : Recording with a ``dither`` column or ``tau_ffw``
    tau : (N, n) [N·m], optional — the torque to extract from (default ``rec.tau``)

    Returns
    -------
    Extraction, or None when the recording has no dither information or the dither is never on.
    """
    on = dither_on(rec)
    if on is None or not on.any():
        return None
    from ditherlab import dither as dmod

    period = dither_period(rec)
    x = rec.tau if tau is None else tau
    sig = dmod.extract(x, rec.t, period)
    w = max(int(round(period * rec.sample_rate)), 1)
    valid = dmod.full_window(on, w)  # the dither was on for the whole window (t - period, t]
    return Extraction(
        upper=np.asarray(sig.upper),
        lower=np.asarray(sig.lower),
        signal=np.asarray(sig.signal),
        centre=np.asarray(sig.centre),
        amplitude=np.asarray(sig.amplitude),
        on=on,
        valid=valid,
        period=period,
    )


# ------------------------------------------------------------------------------- replay
def parse_components(spec: str | Sequence[str] | None) -> list[str]:
    """``"all"``, ``"fxyz"``/``"force"``, or a comma list such as ``"f_x,f_z"`` -> names."""
    if spec is None:
        return list(COMPONENTS)
    if isinstance(spec, str):
        if spec in COMPONENT_SETS:
            return list(COMPONENT_SETS[spec])
        spec = [s.strip() for s in spec.split(",") if s.strip()]
    out = []
    for c in spec:
        if c not in COMPONENTS:
            raise ConfigError(
                f"component {c!r} is unknown; expected all, fxyz, or a comma list of "
                f"{', '.join(COMPONENTS)}"
            )
        out.append(c)
    return [c for c in COMPONENTS if c in out]


def available_variants(rec: Recording) -> list[str]:
    """The variants a recording allows: dither variants need a dither flag or ``tau_ffw``."""
    out = ["nodither_band", "nodither_noband"]
    on = rec.dither if rec.dither is not None else (None if rec.tau_ffw is None else True)
    if on is not None and np.any(on):
        out += ["dither_band", "dither_noband"]
    return out


def model_effects(model: TorqueModel | None, rec: Recording) -> np.ndarray:
    """The model's effects torque (:func:`ditherlab.effects.effects_torque`), (N, n) [N·m],
    computed without the F/T sensor (the estimator is sensorless); zeros without a model or
    without effects."""
    if model is None or not model.effects:
        return np.zeros((len(rec), rec.n))
    from ditherlab.effects import effects_torque

    return effects_torque(model, rec, sensor=False)


def _base_bands(
    model: TorqueModel, rec: Recording, reg: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-sample band and noise (N, n) [N·m] of the no-dither estimator."""
    N, n = len(rec), rec.n
    still = model.band("still")
    lo = np.broadcast_to(still.tau_min, (N, n)).copy()
    hi = np.broadcast_to(still.tau_max, (N, n)).copy()
    sig = np.broadcast_to(still.sigma, (N, n)).copy()
    mv = reg == MOVING
    if mv.any() and "moving" in model.regimes:
        b = model.regimes["moving"]
        dq = rec.dq
        slide = np.zeros((N, n))
        if b.coulomb is not None:
            slide += b.coulomb * np.sign(dq)
        if b.viscous is not None:
            slide += b.viscous * dq
        lo = np.where(mv, b.tau_min + slide, lo)
        hi = np.where(mv, b.tau_max + slide, hi)
        sig = np.where(mv, b.sigma, sig)
    return lo, hi, sig


def band_as_noise(
    lo: np.ndarray, hi: np.ndarray, sig: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drop the uniform term: band -> its centre, its variance ``(b - a)^2 / 12`` into the noise
    (:func:`ditherlab.dither.band_as_noise`).

    Parameters
    ----------
    lo, hi, sig : (N, n) [N·m]

    Returns
    -------
    (centre, centre, sqrt(sig^2 + (hi - lo)^2 / 12)), each (N, n) [N·m]
    """
    from ditherlab import dither as dmod

    c = 0.5 * (lo + hi)
    return c, c.copy(), dmod.band_as_noise(lo, hi, sig)


def replay(
    rec: Recording,
    model: TorqueModel,
    *,
    variants: Sequence[str] | None = None,
    level: float = 0.95,
    interval: str = "profile",
    components: str | Sequence[str] | None = None,
    backend: str = "exact",
    q_tol: float = 0.0,
    progress: Callable[[int, int], None] | None = None,
) -> Estimates:
    """Run the estimator variants over a recording.

    Parameters
    ----------
    rec : Recording (``N`` samples, ``n`` joints)
    model : TorqueModel of the same robot (``still`` band required; ``moving``, ``dither`` used
        when present)
    variants : subset of :data:`VARIANTS` (default: all the recording allows)
    level : interval confidence level in (0, 1)
    interval : ``"profile"`` or ``"set_membership"`` (:func:`ditherlab.estimator.intervals`)
    components : estimated wrench components (``"all"``, ``"fxyz"``, or names); the rest are held
        at the prior mean
    backend : estimator backend (``"exact"``; the QP references are for tests)
    q_tol : [rad] configuration quantisation for gravity/Jacobian (0 = exact; see
        :meth:`ditherlab.robot.RobotModel.gravity`)
    progress : ``progress(done, total)`` callback

    Returns
    -------
    Estimates

    Raises
    ------
    ModelError
        The model is for another robot, or lacks the ``still`` band.
    ConfigError
        Unknown variant, component or interval method, or a level outside (0, 1); a dither
        variant requested for a recording without dither.
    """
    from ditherlab.estimator import estimate, intervals

    check_robot(model, rec)
    model.validate()
    comps = parse_components(components)
    if interval not in INTERVAL_METHODS:
        raise ConfigError(
            f"interval method {interval!r} is unknown; expected one of {', '.join(INTERVAL_METHODS)}"
        )
    if not 0.0 < float(level) < 1.0:
        raise ConfigError(f"interval level is {level!r}, expected a number between 0 and 1")
    allowed = available_variants(rec)
    if variants is None:
        variants = allowed
    for v in variants:
        if v not in VARIANTS:
            raise ConfigError(f"variant {v!r} is unknown; expected one of {', '.join(VARIANTS)}")
        if v not in allowed:
            raise ConfigError(
                f"{rec.name or 'recording'}: variant {v} needs a dither column or tau_ffw, "
                "and this recording has neither (or the dither is never on)"
            )
    variants = [v for v in VARIANTS if v in variants]
    steps = 2 + 2 * len(variants)
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress:
            progress(done, steps)

    robot = rec.robot()
    q = rec.q
    g = robot.gravity(q, tol=q_tol)
    J = robot.jacobian(q, tol=q_tol)
    eff = model_effects(model, rec)
    tau_bar = rec.tau - g - eff
    reg = regimes(rec)
    lo, hi, sig = _base_bands(model, rec, reg)
    tick()

    ext = None
    if any(v.startswith("dither") for v in variants):
        ext = extract_dither(rec)
    tick()

    cols: dict[str, np.ndarray] = {"t": rec.t}
    if rec.has_wrench:
        w = rec.wrench
        for k, c in enumerate(COMPONENTS):
            cols[c] = w[:, k]
    if rec.dither is not None:
        cols["dither"] = rec.dither
    bits = (1 << np.arange(rec.n)).astype(np.int64)
    for v in variants:
        tb, a, b, s = tau_bar, lo, hi, sig
        if v.startswith("dither") and ext is not None:
            use = (reg == DITHER) & ext.valid[:, None]
            tb = np.where(use, ext.signal - g - eff, tau_bar)
            if "dither" in model.regimes:
                db = model.regimes["dither"]
                a = np.where(use, db.tau_min, lo)
                b = np.where(use, db.tau_max, hi)
                s = np.where(use, db.sigma, sig)
            else:
                from ditherlab.dither import dithered_band

                a, b = dithered_band(lo, hi, ext.amplitude, on=use)
        if v.endswith("noband"):
            a, b, s = band_as_noise(a, b, s)
        args = (tb, J, a, b, s, model.prior_mean, model.prior_sigma)
        sol = estimate(*args, components=comps, backend=backend)
        tick()
        if interval == "profile" and v.endswith("noband"):
            ilo, ihi = gaussian_profile_intervals(*args, F_hat=sol.F, level=level, components=comps)
        else:
            ilo, ihi = intervals(*args, F_hat=sol.F, method=interval, level=level, components=comps)
        tick()
        for k, c in enumerate(COMPONENTS):
            cols[f"{v}/{c}"] = sol.F[:, k]
        for k, c in enumerate(COMPONENTS):
            cols[f"{v}/{c}_lo"] = ilo[:, k]
        for k, c in enumerate(COMPONENTS):
            cols[f"{v}/{c}_hi"] = ihi[:, k]
        cols[f"{v}/active"] = np.asarray(sol.active, dtype=np.int64) @ bits
    if ext is not None:
        for j in range(rec.n):
            cols[f"extract/upper_{j + 1}"] = ext.upper[:, j]
            cols[f"extract/lower_{j + 1}"] = ext.lower[:, j]
            cols[f"extract/signal_{j + 1}"] = ext.signal[:, j]
    meta = {
        "schema": SCHEMA,
        "recording": rec.meta,
        "recording_name": rec.name,
        "model": model.to_dict(),
        "n_joints": rec.n,
        "variants": list(variants),
        "interval": {"method": interval, "level": float(level)},
        "components": comps,
    }
    if ext is not None:
        meta["dither_period"] = ext.period
    meta["moving_spans"] = time_spans(rec.t, (reg == MOVING).any(axis=1))
    return Estimates(pd.DataFrame(cols), _plain(meta), name=None)


def runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The runs of True in ``mask`` (N,) bool, as sample indices ``[start, end)``.

    Returns
    -------
    starts, ends : (R,) int
        First sample of each run, and the first sample after it (``N`` for a run at the end).
    """
    e = np.diff(np.r_[0, np.asarray(mask, dtype=bool).astype(np.int8), 0])
    return np.flatnonzero(e == 1), np.flatnonzero(e == -1)


def merge_runs(
    t: np.ndarray, starts: Sequence[int], ends: Sequence[int], gap: float
) -> list[tuple[int, int]]:
    """Runs ``[start, end)`` (in time order) merged where less than ``gap`` [s] apart.

    Parameters
    ----------
    t : (N,) [s]
    starts, ends : (R,) sample indices, e.g. from :func:`runs`
    gap : [s] from the last sample of one run to the first of the next

    Returns
    -------
    list of (start, end) sample indices, in time order
    """
    merged: list[list[int]] = []
    for a, b in zip(starts, ends, strict=True):
        if merged and t[a] - t[merged[-1][1] - 1] < gap:
            merged[-1][1] = int(b)
        else:
            merged.append([int(a), int(b)])
    return [(a, b) for a, b in merged]


def time_spans(t: np.ndarray, mask: np.ndarray) -> list[list[float]]:
    """``[[t_start, t_end], ...]`` [s] of the runs of True in ``mask`` (N,)."""
    s0, s1 = runs(mask)
    return [[float(t[a]), float(t[b - 1])] for a, b in zip(s0, s1, strict=True)]


__all__ = [
    "COMPONENTS",
    "Estimates",
    "Extraction",
    "VARIANTS",
    "available_variants",
    "band_as_noise",
    "dither_on",
    "dither_period",
    "merge_runs",
    "meta_dither_period",
    "model_effects",
    "extract_dither",
    "gaussian_profile_intervals",
    "parse_components",
    "replay",
    "replay_file",
    "runs",
    "time_spans",
    "describe",
    "ModelError",
]


def replay_file(
    path: str | Path,
    model_path: str | Path,
    out: str | Path,
    *,
    read_options: dict | None = None,
    **options: Any,
) -> Estimates:
    """Read a recording and a model, :func:`replay`, and save the estimates (atomic, never over
    an input). ``options`` are those of :func:`replay`."""
    from ditherlab.io import read
    from ditherlab.io.atomic import check_not_input

    check_not_input(out, [path, model_path])
    model = TorqueModel.load(model_path)
    rec = read(path, **(read_options or {}))
    est = replay(rec, model, **options)
    est.save(out)
    est.name = str(out)
    return est


def describe(est: Estimates) -> str:
    """A few lines: samples, variants, interval method, and per variant the force RMS error and
    interval coverage against the F/T sensor when it is there."""
    lines = [
        f"{len(est.data)} samples, variants: {', '.join(est.variants)}; intervals "
        f"{est.meta['interval']['method']} at {est.meta['interval']['level']:.0%}"
    ]
    if est.has_wrench:
        F = est.wrench[:, :3]
        for v in est.variants:
            Fh = est.F(v)[:, :3]
            lo, hi = est.interval(v)
            cov = ((lo[:, :3] <= F) & (F <= hi[:, :3])).mean()
            rms = np.sqrt(((Fh - F) ** 2).mean(axis=0))
            lines.append(
                f"  {v:<16} force error RMS x/y/z {rms[0]:.1f}/{rms[1]:.1f}/{rms[2]:.1f} N,"
                f" interval coverage {cov:.1%}"
            )
    return "\n".join(lines)
