"""Identify the disturbance model of eq. (3) from recordings with a reference F/T sensor.

Per joint and regime the friction residual

``rho = tau - tau_grav(q) - effects_torque - external_torque(sensor_wrench)``   [N·m]

is modelled as a uniform band ``[a, b]`` plus Gaussian noise ``N(0, sigma^2)`` (the paper's §II),
whose density is ``[Phi((x - a)/sigma) - Phi((x - b)/sigma)] / (b - a)``, and fitted by maximum
likelihood. Regimes (:func:`ditherlab.data.recording.regimes`):

- ``still``: the joint stands still without dither; ``rho`` from the raw torque. With a sensor,
  the band is widened to every level the friction held for 0.1 s
  (:func:`ditherlab.physics.band_fit.held_levels`: a level held without a slip is inside the
  static band, however rarely it was held).
- ``dither``: the joint stands still while the dither is on. ``rho`` is taken from the **extracted**
  torque signal (paper §IV-A: per dither period, the mean of the upper and lower means; see
  :func:`ditherlab.physics.dither.extract_dither`), not from the raw square wave: the fitted band is then
  the effective band of the extracted signal, which is exactly what the dither variants of the
  estimator use (:mod:`ditherlab.analysis.estimation`). On the raw torque the band would be the full friction
  band plus the square wave, which the estimator never sees.
- ``moving``: the joint moves; ``rho = coulomb·sign(dq) + viscous·dq + u`` with ``(coulomb,
  viscous)`` by least squares and the remainder ``u`` fitted by the band-plus-noise model, so the
  moving band is centred on the sliding friction.

``R_e = diag(sigma^2)`` per regime. Every parameter carries a standard error from a seeded block
bootstrap: the samples are cut into blocks of ``block`` seconds (per recording), blocks are
resampled with replacement, and the fit is repeated. Neighbouring samples at 250 Hz are far from
independent (the friction state persists between pushes), so the Fisher information of all samples
would be far too optimistic; whole blocks are.

The band-plus-noise fits themselves are :mod:`ditherlab.physics.band_fit`.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass

import numpy as np

from ditherlab.analysis.rest import kept_rows
from ditherlab.core.errors import ConfigError, RecordingError
from ditherlab.core.names import DITHER, MOVING, STILL
from ditherlab.core.spill import SPILL_BYTES, Spill
from ditherlab.core.ticker import Ticker
from ditherlab.core.timeseries import REVERSAL_V, causal_mean, jtf, stick_transitions
from ditherlab.data.recording import Recording, regimes
from ditherlab.data.torque_model import PAPER_PRIOR_SIGMA, Band, TorqueModel
from ditherlab.io.stream import CHUNK_ROWS, Source, pieces_of
from ditherlab.physics.band_fit import (
    HELD_LEVEL,
    HELD_WINDOW_S,
    BandFit,
    band_noise_logpdf,
    fit_band,
    fit_regimes,
    fit_sliding,
    noise_lag,
)
from ditherlab.physics.dither import extract_dither, window_samples
from ditherlab.physics.effect_fit import pooled_lines
from ditherlab.physics.effects import (
    effects_torque,
    external_torque,
    release,
    sensor_wrench,
    signals,
)
from ditherlab.physics.effects.extraction import as_extracted, extracted_rows, logged_view
from ditherlab.physics.residual import check_noise


# ---------------------------------------------------------------------------- residuals
def _effects_torque(model: TorqueModel | None, rec: Recording) -> np.ndarray:
    """Sum of the model's effects [N·m] (N, n); zero when the model has none."""
    if model is None or not model.effects:
        return np.zeros((len(rec), rec.n))
    return effects_torque(model, rec)


def _sensor_external(model: TorqueModel | None, rec: Recording, J: np.ndarray) -> np.ndarray:
    """``external_torque(sensor_wrench)`` [N·m] (N, n): ``J^T F`` through the model's effects."""
    if model is not None and model.effects:
        return external_torque(model, rec, sensor_wrench(model, rec))
    return jtf(J, rec.wrench)


def friction_residual(
    rec: Recording, model: TorqueModel | None = None, *, assume_no_force: bool = False
) -> np.ndarray:
    """``rho = tau - gravity - effects_torque - external_torque(sensor_wrench)`` per sample.

    Parameters
    ----------
    rec : Recording with F/T columns (or ``assume_no_force=True``: the external term is zero)
    model : the model whose effects are subtracted (None: no effects)

    Returns
    -------
    (N, n) [N·m]
    """
    rho = _tau_minus_model(rec.tau, rec, model)
    if assume_no_force:
        return rho
    J = rec.robot().jacobian(rec.q)
    return rho - _sensor_external(model, rec, J)


def _logged_model(model: TorqueModel | None) -> TorqueModel | None:
    """The model whose external torque is what the logged torque shows (``model`` itself when
    it has no term for the dither's extraction, :func:`logged_view`)."""
    if model is None or not model.effects:
        return model
    specs = logged_view(model.effects)
    if len(specs) == len(model.effects):
        return model
    out = model.copy()
    out.effects = specs
    return out


def _tau_minus_model(tau: np.ndarray, rec: Recording, model: TorqueModel | None) -> np.ndarray:
    g = rec.robot().gravity(rec.q)
    return tau - g - _effects_torque(model, rec)


# ---------------------------------------------------------------------------- identification
def _check_input(r: Recording, first: Recording | None, assume_no_force: bool) -> None:
    """Refuse a recording identify cannot use: sensor columns against ``assume_no_force``, or
    another robot than ``first``'s (None: ``r`` is the first)."""
    if assume_no_force and r.has_wrench:
        # refused rather than ignored: the sensor measures the very force the option says is
        # absent, and ignoring it would put every push into the friction bands
        raise RecordingError(
            f"{r.name or 'recording'}: --assume-no-force states that no external force acts, "
            "but this recording has F/T sensor columns f_x..m_z that measure it; drop the "
            "option to fit the bands with the sensor"
        )
    if not assume_no_force and not r.has_wrench:
        raise RecordingError(
            f"{r.name or 'recording'}: identify needs a reference F/T sensor (columns "
            "f_x..m_z) and this recording has none; with --assume-no-force it can still fit "
            "the bands from periods where you state that no external force acts"
        )
    if first is not None and (r.n != first.n or _robot_key(r.meta) != _robot_key(first.meta)):
        raise RecordingError(
            f"{r.name or 'recording'}: robot {r.robot_label} with {r.n} joints differs from "
            f"{first.name or 'the first recording'}'s {first.robot_label} with {first.n} joints"
        )


def _piece_count(r: Recording | Source, rows: int) -> int:
    return 1 if isinstance(r, Recording) else max(1, -(-r.n_rows // int(rows)))


def _times(r: Recording | Source) -> np.ndarray:
    """The whole recording's time stamps (N,) [s]."""
    return r.t if isinstance(r, Recording) else r.times()


def _robot_key(meta: dict) -> str:
    return json.dumps({k: meta.get(k) for k in ("robot", "tool_offset", "payload")}, sort_keys=True)


def identify(
    recs: Sequence[Recording | Source],
    *,
    base: TorqueModel | None = None,
    assume_no_force: bool = False,
    n_boot: int = 50,
    block: float = 2.0,
    min_samples: int = 200,
    dither_band: str = "shrunk",
    max_accel: float = 0.5,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
    chunk_rows: int = CHUNK_ROWS,
    spill_bytes: int = SPILL_BYTES,
    executor: Executor | None = None,
    drop: Sequence[Sequence[tuple[float, float]]] = (),
) -> TorqueModel:
    """Fit the bands, noise and sliding friction of every joint and regime.

    Parameters
    ----------
    recs : recordings of the same robot with F/T columns ``f_x..m_z``: in memory, or
        :class:`~ditherlab.io.stream.Source` s read in pieces of ``chunk_rows`` rows (the same
        model, bit for bit: every per-sample quantity comes from a bounded window, and the
        bootstrap's block labels continue across pieces)
    base : a model to start from: its prior, effects (subtracted before fitting) and any regime
        that the data do not cover are kept; None starts from the paper's prior and no effects.
    assume_no_force : no F/T sensor: treat the external force as zero everywhere (the user states
        that no force acts, e.g. a log of rest periods); the bands then hold any force as friction.
    n_boot : bootstrap replicates for the standard errors (seeded by ``seed``)
    block : bootstrap block length [s]
    min_samples : a joint-regime with fewer samples is not fitted (kept from ``base`` if there)
    dither_band : ``"shrunk"`` (default) or ``"ml"``: the edges of the ``dither`` band.
        ``"shrunk"``: the paper's rule (§IV-A, Fig. 4) — the fitted ``still`` band shrunk on each
        side by the dither amplitude measured in the data (median over the dithered samples of
        the extracted amplitude); where that band does not hold the point the extracted
        residual rests at (its median), the still band was short of the static friction on one
        side and the band is the still band's larger side about that point, shrunk by the
        amplitude (:func:`_shrunk_dither_band` says why); its noise is still fitted on the
        extracted signal.
        ``"ml"``: the band-plus-noise fit of the extracted residual itself. On the built-in
        simulator's push campaign the extracted signal follows ``J^T F`` only in part (the
        paper's underestimate: the servo and the centre loop take up some of the push), so that
        fit spread to [-6.3, 7.5] N·m on joint 1 — almost the still band — and gave away the
        dither's gain; on data where the extraction is faithful (the synthetic tests) both agree.
    max_accel : [rad/s²] the moving regime is fitted only where the joint's acceleration
        (averaged over 0.1 s) is at most this: the model neglects dynamic torques, and on the
        simulator's start-up excitation the abrupt reversals (~200 N·m of inertia on joint 1)
        otherwise widened the moving band to [-202, 102] N·m
    progress : ``progress(done, total)`` callback
    chunk_rows : rows per piece of a Source
    spill_bytes : residual samples held in memory before they go to temporary files
        (:class:`~ditherlab.core.spill.Spill`; about 16 bytes per sample and joint, 32 more per
        moving sample): memory then stays bounded however long the recordings are
    executor : runs the joint-regimes' fits (e.g. a process pool; :func:`~ditherlab.physics.band_fit.
        fit_regimes`): the same model, bit for bit, every joint-regime's samples held at once
    drop : per recording (in the order of ``recs``; missing: none), time spans ``(start, end)``
        [s] of its own time whose samples no regime is fitted on (pushes found without a sensor,
        :func:`ditherlab.analysis.rest.scan_rest`, and the user's ``--exclude``; ends included)

    Returns
    -------
    TorqueModel with ``regimes`` ``still`` / ``dither`` / ``moving`` (those the data cover), each
    :class:`~ditherlab.data.torque_model.Band` with ``stderr`` for every fitted parameter.

    Raises
    ------
    RecordingError
        No F/T columns (and not ``assume_no_force``), recordings of different robots, or no
        joint with enough samples in any regime.
    """
    o = IdentifyOptions(
        assume_no_force, n_boot, block, min_samples, dither_band, max_accel, seed, tuple(drop)
    )
    if dither_band not in ("shrunk", "ml"):
        raise ConfigError(f"dither_band is {dither_band!r}, expected 'shrunk' or 'ml'")
    recs = list(recs)
    if not recs:
        raise RecordingError("identify needs at least one recording")
    # the steps: every piece read, then 3 n fits once n is known
    tick = Ticker(sum(_piece_count(r, chunk_rows) for r in recs), progress)
    with Spill(spill_bytes) as store:
        samples = _Samples(store)
        samples.hold = 0 if assume_no_force else 1  # the held-level test needs a sensor
        first = _gather(recs, base, o, samples, chunk_rows, tick)
        store.flush()  # a long log's last held samples join the rest on disk before fitting
        fits = _fit_all(samples, first.n, o, executor, tick)
        amps = samples.amps
        centres = _dither_centres(samples, first.n)
    if not fits:
        raise RecordingError(
            f"{first.name or 'recording'}: no joint has {min_samples} samples in any regime "
            "(still, dither, moving); record longer"
        )
    _check_fitted_noise(first, fits)
    out_regimes, borrowed = _regimes_of(fits, first.n, base)
    held = _held_widened(out_regimes.get("still"), fits)
    capped = _cap_moving(out_regimes, fits)
    widened = _coulomb_floor(out_regimes, fits)
    amp = None
    if dither_band == "shrunk" and "dither" in out_regimes and "still" in out_regimes and amps:
        out_regimes["dither"], amp = _shrunk_dither_band(
            out_regimes["still"], out_regimes["dither"], amps, centres
        )
    notes = _notes([r.name for r in recs], o, amp, bool(amps), capped, widened, held)
    notes += _coverage_notes(samples.all_moving, max_accel, borrowed)
    return _model_of(first, base, out_regimes, notes)


@dataclass(frozen=True)
class IdentifyOptions:
    """The settings of one :func:`identify`: its parameters of the same names."""

    assume_no_force: bool
    n_boot: int
    block: float
    min_samples: int
    dither_band: str
    max_accel: float
    seed: int
    drop: tuple[Sequence[tuple[float, float]], ...] = ()


def _gather(
    recs: Sequence[Recording | Source],
    base: TorqueModel | None,
    o: IdentifyOptions,
    samples: _Samples,
    chunk_rows: int,
    tick: Ticker,
) -> Recording:
    """Read every recording a piece of ``chunk_rows`` rows at a time and add its friction
    residual's samples to ``samples``; returns the first recording's first piece (the robot,
    its joints and metadata). Once its joints are known, ``tick`` gets 3 fits per joint more."""
    first: Recording | None = None
    for i, r in enumerate(recs):
        spans = o.drop[i] if i < len(o.drop) else ()
        for k, piece in enumerate(pieces_of(r, chunk_rows)):
            if k == 0:
                _check_input(piece.rec, first, o.assume_no_force)
                if first is None:
                    first = piece.rec
                    if base is not None:
                        base.check_robot(first)
                    samples.n = first.n
                    tick.total += 3 * first.n
                samples.start(_times(r), piece.rec.t0, o.block)
            if len(piece.rec) >= 2:  # one sample: no step, no rate, nothing to fit
                samples.add(
                    piece.rec,
                    piece.keep,
                    base,
                    assume_no_force=o.assume_no_force,
                    block=o.block,
                    max_accel=o.max_accel,
                    drop=spans,
                )
            if piece.count > 1:  # a piece of a long log: its robot quantities go now
                release(piece.rec)
            tick()
        samples.finish()
    assert first is not None
    return first


def _fit_all(
    samples: _Samples, n: int, o: IdentifyOptions, executor: Executor | None, tick: Ticker
) -> dict[tuple[int, int], dict[str, tuple[float, float]]]:
    """The band-plus-noise fit of every (regime, joint) with enough samples, by (regime code,
    0-based joint)."""
    fits: dict[tuple[int, int], dict[str, tuple[float, float]]] = {}
    keys = [(code, j) for code in (STILL, DITHER, MOVING) for j in range(n)]
    kw = {"min_samples": o.min_samples, "n_boot": o.n_boot, "seed": o.seed}
    jobs = (samples.fit_job(code, j, **kw) for code, j in keys)
    for (code, j), f in zip(keys, fit_regimes(jobs, executor), strict=True):
        if f is not None:
            fits[(code, j)] = f
        tick()
    return fits


def _dither_centres(samples: _Samples, n: int) -> dict[int, float]:
    """Where the extracted residual rests [N·m] per dithered 0-based joint: its median over the
    dithered samples (the centre loop holds it there between pushes; pushes are a minority of
    the samples, of both signs, and move the median by < 0.005 N·m on the simulator's
    campaigns)."""
    return {
        j: float(np.median(samples.store.load(("x", DITHER, j))))
        for j in range(n)
        if samples.count((DITHER, j))
    }


def _check_fitted_noise(first: Recording, fits: dict[tuple[int, int], dict]) -> None:
    """A joint without noise in every regime fitted: its torque did not vary (refused)."""
    check_noise(
        first.name,
        np.array(
            [
                max((f["sigma"][0] for (_, i), f in fits.items() if i == j), default=np.nan)
                for j in range(first.n)
            ]
        ),
    )


def _regimes_of(
    fits: dict[tuple[int, int], dict], n: int, base: TorqueModel | None
) -> tuple[dict[str, Band], dict[str, list[int]]]:
    """The model's bands by regime name (``base``'s where the data cover none), and per regime
    the 0-based joints whose values were taken from the other regime's fit (:func:`_assemble`)."""
    out: dict[str, Band] = dict(base.regimes) if base is not None else {}
    borrowed: dict[str, list[int]] = {}
    for code in (STILL, DITHER, MOVING):
        band, from_other = _assemble(code, n, fits, out.get(code.label))
        if band is not None:
            out[code.label] = band
            if from_other:
                borrowed[code.label] = from_other
    return out, borrowed


def _model_of(
    first: Recording, base: TorqueModel | None, regs: dict[str, Band], notes: str
) -> TorqueModel:
    """The identified model: the robot of ``first``, the bands ``regs``, ``base``'s prior,
    effects, history and version (the paper's prior and none without a base)."""
    return TorqueModel(
        robot=first.meta["robot"],
        n=first.n,
        regimes=regs,
        prior_mean=base.prior_mean if base is not None else np.zeros(6),
        prior_sigma=base.prior_sigma if base is not None else np.array(PAPER_PRIOR_SIGMA),
        effects=list(base.effects) if base is not None else [],
        history=list(base.history) if base is not None else [],
        version=base.version if base is not None else 1,
        tool_offset=first.meta.get("tool_offset"),
        payload=first.meta.get("payload"),
        notes=notes,
    )


#: pseudo-regime of _Samples: every moving sample, whatever its acceleration
ALL_MOVING = 3
#: regimes whose fit needs each sample's velocity and sliding flag besides the residual
_SLIDING = (MOVING, ALL_MOVING)


class _Samples:
    """The friction residual's samples per (regime, joint), concatenated over recordings.

    Each sample carries a label: its contiguous run inside a time block of its recording (the
    bootstrap unit; lagged differences never cross labels), and in the moving regimes its
    ``dq`` and whether it is on the sliding line (moving, not a break-away transient, slip or
    velocity reversal). Recordings are added piece by piece (:meth:`start`, then :meth:`add`
    per piece): the runs continue across pieces, so the labels are the whole recording's. The
    samples are kept in a :class:`~ditherlab.core.spill.Spill` (on disk past its budget).
    """

    def __init__(self, spill: Spill, n: int = 0):
        #: joints (set from the first recording)
        self.n = n
        self.store = spill
        self.lags: dict[int, int] = {STILL: 1, MOVING: 1, DITHER: 1, ALL_MOVING: 1}
        #: [samples] the window of the still regime's held-level test (HELD_WINDOW_S at the
        #: fastest rate); 0: not tested (set by identify without a sensor: a push the rest
        #: scan missed would be read as static friction). Not the dither regime: under dither
        #: a joint pushed past its shrunk band creeps (too slowly to count as moving) at its
        #: sliding friction, which lies outside that band, so its levels are not held ones
        self.hold = 1
        #: joints whose moving regime was fitted on all moving samples (too few slow ones)
        self.all_moving: list[int] = []
        self.label_offset = 0
        self._t0 = 0.0
        self._nblk = 1
        self._len = 0
        self._runs: dict[tuple[int, int], tuple[int, bool]] = {}

    @property
    def amps(self) -> dict[int, np.ndarray]:
        """Measured dither amplitude [N·m] of every dithered sample, per joint (0-based)."""
        return {
            k[1]: self.store.load(k)
            for k in list(self.store.keys())
            if k[0] == "amp" and self.store.count(k)
        }

    def start(self, t: np.ndarray, t0: float, block: float) -> None:
        """Begin a recording: its whole time stamps ``t`` (N,) [s], first time ``t0`` [s]."""
        self._t0 = t0
        self._nblk = int(((t - t0) // block).max()) + 1 if len(t) else 1
        self._len = len(t)
        self._runs = {}

    def finish(self) -> None:
        """End the recording started last: the next one's labels never meet its labels."""
        self.label_offset += (self._len + 1) * self._nblk + 1

    def add(
        self,
        rec: Recording,
        keep: slice,
        model: TorqueModel | None,
        *,
        assume_no_force: bool,
        block: float,
        max_accel: float,
        drop: Sequence[tuple[float, float]] = (),
    ) -> None:
        """Add the residual samples of the rows ``keep`` of ``rec`` (a piece of the recording
        begun by :meth:`start`, with context around them), every regime (see :func:`identify`),
        except those inside the time spans ``drop`` [s]."""
        reg = regimes(rec)
        out = ~kept_rows(rec.t, (), drop)[:, None] if drop else None
        # rho = (tau - gravity - effects) - external, the parts kept for the dither regime
        rho = _tau_minus_model(rec.tau, rec, model)
        ext = None
        if not assume_no_force:
            J = rec.robot().jacobian(rec.q)
            ext = _sensor_external(model, rec, J)
            logged = _logged_model(model)
            # the still and moving regimes read the logged torque: the external torque as it
            # shows there (without the extraction's view, which the dither regime takes)
            rho_logged = rho - (ext if logged is model else _sensor_external(logged, rec, J))
            rho = rho - ext
        else:
            rho_logged = rho
        blk = ((rec.t[keep] - self._t0) // block).astype(np.int64)
        dq = rec.dq
        # the paper's model neglects dynamic torques ("slow velocities and low accelerations"):
        # the moving regime is fitted where the (0.1 s averaged) acceleration is low
        slow = np.abs(causal_mean(rec.ddq, max(int(round(0.1 * rec.sample_rate)), 1)))
        slow = slow <= max_accel
        # break-away / stopping transients, short slips and velocity reversals are not on the
        # sliding line (the samples diagnose leaves out): the moving band is fitted without them
        # (their outliers, -6..+13 N·m on a simulated joint 2 whose residual is otherwise within
        # +-0.8, set its edges), the sliding friction with them
        slide = ~stick_transitions(reg, rec.sample_rate) & (np.abs(dq) >= REVERSAL_V)
        sources = [
            (STILL, rho_logged, reg == STILL),
            (MOVING, rho_logged, (reg == MOVING) & slow),
            (ALL_MOVING, rho_logged, reg == MOVING),
        ]
        for code in (STILL, MOVING, ALL_MOVING):  # the raw torque's noise, NOISE_LAG_S apart
            self.lags[code] = max(self.lags[code], noise_lag(rec.sample_rate))
        if self.hold:
            self.hold = max(self.hold, int(round(HELD_WINDOW_S * rec.sample_rate)))
        dith = (
            self._dither_source(rec, rho, ext, model, reg, keep) if (reg == DITHER).any() else None
        )
        # a piece without dithered samples still continues the dither regime's runs
        sources.append(dith or (DITHER, rho, np.zeros_like(reg, dtype=bool)))
        for code, r, mask in sources:
            if out is not None:
                mask = mask & ~out
            for j in range(self.n):
                m = mask[keep, j]
                if not len(m):
                    continue
                # run number of every row, continued from the previous piece
                last, was = self._runs.get((code, j), (0, not m[0]))
                run = last + np.cumsum(np.r_[m[0] != was, m[1:] != m[:-1]])
                self._runs[(code, j)] = (int(run[-1]), bool(m[-1]))
                if not m.any():
                    continue
                lab = self.label_offset + run * self._nblk + blk
                st, key = self.store, (code, j)
                st.append(("x", *key), r[keep, j][m])
                st.append(("label", *key), lab[m])
                if code in _SLIDING:
                    st.append(("dq", *key), dq[keep, j][m])
                    st.append(("slide", *key), slide[keep, j][m])

    def _dither_source(
        self,
        rec: Recording,
        rho: np.ndarray,
        ext: np.ndarray | None,
        model: TorqueModel | None,
        reg: np.ndarray,
        keep: slice,
    ) -> tuple[int, np.ndarray, np.ndarray] | None:
        """The dither regime's residual from the extracted signal (paper §IV-A), or None.

        The extracted signal replaces the raw torque, on samples whose one-period window lies
        wholly in the dither. It is (for the slow part) a one-period running mean: it is compared
        with the model torque passed through the same window, so that the extraction's delay
        does not count as friction. The model torque is windowed once: where the model's
        external torque ``ext`` (N, n) [N·m] (None: no sensor term) already is the extraction's
        one-period mean (``dither_extraction``, :func:`extracted_rows`) it is taken as it is.
        ``rho`` (N, n) [N·m] is the raw residual ``tau - model torque``. Records the dither
        amplitude per joint (of the rows ``keep``) and the lag of the noise estimate (one
        period).
        """
        sig = extract_dither(rec)
        if sig is None:
            return None
        model_tau = rec.tau - rho
        w = window_samples(sig.period, rec.sample_rate)
        shown = (
            extracted_rows(model.effects, signals(rec))
            if ext is not None and model is not None and model.effects
            else None
        )
        rest = model_tau if ext is None else model_tau - ext
        rho_d = sig.signal - as_extracted(rest, ext, shown, w)
        dmask = (reg == DITHER) & sig.valid[:, None]
        for j in range(self.n):
            dk = dmask[keep, j]
            if dk.any():
                self.store.append(("amp", j), sig.amplitude[keep][dk, j])
        self.lags[DITHER] = max(self.lags[DITHER], int(round(sig.period * rec.sample_rate)))
        return DITHER, rho_d, dmask

    def fit_job(
        self, code: int, j: int, *, min_samples: int, n_boot: int, seed: int
    ) -> tuple | None:
        """The arguments of :func:`~ditherlab.physics.band_fit.fit_regime` for one joint-regime (its
        samples loaded), or None (too few samples)."""
        key = (code, j)
        if self.count(key) < min_samples:
            if code != MOVING or self.count((ALL_MOVING, j)) < min_samples:
                return None
            # too few low-acceleration samples: the moving regime from all of them (the notes
            # say so; the dynamic torque then widens the band until `inertia` is added)
            key = (ALL_MOVING, j)
            self.all_moving.append(j)
        x, labels = self.store.load(("x", *key)), self.store.load(("label", *key))
        jseed = seed * 1000 + code * 100 + j
        if code == MOVING:
            dq, slide = self.store.load(("dq", *key)), self.store.load(("slide", *key))
            return x, labels, self.lags[code], n_boot, jseed, dq, slide
        hold = self.hold if code == STILL else 0
        return x, labels, self.lags[code], n_boot, jseed, None, None, hold

    def count(self, key: tuple[int, int]) -> int:
        """Samples of one (regime, joint)."""
        return self.store.count(("x", *key))


def _coverage_notes(all_moving: list[int], max_accel: float, borrowed: dict[str, list[int]]) -> str:
    """What the model's regimes rest on, where it is not the plain fit: moving regimes fitted on
    fast samples, and joints whose band stands in for data the recordings do not have."""
    out = ""
    if all_moving:
        out += (
            "; moving regime fitted on all moving samples on joint(s) "
            f"{', '.join(str(j + 1) for j in sorted(set(all_moving)))} (too few with |ddq| <= "
            f"{max_accel:g} rad/s²: the model has no dynamic torque, add it with --add inertia)"
        )
    for name, joints in borrowed.items():
        other = "moving" if name == "still" else "still"
        out += (
            f"; {name} band of joint(s) {', '.join(str(j + 1) for j in joints)} not fitted (too "
            f"few {name} samples): taken from its {other} fit"
        )
    return out


def _notes(
    names: Sequence[str | None],
    o: IdentifyOptions,
    amp: np.ndarray | None,
    dithered: bool,
    capped: list[int],
    widened: list[int],
    held: list[int] = (),
) -> str:
    """The model file's ``notes``: what it was identified from (the recordings ``names``, the
    options ``o``) and every rule applied (the dither band's ``amp``, ``capped`` moving bands,
    ``widened`` still bands, still bands widened to their ``held`` levels)."""
    if amp is not None:
        dither_note = (
            "; dither band = still band shrunk by the measured dither amplitude "
            + "["
            + ", ".join(f"{a:.3g}" for a in amp)
            + "] N·m (paper Fig. 4); where that band does not hold the point the extracted "
            "residual rests at, the static friction (the still band's larger side about that "
            "point) shrunk by it about that point"
        )
    else:
        dither_note = "; dither band fitted on the extracted signal" if dithered else ""
    return (
        "identified by ditherlab identify from "
        + ", ".join(name or "<memory>" for name in names)
        + (" assuming no external force (no F/T sensor)" if o.assume_no_force else "")
        + f"; bootstrap {o.n_boot} x {o.block:g} s blocks, seed {o.seed}"
        + dither_note
        + (
            "; moving band capped at the still band's width and viscous at >= 0 (the moving "
            "data hold torques the sliding-friction model does not explain, e.g. servo transients"
            f" or inertia) on joint(s) {', '.join(str(j + 1) for j in capped)}"
            if capped
            else ""
        )
        + (
            "; still band widened to the sliding friction (a stuck joint holds at least "
            f"coulomb) on joint(s) {', '.join(str(j + 1) for j in widened)}"
            if widened
            else ""
        )
        + (
            f"; still band widened to the levels the friction held for {HELD_WINDOW_S:g} s (a "
            f"one-sided test of each window's mean against its noise, family-wise "
            f"{HELD_LEVEL:g}) on joint(s) {', '.join(str(j + 1) for j in held)}"
            if held
            else ""
        )
    )


def _held_widened(band: Band | None, fits: dict) -> list[int]:
    """Widen the still ``band`` (in place) to contain every level its friction held
    (``held_min``, ``held_max`` of :func:`~ditherlab.physics.band_fit.fit_regime`, present where
    the test ran).

    At rest the friction holds whatever a push leaves on the joint, anywhere in its band, so a
    window whose mean lies beyond an edge by more than the test's margin proves the band short
    there. The band-plus-noise likelihood misses such levels when they are rare: it pays for
    width with every sample, and a few held pushes beyond the bulk read as noise (a plant with
    presliding friction held 2.87 N·m for seconds on a joint whose fitted edge was 1.98, 9.8
    noise sigmas of a 0.1 s mean beyond it). The widened edge's standard error is the noise
    sigma of a window's mean. Returns the joints (0-based) widened.
    """
    if band is None:
        return []
    out = []
    for j in range(len(band.sigma)):
        f = fits.get((STILL, j))
        if f is None or "held_min" not in f:
            continue
        (lo, se_lo), (hi, se_hi) = f["held_min"], f["held_max"]
        wide = False
        if lo < band.tau_min[j]:
            band.tau_min[j] = lo
            if "tau_min" in band.stderr:
                band.stderr["tau_min"][j] = se_lo
            wide = True
        if hi > band.tau_max[j]:
            band.tau_max[j] = hi
            if "tau_max" in band.stderr:
                band.stderr["tau_max"][j] = se_hi
            wide = True
        if wide:
            out.append(j)
    return out


def _cap_moving(regs: dict[str, Band], fits: dict) -> list[int]:
    """Keep the moving band physical: no wider than the still band, about its own centre
    (sliding friction is better known than static friction, the paper's §VI-D), and viscous
    friction not negative. A wider
    ML band means the moving samples hold torques the model lacks (a servo transient at the end
    of the simulator's start-up excitation reached -195 N·m on joint 1). Returns the joints
    (0-based) changed."""
    st, mv = regs.get("still"), regs.get("moving")
    if st is None or mv is None:
        return []
    out = []
    for j in range(len(st.sigma)):
        if (MOVING, j) not in fits:
            continue
        changed = False
        hs = 0.5 * (st.tau_max[j] - st.tau_min[j])
        if mv.tau_max[j] - mv.tau_min[j] > 2 * hs:
            # the width is capped; the centre is kept where a stuck joint could hold it too
            # (inside the still band): an effect's constant part, e.g. a link's gravity that
            # hardly changes with the pose (the hopper's thigh under `dynamics`), stays in the
            # band. Outside it the ML centre is the slips' transients, not friction (-90 N·m
            # on joint 2 of a simulated push campaign, whose moving samples are a few slips
            # under pushes): the band is then centred on the sliding line as before
            c = 0.5 * (mv.tau_max[j] + mv.tau_min[j])
            if not st.tau_min[j] <= c <= st.tau_max[j]:
                c = 0.0
            mv.tau_min[j], mv.tau_max[j] = c - hs, c + hs
            changed = True
        if mv.viscous is not None and mv.viscous[j] < 0:
            mv.viscous[j] = 0.0
            changed = True
        if changed:
            out.append(j)
    return out


def _coulomb_floor(regs: dict[str, Band], fits: dict) -> list[int]:
    """Widen the fitted still band of a joint to ``[-|coulomb|, |coulomb|]`` where the moving
    data give its sliding friction: physically the static band holds at least the sliding
    friction (Fs >= Fc), and a joint that the pushes never moved out of its band shows only a
    sliver of it in the still data. Returns the (0-based) joints widened."""
    st, mv = regs.get("still"), regs.get("moving")
    if st is None or mv is None or mv.coulomb is None:
        return []
    out = []
    for j in range(len(st.sigma)):
        if (MOVING, j) not in fits or (STILL, j) not in fits:
            continue
        c = abs(float(mv.coulomb[j]))
        if st.tau_min[j] > -c or st.tau_max[j] < c:
            st.tau_min[j] = min(st.tau_min[j], -c)
            st.tau_max[j] = max(st.tau_max[j], c)
            out.append(j)
    return out


def _shrunk_dither_band(
    still: Band, fitted: Band, amps: dict[int, np.ndarray], centres: dict[int, float]
) -> tuple[Band, np.ndarray]:
    """The dithered band: the static friction shrunk by the measured dither amplitude on each
    side (paper §IV-A, Fig. 4), holding the point where the extracted residual rests.

    A joint stuck under a square wave of amplitude ``A`` about a mean torque ``m`` stays stuck
    while both ``m - A`` and ``m + A`` lie inside its static band ``[a, b]``: without a push
    the extracted signal (the period's mean) can hold any ``m`` in ``[a + A, b - A]`` (the
    paper's rule). The dither's centre loop holds it at ``c`` (``centres``: the median of the
    extracted residual over the dithered samples [N·m]), so a joint resting there proves
    ``a <= c - A`` and ``b >= c + A``: the paper's band holds ``c``. Where it does not (with a
    margin of two noise sigmas of the extracted signal), the fitted still band is short of the
    static friction on one side: the still band is where the held friction was *seen*, and a
    campaign whose pushes broke a joint one way only leaves the other edge short (seed 61,
    pose C: joint 5 [-1.86, 1.09] N·m for a static friction of 2.5; the paper's rule gave
    [-0.387, -0.387] with the residual resting at 0.000, and the estimate rested 3.7 N off
    zero). There the static friction ``Fs`` is taken as the still band's larger side about
    ``c`` (static friction holds the same torque either way) and the band is
    ``[c - (Fs - A), c + (Fs - A)]``, which contains the paper's band; it is the point ``c``
    when ``A >= Fs`` (the dither breaks the band). Where the paper's band holds ``c`` it is kept
    as it is (exact for a band that is truly asymmetric and was seen whole).

    Parameters
    ----------
    still : the fitted still band, (n,) edges [N·m]
    fitted : the ML fit on the extracted residual (its noise ``sigma`` is kept; joints never
        dithered keep all its values)
    amps : measured dither amplitude [N·m] of every dithered sample, per 0-based joint
    centres : median extracted residual [N·m] per 0-based joint

    Returns
    -------
    (the dithered Band, the median amplitude per joint (n,) [N·m], 0 where never dithered)
    """
    n = len(still.sigma)
    A = np.zeros(n)
    c = np.zeros(n)
    have = np.zeros(n, bool)
    for j, a in amps.items():
        if a.size and j in centres:
            A[j], c[j], have[j] = float(np.median(a)), centres[j], True
    lo, hi = still.tau_min + A, still.tau_max - A  # the paper's rule
    m = 2.0 * fitted.sigma
    holds = (lo <= c - m) & (c + m <= hi)
    below, above = c - still.tau_min, still.tau_max - c
    half = np.maximum(np.maximum(below, above) - A, 0.0)
    lo = np.where(holds, lo, c - half)
    hi = np.where(holds, hi, c + half)
    lo = np.where(have, lo, fitted.tau_min)
    hi = np.where(have, hi, fitted.tau_max)
    stderr = dict(fitted.stderr)
    se_lo, se_hi = (still.stderr.get(k) for k in ("tau_min", "tau_max"))
    if se_lo is not None and se_hi is not None:
        # the paper's edges rest on their still edges; the symmetric band on the larger side
        side = np.where(below >= above, se_lo, se_hi)
        for k, se in (("tau_min", se_lo), ("tau_max", se_hi)):
            stderr[k] = np.where(have, np.where(holds, se, side), fitted.stderr.get(k, -1.0))
    return Band(tau_min=lo, tau_max=hi, sigma=fitted.sigma, stderr=stderr), A


def _assemble(
    code: int,
    n: int,
    fits: dict[tuple[int, int], dict[str, tuple[float, float]]],
    old: Band | None,
) -> tuple[Band | None, list[int]]:
    """One regime's Band from the per-joint fits, and the joints (0-based) whose values were
    taken from the other regime's fit.

    A joint without enough samples in this regime keeps ``old``'s values (a base model) or, for
    the ``still`` regime, takes the static band implied by its sliding friction (``moving``:
    ``[-coulomb + a, coulomb + b]``) with the moving noise, or, for the ``moving`` regime of a
    joint that only stands still, its still band with no sliding line; its standard errors are
    -1 (not fitted). A regime that cannot be completed that way is left out (None).
    """
    keys = ("tau_min", "tau_max", "sigma") + (("coulomb", "viscous") if code == MOVING else ())
    vals = {k: np.full(n, np.nan) for k in keys}
    ses = {k: np.full(n, -1.0) for k in keys}
    borrowed: list[int] = []
    for j in range(n):
        f = fits.get((code, j))
        if f is not None:
            for k in keys:
                vals[k][j] = f[k][0]
                se = f[k][1]
                ses[k][j] = se if np.isfinite(se) else -1.0
        elif old is not None:
            for k in keys:
                v = getattr(old, k)
                if v is not None:
                    vals[k][j] = v[j]
        elif code == STILL and (MOVING, j) in fits:
            m = fits[(MOVING, j)]
            c = abs(m["coulomb"][0])
            vals["tau_min"][j] = -c + m["tau_min"][0]
            vals["tau_max"][j] = c + m["tau_max"][0]
            vals["sigma"][j] = m["sigma"][0]
            borrowed.append(j)
        elif code == MOVING and (STILL, j) in fits:
            # a joint that does not move in these recordings while others do: its moving band
            # is never used on them; the still band with no sliding line stands in (not fitted)
            st = fits[(STILL, j)]
            for k in ("tau_min", "tau_max", "sigma"):
                vals[k][j] = st[k][0]
            vals["coulomb"][j] = 0.0
            vals["viscous"][j] = 0.0
            borrowed.append(j)
    if any(np.isnan(v).any() for v in vals.values()):
        return None, []
    if not np.all(vals["sigma"] > 0):
        return None, []
    band = Band(
        tau_min=vals["tau_min"],
        tau_max=vals["tau_max"],
        sigma=vals["sigma"],
        coulomb=vals.get("coulomb"),
        viscous=vals.get("viscous"),
        stderr=ses,
    )
    return band, borrowed


def summary(model: TorqueModel) -> str:
    """A few lines per regime: band edges and noise per joint with their standard errors; then
    one line per joint where a per-joint effect took values shared over the other joints (too
    little evidence there, :func:`ditherlab.physics.effect_fit.pool_weak_joints`; the model's notes say why)."""
    lines = []
    for name, b in model.regimes.items():
        lines.append(f"[{name}]")
        for j in range(model.n):
            se = {k: v[j] for k, v in b.stderr.items()}

            def pm(k: str, se: dict = se) -> str:
                v = se.get(k, -1.0)
                return f" ± {v:.3g}" if v is not None and v >= 0 else ""

            line = (
                f"  joint {j + 1}: band [{b.tau_min[j]:8.3f}{pm('tau_min')}, "
                f"{b.tau_max[j]:8.3f}{pm('tau_max')}] N·m, sigma {b.sigma[j]:.4f}{pm('sigma')} N·m"
            )
            if b.coulomb is not None:
                line += f", coulomb {b.coulomb[j]:.3f}{pm('coulomb')} N·m"
            if b.viscous is not None:
                line += f", viscous {b.viscous[j]:.3f}{pm('viscous')} N·m·s/rad"
            lines.append(line)
    lines += pooled_lines(model)
    return "\n".join(lines)


__all__ = [
    "BandFit",
    "band_noise_logpdf",
    "fit_band",
    "fit_sliding",
    "IdentifyOptions",
    "friction_residual",
    "identify",
    "summary",
]
