"""The diagnosis report: ``report.md``, ``report.json`` and the evidence and history figures
that ``ditherlab diagnose -o DIR`` writes (the analysis itself is :mod:`ditherlab.analysis.diagnosis`),
and :func:`load_report`, the one reader of that ``report.json`` (``ditherlab view --diagnosis``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ditherlab.analysis.diagnosis import AXES, Diagnosis, nanmean
from ditherlab.analysis.scoring import Candidate, JointScore, unphysical_text
from ditherlab.core.errors import FormatError
from ditherlab.core.files import atomic_path, atomic_write_json, atomic_write_text, plain
from ditherlab.core.names import MOVING
from ditherlab.output.figures import legend, pyplot
from ditherlab.physics.effects import EFFECTS, Effect, design_at, hyper_params, model_text

__all__ = ["DiagnosisLike", "DiagnosisReport", "as_report", "load_report", "write_report"]


def _added_rows(hist: list[dict[str, Any]]) -> list[str]:
    """One line per effect ``identify --add`` added (the history rows with ``added``): the
    held-out share promised and delivered, and the axes whose force error grew."""
    out = []
    for h in hist:
        if not h.get("added"):
            continue
        grew = ", ".join(h.get("force_grew") or []) or "none"
        out.append(
            f"- v{h.get('version')}: {h['added']} on joint(s) "
            f"{', '.join(map(str, h.get('delivery_joints', [])))}: promised "
            f"{100 * h.get('promised', 0.0):.1f} %, delivered {100 * h.get('delivered', 0.0):.1f} "
            f"% of the held-out residual; force error grew on: {grew}"
        )
    return [*out, ""] if out else []


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
            des = design_at(
                e, sc.sig, None if e.shared else j, s.fit.h if s else None, s.fit.ref if s else {}
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
        legend(ax, loc="best", fontsize=7, markerscale=4)
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
    legend(ax, fontsize=7)
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
    hist = [h for h in d.model.history if h.get("torque_rms")]  # the diagnosis rows
    if hist:
        _history_figure(hist, out / "history.png")
    md = [
        f"# Diagnosis of model v{d.model.version}",
        "",
        "Recordings: " + ", ".join(d.recordings),
        "",
    ]
    md += ["## Model", "", "```", model_text(d.model), "```", ""]
    md += _residual_section(d)
    if d.force is not None:
        md += _force_section(d.force)
    if d.windows:
        md += _windows_section(d.windows)
    md += _candidates_section(d, figs)
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
    added = _added_rows(d.model.history)
    if added:
        md += ["## Effects added by identify --add", "", *added]
    for n in d.notes:
        md.append(f"- note: {n}")
    atomic_write_json(out / "report.json", d.to_dict(), indent=2)
    return atomic_write_text(out / "report.md", "\n".join(md) + "\n")


def _residual_section(d: Diagnosis) -> list[str]:
    """The torque residual per joint and regime against the noise floor, as Markdown lines."""
    md = ["## Torque residual (band-aware) against the noise floor", ""]
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
    return md


def _force_section(force: Mapping[str, Any]) -> list[str]:
    """The force error per regime and axis [N, N·m] and the interval's coverage."""
    md = [
        "## Force error (estimate − sensor)",
        "",
        "| regime | samples | " + " | ".join(AXES) + " |",
        "|---|---|" + "---|" * 6,
    ]
    for r in force["per_regime"]:
        md.append(
            f"| {r['regime']} | {r['samples']} | " + " | ".join(f"{v:.3g}" for v in r["rms"]) + " |"
        )
    if force.get("coverage") is not None:
        md.append(
            "| coverage (95 % set-membership) | | "
            + " | ".join(f"{v:.2f}" for v in force["coverage"])
            + " |"
        )
    md.append("")
    return md


def _windows_section(windows: list[dict[str, Any]]) -> list[str]:
    """The worst time windows by residual energy."""
    md = [
        "## Worst time windows",
        "",
        "| recording | t [s] | energy [floor²] | worst joint (× floor) |",
        "|---|---|---|---|",
    ]
    for w in windows:
        md.append(
            f"| {w['recording']} | {w['t0']:.1f}–{w['t1']:.1f} | {w['energy']:.3g} | "
            f"{w['worst_joint']} ({w['worst_joint_ratio']:.2g}) |"
        )
    md.append("")
    return md


def _candidates_section(d: Diagnosis, figs: list[Candidate]) -> list[str]:
    """The candidate effects ranked, the figured ones' evidence, the skipped effects."""
    md = [
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
    for c in d.candidates:
        if c.unphysical:
            md.append(f"- {c.effect}{unphysical_text(c.unphysical)}")
    if any(c.unphysical for c in d.candidates):
        md.append("")
    for c in figs:
        md += [f"### {c.effect}", "", c.text(), "", f"![{c.effect}]({c.figure})", ""]
    for n, why in d.skipped.items():
        md.append(f"- skipped {n}: {why}")
    return md


# ---------------------------------------------------------------------- reading report.json
#: What ``report.json`` was expected to be, for error messages.
_EXPECTED = "the report.json of `ditherlab diagnose -o`"


@dataclass
class DiagnosisReport:
    """A diagnosis as ``report.json`` holds it: the keys of :meth:`Diagnosis.to_dict`.

    Attributes
    ----------
    model : the model's equations, one line each (:func:`ditherlab.physics.effects.model_text`)
    version : the model's version
    effects : the model's effects (``EffectSpec.to_dict()`` each)
    recordings : names of the recordings diagnosed
    residual : ``torque_rms``, ``noise_floor``, ``ratio`` (n,), ``per_regime`` rows and
        ``worst_windows`` (each: ``recording``, ``t0``, ``t1`` [s], ``energy``, ``worst_joint``
        (1-based), ``worst_joint_ratio``)
    force : force error (``rms``, ``bias``, ``per_regime``, ``coverage``, ...) or None without
        an F/T sensor
    candidates : ranked candidate effects (``Candidate.to_dict()`` each: ``effect``, ``joints``,
        ``explained_fraction``, ``suggested``, ``text``, ...)
    skipped : effect name -> why it was not tried
    history : the model's history rows
    notes : remarks of the diagnosis
    """

    model: list[str]
    version: int
    effects: list[dict[str, Any]]
    recordings: list[str]
    residual: dict[str, Any]
    force: dict[str, Any] | None
    candidates: list[dict[str, Any]]
    skipped: dict[str, str]
    history: list[dict[str, Any]]
    notes: list[str]
    verdict: dict[str, Any] | None = None

    @property
    def worst_windows(self) -> list[dict[str, Any]]:
        return list(self.residual["worst_windows"])

    @property
    def suggested(self) -> list[dict[str, Any]]:
        return [c for c in self.candidates if c["suggested"]]

    def to_dict(self) -> dict[str, Any]:
        """The dict that ``report.json`` holds (equal to ``Diagnosis.to_dict()`` made plain)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Any, source: str | Path = "diagnosis") -> DiagnosisReport:
        """Check ``d`` (a loaded ``report.json``) and wrap it.

        Raises
        ------
        FormatError
            One line naming ``source``, the key and what was expected: a key missing or unknown,
            or a value of the wrong kind (top level; ``residual.worst_windows`` and
            ``candidates`` entries, which the view reads).
        """
        if not isinstance(d, Mapping):
            raise FormatError(f"{source}: holds a {type(d).__name__}, expected {_EXPECTED}")
        for key, kinds in _TOP_KEYS.items():
            if key not in d:
                if key in _OPTIONAL_KEYS:
                    continue
                raise FormatError(f"{source}: key {key!r} is missing, expected {_EXPECTED}")
            _check_kind(source, key, d[key], kinds)
        extra = [k for k in d if k not in _TOP_KEYS]
        if extra:
            raise FormatError(
                f"{source}: key {extra[0]!r} is unknown, expected only the keys "
                f"{', '.join(_TOP_KEYS)} of {_EXPECTED}"
            )
        res = d["residual"]
        if "worst_windows" not in res:
            raise FormatError(f"{source}: key 'residual.worst_windows' is missing, expected a list")
        _check_kind(source, "residual.worst_windows", res["worst_windows"], (list,))
        for k, w in enumerate(res["worst_windows"]):
            _check_entry(source, f"residual.worst_windows[{k}]", w, _WINDOW_KEYS)
        for k, c in enumerate(d["candidates"]):
            _check_entry(source, f"candidates[{k}]", c, _CANDIDATE_KEYS)
        return cls(**{k: d.get(k) for k in _TOP_KEYS})


#: Top-level keys of ``Diagnosis.to_dict()`` in its order, and the JSON kinds of their values.
_TOP_KEYS: dict[str, tuple[type, ...]] = {
    "model": (list,),
    "version": (int,),
    "effects": (list,),
    "recordings": (list,),
    "residual": (dict,),
    "force": (dict, type(None)),
    "candidates": (list,),
    "skipped": (dict,),
    "history": (list,),
    "notes": (list,),
    "verdict": (dict, type(None)),
}
#: keys that reports written before they existed lack
_OPTIONAL_KEYS = ("verdict",)
_NUMBER = (int, float)
_WINDOW_KEYS: dict[str, tuple[type, ...]] = {
    "recording": (str,),
    "t0": _NUMBER,
    "t1": _NUMBER,
    "energy": _NUMBER,
    "worst_joint": (int,),
    "worst_joint_ratio": _NUMBER,
}
_CANDIDATE_KEYS: dict[str, tuple[type, ...]] = {
    "effect": (str,),
    "joints": (list,),
    "explained_fraction": _NUMBER,
    "suggested": (bool,),
    "text": (str,),
}
_KIND_NAMES = {
    list: "a list",
    dict: "an object",
    int: "an integer",
    float: "a number",
    str: "a string",
    bool: "true or false",
    type(None): "null",
}


def _check_kind(source: str | Path, key: str, value: Any, kinds: tuple[type, ...]) -> None:
    # bool is an int in Python, not in JSON: true is no version number
    ok = isinstance(value, kinds) and not (isinstance(value, bool) and bool not in kinds)
    if not ok:
        want = " or ".join(dict.fromkeys(_KIND_NAMES[k] for k in kinds))
        raise FormatError(
            f"{source}: key {key!r} is {json.dumps(value, default=str)[:40]}, expected {want} "
            f"({_EXPECTED})"
        )


def _check_entry(
    source: str | Path, where: str, entry: Any, keys: dict[str, tuple[type, ...]]
) -> None:
    _check_kind(source, where, entry, (dict,))
    for key, kinds in keys.items():
        if key not in entry:
            raise FormatError(f"{source}: key '{where}.{key}' is missing, expected {_EXPECTED}")
        _check_kind(source, f"{where}.{key}", entry[key], kinds)


def load_report(path: str | Path) -> DiagnosisReport:
    """Read the ``report.json`` that :func:`write_report` wrote (``Diagnosis.to_dict()``).

    Raises
    ------
    FormatError
        Missing file, not JSON, or not a diagnosis report (see :meth:`DiagnosisReport.from_dict`).
    """
    p = Path(path)
    if not p.is_file():
        raise FormatError(f"{p}: no such diagnosis file")
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FormatError(f"{p}: not a JSON diagnosis report ({exc})") from None
    return DiagnosisReport.from_dict(d, source=p)


#: A diagnosis in any of the forms the view takes (see :func:`as_report`).
DiagnosisLike = Diagnosis | DiagnosisReport | Mapping[str, Any]


def as_report(diagnosis: DiagnosisLike) -> DiagnosisReport:
    """A :class:`DiagnosisReport` of a diagnosis in any of its forms: the report itself, a
    :class:`ditherlab.analysis.diagnosis.Diagnosis` (as its ``report.json`` would hold it) or that dict."""
    if isinstance(diagnosis, DiagnosisReport):
        return diagnosis
    if isinstance(diagnosis, Diagnosis):
        return DiagnosisReport.from_dict(plain(diagnosis.to_dict()), source="diagnosis")
    return DiagnosisReport.from_dict(diagnosis, source="diagnosis")
