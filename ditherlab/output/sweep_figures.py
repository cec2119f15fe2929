"""The sweep's figures (matplotlib, Agg; each PNG written atomically): detection against
vibration, F50 per direction per grid point, and the measured F50 against the predicted.

Both read the sweep's table (:data:`ditherlab.app.sweep.COLUMNS` after the grid's columns);
failed points are left out.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from ditherlab.core.files import atomic_path
from ditherlab.core.names import FORCE_AXES
from ditherlab.output.figures import legend, pyplot

__all__ = ["plot_points", "plot_prediction", "plot_tradeoff"]


def _save(fig, path: Path) -> Path:  # noqa: ANN001 - a matplotlib Figure
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    pyplot().close(fig)
    return Path(path)


def _short(table: pd.DataFrame, grid: Sequence[str], colour_key: str | None) -> list[str]:
    """Each point's values of the grid keys other than the colour key, short: the key's last
    part cut to 4 letters, a per-joint list by its first value (``ampl=0.9…``)."""
    keys = [k for k in grid if k != colour_key]

    def val(v: object) -> str:
        s = f"{v:g}" if isinstance(v, float) else str(v)
        return s.split(":")[0] + "…" if ":" in s else s

    return [
        " ".join(f"{k.split('.')[-1][:4]}={val(r[k])}" for k in keys) for _, r in table.iterrows()
    ]


def plot_tradeoff(table: pd.DataFrame, grid: Sequence[str], limit: float, path: str | Path) -> Path:
    """Mean dithered F50 over x, y, z [N] against the vibration [rad, arm side] per point (log
    axis), coloured by the waveform when it is swept (else by the first grid key), each point
    labelled with its other values, with F50's standard error over seeds as a bar; the vibration limit as a dashed line and the undithered
    F50 (median over points) as a dotted one."""
    plt = pyplot()
    ok = table[table["ok"] & np.isfinite(table["vibration"])].reset_index(drop=True)
    fig, ax = plt.subplots(figsize=(8.5, 5.5))
    key = "dither.waveform" if "dither.waveform" in grid else (grid[0] if grid else None)
    groups = ok[key].astype(str) if key else pd.Series(["all"] * len(ok))
    labels = _short(ok, grid, key)
    for name in dict.fromkeys(groups):
        m = (groups == name).to_numpy()
        sc = ax.scatter(
            ok["vibration"][m], ok["f50_mean"][m], s=40, label=f"{key}={name}" if key else name
        )
        if "f50_mean_sem" in ok and np.isfinite(ok["f50_mean_sem"][m]).any():  # several seeds
            ax.errorbar(ok["vibration"][m], ok["f50_mean"][m], yerr=ok["f50_mean_sem"][m],
                        fmt="none", ecolor=sc.get_facecolor()[0], lw=0.8)  # fmt: skip
    for i, r in ok.iterrows():
        ax.annotate(labels[i], (r["vibration"], r["f50_mean"]), fontsize=6, xytext=(3, 3),
                    textcoords="offset points")  # fmt: skip
    ax.axvline(limit, color="tab:red", ls="--", lw=1, label=f"vibration limit {limit:g} rad")
    nd = (
        np.nanmedian(ok[[f"nodither_f50_{a}" for a in FORCE_AXES]].mean(axis=1))
        if len(ok)
        else np.nan
    )
    if np.isfinite(nd):
        ax.axhline(nd, color="grey", ls=":", lw=1, label=f"no dither, median F50 {nd:.0f} N")
    if len(ok) and (ok["vibration"] > 0).all():
        ax.set_xscale("log")
    ax.set_xlabel("arm vibration: half peak-to-peak of the link angle per dither period [rad]")
    ax.set_ylabel("dithered F50, mean of x / y / z [N]")
    ax.set_title("Dither design: detection (F50) against vibration")
    legend(ax, fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_points(table: pd.DataFrame, limit: float, path: str | Path) -> Path:
    """F50 per direction [N] of each point as grouped bars (dither, and the undithered baseline
    as ticks); points beyond the vibration limit hatched. A bar whose pushes were all seen shows
    the smallest push (an upper bound of F50)."""
    plt = pyplot()
    ok = table[table["ok"]].reset_index(drop=True)
    fig, ax = plt.subplots(figsize=(max(6.0, 0.9 * len(ok) + 2), 5.0))
    x = np.arange(len(ok))
    w = 0.27
    colours = {"x": "tab:blue", "y": "tab:orange", "z": "tab:green"}
    for i, a in enumerate(FORCE_AXES):
        hatch = ["//" if not v else "" for v in ok["within_limit"]]
        bars = ax.bar(x + (i - 1) * w, ok[f"f50_{a}"], w, color=colours[a], label=f"F50 {a}")
        for b, h in zip(bars, hatch, strict=True):
            b.set_hatch(h)
        ax.scatter(x + (i - 1) * w, ok[f"nodither_f50_{a}"], marker="_", s=120, color="black",
                   label="no dither" if i == 0 else None)  # fmt: skip
    ax.set_xticks(x)
    ax.set_xticklabels([p.replace(" ", "\n") for p in ok["point"]], fontsize=6)
    ax.set_ylabel("F50 [N]")
    ax.set_title(f"F50 per direction and point (hatched: vibration above {limit:g} rad)")
    legend(ax, fontsize=7)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_prediction(table: pd.DataFrame, path: Path) -> Path:
    """Measured F50 against the F50 predicted at each point's pose
    (:mod:`ditherlab.analysis.sensitivity`), per axis, without and with dither [N], on log axes,
    with the line of equality and ±25 %; a direction whose pushes were all (none) seen is
    drawn hollow at its bound's force."""
    plt = pyplot()
    from matplotlib import ticker  # after pyplot(), which selects the Agg backend

    fig, axs = plt.subplots(1, 2, figsize=(10, 4.6), constrained_layout=True)
    ok = table[table["ok"]]
    conds = (("nodither_", "without dither"), ("", "with dither"))
    for ax, (prefix, title) in zip(axs, conds, strict=True):
        lo, hi = np.inf, 0.0
        for a, colour in zip(FORCE_AXES, ("C0", "C1", "C2"), strict=True):
            m = ok[f"{prefix}f50_{a}"].to_numpy(float)
            p = ok[f"pred_{prefix}f50_{a}"].to_numpy(float)
            bound = (
                ok[f"f50_{a}_bound"].astype(bool).to_numpy()
                if not prefix
                else np.zeros(len(ok), bool)
            )
            good = np.isfinite(m) & np.isfinite(p) & (m > 0) & (p > 0)
            for sel, face in ((good & ~bound, colour), (good & bound, "none")):
                ax.scatter(p[sel], m[sel], edgecolors=colour, facecolors=face, label=None)
            ax.scatter([], [], color=colour, label=a)
            if good.any():
                lo, hi = (
                    min(lo, p[good].min(), m[good].min()),
                    max(hi, p[good].max(), m[good].max()),
                )
        if np.isfinite(lo):
            x = np.geomspace(lo / 1.3, hi * 1.3, 50)
            ax.plot(x, x, "k-", lw=0.8)
            ax.fill_between(x, x / 1.25, x * 1.25, color="0.85", zorder=0, label="±25 %")
            ax.set_xscale("log")
            ax.set_yscale("log")
            for axis in (ax.xaxis, ax.yaxis):
                axis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
                axis.set_major_formatter(ticker.ScalarFormatter())
                axis.set_minor_formatter(ticker.NullFormatter())
        ax.set_xlabel("predicted F50 [N]")
        ax.set_ylabel("measured F50 [N]")
        ax.set_title(title)
        legend(ax, fontsize=8)
    return _save(fig, path)
