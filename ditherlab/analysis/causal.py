"""The force estimate of eq. (3) computed sample by sample from the past alone: the one update
behind ``ditherlab replay --causal`` and ``ditherlab live``.

:func:`ditherlab.analysis.estimation.replay` sees a whole recording: its velocity (when only ``q``
is logged) is a central difference, its acceleration a centred Savitzky–Golay fit, its regimes a
centred velocity mean. A robot running live has only the samples so far. :class:`CausalEstimator`
keeps the few samples it needs (:attr:`CausalEstimator.context`) and, for every new sample,
computes

- ``dq``: the logged velocity, else the backward difference ``(q_i - q_{i-1}) / (t_i - t_{i-1})``
  (0 at the first sample);
- ``ddq``: the backward difference of ``dq`` over :data:`DDQ_SPAN` (40 ms, the offline fit's
  span): ``(dq_i - dq_{i-k}) / (t_i - t_{i-k})``, a lag of about 20 ms;
- the regime: a joint moves when its velocity averaged over the last :data:`MOVING_WINDOW`
  (0.1 s, the offline window, trailing instead of centred: a lag of about 50 ms) exceeds
  :data:`MOVING_THRESHOLD`; it is in the dither regime when the dither is on and it stands
  still;
- the dither: on where the ``dither`` flag says so, else where the feedforward's range over the
  last period is non-zero; the extraction's period means over the last period
  (:func:`ditherlab.physics.dither.extract`, already causal: the same values as offline), and
  gravity plus the model's effects through the same window
  (:func:`ditherlab.analysis.estimation.model_seen`, their values at the kept past remembered),
  what the dither variants subtract from it;
- the dither's ramp-in per joint (:func:`ditherlab.physics.dither.ramp_in`, from the switch-on
  of the dither until the joint's extracted amplitude is up, at most
  :data:`~ditherlab.physics.dither.RAMP_MAX_S`), the rule's state carried from update to
  update (afresh after a gap): the offline rule, which reads only the past;

and then runs the very estimator of the offline replay on these inputs
(:func:`ditherlab.analysis.estimation.variant_estimate`). Each value comes from its own window
of past samples (no running sums), so the result of a sample does not depend on how the stream
was cut into blocks: ``replay --causal`` (blocks of a file) and ``live`` (whatever arrived) give
the same floats for the same samples.

Model effects are applied per sample (their ``ddq`` and regime the causal ones above). The
dither extraction's effect (``dither_extraction``) is causal as the offline replay applies it:
its gain scales the Jacobian's rows where a dither variant reads the extraction
(:func:`~ditherlab.analysis.estimation.extraction_jacobian`, per sample), and its lead
(:func:`~ditherlab.analysis.estimation.extraction_lead`) reads the variant's torque of half a
period before, kept per variant across updates
(:class:`~ditherlab.analysis.estimation.LeadCarry`, afresh after a gap). A torque effect that is
a filter in time (:attr:`ditherlab.physics.effects.base.Effect.pointwise` False) has no causal
form here and is refused.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from ditherlab.analysis.causal_fast import FastPath, as_kernel, fast_params, supported
from ditherlab.analysis.estimation import (
    LeadCarry,
    ReplayHow,
    ReplayInputs,
    available_variants,
    model_seen,
    parse_components,
    variant_estimate,
)
from ditherlab.core.errors import ConfigError
from ditherlab.core.names import DITHER, MOVING, STILL
from ditherlab.core.stamps import wire_time
from ditherlab.core.ticker import Ticker
from ditherlab.core.timeseries import causal_mean, time_spans
from ditherlab.data.estimates import COMPONENTS, SCHEMA, VARIANTS
from ditherlab.data.recording import (
    GAP_MIN_S,
    GAP_STEPS,
    Recording,
    RecordingArrays,
    TimeBase,
)
from ditherlab.data.torque_model import TorqueModel
from ditherlab.physics.dither import (
    Extraction,
    check_waveform,
    dither_period,
    dither_waveform,
    extract,
    full_window,
    has_dither,
    ramp_in,
    ramp_level,
    ramp_samples,
    ramp_state,
)
from ditherlab.physics.effects import effects_torque, force_gain, get_effect, signals
from ditherlab.robot import RobotModel

__all__ = [
    "DDQ_SPAN",
    "MOVING_THRESHOLD",
    "MOVING_WINDOW",
    "CausalBlock",
    "CausalEstimator",
    "CausalSettings",
    "block_of",
    "settings_for",
]

#: [s] the span of the backward difference that gives ``ddq`` (the offline fit's span)
DDQ_SPAN = 0.04
#: [s] the trailing window of the velocity mean that decides whether a joint moves
MOVING_WINDOW = 0.1
#: [rad/s] a joint moves above this mean velocity (:func:`ditherlab.data.recording.regimes`)
MOVING_THRESHOLD = 5e-3
#: a feedforward whose range over the last period exceeds this [N·m] is on
FFW_ON = 1e-6


@dataclass(frozen=True)
class CausalSettings:
    """What a causal estimate is computed with, fixed before the first sample.

    Attributes
    ----------
    dt : [s] the nominal sample step: it turns the windows into sample counts
    period : [s] the dither period; None runs no dither variant
    variants : the estimator variants, in file order (:data:`VARIANTS`)
    level : the intervals' confidence level in (0, 1) ; interval : ``profile`` or
        ``set_membership``
    components : ``all``, ``fxyz`` or a comma list (:func:`parse_components`)
    waveform : the dither waveform (``square``, ``sine``, ``triangle``)
    """

    dt: float
    period: float | None = None
    variants: tuple[str, ...] = ("nodither_band", "nodither_noband")
    level: float = 0.95
    interval: str = "profile"
    components: str = "all"
    waveform: str = "square"

    def windows(self) -> dict[str, int]:
        """The windows in samples: ``move`` (velocity mean), ``ddq`` (difference span),
        ``period`` (one dither period, 1 without dither)."""
        per = 1 if self.period is None else max(int(round(self.period / self.dt)), 1)
        return {
            "move": max(1, int(round(MOVING_WINDOW / self.dt))),
            "ddq": max(1, int(round(DDQ_SPAN / self.dt))),
            "period": per,
        }


class CausalBlock(NamedTuple):
    """New samples, in time order, time first.

    Attributes
    ----------
    t : (N,) [s] strictly increasing, after every earlier sample
    q : (N, n) [rad] ; tau : (N, n) [N·m]
    dq : (N, n) [rad/s] or None (then differenced from ``q``)
    dither : (N,) bool or None ; tau_ffw : (N, n) [N·m] or None
    wrench : (N, 6) [N, N·m] or None: a sensor's wrench, copied to the output for comparison
    """

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    dq: np.ndarray | None = None
    dither: np.ndarray | None = None
    tau_ffw: np.ndarray | None = None
    wrench: np.ndarray | None = None


class CausalEstimator:
    """The per-sample causal estimate (module docstring): :meth:`update` takes new samples and
    returns their rows of the estimates file.

    Parameters
    ----------
    model : the torque model ; meta : the stream's recording metadata (``robot`` at least; the
        robot must be the model's)
    settings : :class:`CausalSettings`
    robot : the robot already built from ``meta`` (optional)
    fast : run the per-sample path (:mod:`ditherlab.analysis.causal_fast`) where it covers the
        model and settings (:attr:`fast` not None); False: the general update, its reference
    """

    def __init__(
        self,
        model: TorqueModel,
        meta: Mapping[str, Any],
        settings: CausalSettings,
        robot: RobotModel | None = None,
        fast: bool = True,
    ) -> None:
        self.model, self.settings = model, settings
        self.meta = {"schema": SCHEMA, **dict(meta)}
        self.robot = robot or RobotModel.from_recording_meta(self.meta, n_expected=model.n)
        _check(model, settings)
        self.n = model.n
        self.how = ReplayHow(
            settings.level, settings.interval, "exact", parse_components(settings.components)
        )
        self.win = settings.windows()
        #: the dither's ramp-in: the level that ends it (n,) [N·m] or None, its longest
        #: [samples], its state (:func:`ditherlab.physics.dither.ramp_state`)
        self.ramp = (ramp_level(model), ramp_samples(1.0 / settings.dt), ramp_state(self.n))
        #: rows kept of the past: the longest window of any quantity, plus one
        self.keep = max(self.win.values()) + 2
        self.context: dict[str, np.ndarray] | None = None
        #: the rows of the past the extraction's lead reads (afresh with the context)
        self.lead = LeadCarry()
        self.t0: float | None = None
        self.gain = force_gain(model)
        #: the model with its torque effects alone (what :meth:`_effects` evaluates; the
        #: external ones act on ``J^T F`` in the estimator), None without any
        self.torque_model = _torque_effects(model)
        #: ``[[t_start, t_end], ...]`` [s]: where any joint moved (causal regimes), so far
        self.moving_spans: list[list[float]] = []
        #: gaps in the stream so far (each starts the estimate afresh)
        self.gaps = 0
        self._moved = False
        #: the per-sample path, None where the general update runs (:func:`supported`)
        self.fast: FastPath | None = None
        if fast and supported(model, settings.interval) is None:
            par = fast_params(
                model, settings, self.how.comps, self.gain, (MOVING_THRESHOLD, FFW_ON)
            )
            if len(par.free):
                self.fast = FastPath(par, self.robot, max(GAP_MIN_S, GAP_STEPS * settings.dt))
                self._names = _row_names(settings.variants, self.n, settings.period is not None)

    def update(self, block: CausalBlock) -> dict[str, np.ndarray]:
        """The estimates of new samples, as the estimates file's columns (each (N,), file order:
        ``t``, the sensor's wrench and ``dither`` when given, per variant ``V/f_x .. V/m_z``,
        ``_lo``, ``_hi``, ``V/active``, the extraction's columns with dither).

        A step longer than :data:`GAP_STEPS` sample steps and :data:`GAP_MIN_S` (the offline
        derivative's gap) starts the estimate afresh: no window reaches across it (counted in
        :attr:`gaps`).

        Raises ConfigError when a time is not after the previous one or a value is not finite.
        """
        if self.fast is not None:
            return self._fast_update(block)
        b = self._checked(block)
        every = b.t if self.context is None else np.r_[self.context["t"][-1], b.t]
        gap = max(GAP_MIN_S, GAP_STEPS * self.settings.dt)
        # the rows of b that start afresh (step k of `every` ends at row k + 1 - off of b)
        off = 0 if self.context is None else 1
        cuts = np.flatnonzero(np.diff(every) > gap) + 1 - off
        if not len(cuts):
            return self._update(b)
        parts = []
        for a, e in zip(np.r_[0, cuts], np.r_[cuts, len(b.t)], strict=True):
            if a == e:
                continue
            if a in cuts:
                self.gaps += 1
                self.context = None
            parts.append(self._update(_rows(b, slice(a, e))))
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}

    def _fast_update(self, block: CausalBlock) -> dict[str, np.ndarray]:
        """:meth:`update` by the per-sample path."""
        N = np.size(block.t)
        t = as_kernel(block.t, (N,))

        def arr(x: Any, width: int) -> np.ndarray | None:
            return None if x is None else as_kernel(x, (N, width))

        on = None if block.dither is None else as_kernel(block.dither, (N,), np.bool_)
        q, tau, dq, ffw = (arr(x, self.n) for x in (block.q, block.tau, block.dq, block.tau_ffw))
        rows, act = self.fast.run(t, q, tau, dq, on, ffw)
        self.gaps = self.fast.gaps
        if self.t0 is None and N:
            self.t0 = float(t[0])
        cols: dict[str, np.ndarray] = {"t": t}
        if block.wrench is not None:
            cols.update(zip(COMPONENTS, arr(block.wrench, 6).T.copy(), strict=True))
        if on is not None:
            cols["dither"] = on
        per, ext = self._names
        it = iter(rows)
        for (names, active), a in zip(per, act, strict=True):
            cols.update(zip(names, it, strict=False))
            cols[active] = a
        cols.update(zip(ext, it, strict=False))
        self._track(t, rows[-1])
        return cols

    def _update(self, b: CausalBlock) -> dict[str, np.ndarray]:
        """:meth:`update` of rows without a gap."""
        if self.context is None:
            self.lead.clear()
        X = self._joined(b)
        N = len(b.t)
        feats = self._features(X, N)
        inp = self._inputs(b, feats, X.get("model_past"))
        cols = self._columns(b, inp)
        self._remember(X, feats, inp)
        self._track(b.t, (feats["reg"] == MOVING).any(axis=1))
        return cols

    def metadata(self, name: str | None = None) -> dict[str, Any]:
        """The estimates file's metadata (as :func:`ditherlab.analysis.estimation.replay_columns`
        writes it), with ``causal`` stating the windows."""
        s = self.settings
        meta: dict[str, Any] = {
            "schema": SCHEMA,
            "recording": self.meta,
            "recording_name": name,
            "model": self.model.to_dict(),
            "n_joints": self.n,
            "variants": list(s.variants),
            "interval": {"method": s.interval, "level": float(s.level)},
            "components": self.how.comps,
            "moving_spans": [list(s) for s in self.moving_spans],
            "causal": {"ddq_span": DDQ_SPAN, "moving_window": MOVING_WINDOW, "dt": s.dt},
        }
        if s.period is not None:
            meta["dither_period"] = s.period
        return meta

    # ------------------------------------------------------------------ the steps
    def _checked(self, b: CausalBlock) -> CausalBlock:
        """``b`` as float arrays of the right shapes; ConfigError for a time not after the
        last one or a value that is not finite."""
        t = np.atleast_1d(np.asarray(b.t, dtype=float))
        every = t if self.context is None else np.r_[self.context["t"][-1], t]
        steps = np.diff(every)
        if len(steps) and not (steps > 0).all():
            k = int(np.argmax(~(steps > 0)))
            raise ConfigError(
                f"sample time {every[k + 1]!r} s is not after the previous one "
                f"({every[k]!r} s); expected strictly increasing times"
            )

        def arr(x: Any, width: int | None) -> np.ndarray | None:
            if x is None:
                return None
            a = np.asarray(x, dtype=float)
            return a.reshape(len(t), width) if width else a.reshape(len(t))

        out = CausalBlock(
            t, arr(b.q, self.n), arr(b.tau, self.n), arr(b.dq, self.n),
            None if b.dither is None else np.asarray(b.dither, dtype=bool).reshape(len(t)),
            arr(b.tau_ffw, self.n), arr(b.wrench, 6),
        )  # fmt: skip
        for k, v in zip(CausalBlock._fields[:-1], out[:-1], strict=True):  # a sensor: as it is
            if v is not None and v.dtype == float and not np.isfinite(v).all():
                raise ConfigError(f"{k} at t = {t[0]:.6f} s is not finite; expected numbers")
        return out

    def _joined(self, b: CausalBlock) -> dict[str, np.ndarray]:
        """The kept past and the new samples, one array per raw quantity (``dq_in`` the logged
        velocity or None, ``on`` the dither flag or None)."""
        new = {"t": b.t, "q": b.q, "tau": b.tau, "dq_in": b.dq, "on_in": b.dither, "ffw": b.tau_ffw}
        if self.t0 is None:
            self.t0 = float(b.t[0])
        if self.context is None:
            return {k: v for k, v in new.items() if v is not None}
        out = {}
        for k, v in new.items():
            old = self.context.get(k)
            if (v is None) != (old is None):
                raise ConfigError(
                    f"the stream's {k.removesuffix('_in')} is given for some samples only; "
                    "expected it for every sample or for none"
                )
            if v is not None:
                out[k] = np.concatenate([old, v])
        for k in ("dq", "on", "model"):  # derived values of the past, kept
            out[k + "_past"] = self.context[k]
        return out

    def _features(self, X: dict[str, np.ndarray], N: int) -> dict[str, Any]:
        """The causal quantities of the ``N`` newest rows of ``X`` (module docstring): ``dq``,
        ``ddq``, ``on``, ``reg``, the extraction ``ext`` and ``dq_mean``; ``dq`` and ``on`` also
        for the kept past (``dq_all``, ``on_all``), to be remembered."""
        t, q = X["t"], X["q"]
        P = len(t) - N  # rows of the past
        dq_new = X["dq_in"][P:] if "dq_in" in X else _backward(t, q, P, 1)
        dq_all = dq_new if P == 0 else np.concatenate([X["dq_past"], dq_new])
        ddq = _backward(t, dq_all, P, self.win["ddq"])
        moving = np.abs(causal_mean(dq_all, self.win["move"])[P:]) > MOVING_THRESHOLD
        on_all = _dither_on(X, P, self.win["period"])
        reg = np.full((N, self.n), STILL, dtype=np.int8)
        if on_all is not None:
            reg[on_all[P:], :] = DITHER
        reg[moving] = MOVING
        ext, dq_mean = None, None
        if self.settings.period is not None:
            ext = self._extraction(X, on_all, P)
            dq_mean = causal_mean(dq_all, self.win["period"])[P:]
        return {
            "dq": dq_new, "ddq": ddq, "reg": reg, "ext": ext, "dq_mean": dq_mean,
            "dq_all": dq_all, "on_all": on_all,
        }  # fmt: skip

    def _extraction(self, X: dict[str, np.ndarray], on_all: np.ndarray | None, P: int):
        """The dither extraction of the new rows (:func:`ditherlab.physics.dither.extract` over
        the kept past and them) and their ramp-in (the rule's state carried; afresh without a
        past)."""
        s = self.settings
        sig = extract(X["tau"], X["t"], s.period, dt=s.dt, waveform=s.waveform)
        on = np.zeros(len(X["t"]), bool) if on_all is None else on_all
        valid = full_window(on, self.win["period"])
        level, longest, state = self.ramp
        if P == 0:
            state[:] = -1
        ramp = ramp_in(on[P:], valid[P:], sig.amplitude[P:], level, longest, state)
        return Extraction(
            upper=sig.upper[P:], lower=sig.lower[P:], signal=sig.signal[P:],
            centre=sig.centre[P:], amplitude=sig.amplitude[P:], on=on[P:], valid=valid[P:],
            period=float(s.period), waveform=s.waveform, ramp=ramp,
        )  # fmt: skip

    def _inputs(self, b: CausalBlock, f: dict[str, Any], past: np.ndarray | None) -> ReplayInputs:
        """The estimator's inputs of the new rows: gravity, Jacobians, effects, bands, and with
        dither gravity and the effects through the extraction's window (over ``past`` (P, n)
        [N·m], their sum at the kept rows, and the new rows)."""
        # every pose of a live robot is new: no deduplication and no cache to grow
        g, J = self.robot.gravity_jacobian(b.q, dedup=False)
        J *= self.gain[None, None, :]
        eff = self._effects(b, f)
        base = (b.tau - g - eff, *self.model.sample_bands(f["reg"], f["dq"]))
        w = self.win["period"]
        seen = None
        if f["ext"] is not None:
            m = g + eff
            seen = model_seen(m if past is None else np.concatenate([past, m]), w)[-len(m) :]
        return ReplayInputs(g, J, eff, f["reg"], base, f["ext"], w, f["dq_mean"], seen)

    def _effects(self, b: CausalBlock, f: dict[str, Any]) -> np.ndarray:
        """The model's effects (N, n) [N·m] at the new rows, driven by the causal ``dq``,
        ``ddq`` and regimes (a recording of these rows whose derived quantities are set)."""
        if self.torque_model is None:
            return np.zeros((len(b.t), self.n))
        arrays = RecordingArrays(t=b.t, q=b.q, tau=b.tau, dq=f["dq"], tau_ffw=b.tau_ffw)
        tb = TimeBase(float(self.t0), self.settings.dt, True, self.settings.period)
        rec = Recording(pd.DataFrame(arrays.columns()), self.meta, timebase=tb)
        rec.share_robot(self.robot)
        rec.__dict__["ddq"] = f["ddq"]  # the causal one (a cached property of the recording)
        signals(rec)._shared["regime"] = f["reg"]
        return effects_torque(self.torque_model, rec, sensor=False)

    def _columns(self, b: CausalBlock, inp: ReplayInputs) -> dict[str, np.ndarray]:
        """The estimates file's columns of the new rows."""
        cols: dict[str, np.ndarray] = {"t": b.t}
        if b.wrench is not None:
            cols.update({c: np.ascontiguousarray(b.wrench[:, k]) for k, c in enumerate(COMPONENTS)})
        if b.dither is not None:
            cols["dither"] = b.dither
        bits = (1 << np.arange(self.n)).astype(np.int64)
        tick = Ticker(2 * len(self.settings.variants), None)
        for v in self.settings.variants:
            F, active, lo, hi = variant_estimate(v, inp, self.model, self.how, tick, self.lead)
            for suffix, M in (("", F), ("_lo", lo), ("_hi", hi)):
                for k, c in enumerate(COMPONENTS):
                    cols[f"{v}/{c}{suffix}"] = np.ascontiguousarray(M[:, k])
            cols[f"{v}/active"] = np.asarray(active, dtype=np.int64) @ bits
        if inp.ext is not None:
            for j in range(self.n):
                cols[f"extract/upper_{j + 1}"] = np.ascontiguousarray(inp.ext.upper[:, j])
                cols[f"extract/lower_{j + 1}"] = np.ascontiguousarray(inp.ext.lower[:, j])
                cols[f"extract/signal_{j + 1}"] = np.ascontiguousarray(inp.ext.signal[:, j])
        return cols

    def _track(self, t: np.ndarray, moving: np.ndarray) -> None:
        """Extend :attr:`moving_spans` by the new rows' ``moving`` (N,) (bool, or 0 and 1) at
        ``t`` (N,) [s]."""
        if len(t) == 1:  # one sample (the live loop): its own span, or the one it continues
            now = bool(moving[0])
            if now and self._moved and self.moving_spans:
                self.moving_spans[-1][1] = float(t[0])
            elif now:
                self.moving_spans.append([float(t[0]), float(t[0])])
            self._moved = now
            return
        if not len(t):
            return
        moving = np.asarray(moving, dtype=bool)
        for a, b in time_spans(t, moving):
            if self._moved and a == t[0] and self.moving_spans:
                self.moving_spans[-1][1] = b  # a motion across the blocks continues
            else:
                self.moving_spans.append([a, b])
        self._moved = bool(moving[-1])

    def _remember(self, X: dict[str, np.ndarray], f: dict[str, Any], inp: ReplayInputs) -> None:
        """Keep the last :attr:`keep` rows of the raw quantities, of ``dq`` and the dither flag,
        and of gravity plus the effects (the extraction's window of them needs ``w - 1``)."""
        k = self.keep
        ctx = {key: v[-k:] for key, v in X.items() if not key.endswith("_past")}
        ctx["dq"] = f["dq_all"][-k:]
        ctx["on"] = None if f["on_all"] is None else f["on_all"][-k:]
        m, past = inp.g + inp.eff, X.get("model_past")
        ctx["model"] = (m if past is None else np.concatenate([past, m]))[-k:]
        for key in ("dq_in", "on_in", "ffw"):
            ctx.setdefault(key, None)
        self.context = ctx


def _row_names(
    variants: Sequence[str], n: int, dither: bool
) -> tuple[list[tuple[list[str], str]], list[str]]:
    """The estimates file's columns of the per-sample path's outputs: per variant the names of
    its rows (the wrench, ``_lo``, ``_hi``) and of its active joints; the extraction's rows."""
    per = []
    for v in variants:
        names = [f"{v}/{c}{suffix}" for suffix in ("", "_lo", "_hi") for c in COMPONENTS]
        per.append((names, f"{v}/active"))
    ext = []
    if dither:
        for j in range(1, n + 1):
            ext += [f"extract/upper_{j}", f"extract/lower_{j}", f"extract/signal_{j}"]
    return per, ext


def _rows(b: CausalBlock, rows: slice) -> CausalBlock:
    """Rows of a block."""
    return CausalBlock(*(None if v is None else v[rows] for v in b))


def _check(model: TorqueModel, s: CausalSettings) -> None:
    """ConfigError for settings or a model the causal estimate cannot run."""
    model.validate()
    model.band("still")
    if not (np.isfinite(s.dt) and s.dt > 0):
        raise ConfigError(f"sample step is {s.dt!r} s; expected a positive time")
    if s.period is not None and not (np.isfinite(s.period) and s.period > 0):
        raise ConfigError(f"dither period is {s.period!r} s; expected a positive time")
    check_waveform(s.waveform)
    for v in s.variants:
        if v not in VARIANTS:
            raise ConfigError(f"variant {v!r} is unknown; expected one of {', '.join(VARIANTS)}")
        if v.startswith("dither") and s.period is None:
            raise ConfigError(f"variant {v} needs the dither period; none is known")
    for spec in model.effects:
        e = get_effect(spec.name)
        if e.kind == "torque" and not e.pointwise:
            raise ConfigError(
                f"the model's effect {spec.name} is a filter in time, which the causal estimate "
                "does not apply; expected a model of pointwise effects (identify without it)"
            )


def _torque_effects(model: TorqueModel) -> TorqueModel | None:
    """``model`` with only its torque effects (an external effect such as ``dither_extraction``
    is applied by the estimator, and may check for a sensor a live stream lacks), None when it
    has none."""
    torque = [s for s in model.effects if get_effect(s.name).kind == "torque"]
    if not torque:
        return None
    if len(torque) == len(model.effects):
        return model
    out = model.copy()
    out.effects = torque
    return out


def _backward(t: np.ndarray, x: np.ndarray, P: int, k: int) -> np.ndarray:
    """``(x_i - x_{i-k}) / (t_i - t_{i-k})`` for the rows ``i >= P`` of ``x`` (R, n), the
    oldest row standing in for ``i - k`` where there is none; 0 where ``i`` is the first row.

    Returns (R - P, n) [unit of x / s]."""
    i = np.arange(P, len(t))
    j = np.maximum(i - k, 0)
    out = np.zeros((len(i), x.shape[1]))
    ok = i > j
    out[ok] = (x[i[ok]] - x[j[ok]]) / (t[i[ok]] - t[j[ok]])[:, None]
    return out


def _dither_on(X: dict[str, np.ndarray], P: int, period: int) -> np.ndarray | None:
    """Where the dither is on, for the kept past and the new rows (R,): the flag when the
    stream has one, else where the feedforward's range over the last period (``period``
    samples) exceeds :data:`FFW_ON`; None without either."""
    if "on_in" in X:
        return X["on_in"]
    if "ffw" not in X:
        return None
    ffw = X["ffw"]
    past = X.get("on_past")
    on_new = np.empty(len(ffw) - P, bool)
    for r, i in enumerate(range(P, len(ffw))):
        win = ffw[max(0, i - period + 1) : i + 1]
        on_new[r] = bool(((win.max(axis=0) - win.min(axis=0)) > FFW_ON).any())
    return on_new if past is None or P == 0 else np.concatenate([past, on_new])


def settings_for(
    rec: Recording,
    *,
    variants: Sequence[str] | None = None,
    level: float = 0.95,
    interval: str = "profile",
    components: str = "all",
) -> CausalSettings:
    """The settings of a recording's causal replay: its step (:attr:`Recording.dt`), its dither
    period and waveform (:func:`ditherlab.physics.dither.dither_period`) when it has dither, and
    the variants it allows (:func:`ditherlab.analysis.estimation.available_variants`) or those
    asked for (a dither variant of a recording without dither is a ConfigError)."""
    allowed = available_variants(rec)
    asked = list(allowed) if variants is None else list(variants)
    for v in asked:
        if v in VARIANTS and v not in allowed:
            raise ConfigError(
                f"{rec.name or 'recording'}: variant {v} needs a dither column or tau_ffw, "
                "and this recording has neither (or the dither is never on)"
            )
    dithered = has_dither(rec)
    return CausalSettings(
        dt=rec.dt,
        period=dither_period(rec) if dithered else None,
        variants=tuple(v for v in VARIANTS if v in asked)
        + tuple(v for v in asked if v not in VARIANTS),
        level=level,
        interval=interval,
        components=components,
        waveform=dither_waveform(rec.meta) if dithered else "square",
    )


def block_of(rec: Recording, rows: slice | np.ndarray | None = None) -> CausalBlock:
    """The samples of ``rec`` (at ``rows``) as a :class:`CausalBlock`, times as DDS carries
    them (whole nanoseconds, :func:`ditherlab.core.stamps.wire_time`): what a recording
    streamed live is."""
    pick = (lambda a: a) if rows is None else (lambda a: None if a is None else a[rows])
    return CausalBlock(
        t=wire_time(pick(rec.t)),
        q=pick(rec.q),
        tau=pick(rec.tau),
        dq=pick(rec.dq) if rec.has_dq else None,
        dither=pick(rec.dither),
        tau_ffw=pick(rec.tau_ffw) if rec.dither is None else None,
        wrench=pick(rec.wrench),
    )
