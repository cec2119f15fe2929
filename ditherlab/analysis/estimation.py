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
    and below the period mean, averaged; :func:`extract_dither`), less gravity and the model's
    effects through the same window (:func:`model_seen`), and the band is the model's
    ``dither`` band — identified on that same extracted signal (:mod:`ditherlab.analysis.identification`). A
    model without a ``dither`` band falls back to the paper's rule: the ``still`` band shrunk by
    the extracted dither amplitude on each side (Fig. 4). Samples without dither (before the
    dither, the first dither period) are treated as in ``nodither_band``, and so is a joint in
    the dither's ramp-in (:func:`ditherlab.physics.dither.ramp_in`: after the dither switches
    on, until the joint's extracted amplitude reaches the ramp-in fraction of the amplitude the
    model's dither band was built with): its extracted signal and dither band are not yet the
    regime's.
``dither_noband``
    ``dither_band`` without the uniform term, as in the paper's Fig. 6 (right column).

The result is an :class:`Estimates` table in the estimates format (brief: Parquet with ``t``,
the sensor columns and ``dither`` copied, per variant ``V/f_x .. V/m_z``, ``V/<c>_lo``,
``V/<c>_hi``, ``V/active`` as a joint bitmask; for dither variants ``extract/upper_j``,
``extract/lower_j``, ``extract/signal_j``; key-value metadata ``ditherlab`` = JSON).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from ditherlab.analysis.known_load import known_columns
from ditherlab.analysis.vendor import vendor_columns
from ditherlab.core.errors import ConfigError
from ditherlab.core.files import plain
from ditherlab.core.names import DITHER, MOVING
from ditherlab.core.ticker import Ticker
from ditherlab.core.timeseries import causal_mean, time_spans
from ditherlab.data.estimates import COMPONENTS, SCHEMA, VARIANTS, Estimates
from ditherlab.data.recording import Recording, regimes
from ditherlab.data.torque_model import TorqueModel
from ditherlab.estimator import intervals, problem, solve
from ditherlab.estimator.interval_methods.gaussian import (
    gaussian_problem_estimate,
    gaussian_profile_intervals,
)
from ditherlab.physics.dither import (
    Extraction,
    dithered_band,
    extract_dither,
    ramp_in,
    ramp_level,
    ramp_samples,
    ramp_state,
    window_samples,
)
from ditherlab.physics.dither import band_as_noise as band_variance_as_noise
from ditherlab.physics.effects import effects_torque, force_gain
from ditherlab.physics.effects.extraction import as_extracted, extraction_gain

INTERVAL_METHODS = ("profile", "set_membership")
#: ``--components`` shorthands.
COMPONENT_SETS = {"all": COMPONENTS, "fxyz": COMPONENTS[:3], "force": COMPONENTS[:3]}


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
    if rec.timebase is not None:  # a piece: what the whole recording allows
        on = rec.timebase.dither_period is not None
    else:
        on = rec.dither if rec.dither is not None else (None if rec.tau_ffw is None else True)
    if on is not None and np.any(on):
        out += ["dither_band", "dither_noband"]
    return out


def model_effects(model: TorqueModel | None, rec: Recording) -> np.ndarray:
    """The model's effects torque (:func:`ditherlab.physics.effects.effects_torque`), (N, n) [N·m],
    computed without the F/T sensor (the estimator is sensorless); zeros without a model or
    without effects."""
    if model is None or not model.effects:
        return np.zeros((len(rec), rec.n))
    return effects_torque(model, rec, sensor=False)


def band_as_noise(
    lo: np.ndarray, hi: np.ndarray, sig: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drop the uniform term: band -> its centre, its variance ``(b - a)^2 / 12`` into the noise
    (:func:`ditherlab.physics.dither.band_as_noise`).

    Parameters
    ----------
    lo, hi, sig : (N, n) [N·m]

    Returns
    -------
    (centre, centre, sqrt(sig^2 + (hi - lo)^2 / 12)), each (N, n) [N·m]
    """
    c = 0.5 * (lo + hi)
    return c, c.copy(), band_variance_as_noise(lo, hi, sig)


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
    cols, meta = replay_columns(
        rec, model, variants=variants, level=level, interval=interval, components=components,
        backend=backend, q_tol=q_tol, progress=progress,
    )  # fmt: skip
    return Estimates(pd.DataFrame(cols), plain(meta), name=None)


def replay_columns(
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
    carry: RampCarry | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """What :func:`replay` computes, as the estimates file's columns (each (N,), in file order)
    and its metadata before :func:`~ditherlab.core.files.plain` (``recording`` is ``rec.meta``
    itself): :func:`ditherlab.app.replay.replay_stream` writes the columns straight to Parquet without a DataFrame
    and converts the metadata of its first piece only; ``carry`` (:class:`RampCarry`) carries
    the dither's ramp-in from its previous piece. Parameters and errors as :func:`replay`."""
    model.check_robot(rec)
    model.validate()
    comps = parse_components(components)
    variants = _check_options(rec, variants, interval, level)
    tick = Ticker(2 + 2 * len(variants), progress)
    inp = _replay_inputs(rec, model, variants, q_tol, tick, carry)
    how = ReplayHow(level, interval, backend, comps)
    cols = _recording_columns(rec)
    cols.update(known_columns(rec))  # the known load's wrench, when the recording declares one
    vendor_cols, vendor_meta = vendor_columns(rec)
    cols.update(vendor_cols)
    bits = (1 << np.arange(rec.n)).astype(np.int64)
    for v in variants:
        F, active, ilo, ihi = variant_estimate(v, inp, model, how, tick)
        for suffix, X in (("", F), ("_lo", ilo), ("_hi", ihi)):
            Xc = _columns(X)
            for k, c in enumerate(COMPONENTS):
                cols[f"{v}/{c}{suffix}"] = Xc[k]
        cols[f"{v}/active"] = np.asarray(active, dtype=np.int64) @ bits
    if inp.ext is not None:
        cols.update(_extraction_columns(inp.ext, rec.n))
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
    if vendor_meta:
        meta["vendor"] = vendor_meta
    if inp.ext is not None:
        meta["dither_period"] = inp.ext.period
    meta["moving_spans"] = time_spans(rec.t, (inp.reg == MOVING).any(axis=1))
    return cols, meta


class ReplayHow(NamedTuple):
    """How every variant of one replay is estimated: the intervals' ``level`` and method
    (``interval``), the solver ``backend``, the estimated components ``comps``."""

    level: float
    interval: str
    backend: str
    comps: list[str]


class ReplayInputs(NamedTuple):
    """What every variant of one replay reads.

    Attributes
    ----------
    g : (N, n) [N·m] gravity; J : (N, 6, n) the Jacobians, scaled by the drive gains
    eff : (N, n) [N·m] the model's effects
    reg : (N, n) the regime codes
    base : the still-band inputs (``tau - g - eff`` (N, n) [N·m], then the model's bands and
        noise per sample)
    ext : the dither extraction (None when no dither variant runs)
    w_ext : [samples] one dither period (1 without extraction)
    dq_mean : (N, n) [rad/s] the velocity's causal mean over it (None without extraction)
    seen : (N, n) [N·m] gravity and the effects as the extraction shows them: their causal mean
        over ``w_ext`` samples (:func:`~ditherlab.physics.effects.extraction.as_extracted`),
        what a dither variant subtracts from the extracted signal (None without extraction)
    """

    g: np.ndarray
    J: np.ndarray
    eff: np.ndarray
    reg: np.ndarray
    base: tuple
    ext: Extraction | None
    w_ext: int
    dq_mean: np.ndarray | None
    seen: np.ndarray | None


def _replay_inputs(
    rec: Recording,
    model: TorqueModel,
    variants: Sequence[str],
    q_tol: float,
    tick: Ticker,
    carry: RampCarry | None = None,
) -> ReplayInputs:
    """The robot's quantities, the model's effects and bands per sample (one ``tick``), and the
    dither extraction with its ramp-in when a dither variant runs (one more; ``carry`` the
    ramp-in of the previous piece)."""
    robot = rec.robot()
    # one deduplication pass for both (a whole hour is too large for the robot's cache)
    g, J = robot.gravity_jacobian(rec.q, tol=q_tol)
    # the log's drive gains scale the pushes' torque too (drive_gain): J^T row j times k_j
    J *= force_gain(model)[None, None, :]
    eff = model_effects(model, rec)
    reg = regimes(rec)
    model.band("still")  # the estimator needs it: a clear error without
    base = (rec.tau - g - eff, *model.sample_bands(reg, rec.dq))
    tick()
    ext = extract_dither(rec) if any(v.startswith("dither") for v in variants) else None
    w_ext = window_samples(ext.period, rec.sample_rate) if ext is not None else 1
    if ext is not None:
        args = (ext.on, ext.valid, ext.amplitude, ramp_level(model), ramp_samples(rec.sample_rate))
        ext.ramp = ramp_in(*args) if carry is None else carry.marks(*args)
    dq_mean = causal_mean(rec.dq, w_ext) if ext is not None else None
    seen = model_seen(g + eff, w_ext) if ext is not None else None
    tick()
    return ReplayInputs(g, J, eff, reg, base, ext, w_ext, dq_mean, seen)


def model_seen(model_tau: np.ndarray, w: int) -> np.ndarray:
    """(N, n) [N·m]: gravity plus the model's effects ``model_tau`` (N, n) [N·m] as the dither's
    extraction shows them, through the same window of ``w`` samples (one dither period):
    :func:`~ditherlab.physics.effects.extraction.as_extracted` without an external torque (the
    estimator's unknown). The value of a row needs the ``w - 1`` rows before it."""
    return as_extracted(model_tau, None, None, w)


def _columns(X: np.ndarray) -> np.ndarray:
    """(N, k) -> k contiguous (N,) columns."""
    return np.ascontiguousarray(X.T)


def _recording_columns(rec: Recording) -> dict[str, np.ndarray]:
    """The estimates file's first columns: ``t``, the sensor's wrench, the dither flag."""
    cols: dict[str, np.ndarray] = {"t": rec.t}
    if rec.has_wrench:
        w = _columns(rec.wrench)
        for k, c in enumerate(COMPONENTS):
            cols[c] = w[k]
    if rec.dither is not None:
        cols["dither"] = rec.dither
    return cols


def variant_estimate(
    v: str,
    inp: ReplayInputs,
    model: TorqueModel,
    how: ReplayHow,
    tick: Ticker,
    lead: LeadCarry | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Variant ``v``'s estimate ``F`` (N, 6) [N, N·m], active joints (N, n) and interval
    ``lo``, ``hi`` (N, 6) (two ``tick``); ``lead`` the rows of the past the extraction's lead
    reads when ``inp`` are new rows of a stream (:class:`LeadCarry`; None: ``inp`` is the
    whole of it)."""
    tb, a, b, s = variant_inputs(v, inp.base, model, inp.reg, inp.seen, inp.ext, inp.dq_mean)
    Jv = inp.J
    if v.startswith("dither"):
        Jv = extraction_jacobian(inp.J, model, inp.reg, inp.ext)
        past = None if lead is None else lead.swap(v, tb, inp.reg, inp.ext, inp.w_ext)
        tb = extraction_lead(tb, model, inp.reg, inp.ext, inp.w_ext, past)
    # one validated problem for the estimate and its intervals
    prob = problem(tb, Jv, a, b, s, model.prior_mean, model.prior_sigma, how.comps)
    closed = how.interval == "profile" and v.endswith("noband")  # zero-width bands
    if closed and how.backend == "exact":  # the estimate and its interval, one factorisation
        F, active, ilo, ihi = gaussian_problem_estimate(prob, level=how.level)
        tick()
    else:
        sol = solve(prob, how.backend)
        F, active = sol.F, sol.active
        tick()
        if closed:
            ilo, ihi = gaussian_profile_intervals(prob, F, level=how.level)
        else:
            ilo, ihi = intervals(prob, F, method=how.interval, level=how.level)
    tick()
    return F, active, ilo, ihi


def _extraction_columns(ext: Extraction, n: int) -> dict[str, np.ndarray]:
    """The dither extraction's columns: upper and lower means and the signal per joint."""
    up, low, sig = _columns(ext.upper), _columns(ext.lower), _columns(ext.signal)
    cols = {}
    for j in range(n):
        cols[f"extract/upper_{j + 1}"] = up[j]
        cols[f"extract/lower_{j + 1}"] = low[j]
        cols[f"extract/signal_{j + 1}"] = sig[j]
    return cols


def _check_options(
    rec: Recording, variants: Sequence[str] | None, interval: str, level: float
) -> list[str]:
    """The variants to run, in file order; ConfigError for an unknown or impossible option."""
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
    return [v for v in VARIANTS if v in variants]


def variant_inputs(
    variant: str,
    base: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    model: TorqueModel,
    reg: np.ndarray,
    seen: np.ndarray | None,
    ext: Extraction | None,
    dq_mean: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The estimator's inputs of one variant: ``tau_bar``, band edges and noise per sample.

    ``tau_bar = tau - gravity - effects`` with the model's per-sample bands
    (:meth:`ditherlab.data.torque_model.TorqueModel.sample_bands`); a dither variant takes the extracted
    signal less gravity and the effects through the same window (``seen``: the extracted signal
    is a mean over the last dither period, so the model torque is compared with it as the
    extraction shows it, its part at the dither's own frequency averaged out) and the dither
    band (or the still band shrunk by the dither amplitude) where a joint
    stands still with the dither on over a whole window and out of its ramp-in
    (:attr:`ditherlab.physics.dither.Extraction.ramp`: there it keeps the raw torque and its
    band without dither); a no-band variant moves the band into the noise
    (:func:`band_as_noise`).

    Parameters
    ----------
    variant : one of :data:`VARIANTS`
    base : ``tau - gravity - effects`` and the model's per-sample band and noise, each (N, n)
    reg : (N, n) regimes
    seen : (N, n) [N·m] gravity and the model's effects through the extraction's window
        (:func:`model_seen`; None without dither)
    ext : the recording's dither extraction (None without dither)
    dq_mean : (N, n) [rad/s] joint velocities averaged over the last dither period: with them, a
        dither variant also reads the extracted signal where a joint moves with the dither on
        over a whole window (it creeps under a push: the raw torque there carries the dither's
        square wave, up to the band), with the moving band about the sliding line at this
        velocity (the dither's own vibration averaged out)

    Returns
    -------
    tau_bar, tau_min, tau_max, sigma : each (N, n) [N·m]
    """
    tau_bar, lo, hi, sig = base
    tb, a, b, s = base
    if variant.startswith("dither") and ext is not None:
        use = (reg == DITHER) & ext.valid[:, None] & settled(ext)
        tb = np.where(use, ext.signal - seen, tau_bar)
        if "dither" in model.regimes:
            db = model.regimes["dither"]
            a = np.where(use, db.tau_min, lo)
            b = np.where(use, db.tau_max, hi)
            s = np.where(use, db.sigma, sig)
        else:
            a, b = dithered_band(lo, hi, ext.amplitude, on=use)
        if dq_mean is not None and "moving" in model.regimes:
            creep = (reg == MOVING) & (ext.valid & ext.on)[:, None] & settled(ext)
            if creep.any():
                mb = model.regimes["moving"]
                slide = mb.sliding(dq_mean)
                tb = np.where(creep, ext.signal - seen, tb)
                a = np.where(creep, mb.tau_min + slide, a)
                b = np.where(creep, mb.tau_max + slide, b)
                s = np.where(creep, mb.sigma, s)
    if variant.endswith("noband"):
        a, b, s = band_as_noise(a, b, s)
    return tb, a, b, s


def settled(ext: Extraction) -> np.ndarray | bool:
    """(N, n) bool: the joints out of the dither's ramp-in (:attr:`Extraction.ramp`); True
    where none is marked."""
    return True if ext.ramp is None else ~ext.ramp


def reads_extraction(reg: np.ndarray, ext: Extraction) -> np.ndarray:
    """(N, n) bool: where a dither variant reads the extracted signal of a joint: the dither on
    over a whole window, the joint in the dither regime or creeping under a push (``reg``
    (N, n) regimes) and out of its ramp-in."""
    return ((reg == DITHER) | (reg == MOVING)) & (ext.valid & ext.on)[:, None] & settled(ext)


class RampCarry:
    """The dither's ramp-in (:func:`ditherlab.physics.dither.ramp_in`) carried across the
    overlapping pieces of a recording (:func:`ditherlab.app.replay.replay_stream`), so that a
    ramp-in longer than a piece's context is marked as in the whole: the marks of the last
    piece's rows from its owned ones on, and the rule's state at the end of its owned rows.
    Call :meth:`at` before each piece, in order."""

    def __init__(self) -> None:
        self.start, self.keep = 0, slice(0, None)
        self.done: np.ndarray | None = None  # the last piece's marks, rows from `row` on
        self.row = 0  # the whole recording's row of done[0]
        self.state: np.ndarray | None = None  # after the rows before `end`
        self.end = 0

    def at(self, start: int, keep: slice) -> None:
        """The next piece: its first row ``start`` in the whole recording and its owned rows
        ``keep`` (:class:`ditherlab.io.stream.Piece`)."""
        self.start, self.keep = int(start), keep

    def marks(self, flag, valid, amp, level, longest) -> np.ndarray:
        """:func:`~ditherlab.physics.dither.ramp_in` of the piece (arguments as there): rows
        before its owned ones from the last piece, the rest from the state at their start."""
        N, n = np.shape(amp)
        a = self.keep.start
        b = N if self.keep.stop is None else self.keep.stop
        out = np.zeros((N, n), dtype=bool)
        if self.done is not None and a > 0:
            lo = self.start - self.row  # this piece's first row in the last piece's marks
            out[:a] = self.done[lo : lo + a]
        st = ramp_state(n) if self.state is None or self.end != self.start + a else self.state
        out[a:b] = ramp_in(flag[a:b], valid[a:b], amp[a:b], level, longest, st)
        self.state, self.end = st.copy(), self.start + b
        out[b:] = ramp_in(flag[b:], valid[b:], amp[b:], level, longest, st)
        self.done, self.row = out[a:], self.start + a
        return out


def extraction_jacobian(
    J: np.ndarray, model: TorqueModel, reg: np.ndarray, ext: Extraction | None
) -> np.ndarray:
    """``J`` (N, 6, n) with joint j's row scaled by the model's ``dither_extraction`` gain
    where a dither variant reads the extracted signal of that joint (the dither on over a whole
    window, the joint in the dither regime or creeping under a push): the extracted signal shows
    ``gain`` of the push's torque there (:mod:`ditherlab.physics.effects.extraction`). ``J`` itself
    without the effect or without dither."""
    gain = extraction_gain(model.effects, J.shape[2])
    if gain is None or ext is None:
        return J
    use = reads_extraction(reg, ext)
    scale = np.where(use, gain[None, :], 1.0)  # (N, n)
    return J * scale[:, None, :]


def extraction_lead(
    tb: np.ndarray,
    model: TorqueModel,
    reg: np.ndarray,
    ext: Extraction | None,
    window: int,
    past: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The torque a dither variant reads, moved forward by the extraction's delay on the
    joints the model's ``dither_extraction`` names, where the dither is on over whole windows.

    The extracted signal is the mean of the last ``window`` samples, through the effect's
    first-order lag of ``lag_j`` samples: it shows joint j's push torque of
    ``d_j = (window - 1) / 2 + lag_j`` samples ago. For a first-order lag ``x = y + T dy/dt``;
    the causal extrapolation ``y(t) + d_j / k (y(t) - y(t - k))`` (``k`` = half a window, the
    shortest difference the window's ripple allows) reads it at ``t`` again. Friction held
    still does not change ``y``: at rest only the noise of the difference is added.

    Parameters
    ----------
    tb : (N, n) [N·m] the variant's torque ``tau_bar`` ; reg : (N, n) regimes
    ext : the recording's extraction ; window : samples per dither period
    past : the rows of the same stream just before ``tb`` (a causal estimate's kept past,
        :class:`LeadCarry`): their ``tb`` (P, n) [N·m] and where they read the extraction
        (:func:`reads_extraction`, (P, n) bool); None: ``tb`` starts the stream

    Returns
    -------
    (N, n) [N·m]: ``tb`` moved (``tb`` itself when nothing applies)
    """
    lags = extraction_gain(model.effects, model.n, "lag")
    if ext is None or lags is None:
        return tb
    named = sorted(
        {jj - 1 for s in model.effects if s.name == "dither_extraction" for jj in s.joints}
    )
    k = lead_span(window)
    use = reads_extraction(reg, ext)
    P, y = 0, tb
    if past is not None and len(past[0]):
        P, y, use = len(past[0]), np.concatenate([past[0], tb]), np.concatenate([past[1], use])
    if len(y) <= k:
        return tb
    use[k:] &= use[:-k]  # the older sample also read through a whole window
    use[:k] = False
    out = tb.copy()
    for j in named:
        d = (window - 1) / 2 + lags[j]
        step = np.zeros(len(y))
        step[k:] = (y[k:, j] - y[:-k, j]) * (d / k)
        out[:, j] = np.where(use[P:, j], tb[:, j] + step[P:], tb[:, j])
    return out


def lead_span(window: int) -> int:
    """[samples] the span ``k`` of the extraction lead's difference: half a dither period of
    ``window`` samples, at least 1 (:func:`extraction_lead`)."""
    return max((window - 1) // 2, 1)


class LeadCarry:
    """The rows of the past the extraction's lead (:func:`extraction_lead`) reads, carried
    across the updates of a causal estimate (:mod:`ditherlab.analysis.causal`): per dither
    variant the last :func:`lead_span` rows of its torque before the lead and where they read
    the extraction. :meth:`clear` starts afresh (a gap in the stream)."""

    def __init__(self) -> None:
        self.rows: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def clear(self) -> None:
        """Forget the past: the next rows start the stream."""
        self.rows.clear()

    def swap(
        self, v: str, tb: np.ndarray, reg: np.ndarray, ext: Extraction | None, window: int
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Variant ``v``'s kept rows before the new ones (``past`` of :func:`extraction_lead`;
        None at the start), and keep the last rows of them and the new ones: ``tb`` (N, n)
        [N·m] the variant's torque, ``reg`` (N, n) regimes, ``ext`` the extraction of the new
        rows, ``window`` samples per dither period."""
        past = self.rows.get(v)
        if ext is None:
            return past
        k = lead_span(window)
        use = reads_extraction(reg, ext)
        if past is not None:
            tb, use = np.concatenate([past[0], tb]), np.concatenate([past[1], use])
        self.rows[v] = (tb[-k:].copy(), use[-k:].copy())
        return past


__all__ = [
    "COMPONENTS",
    "Estimates",
    "VARIANTS",
    "available_variants",
    "band_as_noise",
    "extraction_jacobian",
    "extraction_lead",
    "lead_span",
    "LeadCarry",
    "model_effects",
    "model_seen",
    "parse_components",
    "RampCarry",
    "replay",
    "replay_columns",
    "variant_inputs",
]
