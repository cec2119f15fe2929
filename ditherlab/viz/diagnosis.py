"""The diagnosis report: ``report.md``, ``report.json`` and the evidence and history figures
that ``ditherlab diagnose -o DIR`` writes (the analysis itself is :mod:`ditherlab.diagnose`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.diagnose import AXES, Diagnosis, nanmean
from ditherlab.effects import EFFECTS, Effect, hyper_params, model_text
from ditherlab.io.atomic import atomic_path, atomic_write_json, atomic_write_text
from ditherlab.recording import MOVING
from ditherlab.scoring import Candidate, JointScore
from ditherlab.viz.figures import pyplot

__all__ = ["write_report"]


def _history_rows(hist: list[dict[str, Any]]) -> list[str]:
    rows = [
        "| version | effects | torque RMS per joint [N·m] | floor | force RMS f_x f_y f_z [N] | coverage |",
        "|---|---|---|---|---|---|",
    ]
    for h in hist:
        tr = " ".join(f"{v:.3g}" for v in h.get("torque_rms", []))
        fl = " ".join(f"{v:.3g}" for v in h.get("noise_floor", []))
        fr = " ".join(f"{v:.3g}" for v in (h.get("force_rms") or [])[:3]) or "–"
        cov = h.get("coverage")
        rows.append(
            f"| {h.get('version')} | {', '.join(h.get('effects', [])) or 'base'} | {tr} | {fl} | {fr} | "
            f"{'–' if cov is None else f'{cov:.2f}'} |"
        )
    return rows


def _evidence_figure(d: Diagnosis, c: Candidate, path: Path) -> None:
    """Residual against the effect's driving variable, per joint, with the fitted effect."""
    plt = pyplot()
    e = EFFECTS[c.effect]
    joints = [j - 1 for j in c.joints][:4] or [0]
    fig, axes = plt.subplots(1, len(joints), figsize=(4.2 * len(joints), 3.4), squeeze=False)
    for ax, j in zip(axes[0], joints, strict=False):
        s = next((s for s in c.scores if s.joint in (j, None)), None)
        xs, ys, ps = [], [], []
        label = ""
        for sc in d.scs:
            p = _params_for_plot(e, c, s, j)
            x, label = e.driver(sc.sig, j, p)
            des = e.design(
                sc.sig, None if e.shared else j, s.fit.h if s else None, s.fit.ref if s else {}
            )
            if e.shared:
                shift = des.centre[:, j, :] @ s.fit.w + (
                    des.offset[:, j] if des.offset is not None else 0
                )
            else:
                shift = des.centre @ s.fit.w + (des.offset if des.offset is not None else 0)
            m = sc.use[:, j] & ((sc.sig.regime[:, j] == MOVING) | (np.abs(sc.e[:, j]) > sc.h[:, j]))
            y = sc.e[:, j] - np.sign(sc.e[:, j]) * np.where(
                sc.sig.regime[:, j] == MOVING, 0, sc.h[:, j]
            )
            if e.signed_evidence:
                mv = sc.sig.regime[:, j] == MOVING
                sg = np.where(mv, np.sign(sc.sig.dq[:, j]), 1.0)
                y, shift = y * sg, shift * sg
            xs.append(x[m])
            ys.append(y[m])
            ps.append(np.broadcast_to(shift, x.shape)[m])
        x, y, p = (np.concatenate(a) for a in (xs, ys, ps))
        if len(x) > 4000:
            idx = np.random.default_rng(0).choice(len(x), 4000, replace=False)
            x, y, p = x[idx], y[idx], p[idx]
        ax.scatter(x, y, s=2, alpha=0.3, color="0.4", label="residual")
        o = np.argsort(x)
        ax.plot(x[o], p[o], ".", ms=2, color="C3", label=f"fitted {c.effect}")
        ax.set_xlabel(label)
        ax.set_ylabel(f"residual{' · sign(dq)' if e.signed_evidence else ''} joint {j + 1} [N·m]")
        ax.legend(loc="best", fontsize=7, markerscale=4)
    fig.suptitle(
        f"{c.effect}: {100 * c.explained_fraction:.1f} % explained (held-out)", fontsize=10
    )
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)


def _params_for_plot(e: Effect, c: Candidate, s: JointScore | None, j: int) -> dict[str, Any]:
    if s is None:
        return {}
    if e.shared:
        return e.linear_params(s.fit.w)
    p = {name: float(v) for name, v in zip(e.linear, s.fit.w, strict=False)}
    p.update(hyper_params(e, s.fit.h))
    p.update(s.fit.ref)
    return p


def _history_figure(hist: list[dict[str, Any]], path: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.2))
    v = [h["version"] for h in hist]
    tr = np.array([h["torque_rms"] for h in hist])
    for j in range(tr.shape[1]):
        ax.plot(v, tr[:, j], "o-", label=f"joint {j + 1}")
    fl = np.array([h.get("noise_floor", [np.nan] * tr.shape[1]) for h in hist])
    ax.plot(v, nanmean(fl, axis=1), "k--", label="noise floor (mean)")
    ax.set_xlabel("model version")
    ax.xaxis.set_major_locator(plt.MaxNLocator(integer=True))
    ax.set_ylabel("torque residual RMS [N·m]")
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)


def write_report(d: Diagnosis, out_dir: str | Path, max_figures: int = 4) -> Path:
    """Write ``report.md``, ``report.json`` and PNG evidence figures into ``out_dir``.

    Returns the path of ``report.md``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figs = d.suggested[:max_figures] or d.candidates[:1]
    for c in figs:
        name = f"evidence_{c.effect}.png"
        _evidence_figure(d, c, out / name)
        c.figure = name
    hist = d.model.history
    if hist:
        _history_figure(hist, out / "history.png")
    md = [
        f"# Diagnosis of model v{d.model.version}",
        "",
        "Recordings: " + ", ".join(d.recordings),
        "",
    ]
    md += ["## Model", "", "```", model_text(d.model), "```", ""]
    md += ["## Torque residual (band-aware) against the noise floor", ""]
    md += [
        "| joint | regime | samples | RMS [N·m] | floor [N·m] | outside band | mean excess [σ] |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in d.residual["per_regime"]:
        md.append(
            f"| {r['joint']} | {r['regime']} | {r['samples']} | {r['rms']:.3g} | {r['floor']:.3g} | "
            f"{100 * r['outside_fraction']:.0f} % | {r['mean_excess_sigma']:+.2f} |"
        )
    md.append("")
    if d.force is not None:
        md += [
            "## Force error (estimate − sensor)",
            "",
            "| regime | samples | " + " | ".join(AXES) + " |",
            "|---|---|" + "---|" * 6,
        ]
        for r in d.force["per_regime"]:
            md.append(
                f"| {r['regime']} | {r['samples']} | "
                + " | ".join(f"{v:.3g}" for v in r["rms"])
                + " |"
            )
        if d.force.get("coverage") is not None:
            md.append(
                "| coverage (95 % set-membership) | | "
                + " | ".join(f"{v:.2f}" for v in d.force["coverage"])
                + " |"
            )
        md.append("")
    if d.windows:
        md += [
            "## Worst time windows",
            "",
            "| recording | t [s] | energy [floor²] | worst joint (× floor) |",
            "|---|---|---|---|",
        ]
        for w in d.windows:
            md.append(
                f"| {w['recording']} | {w['t0']:.1f}–{w['t1']:.1f} | {w['energy']:.3g} | "
                f"{w['worst_joint']} ({w['worst_joint_ratio']:.2g}) |"
            )
        md.append("")
    md += [
        "## Candidate effects (held-out explained fraction, best first)",
        "",
        "| effect | joints | explained | suggested | ΔBIC (best joint) |",
        "|---|---|---|---|---|",
    ]
    for c in d.candidates:
        bic = min((s.delta_bic for s in c.scores), default=float("nan"))
        md.append(
            f"| {c.effect} | {', '.join(map(str, c.joints))} | {100 * c.explained_fraction:.1f} % | "
            f"{'yes' if c.suggested else 'no'} | {bic:.1f} |"
        )
    md.append("")
    for c in figs:
        md += [f"### {c.effect}", "", c.text(), "", f"![{c.effect}]({c.figure})", ""]
    for n, why in d.skipped.items():
        md.append(f"- skipped {n}: {why}")
    if hist:
        md += [
            "",
            "## History: the error falling",
            "",
            *_history_rows(hist),
            "",
            "![history](history.png)",
            "",
        ]
    for n in d.notes:
        md.append(f"- note: {n}")
    atomic_write_json(out / "report.json", d.to_dict(), indent=2)
    return atomic_write_text(out / "report.md", "\n".join(md) + "\n")
