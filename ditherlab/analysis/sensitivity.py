"""Pose sensitivity: the detection threshold of a push, per direction, predicted at a pose.

:func:`predict` gives, for a push applied at the tool along ±x, ±y, ±z of the base frame, the
force [N] at which half (F50) and nine tenths (F90) of the pushes give a *response* in the sense
of :mod:`ditherlab.analysis.detection`, from the Jacobian at the pose (levers [m]), the friction
bands and noise [N·m] of one condition (:func:`condition_bands`: a model file, or the
simulator's defaults), the joints' friction states before a push, the dithered push's
transmission through the plant, and the estimator of eq. (3) itself;
:mod:`ditherlab.analysis.sensitivity_map` does it over a grid of poses.

The derivation, the measurements behind its choices (the states a campaign leaves, the centre
loop's hold with dither, the transmission table) and what it leaves out are in
``docs/design/analysis-sensitivity.md``; the command is on ``docs/dither-design.md``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ditherlab.analysis.estimation import parse_components
from ditherlab.analysis.sensitivity_plant import (
    TRANSMISSION_DURATIONS,
    TRANSMISSION_TORQUES,
    dither_transmission,
    extraction_peak,
    transmitted,
)
from ditherlab.core.errors import ConfigError, ModelError, RobotError
from ditherlab.data.torque_model import PAPER_PRIOR_SIGMA, TorqueModel
from ditherlab.estimator import estimate
from ditherlab.estimator.formulation import normal_quantile
from ditherlab.physics.effects.extraction import extraction_gain
from ditherlab.robot.model import RobotModel
from ditherlab.sim.params import load_params

__all__ = [
    "DIRECTIONS",
    "Bands",
    "campaign_states",
    "centre_loop_gain",
    "condition_bands",
    "dither_transmission",
    "predict",
    "shared_fraction",
    "transmission_table",
]

#: The six push directions: (name, axis index, sign of the applied force).
DIRECTIONS: tuple[tuple[str, int, int], ...] = (
    ("+x", 0, 1),
    ("-x", 0, -1),
    ("+y", 1, 1),
    ("-y", 1, -1),
    ("+z", 2, 1),
    ("-z", 2, -1),
)
AXES = ("x", "y", "z")
#: the report's response definition (:func:`ditherlab.analysis.detection.analyse`)
QUANTILE = 0.999
FLOOR = 1.0
#: the simulator's robot
SIM_ROBOT = "irb140"
#: lighter settings of :func:`predict` for every pose of a map (a few tenths of a second each)
MAP_OPTIONS = {"forces": 80, "draws": 120, "rest_samples": 5000}
#: the simulator's push magnitudes (``push_campaign.magnitude_min/max``) [N]
DEFAULT_RANGE = (10.0, 60.0)
#: how the friction states of the joints before a push are drawn (:func:`predict`)
STATES = ("auto", "campaign", "plant", "mixed", "shared", "independent")
#: the simulator's mean push length (``push_campaign.duration_min/max``) [s], log rate [Hz] and
#: dither period (2 pi / 80 rad/s) [s]
PUSH_DURATION = 1.25
SAMPLE_RATE = 250.0
DITHER_PERIOD = 2 * math.pi / 80.0
#: the top of a push: where the raised cosine is within this fraction of its peak
PEAK_TOP = 0.05


@dataclass
class Bands:
    """The disturbance model of one condition, per joint.

    Attributes
    ----------
    lo, hi : (n,) [N·m] band edges (of the gravity-compensated torque, or of the extracted
        signal with dither)
    sigma : (n,) [N·m] noise standard deviation
    dithered : whether this is the dithered condition
    source : where the numbers come from (a model file, or the simulator's defaults)
    prior_mean, prior_sigma : (6,) [N, N·m] the estimator's prior (the model's, else the
        paper's)
    gain : [-] the share of a push's torque the residual shows at the push's peak: 1 without
        dither; with dither the dither's centre loop eats part of it (:func:`centre_loop_gain`)
    link_share : [-] the share of the band behind the gear spring (the simulator's
        ``1 - friction.motor_share``): a push must break that part to move the link
        (:func:`campaign_states`)
    sliding : [-] the sliding friction over the static one (``friction.coulomb_ratio``): where
        the servo's return after a slip leaves the state, as a share of the half band
    plant : the simulator parameters (a nested dict) whose joints, friction, servo and dither
        loops :func:`dither_transmission` simulates (with dither; None without)
    extraction_gain, extraction_lag : (n,) [-, samples] the model's ``dither_extraction``
        per joint (gain 1, lag 0 where it names no joint), None when the model has not the
        effect: where it names a joint the transmission is its linear law instead of the plant's
    """

    lo: np.ndarray
    hi: np.ndarray
    sigma: np.ndarray
    dithered: bool
    source: str
    prior_mean: np.ndarray
    prior_sigma: np.ndarray
    gain: float = 1.0
    link_share: float = 0.9
    sliding: float = 0.85
    plant: Mapping[str, Any] | None = None
    extraction_gain: np.ndarray | None = None
    extraction_lag: np.ndarray | None = None


def _plant_shares(p: Mapping[str, Any]) -> dict[str, float]:
    """``link_share`` and ``sliding`` [-] of :class:`Bands` from simulator parameters ``p``."""
    f = p["friction"]
    return {
        "link_share": 1.0 - float(f["motor_share"]),
        "sliding": float(f["coulomb_ratio"]),
    }


def condition_bands(
    n: int,
    model: TorqueModel | None = None,
    *,
    dither: bool = False,
    params: Mapping[str, Any] | None = None,
    robot_name: str = "irb140",
) -> Bands:
    """The band and noise the estimator uses in one condition (where the numbers come from:
    ``docs/design/analysis-sensitivity.md``).

    Parameters
    ----------
    n : number of joints of the robot
    model : a model from ``ditherlab identify`` (None: the simulator's parameters)
    dither : the dithered condition (the ``dither`` band) or not (``still``)
    params : simulator parameters (a nested dict over ``irb140.toml``; None: the defaults),
        used without a model, and for the dither amplitude when a model has no dither band
    robot_name : the robot's name; without a model it must be the simulator's (``irb140``)

    Raises
    ------
    ModelError
        The model has another number of joints, or no ``still`` band.
    RobotError
        No model and the robot is not the simulator's IRB140.
    """
    if model is not None:
        if model.n != n:
            raise ModelError(
                f"{model.source or 'model'}: the model has {model.n} joints, the robot {n}; "
                "expected a model of this robot"
            )
        still = model.band("still")
        src = f"model {model.source}" if model.source else "model"
        pm, ps = model.prior_mean.copy(), model.prior_sigma.copy()
        p = load_params(params)
        sh = _plant_shares(p)
        if not dither:
            return Bands(still.tau_min, still.tau_max, still.sigma, False, src, pm, ps, **sh)
        g = centre_loop_gain(p)
        sh = {
            **sh,
            "plant": p,
            "extraction_gain": extraction_gain(model.effects, n, "gain"),
            "extraction_lag": extraction_gain(model.effects, n, "lag"),
        }
        if "dither" in model.regimes:
            d = model.regimes["dither"]
            return Bands(
                d.tau_min, d.tau_max, d.sigma, True, f"{src} [regimes.dither]", pm, ps, g, **sh
            )
        amp = (
            np.asarray(p["dither"]["amplitude_fraction"], float)[:n]
            * np.asarray(p["friction"]["static"], float)[:n]
        )
        mid = 0.5 * (still.tau_min + still.tau_max)
        lo, hi = np.minimum(still.tau_min + amp, mid), np.maximum(still.tau_max - amp, mid)
        return Bands(
            lo, hi, _period_noise(still.sigma, p), True,
            f"{src} (still band shrunk by the simulator's dither amplitude)", pm, ps, g, **sh,
        )  # fmt: skip
    p = load_params(params)
    fs = np.asarray(p["friction"]["static"], float)
    if n != len(fs) or robot_name != SIM_ROBOT:
        raise RobotError(
            f"the simulator's friction and noise are those of its {len(fs)}-joint "
            f"{SIM_ROBOT}, not of robot {robot_name!r}; expected --model (a model file of this "
            "robot from ditherlab identify)"
        )
    sig = float(p["noise"]["tau_sigma_fraction"]) * fs
    pm, ps = np.zeros(6), np.array(PAPER_PRIOR_SIGMA)
    sh = _plant_shares(p)
    if not dither:
        return Bands(-fs, fs, sig, False, "simulator defaults (irb140.toml)", pm, ps, **sh)
    half = np.maximum(1.0 - np.asarray(p["dither"]["amplitude_fraction"], float), 0.0) * fs
    src = "simulator defaults (irb140.toml)"
    g = centre_loop_gain(p)
    return Bands(-half, half, _period_noise(sig, p), True, src, pm, ps, g, plant=p, **sh)


def centre_loop_gain(p: Mapping[str, Any]) -> float:
    """The share [-] of a push the extracted signal shows at the push's largest response, mean
    over the campaign's push lengths: the dither's centre loop (``dither.centre_gain`` Kc
    [1/s], updated every ``dither.update_every`` samples from the mean of the last
    ``dither.periods`` periods) drives the signal's centre back to the gravity torque, so a
    push reaches the signal high-passed. Simulated on a raised-cosine push of each length in
    ``push_campaign.duration_min .. duration_max`` [s] (six lengths), its peak taken over the
    push and the report's 0.3 s after it. 1 for a loop gain of 0."""
    d = p["dither"]
    kc = float(d["centre_gain"])
    if kc <= 0.0:
        return 1.0
    dt = 1.0 / float(p["timing"]["sample_rate_hz"])
    every = max(int(d["update_every"]), 1)
    win = max(int(round(float(d["periods"]) * 2 * math.pi / float(d["frequency"]) / dt)), 1)
    pc = p["push_campaign"]
    peaks = []
    for D in np.linspace(float(pc["duration_min"]), float(pc["duration_max"]), 6):
        t = np.arange(0.0, D + 0.3, dt)
        e = np.where(t < D, 0.5 * (1.0 - np.cos(2 * np.pi * t / D)), 0.0)
        c, y = 0.0, np.zeros_like(t)
        for k in range(len(t)):
            y[k] = e[k] + c
            if k and k % every == 0:
                c -= kc * y[max(0, k - win + 1) : k + 1].mean() * every * dt
        peaks.append(float(y.max()))
    return float(np.mean(peaks))


def transmission_table(
    robot: RobotModel, q: np.ndarray, bands: Bands
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """The dithered push transmission at pose ``q`` (n,) [rad] for :func:`predict`: per joint
    the drop of the extracted signal for push torques on a grid of multiples of the joint's
    Fs (:data:`TRANSMISSION_TORQUES`) and for :data:`TRANSMISSION_DURATIONS` push lengths over
    the campaign's range (``push_campaign.duration_min/max``): from the model's
    ``dither_extraction`` law ``gain · lag(mean_period(J^T F))`` on the joints it names (its
    gain and lag, the push's peak through it, :func:`extraction_peak`), from the plant's
    equations elsewhere (:func:`dither_transmission`, the links' inertia at ``q``).

    Returns
    -------
    durations : (D,) [s]
    torques : (m, n) [N·m]
    drop : (D, m, n) [N·m]
    what : where the numbers come from, for the output
    """
    p = bands.plant if bands.plant is not None else load_params()
    n = robot.n
    fs = np.broadcast_to(np.asarray(p["friction"]["static"], float), (n,))
    torques = np.asarray(TRANSMISSION_TORQUES, float)[:, None] * fs[None, :]
    pc = p["push_campaign"]
    lo_d, hi_d = float(pc["duration_min"]), float(pc["duration_max"])
    k = TRANSMISSION_DURATIONS
    durations = lo_d + (np.arange(k) + 0.5) / k * (hi_d - lo_d)
    named = np.zeros(n, bool)
    if bands.extraction_gain is not None and bands.extraction_lag is not None:
        named = (bands.extraction_gain != 1.0) | (bands.extraction_lag != 0.0)
    M = robot.mass_matrix(np.asarray(q, float)[None, :])[0]
    M = M + np.diag(np.broadcast_to(np.asarray(p["joints"]["output_inertia"], float), (n,)))
    inertia = np.diag(M).copy()  # one joint at a time, the other links held
    drop = np.zeros((k, len(torques), n))
    if not named.all():
        drop = dither_transmission(p, inertia, torques, durations)
    what = "the plant's joints simulated one at a time (dither_transmission)"
    if named.any():
        rate = float(p["timing"]["sample_rate_hz"])
        w = max(int(round(2 * math.pi / float(p["dither"]["frequency"]) * rate)), 1)
        for j in np.flatnonzero(named):
            g, lag = float(bands.extraction_gain[j]), float(bands.extraction_lag[j])
            pk = np.array([extraction_peak(D, lag, w, rate) for D in durations])
            drop[:, :, j] = g * pk[:, None] * torques[None, :, j]
        js = ", ".join(str(j + 1) for j in np.flatnonzero(named))
        what = f"the model's dither_extraction (gain, lag) on joint(s) {js}" + (
            "; the plant's joints simulated elsewhere" if not named.all() else ""
        )
    return durations, torques, drop, what


def _period_noise(sigma: np.ndarray, p: Mapping[str, Any]) -> np.ndarray:
    """The noise of the extracted signal [N·m] (n,): white torque noise ``sigma`` averaged over
    the samples of one dither period."""
    per = 2 * math.pi / float(p["dither"]["frequency"]) * float(p["timing"]["sample_rate_hz"])
    return np.asarray(sigma, float) / math.sqrt(max(per, 1.0))


# ------------------------------------------------------------------ the prediction
def _estimates(r: np.ndarray, J: np.ndarray, bands: Bands, components: str) -> np.ndarray:
    """``F̂`` (N, 3) [N] of eq. (3) for residuals ``r`` (N, n) [N·m] at one pose ``J`` (6, n)."""
    Jb = np.broadcast_to(J, (len(r), *J.shape))
    sol = estimate(
        r, Jb, bands.lo, bands.hi, bands.sigma, bands.prior_mean, bands.prior_sigma,
        components=parse_components(components),
    )  # fmt: skip
    return sol.F[:, :3]


def _strata(rng: np.random.Generator, draws: int, n: int) -> np.ndarray:
    """Stratified uniform draws on [0, 1) (draws, n): one per stratum, shuffled per joint."""
    u = (np.arange(draws)[:, None] + rng.random((draws, n))) / draws
    for j in range(n):
        rng.shuffle(u[:, j])
    return u


def noise_levels(
    J: np.ndarray,
    bands: Bands,
    *,
    components: str = "fxyz",
    rest_samples: int = 20_000,
    quantile: float = QUANTILE,
    floor: float = FLOOR,
    seed: int = 0,
    rest_states: np.ndarray | None = None,
) -> np.ndarray:
    """The predicted noise level per axis (3,) [N]: the ``quantile`` of ``|F̂_axis|`` at rest,
    at least ``floor``: ``rest_samples`` residuals of the friction state plus Gaussian noise,
    the state ``rest_states`` (K, n) [N·m] taken in turn when given (the states a campaign
    leaves, :func:`campaign_states`), else uniform in the band without dither and at the
    band's middle with dither (the dither's centre loop drives the extracted signal back to
    the gravity torque at rest). ``J`` (6, n) the pose's Jacobian."""
    rng = np.random.default_rng(seed)
    u = _strata(rng, rest_samples, len(bands.lo))
    if bands.dithered:  # the centre loop holds the extracted signal at the band's middle
        u = np.full_like(u, 0.5)
    state = bands.lo + u * (bands.hi - bands.lo)
    if rest_states is not None and len(rest_states):
        state = np.asarray(rest_states, float)[np.arange(rest_samples) % len(rest_states)]
    r = state + rng.standard_normal(u.shape) * bands.sigma
    F = _estimates(r, J, bands, components)
    return np.maximum(np.quantile(np.abs(F), quantile, axis=0), floor)


def shared_fraction(
    J: np.ndarray, bands: Bands, force_range: tuple[float, float], n: int
) -> dict[str, float]:
    """Per push direction, the probability [-] that the two joints which see it first (the two
    lowest single-joint thresholds ``W_j / |l_j|``) were last slipped by the same push, so that
    their friction states sit alike: ``sum_d min(a_i(d), a_j(d)) / sum_d max(a_i(d), a_j(d))``
    over the six push directions ``d``, with ``a_j(d)`` the chance that a push along ``d``
    (magnitude uniform over ``force_range`` [N]) crosses joint ``j``'s band,
    ``E[min(1, P |l_j(d)| / W_j)]``; a larger push slips every joint a smaller one does, so
    the most recent push that slipped either slipped both with the ratio of the smaller to the
    larger chance. 1 when one joint alone sees the direction. ``J`` (6, n) at the pose."""
    P = np.linspace(force_range[0], force_range[1], 41)
    width = np.maximum(bands.hi - bands.lo, 1e-12)
    a = {}
    for name, ax, _ in DIRECTIONS:
        lev = np.abs(J[ax, :n])
        a[name] = np.minimum(1.0, P[:, None] * lev[None, :] / width).mean(axis=0)  # (n,)
    A = np.array([a[d] for d, _, _ in DIRECTIONS])  # (6, n)
    out = {}
    for name, ax, _ in DIRECTIONS:
        lev = np.abs(J[ax, :n])
        thr = np.where(lev > 0, width / np.maximum(lev, 1e-300), np.inf)
        i, j = np.argsort(thr)[:2]
        if not np.isfinite(thr[j]):
            out[name] = 1.0
            continue
        hi = np.maximum(A[:, i], A[:, j]).sum()
        out[name] = float(np.minimum(A[:, i], A[:, j]).sum() / hi) if hi > 0 else 1.0
    return out


def campaign_states(
    J: np.ndarray,
    bands: Bands,
    force_range: tuple[float, float],
    pushes: int = 3000,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The friction states a push campaign leaves before each push, without dither: the
    campaign's pushes (direction one of the six at random, magnitude uniform over
    ``force_range`` [N]) played on every joint at once from the middle of the band.

    The plant's band sits mostly behind the gear spring (``bands.link_share`` of it): the logged
    torque does not move while the link's friction holds the push, and a push moves the link
    only once its torque ``P |l_j|`` breaks ``link_share · W_j / 2 - sign(l_j) (s_j - mid_j)``
    with ``s_j`` the logged residual before the push (at rest the spring carries the link's
    friction, so the logged state mirrors it: a residual on the edge the push drives towards is
    a link friction on the far edge; measured against the plant,
    ``docs/design/analysis-sensitivity.md``).
    After a push that slipped the joint the servo leaves the motor ahead of the link and the
    spring holds the link along the push at the sliding level (measured after pushes beyond
    about 2 Fs), ``s_j = mid_j + sign(l_j) · sliding · W_j / 2``: a push the same way next
    breaks the link at ``(link_share - sliding) W/2``, one the other way only at
    ``(link_share + sliding) W/2`` (1.75 Fs on the default plant). A push that does not slip
    the joint leaves its state. Not modelled: after smaller slips the position loop's slow
    return (velocity integral against the spring, ~1.5 s) walks the state back across the
    band during the rest, so the plant's states spread between the two levels.

    Parameters
    ----------
    J : (6, n) the pose's Jacobian
    bands : the no-dither bands (:func:`condition_bands`)
    force_range : (min, max) [N] the campaign's push magnitudes
    pushes : pushes simulated (the first 20 % are a burn-in, not returned)
    seed : the push sequence's seed

    Returns
    -------
    direction : (K,) index into :data:`DIRECTIONS` of each push
    magnitude : (K,) [N] its magnitude
    state : (K, n) [N·m] the logged residual of each joint before it
    """
    rng = np.random.default_rng(seed)
    n = J.shape[1]
    mid = 0.5 * (bands.lo + bands.hi)
    half = 0.5 * (bands.hi - bands.lo)
    levs = np.array([J[:3].T @ (sg * np.eye(3)[ax]) for _, ax, sg in DIRECTIONS])  # (6, n)
    d = rng.integers(0, len(DIRECTIONS), pushes)
    mag = rng.uniform(force_range[0], force_range[1], pushes)
    s = mid.copy()
    states = np.empty((pushes, n))
    for k in range(pushes):
        states[k] = s
        lev = levs[d[k]]
        sg = np.sign(lev)
        slip = mag[k] * np.abs(lev) > bands.link_share * half - sg * (s - mid)
        s = np.where(slip, mid + sg * bands.sliding * half, s)
    keep = slice(pushes // 5, None)
    return d[keep], mag[keep], states[keep]


def peak_noise_factor(
    bands: Bands,
    push_duration: float = PUSH_DURATION,
    sample_rate: float = SAMPLE_RATE,
    period: float = DITHER_PERIOD,
) -> float:
    """The median of the largest of the independent noise values over a push's top, in
    standard deviations: ``Phi^-1(0.5^(1/K))`` with ``K`` the samples [-] where a raised-cosine
    push of ``push_duration`` [s] is within :data:`PEAK_TOP` of its peak (``2 D acos(1 - 2
    PEAK_TOP) / (2 pi)`` seconds at ``sample_rate`` [Hz]), counted once per dither ``period``
    [s] with dither (the extraction averages over one period, so its noise is correlated over
    it); 0 when ``K <= 1``."""
    top = push_duration * math.acos(1.0 - 2.0 * PEAK_TOP) / math.pi  # [s]
    k = top / period if bands.dithered else top * sample_rate
    if k <= 1.0:
        return 0.0
    return normal_quantile(0.5 ** (1.0 / k))


def _logistic_fit(force: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """(F50, F90) [N] of the logistic ``1 / (1 + exp(-(F - F50) / s))`` that maximises the
    expected log-likelihood of hits with probability ``p`` (P,) at forces ``force`` (P,) [N],
    on the report's grid (:func:`ditherlab.analysis.detection.fit_logistic`); NaN where ``p`` is all
    0 or all 1 (no transition: the report gives a bound then)."""
    if np.all(p >= 1.0 - 1e-9) or np.all(p <= 1e-9):
        return math.nan, math.nan
    g50 = np.linspace(0.0, 1.5 * float(force.max()), 300)
    gs = np.geomspace(0.25, 50.0, 60)
    z = (force[None, None, :] - g50[:, None, None]) / gs[None, :, None]
    lp = -np.logaddexp(0.0, -z)  # log sigma(z)
    lq = -np.logaddexp(0.0, z)  # log (1 - sigma(z))
    ll = (p * lp + (1.0 - p) * lq).sum(axis=2)
    i, j = np.unravel_index(int(np.argmax(ll)), ll.shape)
    return float(g50[i]), float(g50[i] + gs[j] * math.log(9.0))


def _crossing(force: np.ndarray, p: np.ndarray, level: float) -> float:
    """The force [N] where the (non-decreasing) ``p`` first reaches ``level``, interpolated;
    inf when it never does."""
    k = np.flatnonzero(p >= level)
    if not len(k):
        return math.inf
    i = int(k[0])
    if i == 0:
        return float(force[0])
    f0, f1, p0, p1 = force[i - 1], force[i], p[i - 1], p[i]
    return float(f0 + (level - p0) / (p1 - p0) * (f1 - f0)) if p1 > p0 else float(f1)


def predict(
    robot: RobotModel,
    q: Sequence[float] | np.ndarray,
    bands: Bands,
    *,
    components: str = "fxyz",
    force_range: tuple[float, float] = DEFAULT_RANGE,
    max_force: float = 200.0,
    forces: int = 120,
    draws: int = 300,
    rest_samples: int = 20_000,
    noise_level: Sequence[float] | None = None,
    noise_source: str | None = None,
    states: str = "auto",
    push_duration: float = PUSH_DURATION,
    sample_rate: float = SAMPLE_RATE,
    period: float = DITHER_PERIOD,
    seed: int = 0,
) -> dict[str, Any]:
    """Predicted detection thresholds per push direction at pose ``q``
    (``docs/design/analysis-sensitivity.md`` derives them).

    Parameters
    ----------
    robot : the robot (its tool-point Jacobian at ``q``)
    q : (n,) [rad] the pose
    bands : :func:`condition_bands`
    components : estimated wrench components (as ``replay --components``)
    force_range : (min, max) [N] push magnitudes of the campaign the report's curve is fitted to
    max_force : largest force searched [N] (with ``states="plant"`` at most twice the
        campaign's largest push plus 20 N)
    forces, draws : force grid points over ``(0, max_force]`` (at least 400 with
        ``states="plant"``) and friction-state draws per force
    rest_samples : draws of the state at rest for the noise level
    noise_level : (3,) [N] use these noise levels (e.g. measured, the report's at rest) instead
        of the predicted ones; the predicted ones are still returned beside
    noise_source : where ``noise_level`` comes from, for the output (default ``"given"``)
    states : how the joints' friction states before a push are drawn (the design note's step
        2): ``"campaign"`` (the states a campaign leaves on the plant, :func:`campaign_states`;
        without dither only), ``"plant"`` (with dither only: every joint at the centre loop's
        gravity torque, the push through :func:`transmission_table`), ``"mixed"``,
        ``"shared"`` or ``"independent"`` (uniform in the band, the estimator's own model, for
        either condition); ``"auto"``: campaign without dither, plant with
    push_duration, sample_rate, period : the push's mean length [s], the log's rate [Hz] and the
        dither period [s] (:func:`peak_noise_factor`)
    seed : the draws' seed (the same seed gives the same numbers)

    Returns
    -------
    dict (JSON-ready): ``q`` [rad], ``levers`` (3, n) [m] (``|J_f|``), ``noise_level`` per
    axis [N] (the one the thresholds use), ``noise_level_predicted`` per axis [N] (from the
    bands alone), ``noise_level_source`` (``"predicted"`` or ``noise_source``), ``directions``: per direction ``f50``, ``f90`` (crossings of the detection
    probability, inf when never reached), ``curve_f50``, ``curve_f90`` (the report's logistic
    fit over ``force_range``), ``joints`` (the joints whose lever exceeds 1 % of the largest);
    ``axes``: per axis ``f50``, ``f90`` of that fit to both signs; ``source``, ``dithered``,
    ``states`` and ``transmission`` (with ``states="plant"``: where the push transmission
    comes from, else None).
    """
    q = np.asarray(q, float).reshape(robot.n)
    J = robot.jacobian(q[None, :])[0]  # (6, n)
    o = PredictOptions(
        components, force_range, max_force, forces, draws, rest_samples, noise_level,
        noise_source, _states_for(states, bands), push_duration, sample_rate, period, seed,
    )  # fmt: skip
    st = _setting(robot, q, J, bands, o)
    fr = np.linspace(o.force_range[0], o.force_range[1], 41)
    out: dict[str, Any] = {}
    curves: dict[str, np.ndarray] = {}
    for di, (name, ax, sign) in enumerate(DIRECTIONS):
        u = np.zeros(3)
        u[ax] = sign
        lev = J[:3].T @ u  # (n,) [m] joint torque per newton applied along u
        if st.camp is not None:
            p = _campaign_detection(st, di, u, lev, ax)
        elif st.table is not None:
            p = _plant_detection(st, u, lev, ax)
        else:
            p = _uniform_detection(st, name, u, lev, ax)
        p = np.maximum.accumulate(p)  # the response grows with P; ties of the draws aside
        curves[name] = np.interp(fr, st.P, p, left=0.0)
        out[name] = _direction_result(st.P, p, fr, curves[name], lev)
    return {
        "q": q.tolist(),
        "levers": np.abs(J[:3]).tolist(),
        "noise_level": dict(zip(AXES, st.nl.tolist(), strict=True)),
        "noise_level_predicted": dict(zip(AXES, st.nl_pred.tolist(), strict=True)),
        "noise_level_source": "predicted" if noise_level is None else noise_source or "given",
        "directions": out,
        "axes": _axes_fit(curves, fr),
        "source": bands.source,
        "dithered": bands.dithered,
        "states": o.states,
        "transmission": st.table[3] if st.table is not None else None,
        "force_range": list(force_range),
        "components": components,
        "borrowed": borrowed_values(robot.name, bands, st.table is not None),
    }


def borrowed_values(robot_name: str, bands: Bands, plant: bool) -> list[str]:
    """The values a prediction for ``robot_name`` takes from the simulator's IRB140 (none for
    the IRB140 itself): the dither amplitude that shrinks a model's still band (a model without
    a dither band) and the push transmission through the simulator's plant (``plant``)."""
    if robot_name == SIM_ROBOT:
        return []
    out = []
    if "simulator's dither amplitude" in bands.source:
        out.append("dither amplitude")
    if plant:
        out.append("push transmission")
    return out


@dataclass(frozen=True)
class PredictOptions:
    """The settings of one :func:`predict`: its parameters of the same names, ``states``
    resolved (never ``"auto"``)."""

    components: str
    force_range: tuple[float, float]
    max_force: float
    forces: int
    draws: int
    rest_samples: int
    noise_level: Sequence[float] | None
    noise_source: str | None
    states: str
    push_duration: float
    sample_rate: float
    period: float
    seed: int


def _states_for(states: str, bands: Bands) -> str:
    """``states`` checked against the bands' condition, ``"auto"`` resolved: ``"plant"`` with
    dither, ``"campaign"`` without."""
    if states not in STATES:
        raise ConfigError(f"states {states!r} is unknown; expected one of {', '.join(STATES)}")
    if states == "auto":
        states = "plant" if bands.dithered else "campaign"
    if states == "campaign" and bands.dithered:
        raise ConfigError(
            "states 'campaign' is the plant without dither; expected plant, mixed, shared or "
            "independent for the dithered bands (the centre loop re-centres the state)"
        )
    if states == "plant" and not bands.dithered:
        raise ConfigError(
            "states 'plant' is the plant with dither; expected campaign, mixed, shared or "
            "independent for the undithered bands"
        )
    return states


@dataclass(frozen=True)
class _Setting:
    """What every push direction of one :func:`predict` is evaluated with.

    Attributes
    ----------
    J : (6, n) the pose's Jacobian
    bands : the condition's bands
    o : the options (``states`` resolved)
    P : (forces,) [N] the force grid
    forces : its points
    nl, nl_pred : (3,) [N] the noise level the thresholds use, and the predicted one
    z_peak : [-] the noise's median maximum over a push's top (:func:`peak_noise_factor`)
    camp : :func:`campaign_states` (``states="campaign"``), else None
    table : :func:`transmission_table` (``states="plant"``), else None
    centre : (n,) [N·m] the residual the centre loop holds (``states="plant"``), else None
    shared_u, own_u : (draws, 1), (draws, n) stratified uniform draws of the friction state
    rho : per direction :func:`shared_fraction` (``states="mixed"``), else None
    """

    J: np.ndarray
    bands: Bands
    o: PredictOptions
    P: np.ndarray
    forces: int
    nl: np.ndarray
    nl_pred: np.ndarray
    z_peak: float
    camp: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    table: tuple[np.ndarray, np.ndarray, np.ndarray, str] | None
    centre: np.ndarray | None
    shared_u: np.ndarray
    own_u: np.ndarray
    rho: dict[str, float] | None


def _setting(
    robot: RobotModel, q: np.ndarray, J: np.ndarray, bands: Bands, o: PredictOptions
) -> _Setting:
    """The friction states (or the push transmission), the noise levels, the force grid and the
    draws of :func:`predict` at pose ``q`` (n,) [rad] with Jacobian ``J`` (6, n)."""
    n = robot.n
    camp = None
    if o.states == "campaign":
        camp = campaign_states(J, bands, o.force_range, seed=o.seed + 2)
    # with dither the centre loop holds the extracted signal at the gravity torque: residual 0,
    # wherever the model's band lies (one off 0 offsets the estimate at rest and after)
    centre = np.zeros(n) if o.states == "plant" else None
    table = transmission_table(robot, q, bands) if o.states == "plant" else None
    nl_pred = noise_levels(
        J,
        bands,
        components=o.components,
        rest_samples=o.rest_samples,
        seed=o.seed,
        rest_states=camp[2] if camp is not None else None if centre is None else centre[None],
    )  # fmt: skip
    nl = nl_pred if o.noise_level is None else np.asarray(o.noise_level, float).reshape(3)
    rng = np.random.default_rng(o.seed + 1)
    forces, P = _force_grid(o, table is not None)
    return _Setting(
        J, bands, o, P, forces, nl, nl_pred,
        z_peak=peak_noise_factor(bands, o.push_duration, o.sample_rate, o.period),
        camp=camp,
        table=table,
        centre=centre,
        shared_u=_strata(rng, o.draws, 1),
        own_u=_strata(rng, o.draws, n),
        rho=shared_fraction(J, bands, o.force_range, n) if o.states == "mixed" else None,
    )  # fmt: skip


def _force_grid(o: PredictOptions, plant: bool) -> tuple[int, np.ndarray]:
    """The force grid's points and forces (forces,) [N] over ``(0, max_force]``; with the
    plant's transmission (``plant``) thresholds of a few newtons: a finer grid (at least 400
    points) over a shorter span (at most twice the campaign's largest push plus 20 N)."""
    if plant:
        forces = max(o.forces, 400)
        top = min(o.max_force, 2.0 * o.force_range[1] + 20.0)
        return forces, np.linspace(top / forces, top, forces)
    return o.forces, np.linspace(o.max_force / o.forces, o.max_force, o.forces)


def _campaign_detection(
    st: _Setting, di: int, u: np.ndarray, lev: np.ndarray, ax: int
) -> np.ndarray:
    """Detection probability (forces,) along direction ``di`` (unit ``u``, levers ``lev`` (n,)
    [m], axis ``ax``) from the campaign's states before pushes along it: a joint shows the push
    once it breaks the link's friction, and then carries it whole."""
    bands, n = st.bands, len(lev)
    mid, half = 0.5 * (bands.lo + bands.hi), 0.5 * (bands.hi - bands.lo)
    s = st.camp[2][st.camp[0] == di][: st.o.draws]  # (m, n)
    brk = bands.link_share * half - np.sign(lev) * (s - mid)  # (m, n) [N·m]
    slip = st.P[:, None, None] * np.abs(lev) > brk[None]
    r = np.where(slip, mid - st.P[:, None, None] * lev, s[None])
    r = (r - np.sign(lev) * st.z_peak * bands.sigma).reshape(-1, n)
    F = _estimates(r, st.J, bands, st.o.components)
    return np.mean(-(F @ u).reshape(st.forces, len(s)) > st.nl[ax], axis=1)


def _plant_detection(st: _Setting, u: np.ndarray, lev: np.ndarray, ax: int) -> np.ndarray:
    """Detection probability (forces,) along unit ``u`` (levers ``lev`` (n,) [m], axis ``ax``)
    with every joint at the centre: the extracted signal drops by what the plant (or the
    model's dither_extraction) passes of the joint's push torque, per push length."""
    bands, n = st.bands, len(lev)
    _, tq, drop, _ = st.table
    dr = transmitted(st.P[:, None] * np.abs(lev)[None, :], tq, drop)  # (D, forces, n)
    s = st.centre - np.sign(lev) * st.z_peak * bands.sigma
    r = (s - np.sign(lev) * dr).reshape(-1, n)
    F = _estimates(r, st.J, bands, st.o.components)
    return np.mean(-(F @ u).reshape(len(drop), st.forces) > st.nl[ax], axis=0)


def _uniform_detection(
    st: _Setting, name: str, u: np.ndarray, lev: np.ndarray, ax: int
) -> np.ndarray:
    """Detection probability (forces,) along direction ``name`` (unit ``u``, levers ``lev``
    (n,) [m], axis ``ax``) with the states uniform in the band: the state's distance to the edge
    the push drives the residual towards is ``u·W``, ``u`` shared by the joints, independent, or
    (``"mixed"``) the first ``round(rho·draws)`` draws shared and the rest independent."""
    bands, n, draws = st.bands, len(lev), st.o.draws
    if st.o.states == "shared":
        u01 = st.shared_u
    elif st.o.states == "independent":
        u01 = st.own_u
    else:
        u01 = np.where(
            np.arange(draws)[:, None] < round(st.rho[name] * draws), st.shared_u, st.own_u
        )
    width = bands.hi - bands.lo
    s = np.where(lev > 0, bands.lo + u01 * width, bands.hi - u01 * width)  # (draws, n)
    # the report takes the largest estimate of the push: the noise's median maximum over the
    # push's top, on every joint in the direction the push drives its residual
    s = s - np.sign(lev) * st.z_peak * bands.sigma
    r = (s[None, :, :] - bands.gain * st.P[:, None, None] * lev).reshape(-1, n)
    F = _estimates(r, st.J, bands, st.o.components)
    resp = -(F @ u).reshape(st.forces, draws)
    return np.mean(resp > st.nl[ax], axis=1)


def _direction_result(
    P: np.ndarray, p: np.ndarray, fr: np.ndarray, curve: np.ndarray, lev: np.ndarray
) -> dict[str, Any]:
    """One direction's thresholds: the crossings of ``p`` (forces,) over the grid ``P`` [N], the
    report's logistic fit to ``curve`` over the campaign's forces ``fr`` [N], and the joints
    whose lever (``lev`` (n,) [m]) exceeds 1 % of the largest."""
    c50, c90 = _logistic_fit(fr, curve)
    big = np.abs(lev).max()
    return {
        "f50": _crossing(P, p, 0.5),
        "f90": _crossing(P, p, 0.9),
        "curve_f50": c50,
        "curve_f90": c90,
        "joints": [j + 1 for j in range(len(lev)) if big > 0 and abs(lev[j]) >= 0.01 * big],
    }


def _axes_fit(curves: dict[str, np.ndarray], fr: np.ndarray) -> dict[str, dict[str, float]]:
    """Per axis, F50 and F90 [N] of the report's logistic fit to both signs' curves."""
    axes = {}
    for a in AXES:
        both = np.concatenate([curves[f"+{a}"], curves[f"-{a}"]])
        f50, f90 = _logistic_fit(np.concatenate([fr, fr]), both)
        axes[a] = {"f50": f50, "f90": f90}
    return axes
