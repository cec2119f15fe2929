"""The time-series panels: per joint the torques (``tau``, ``tau_bar`` beside ``J^T F`` of the
sensor, the model's bands), the dither (Fig. 5 centre and amplitude, Fig. 4 extraction), the
friction residual of every model version; per force axis the sensor and the estimates."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import pandas as pd
import rerun as rr

from ditherlab.analysis.estimation import model_effects, model_seen
from ditherlab.core.errors import ConfigError
from ditherlab.core.names import DITHER, FORCE_AXES, STILL, VENDOR
from ditherlab.core.timeseries import causal_mean
from ditherlab.data.estimates import Estimates
from ditherlab.data.recording import Recording
from ditherlab.data.torque_model import Band, TorqueModel
from ditherlab.output.rerun.columns import REGIME_COLORS, SENSOR_COLOR, VARIANT_COLORS, ColumnLogger
from ditherlab.physics import dither
from ditherlab.physics.dither import (
    Extraction,
    dithered_band,
    extract_dither,
    full_window,
    has_dither,
    window_samples,
)
from ditherlab.physics.effects import effects_torque, external_torque, sensor_wrench, signals

EXTRACT_SIGNALS = ("upper", "lower", "signal")
_DITHER_COL = re.compile(r"^dither_(?P<name>[A-Za-z0-9_]+?)_(?P<j>\d+)$")
#: colours of the model versions' residuals and of the joints' history bars
_PALETTE = [(200, 60, 60), (230, 150, 40), (60, 160, 60), (40, 110, 230), (140, 60, 200)]
#: Fig. 5 signals a simulator or controller may log: centre_ref_3, amp_meas_3, centre_ffw_3 ...
_FIG5_COL = re.compile(r"^(?P<name>(?:centre|center|amp|amplitude)(?:_[a-z]+)?)_(?P<j>\d+)$")


# ---------------------------------------------------------------------- per joint
def tau_bar(rec: Recording, gravity: np.ndarray, model: TorqueModel | None = None) -> np.ndarray:
    """Gravity-compensated torque ``tau - gravity(q) - effects_torque`` as replay uses it.

    Parameters
    ----------
    rec : recording with ``q (N, n)`` [rad], ``tau (N, n)`` [N·m]
    gravity : (N, n) [N·m], ``rec.robot().gravity(rec.q)``
    model : optional; its effects are subtracted when it has any

    Returns
    -------
    (N, n) [N·m]
    """
    return rec.tau - gravity - model_effects(model, rec)


def external_sensor(rec: Recording) -> np.ndarray | None:
    """``J(q)^T F_sensor`` (N, n) [N·m]: the joint torque of the sensed wrench
    (:meth:`ditherlab.physics.effects.Signals.jtf`, on the recording's cached Jacobian), or None."""
    if not rec.has_wrench:
        return None
    return signals(rec).jtf(rec.wrench)


def log_joints(
    log: ColumnLogger,
    rec: Recording,
    keep: slice,
    tb: np.ndarray,
    jtf: np.ndarray | None,
    model: TorqueModel | None,
) -> None:
    """Per joint ``tau`` and ``tau_bar`` beside ``J^T F`` of the sensor.

    ``rec`` is a piece (or the whole recording) and ``keep`` its owned rows; ``tb`` and ``jtf``
    (L, n) [N·m] are on all of its rows."""
    tau = rec.tau[keep]
    tb = tb[keep]
    jtf = None if jtf is None else jtf[keep]
    label = "tau - gravity" if model is None or not model.effects else "tau - gravity - effects"
    for j in range(rec.n):
        base = f"joints/{j + 1}"
        log.series(
            f"{base}/tau", tau[:, j], names="tau", colors=[[120, 120, 120]], widths=1.0, thin=False
        )
        # tau_bar and J^T F of the sensor share one entity: same units and scale, and one time
        # column and row id for both halves the file size of the pair.
        if jtf is None:
            vals, names, colors = tb[:, j], label, [[0, 0, 0]]
        else:
            vals = np.column_stack([tb[:, j], jtf[:, j]])
            names, colors = [label, "J^T F (sensor)"], [[0, 0, 0], [0, 150, 150]]
        log.series(f"{base}/tau_bar", vals, names=names, colors=colors, widths=1.5, thin=False)


def log_bands(log: ColumnLogger, n: int, model: TorqueModel | None, span: np.ndarray) -> None:
    """The model's band edges per joint and regime at ``span`` (the recording's first and last
    time [s]), once."""
    if model is None:
        return
    for j in range(n):
        for regime in (STILL.label, DITHER.label):
            if regime not in model.regimes:
                continue
            b = model.regimes[regime]
            edges = np.tile([b.tau_min[j], b.tau_max[j]], (len(span), 1))
            log.series(
                f"joints/{j + 1}/band/{regime}",
                edges,
                names=[f"{regime} band min", f"{regime} band max"],
                colors=[REGIME_COLORS[regime]] * 2,
                widths=1.0,
                t=span,
                thin=False,
            )


def dither_period(rec: Recording, estimates: Estimates | None = None) -> float | None:
    """The dither period [s] of a recording, or None when it has no dither (or none is found).

    The estimates file's ``dither_period`` (what replay used) when it states one, else
    :func:`ditherlab.physics.dither.dither_period` (the metadata, the feedforward's square wave, the
    torque's spectrum) where :func:`ditherlab.physics.dither.dither_on` finds the dither on (for a
    piece of a longer recording: the whole recording's, from its time base).
    """
    if estimates is not None and estimates.meta.get("dither_period"):
        return float(estimates.meta["dither_period"])
    try:
        # the feedforward's interpolation divides by zero where the square wave is flat; those
        # entries are unused
        with np.errstate(invalid="ignore", divide="ignore"):
            if not has_dither(rec):  # a piece: whether the whole recording has it
                return None
            return dither.dither_period(rec)
    except ConfigError:
        return None


def _extraction(rec: Recording) -> Extraction | None:
    """:func:`ditherlab.physics.dither.extract_dither` (the extraction replay writes), or None when the
    recording has no dither or no period is found."""
    try:
        with np.errstate(invalid="ignore", divide="ignore"):  # as in dither_period
            return extract_dither(rec)
    except ConfigError:
        return None


def _fig5_group(col: str, n: int) -> tuple[str, str, int] | None:
    """Recording column -> (``centre``/``amplitude``/``other``, series name, joint) for Fig. 5."""
    m = _DITHER_COL.match(col) or _FIG5_COL.match(col)
    if m is None or not 1 <= int(m["j"]) <= n:
        return None
    name = m["name"]
    if name.startswith(("centre", "center")):
        group = "centre"
    elif name.startswith("amp"):
        group = "amplitude"
    else:
        group = "other"
    return group, name, int(m["j"])


#: Fig. 5's colours: the centre, the amplitude, the other dither columns
_SHADES = {"centre": (40, 110, 230), "amplitude": (230, 130, 30), "other": (120, 120, 120)}


def _light(c: tuple[int, ...]) -> tuple[int, ...]:
    """Colour ``c`` half-way to white (references and commands beside their measured series)."""
    return tuple(int(x + (255 - x) * 0.5) for x in c)


def log_dither(
    log: ColumnLogger,
    rec: Recording,
    keep: slice,
    estimates: Estimates | None,
    g: np.ndarray,
    tb: np.ndarray,
    model: TorqueModel | None,
    period: float | None,
) -> None:
    """Fig. 5 (centre and amplitude: measured, reference, feedforward) and Fig. 4 (upper, lower,
    extracted signal; the signal minus gravity against J^T F of the sensor and the bands).

    ``rec`` is a piece (or the whole recording) and ``keep`` its owned rows; ``g``, ``tb`` (L, n)
    [N·m] on all its rows; ``estimates`` the owned rows' estimates; ``period`` [s] the whole
    recording's dither period (:func:`dither_period`), None without dither."""
    _log_fig5_columns(log, rec, keep)
    d = estimates.data if estimates is not None else None
    have = d is not None and all(f"extract/{s}_1" in d.columns for s in EXTRACT_SIGNALS)
    if period is None:
        return
    # The estimates file's own columns when present (the extraction replay did and wrote, read
    # back rather than redone); without them the same extraction, ditherlab.physics.dither.extract_dither.
    ext = None if have else _extraction(rec)
    if not have and ext is None:
        return
    # The window is the extraction's: whole periods at this rate; the centre (not in the file) is
    # its window mean.
    window = max(2, int(round(period / rec.dt))) if len(rec) > 1 else 2
    centre = (causal_mean(rec.tau, window) if ext is None else ext.centre)[keep]  # (M, n) [N·m]
    still = model.regimes.get(STILL.label) if model is not None else None
    # Dither quantities mean something only where the dither was on over the whole window; NaN
    # elsewhere (runs of NaN thin to their two ends, so the off stretches cost two rows each).
    on = _dither_window_on(rec, window)[keep]
    # gravity and the effects through the estimator's window (one period of samples)
    seen = model_seen(rec.tau - tb, window_samples(period, rec.sample_rate))[keep]
    rows = _DitherRows(
        centre, g[keep], rec.tau[keep], seen, on, ~on,
        # the simulator states its amplitude set-points (the reference of Fig. 5) in its metadata
        ((rec.meta.get("sim") or {}).get("dither_amplitudes") or {}).get("set_point"),
        # the paper's rule (Fig. 4) for a model without a dither band
        still if still is not None and (model is None or DITHER.label not in model.regimes)
        else None,
    )  # fmt: skip
    for j in range(1, rec.n + 1):
        sig: dict[str, np.ndarray] = {}
        for s in EXTRACT_SIGNALS:
            if ext is None:
                assert d is not None
                sig[s] = d[f"extract/{s}_{j}"].to_numpy(dtype=float)
            else:
                sig[s] = getattr(ext, s)[keep, j - 1]
        amp = _log_extraction_joint(log, rows, sig, j)
        _log_fig4_joint(log, rows, sig, amp, j)


def _log_fig5_columns(log: ColumnLogger, rec: Recording, keep: slice) -> None:
    """The dither's feedforward and the recording's own Fig. 5 columns (centre, amplitude,
    their references and commands) on the owned rows ``keep``."""
    ffw = rec.tau_ffw
    if ffw is not None:
        for j in range(rec.n):
            log.series(
                f"joints/{j + 1}/dither/ffw",
                ffw[keep, j],
                names="tau_ffw",
                colors=[[150, 150, 150]],
            )
    for col in rec.data.columns:
        hit = _fig5_group(str(col), rec.n)
        if hit is None:
            continue
        group, name, j = hit
        light = "ref" in name or "ffw" in name or "cmd" in name
        c = _SHADES[group] if not light else _light(_SHADES[group])
        vals = pd.to_numeric(rec.data[col].iloc[keep], errors="coerce").to_numpy(dtype=float)
        log.series(f"joints/{j}/dither/{group}/{name}", vals, names=name, colors=[c], step=True)


class _DitherRows(NamedTuple):
    """The owned rows of a piece, for every joint's dither panels: the window mean ``centre``,
    gravity ``g``, torque ``tau`` and gravity plus the effects as the dither variants subtract
    them from the extracted signal, through one dither period (``seen``) (M, n) [N·m]; where the
    dither was on over the whole window (``on``) and not (``off``) (M,); the simulator's
    amplitude set-points (n,) [N·m] or None; the still band to shrink by the paper's rule, or
    None (the model has a dither band, or no still band)."""

    centre: np.ndarray
    g: np.ndarray
    tau: np.ndarray
    seen: np.ndarray
    on: np.ndarray
    off: np.ndarray
    setpoint: list[float] | None
    shrink: Band | None


def _log_extraction_joint(
    log: ColumnLogger, rows: _DitherRows, sig: Mapping[str, np.ndarray], j: int
) -> np.ndarray:
    """Joint ``j``'s (1-based) extraction ``sig`` (upper, lower, signal) beside the window mean
    and gravity, and the extracted amplitude beside its set-point; returns the amplitude (M,)
    [N·m]."""
    off = rows.off
    # upper, lower, signal, the window mean (Fig. 5's measured centre) and its reference, the
    # gravity torque, share one entity (same units, scale and time base: one time column and
    # row id for five series).
    log.series(
        f"joints/{j}/extract",
        np.where(
            off[:, None],
            np.nan,
            np.column_stack(
                [sig[s] for s in EXTRACT_SIGNALS] + [rows.centre[:, j - 1], rows.g[:, j - 1]]
            ),
        ),
        names=[*EXTRACT_SIGNALS, "centre (window mean)", "centre reference (gravity)"],
        colors=[
            [220, 50, 50],
            [40, 170, 60],
            [0, 0, 0],
            _SHADES["centre"],
            _light(_SHADES["centre"]),
        ],
        widths=[1.0, 1.0, 2.0, 2.0, 1.5],
    )
    amp = (sig["upper"] - sig["lower"]) / 2
    log.series(
        f"joints/{j}/dither/amplitude/extracted",
        np.where(off, np.nan, amp),
        names="amplitude (extracted)",
        colors=[_SHADES["amplitude"]],
        widths=2.0,
    )
    if rows.setpoint is not None and j <= len(rows.setpoint):
        log.series(
            f"joints/{j}/dither/amplitude/set_point",
            np.where(off, np.nan, float(rows.setpoint[j - 1])),
            names="amplitude set-point",
            colors=[_light(_SHADES["amplitude"])],
            widths=1.5,
        )
    return amp


def _log_fig4_joint(
    log: ColumnLogger,
    rows: _DitherRows,
    sig: Mapping[str, np.ndarray],
    amp: np.ndarray,
    j: int,
) -> None:
    """Fig. 4, lower, of joint ``j`` (1-based): the extracted signal in the estimator's units
    (gravity and effects through the window off), and the still band shrunk by the amplitude
    ``amp`` (M,) [N·m]."""
    log.series(
        f"joints/{j}/fig4/signal_bar",
        np.where(rows.off, np.nan, sig["signal"] - rows.seen[:, j - 1]),
        names="extracted signal - gravity",
        colors=[[200, 0, 200]],
        widths=2.0,
    )
    if rows.shrink is not None:
        # The paper's rule (Fig. 4): the still band shrunk by the dither amplitude on each
        # side, where the dither was on over the whole window; the still band elsewhere.
        still = rows.shrink
        lo, hi = dithered_band(still.tau_min[j - 1], still.tau_max[j - 1], amp, on=rows.on)
        log.series(
            f"joints/{j}/band/dither_shrunk",
            np.column_stack([lo, hi]),
            names=["shrunk band min", "shrunk band max"],
            colors=[REGIME_COLORS[DITHER.label]] * 2,
        )


def _dither_window_on(rec: Recording, window: int) -> np.ndarray:
    """(N,) bool: the dither flag was on for each of the last ``window`` samples."""
    on = rec.dither if rec.dither is not None else np.ones(len(rec), dtype=bool)
    return full_window(on, window)


# ---------------------------------------------------------------------- per force axis
#: the vendor's own estimate in the force panels (RGB): apart from the variants and the sensor
VENDOR_COLOR = (200, 0, 160)


def log_forces(log: ColumnLogger, rec: Recording, keep: slice, estimates: Estimates | None) -> None:
    """Per force axis the sensor, the controller's online estimate and every variant's estimate
    with its interval (``rec`` a piece, ``keep`` its owned rows, ``estimates`` theirs)."""
    if rec.has_wrench:
        w = rec.wrench[keep]
        for k, a in enumerate(FORCE_AXES):
            log.series(
                f"force/{a}/sensor",
                w[:, k],
                names="sensor",
                colors=[SENSOR_COLOR],
                widths=1.5,
                thin=False,
            )
    # An estimate the controller used online (the simulator's lead-through logs fhat_x..z).
    for a in FORCE_AXES:
        if f"fhat_{a}" in rec.data.columns:
            log.series(
                f"force/{a}/online",
                rec.data[f"fhat_{a}"].to_numpy(dtype=float)[keep],
                names="online estimate (controller)",
                colors=[[150, 60, 200]],
                widths=1.5,
            )
    if estimates is None:
        return
    d = estimates.data
    if f"{VENDOR}/f_x" in d.columns:  # the vendor's own estimate, beside ditherlab's
        for a in FORCE_AXES:
            log.series(
                f"force/{a}/{VENDOR}",
                d[f"{VENDOR}/f_{a}"].to_numpy(dtype=float),
                names="vendor's estimate",
                colors=[VENDOR_COLOR],
                widths=1.5,
            )
    for v in estimates.variants:
        c = VARIANT_COLORS[v]
        light = tuple(int(x + (255 - x) * 0.55) for x in c)
        for a in FORCE_AXES:
            cols = [f"{v}/f_{a}", f"{v}/f_{a}_lo", f"{v}/f_{a}_hi"]
            have = [x for x in cols if x in d.columns]
            names = [v, f"{v} lo", f"{v} hi"][: len(have)]
            log.series(
                f"force/{a}/{v}",
                d[have].to_numpy(dtype=float),
                names=names,
                colors=[c, light, light][: len(have)],
                widths=[2.0, 1.0, 1.0][: len(have)],
            )


# ---------------------------------------------------------------------- residuals
def model_versions(model: TorqueModel) -> dict[int, TorqueModel]:
    """The model of every version in ``model.history`` that can be rebuilt exactly, and the model.

    ``add_effect`` appends an effect and keeps the earlier ones unchanged, so version k's effects
    are the first ones of the current model when the names of its history row (``effects``) are
    a prefix of the current names. Rows that are not (an effect replaced or removed since) are
    left out. Bands do not enter the residual, so they are not rebuilt.

    Returns
    -------
    dict version -> TorqueModel, in increasing version order
    """
    names = model.effect_names()
    out: dict[int, TorqueModel] = {}
    for h in model.history:
        if not isinstance(h, Mapping) or "version" not in h:
            continue
        effs = [e if isinstance(e, str) else e.get("name") for e in h.get("effects", [])]
        if names[: len(effs)] != effs:
            continue
        m = model.copy()
        m.effects = m.effects[: len(effs)]
        m.version = int(h["version"])
        out[m.version] = m
    out[model.version] = model
    return dict(sorted(out.items()))


def residual(rec: Recording, gravity: np.ndarray, model: TorqueModel) -> np.ndarray:
    """Friction residual ``tau - gravity - effects_torque - external_torque(sensor_wrench)``.

    Parameters
    ----------
    rec : recording with the F/T sensor columns
    gravity : (N, n) [N·m]
    model : TorqueModel (its effects, ``attenuation_lag`` and ``ft_bias`` included)

    Returns
    -------
    (N, n) [N·m]
    """
    ext = external_torque(model, rec, sensor_wrench(model, rec))
    return rec.tau - gravity - effects_torque(model, rec) - ext


def log_residuals(
    log: ColumnLogger, rec: Recording, keep: slice, g: np.ndarray, model: TorqueModel | None
) -> None:
    """Residual per joint for every rebuildable model version (``rec`` a piece, ``keep`` its
    owned rows, ``g`` (L, n) [N·m] on all its rows)."""
    if model is None:
        return
    if rec.has_wrench:
        for k, (ver, m) in enumerate(model_versions(model).items()):
            rho = residual(rec, g, m)[keep]
            label = f"v{ver}: " + (" + ".join(m.effect_names()) or "base model")
            for j in range(rec.n):
                log.series(
                    f"joints/{j + 1}/residual/v{ver}",
                    rho[:, j],
                    names=label,
                    colors=[_PALETTE[k % len(_PALETTE)]],
                    widths=1.0,
                    thin=False,
                )


def log_history(log: ColumnLogger, model: TorqueModel | None) -> None:
    """The model history's residual RMS per version (bar charts and a table, static), once."""
    if model is None:
        return
    rows = [h for h in model.history if isinstance(h, Mapping) and h.get("torque_rms")]
    if not rows:
        return
    rms = np.array([h["torque_rms"] for h in rows], dtype=float)  # (versions, n) [N·m]
    versions = np.array([float(h.get("version", i + 1)) for i, h in enumerate(rows)])
    for j in range(rms.shape[1]):
        log.stream.log(
            f"history/torque_rms/{j + 1}",
            rr.BarChart(rms[:, j], abscissa=versions, color=_PALETTE[j % len(_PALETTE)]),
            static=True,
        )
    lines = [
        "| version | effects | torque residual RMS per joint [N·m] | force RMS f_x f_y f_z [N] |",
        "|---|---|---|---|",
    ]
    for h in rows:
        fr = " ".join(f"{v:.3g}" for v in (h.get("force_rms") or [])[:3]) or "-"
        lines.append(
            f"| {h.get('version')} | {', '.join(h.get('effects', [])) or 'base'} | "
            f"{' '.join(f'{v:.3g}' for v in h['torque_rms'])} | {fr} |"
        )
    log.stream.log(
        "info/history", rr.TextDocument("\n".join(lines), media_type="text/markdown"), static=True
    )
