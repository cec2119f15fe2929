"""The fleet report, read from the fleet table alone: per-robot bands and noise, their drift over
dates, which robots need which effect, and outliers.

Every figure here is computed from the rows :mod:`ditherlab.analysis.fleet_job` wrote (nothing is
re-identified), so ``ditherlab fleet`` and a user reading ``fleet.parquet`` see the same numbers.

- **half-width** of a band: ``(tau_max - tau_min) / 2`` [N·m] (the still regime's is the stick
  band the paper's dither shrinks; the moving regime's the spread about the sliding line).
- **drift**: per robot, regime and joint with recordings on at least :data:`MIN_DATES` dates,
  the least-squares slope of the half-width and of ``coulomb`` over time [N·m per 30 days], its
  standard error, and the change over the dates covered; "growing" when the slope exceeds
  :data:`DRIFT_Z` standard errors and the change is at least :data:`DRIFT_SHARE` of the first
  value (friction growing with use = wear).
- **outliers**: per regime and joint over the fleet's latest recording of each robot, the robust
  z-score ``0.6745 (x - median) / MAD`` of half-width, sigma and coulomb; ``|z| >`` :data:`OUTLIER_Z`
  (Iglewicz and Hoaglin's 3.5) with at least :data:`MIN_ROBOTS` robots.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

__all__ = [
    "DRIFT_SHARE",
    "DRIFT_Z",
    "MIN_DATES",
    "MIN_ROBOTS",
    "OUTLIER_Z",
    "summarise",
    "to_markdown",
]

MIN_DATES = 3
DRIFT_Z = 3.0
DRIFT_SHARE = 0.10
OUTLIER_Z = 3.5
MIN_ROBOTS = 5
QUANTITIES = ("half_width", "sigma", "coulomb")


def _with_half_width(table: pd.DataFrame) -> pd.DataFrame:
    t = table.copy()
    t["half_width"] = (t["tau_max"] - t["tau_min"]) / 2.0
    return t


def per_robot(table: pd.DataFrame) -> pd.DataFrame:
    """Mean half-width, sigma, coulomb and residual/floor per robot, regime and joint."""
    t = _with_half_width(table)
    t["residual_ratio"] = t["torque_rms"] / t["noise_floor"]
    g = t.groupby(["robot", "regime", "joint"], sort=True)
    return g[["half_width", "sigma", "coulomb", "residual_ratio"]].mean().reset_index()


def drift(table: pd.DataFrame) -> pd.DataFrame:
    """Slopes over dates per robot, regime, joint and quantity (half-width, coulomb)."""
    t = _with_half_width(table)
    t = t[t["date"].notna()].copy()
    rows = []
    if t.empty:
        return pd.DataFrame(
            columns=[
                "robot",
                "regime",
                "joint",
                "quantity",
                "dates",
                "slope_per_30d",
                "stderr",
                "change",
                "first",
                "growing",
            ]
        )
    t["day"] = pd.to_datetime(t["date"]).map(lambda d: d.toordinal()).astype(float)
    for (robot, regime, joint), g in t.groupby(["robot", "regime", "joint"], sort=True):
        if g["day"].nunique() < MIN_DATES:
            continue
        g = g.sort_values("day")
        for qty in ("half_width", "coulomb"):
            y = g[qty].to_numpy(float)
            x = g["day"].to_numpy(float)
            ok = np.isfinite(y)
            if ok.sum() < MIN_DATES:
                continue
            x, y = x[ok], y[ok]
            X = np.column_stack([np.ones_like(x), x - x.mean()])
            coef, *_ = np.linalg.lstsq(X, y, rcond=None)
            dof = max(len(y) - 2, 1)
            s2 = float(np.sum((y - X @ coef) ** 2) / dof)
            se = float(np.sqrt(s2 / max(np.sum((x - x.mean()) ** 2), 1e-300)))
            change = float(coef[1] * (x.max() - x.min()))
            first = float(coef[0] + coef[1] * (x.min() - x.mean()))
            growing = bool(
                coef[1] > DRIFT_Z * max(se, 1e-12) and change >= DRIFT_SHARE * abs(first)
            )
            rows.append(
                {
                    "robot": robot,
                    "regime": regime,
                    "joint": int(joint),
                    "quantity": qty,
                    "dates": int(len(np.unique(x))),
                    "slope_per_30d": float(coef[1] * 30.0),
                    "stderr": se * 30.0,
                    "change": change,
                    "first": first,
                    "growing": growing,
                }
            )
    return pd.DataFrame(rows)


def effects_needed(table: pd.DataFrame) -> dict[str, dict[str, list[int]]]:
    """Effect -> robot -> joints (1-based): each recording's first suggestion (the one diagnosis
    says to add next; the others are often the same residual explained another way)."""
    out: dict[str, dict[str, set[int]]] = {}
    rows = table[table["effect_on_joint"].astype(bool)].drop_duplicates(["file", "joint"])
    for _, r in rows.iterrows():
        out.setdefault(str(r["effect"]), {}).setdefault(str(r["robot"]), set()).add(int(r["joint"]))
    return {e: {rb: sorted(js) for rb, js in sorted(v.items())} for e, v in sorted(out.items())}


def outliers(table: pd.DataFrame) -> pd.DataFrame:
    """Robust z-scores beyond :data:`OUTLIER_Z` over each robot's latest recording."""
    t = _with_half_width(table)
    key = t["date"].fillna("").astype(str)
    latest = t.assign(_k=key).sort_values("_k").groupby(["robot", "regime", "joint"]).tail(1)
    rows = []
    for (regime, joint), g in latest.groupby(["regime", "joint"], sort=True):
        if g["robot"].nunique() < MIN_ROBOTS:
            continue
        for qty in QUANTITIES:
            x = g[qty].to_numpy(float)
            ok = np.isfinite(x)
            if ok.sum() < MIN_ROBOTS:
                continue
            med = float(np.median(x[ok]))
            mad = float(np.median(np.abs(x[ok] - med)))
            if mad <= 1e-12 * max(abs(med), 1.0):
                continue
            z = 0.6745 * (x - med) / mad
            for robot, v, zz in zip(g["robot"], x, z, strict=True):
                if np.isfinite(zz) and abs(zz) > OUTLIER_Z:
                    rows.append(
                        {
                            "robot": robot,
                            "regime": regime,
                            "joint": int(joint),
                            "quantity": qty,
                            "value": float(v),
                            "fleet_median": med,
                            "z": float(zz),
                        }
                    )
    return pd.DataFrame(
        rows, columns=["robot", "regime", "joint", "quantity", "value", "fleet_median", "z"]
    )


def summarise(
    table: pd.DataFrame,
    failures: list[dict[str, str]],
    skipped: list[dict[str, str]] | None = None,
    named_by_file: list[str] | None = None,
) -> dict[str, Any]:
    """The fleet report as JSON-ready data (see the module docstring for each part).

    ``failures``: ``{file, error}`` of the recordings that failed; ``skipped``: ``{file, step,
    error}`` of an optional step that failed on a recording whose rows stand; ``named_by_file``:
    the recordings whose robot is named by their file (no manifest ``robot``, no metadata
    ``robot_id``)."""
    return {
        "recordings": int(table["file"].nunique()) if len(table) else 0,
        "robots": sorted(map(str, table["robot"].unique())) if len(table) else [],
        "failures": failures,
        "skipped": list(skipped or []),
        "named_by_file": list(named_by_file or []),
        "per_robot": per_robot(table).to_dict("records") if len(table) else [],
        "drift": drift(table).to_dict("records") if len(table) else [],
        "effects": effects_needed(table) if len(table) else {},
        "outliers": outliers(table).to_dict("records") if len(table) else [],
        "definitions": {
            "half_width": "(tau_max - tau_min) / 2 of the regime's band [N·m]",
            "drift": f"least-squares slope over dates (>= {MIN_DATES} dates) per 30 days; growing"
            f" when > {DRIFT_Z:g} standard errors and the change >= {DRIFT_SHARE:.0%} of the "
            "first value",
            "outlier": f"|0.6745 (x - median) / MAD| > {OUTLIER_Z:g} over each robot's latest "
            f"recording (>= {MIN_ROBOTS} robots)",
        },
    }


def _md_table(rows: list[dict[str, Any]], cols: list[str]) -> list[str]:
    def f(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}"
        return str(v)

    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(f(r[c]) for c in cols) + " |" for r in rows]
    return out


def _md_partial(s: dict[str, Any]) -> list[str]:
    """The optional steps that failed, and the robots named by their file, as sections."""
    lines: list[str] = []
    if s.get("skipped"):
        lines += ["## Optional steps not done", ""]
        lines += [f"- `{k['file']}`: {k['step']}: {k['error']}" for k in s["skipped"]]
        lines.append("")
    if s.get("named_by_file"):
        lines += ["## Robots named by their file", ""]
        lines.append(
            "No manifest `robot` and no metadata `robot_id`: each of these recordings is its "
            "own robot, named by its file."
        )
        lines += ["", *(f"- `{f}`" for f in s["named_by_file"]), ""]
    return lines


def to_markdown(s: dict[str, Any]) -> str:
    """``fleet.md``: the summary in words and tables."""
    lines = [
        "# Fleet report",
        "",
        f"{s['recordings']} recordings of {len(s['robots'])} robots analysed, "
        f"{len(s['failures'])} failed.",
        "",
    ]
    if s["failures"]:
        lines += ["## Failed recordings", ""]
        lines += [
            f"- {f['error']}"
            if f["error"].startswith(f["file"])
            else f"- `{f['file']}`: {f['error']}"
            for f in s["failures"]
        ]
        lines.append("")
    lines += _md_partial(s)
    lines += ["## Which robots need which effect", ""]
    if s["effects"]:
        for e, robots in s["effects"].items():
            who = "; ".join(f"{r} (joints {', '.join(map(str, js))})" for r, js in robots.items())
            lines.append(f"- **{e}**: {who}")
    else:
        lines.append("No effect suggested on any recording.")
    lines += ["", "## Drift over dates", ""]
    grow = [d for d in s["drift"] if d["growing"]]
    if not s["drift"]:
        lines.append(f"No robot has recordings on {MIN_DATES} or more dates.")
    elif grow:
        lines += _md_table(
            grow,
            ["robot", "regime", "joint", "quantity", "dates", "slope_per_30d", "stderr", "change"],
        )
    else:
        lines.append("No band or Coulomb friction grows significantly over the dates recorded.")
    lines += ["", "## Outliers", ""]
    if s["outliers"]:
        lines += _md_table(
            s["outliers"], ["robot", "regime", "joint", "quantity", "value", "fleet_median", "z"]
        )
    else:
        lines.append("No robot stands out (or fewer robots than the test needs).")
    lines += ["", "## Per robot (still regime)", ""]
    still = [r for r in s["per_robot"] if r["regime"] == "still"]
    lines += _md_table(
        still, ["robot", "joint", "half_width", "sigma", "coulomb", "residual_ratio"]
    )
    lines += ["", "## Definitions", ""]
    lines += [f"- {k}: {v}" for k, v in s["definitions"].items()]
    return "\n".join(lines) + "\n"
