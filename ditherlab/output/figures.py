"""Static PNG figures for the report, after the paper's Figs. 2, 4, 5 and 6 (matplotlib, Agg).

Each function takes arrays or the objects of :mod:`ditherlab.analysis.estimation` / :mod:`ditherlab.analysis.detection`,
writes one PNG atomically and returns its path. Forces are shown as the applied force ``P = -F``
(the paper plots the force applied to the robot); torques on the arm side [N·m].
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.core.files import atomic_path
from ditherlab.core.names import FORCE_AXES

COLOURS = {"sensor": "black", "estimate": "tab:blue", "interval": "tab:blue"}


def pyplot():
    """matplotlib.pyplot on the Agg backend (imported on first use: ~0.3 s that commands
    without figures do not pay)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def legend(ax, **kw) -> None:
    """``ax.legend(**kw)`` when the axes hold a labelled artist (a recording may lack an axis's
    pushes or a condition: no empty legend, and no matplotlib warning on the user's terminal)."""
    if ax.get_legend_handles_labels()[1]:
        ax.legend(**kw)


def _save(fig, path: Path) -> Path:
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    pyplot().close(fig)
    return Path(path)


def _window(t: np.ndarray, pushes: Sequence[dict], n: int = 6) -> tuple[float, float]:
    """A time window holding about ``n`` pushes of increasing size (from the first pushes)."""
    if not pushes:
        return float(t[0]), float(t[-1])
    ps = sorted(pushes, key=lambda p: p["start"])[:n]
    return max(float(t[0]), ps[0]["start"] - 1.0), min(float(t[-1]), ps[-1]["end"] + 1.5)


def fig6_windows(
    t_first: float, t_last: float, rinfo: dict, max_seconds: float = 40.0
) -> list[tuple[float, float]]:
    """The stretch ``(t0, t1)`` [s] :func:`fig6_estimates` shows per force axis (x, y, z) of a
    recording spanning ``t_first .. t_last`` [s] whose analysis row (pushes) is ``rinfo``."""
    span = np.array([t_first, t_last], dtype=float)
    out = []
    for a in FORCE_AXES:
        pushes = [p for p in rinfo["pushes"] if p["axis"] == a]
        t0, t1 = _window(span, sorted(pushes, key=lambda p: p["peak"])[:: max(len(pushes) // 6, 1)])
        if not pushes:
            t0, t1 = float(t_first), float(t_last)
        out.append((t0, min(t1, t0 + max_seconds)))
    return out


def fig6_estimates(
    panels: Sequence[tuple[str, Any, dict] | tuple[str, Any, dict, tuple[float, float]]],
    path: Path,
    max_seconds: float = 40.0,
) -> Path:
    """Estimated and measured force per direction, one column per condition (paper Fig. 6).

    Parameters
    ----------
    panels : (title, Estimates, recording dict of the analysis) per column, optionally with the
        whole file's ``(t_first, t_last)`` [s] when the Estimates hold only the rows shown
        (:func:`fig6_windows`); the variant is the title's first word
    path : PNG to write
    max_seconds : longest stretch shown per column [s]
    """
    plt = pyplot()
    fig, axs = plt.subplots(
        3, len(panels), figsize=(4.2 * len(panels), 7.5), squeeze=False, sharex="col"
    )
    for c, (title, est, rinfo, *span) in enumerate(panels):
        variant = title.split()[0]
        t = est.t
        F = est.wrench
        Fh = est.F(variant)
        lo, hi = est.interval(variant)
        first, last = span[0] if span else (float(t[0]), float(t[-1]))
        windows = fig6_windows(first, last, rinfo, max_seconds)
        for k, a in enumerate(FORCE_AXES):
            t0, t1 = windows[k]
            m = (t >= t0) & (t <= t1)
            ax = axs[k, c]
            ax.fill_between(
                t[m],
                -hi[m, k],
                -lo[m, k],
                color=COLOURS["interval"],
                alpha=0.2,
                lw=0,
                label="interval",
            )
            ax.plot(t[m], -F[m, k], color=COLOURS["sensor"], lw=1.0, label="F/T sensor")
            ax.plot(t[m], -Fh[m, k], color=COLOURS["estimate"], lw=1.0, label="estimate")
            ax.set_ylabel(f"applied $P_{a}$ [N]")
            if k == 0:
                ax.set_title(title, fontsize=9)
            if k == 2:
                ax.set_xlabel("t [s]")
            ax.grid(alpha=0.3)
            fin = np.isfinite(lo[m, k]) & np.isfinite(hi[m, k])
            span = np.abs(np.r_[F[m, k], Fh[m, k], lo[m, k][fin], hi[m, k][fin]])
            lim = float(np.quantile(span, 0.99)) * 1.1 + 5 if span.size else 60.0
            ax.set_ylim(-lim, lim)
    legend(axs[0, 0], fontsize=7, loc="upper left")
    fig.suptitle("Estimated and measured forces (cf. the paper's Fig. 6)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def detection_curves(analysis: dict, path: Path) -> Path:
    """Response (estimate along the axis) against applied force, per direction and condition,
    with the noise level, the 10 N line and the fitted detection probability."""
    plt = pyplot()
    conds = list(analysis["conditions"])
    fig, axs = plt.subplots(2, 3, figsize=(13, 7.5), squeeze=False)
    cmap = plt.get_cmap("tab10")
    for k, a in enumerate(FORCE_AXES):
        ax, axp = axs[0, k], axs[1, k]
        for i, c in enumerate(conds):
            d = analysis["conditions"][c]
            ps = [p for p in d["pushes"] if p["axis"] == a]
            if not ps:
                continue
            f = np.array([p["peak"] for p in ps])
            r = np.array([p["response"] for p in ps])
            ax.scatter(f, r, s=10, color=cmap(i), label=c, alpha=0.7)
            st = d["directions"].get(a)
            if st and np.isfinite(st["curve"]["F50"]):
                ff = np.linspace(0, f.max() * 1.1, 200)
                pp = 1 / (1 + np.exp(-(ff - st["curve"]["F50"]) / st["curve"]["scale"]))
                axp.plot(ff, pp, color=cmap(i), label=f"{c}: F50 {st['curve']['F50']:.0f} N")
                det = np.array([p["detected"] for p in ps], float)
                axp.scatter(f, det + (i - len(conds) / 2) * 0.015, s=6, color=cmap(i), alpha=0.5)
        ax.axhline(10, color="grey", ls="--", lw=0.8)
        ax.plot([0, ax.get_xlim()[1]], [0, ax.get_xlim()[1]], color="black", lw=0.6, ls=":")
        ax.set_title(f"{a}: response vs applied force", fontsize=9)
        ax.set_xlabel("applied force (peak) [N]")
        ax.set_ylabel("largest estimate [N]")
        ax.grid(alpha=0.3)
        axp.set_xlabel("applied force (peak) [N]")
        axp.set_ylabel("P(response)")
        axp.grid(alpha=0.3)
        legend(axp, fontsize=6)  # no fitted curve: nothing to label
    legend(axs[0, 0], fontsize=6)
    fig.tight_layout()
    return _save(fig, path)


def fig2_torques(
    panels: Sequence[tuple[str, np.ndarray, np.ndarray, np.ndarray, tuple[float, float]]],
    path: Path,
    joint: int,
) -> Path:
    """Torque of one joint during pushes without and with dither (paper Fig. 2).

    Parameters
    ----------
    panels : (title, t (N,) [s], tau_bar (N,) [N·m] = tau - gravity, tau_ext (N,) [N·m] =
        J^T F of the sensor, band (a, b) [N·m]) per column
    joint : 1-based joint shown
    """
    plt = pyplot()
    fig, axs = plt.subplots(1, len(panels), figsize=(6 * len(panels), 3.8), squeeze=False)
    for c, (title, t, tb, ext, band) in enumerate(panels):
        ax = axs[0, c]
        ax.plot(t, tb, lw=0.6, color="tab:blue", label=r"$\tau - \tau_{grav}$")
        ax.plot(t, ext, lw=1.0, color="black", label=r"$J^T F$ (sensor)")
        ax.axhline(band[0], color="tab:red", ls="--", lw=0.8, label="friction band")
        ax.axhline(band[1], color="tab:red", ls="--", lw=0.8)
        ax.set_title(f"{title}, joint {joint}", fontsize=9)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("torque [N·m]")
        ax.grid(alpha=0.3)
    legend(axs[0, 0], fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def fig4_extraction(
    t: np.ndarray,
    upper: np.ndarray,
    lower: np.ndarray,
    signal: np.ndarray,
    tau_bar: np.ndarray,
    tau_ext: np.ndarray,
    band: tuple[float, float],
    new_band: tuple[float, float],
    path: Path,
    joint: int,
) -> Path:
    """Extraction of the torque signal and the shrunk band (paper Fig. 4); all (N,) [N·m]."""
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    a1.plot(t, tau_bar, lw=0.4, color="grey", label=r"$\tau - \tau_{grav}$")
    a1.plot(t, upper, color="tab:red", lw=1.0, label="upper")
    a1.plot(t, lower, color="tab:green", lw=1.0, label="lower")
    a1.set_ylabel("torque [N·m]")
    legend(a1, fontsize=7)
    a1.grid(alpha=0.3)
    a2.plot(t, signal, color="tab:blue", lw=1.0, label="extracted signal")
    a2.plot(t, tau_ext, color="black", lw=1.0, label=r"$J^T F$ (sensor)")
    for y in band:
        a2.axhline(y, color="tab:red", ls="--", lw=0.8)
    for y in new_band:
        a2.axhline(y, color="tab:orange", ls="-.", lw=0.8)
    a2.plot([], [], color="tab:red", ls="--", label="friction band")
    a2.plot([], [], color="tab:orange", ls="-.", label="band with dither")
    a2.set_xlabel("t [s]")
    a2.set_ylabel("torque [N·m]")
    legend(a2, fontsize=7)
    a2.grid(alpha=0.3)
    fig.suptitle(f"Extraction of the torque signal, joint {joint} (cf. Fig. 4)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def fig5_dither_control(
    t: np.ndarray,
    centre: np.ndarray,
    amplitude: np.ndarray,
    ffw: np.ndarray | None,
    tau: np.ndarray,
    gravity: np.ndarray,
    band: tuple[float, float],
    amp_ref: float | None,
    path: Path,
    joint: int,
) -> Path:
    """Dither control of one joint (paper Fig. 5): measured centre and amplitude (five-period
    means), the feedforward, and the torque with the band around gravity; all (N,) [N·m]."""
    plt = pyplot()
    fig, axs = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    axs[0].plot(t, centre, label="centre (measured)")
    axs[0].plot(t, gravity, ls="--", label="centre reference (gravity)")
    axs[0].plot(t, amplitude, label="amplitude (measured)")
    if amp_ref is not None:
        axs[0].axhline(amp_ref, color="tab:red", ls="--", lw=0.8, label="amplitude set-point")
    legend(axs[0], fontsize=7)
    if ffw is not None:
        axs[1].plot(t, ffw, lw=0.5, label=r"$\tau_{ffw}$")
        legend(axs[1], fontsize=7)
    axs[2].plot(t, tau, lw=0.4, label=r"$\tau$")
    axs[2].plot(t, gravity + band[0], color="tab:red", ls="--", lw=0.8, label="band")
    axs[2].plot(t, gravity + band[1], color="tab:red", ls="--", lw=0.8)
    axs[2].plot(t, centre, color="tab:orange", lw=0.8, label="centre")
    legend(axs[2], fontsize=7)
    axs[2].set_xlabel("t [s]")
    for ax in axs:
        ax.set_ylabel("[N·m]")
        ax.grid(alpha=0.3)
    fig.suptitle(f"Dither control, joint {joint} (cf. Fig. 5)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)
