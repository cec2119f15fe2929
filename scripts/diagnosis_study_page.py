"""Write docs/diagnosis-study.md and its figure from runs of the two diagnosis studies.

Usage (from the repository root)::

    python -m bench.bench_false_discovery --plant band --n 50 --out runs/fd-band
    python -m bench.bench_false_discovery --plant lugre --n 28 --out runs/fd-lugre
    python -m bench.bench_power --plant band --n 22 --out runs/power-band
    python -m bench.bench_power --plant lugre --n 22 --out runs/power-lugre
    python scripts/diagnosis_study_page.py --fd runs/fd-band runs/fd-lugre \\
        --power runs/power-band runs/power-lugre

Every number on the page is read from the runs' ``study.csv`` (false discoveries) and
``power.csv`` (power) files; the figure (``docs/diagnosis-study-power.png``) is drawn from the
same rows. "Which effects need which recordings" joins each library effect's own statement of
what drives it, where it shows and what it needs (the rule behind ``identify --add`` and
diagnosis's *not identifiable*) with what the runs measured.
"""

from __future__ import annotations

import argparse
import csv
import math
import re
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_power import ABSORBED, BINS, rates  # noqa: E402

PAGE = ROOT / "docs" / "diagnosis-study.md"
FIGURE = ROOT / "docs" / "diagnosis-study-power.png"
PLANT_TEXT = {"band": "built-in plant", "lugre": "LuGre plant"}


def read_rows(folders: list[Path], name: str) -> list[dict[str, str]]:
    """Every row of ``folder/name`` over ``folders`` (a row without a plant: the built-in one);
    the rows of a later folder replace an earlier folder's rows of the same plant and id (a
    rerun of some ids with ``--only``)."""
    by_key: dict[tuple[str, str], list[dict[str, str]]] = {}
    for folder in folders:
        mine: dict[tuple[str, str], list[dict[str, str]]] = defaultdict(list)
        with open(folder / name, newline="") as f:
            for r in csv.DictReader(f):
                r["plant"] = r.get("plant") or "band"
                mine[(r["plant"], r["id"])].append(r)
        by_key.update(mine)
    return [r for rs in by_key.values() for r in rs]


def upper95(k: int, m: int) -> float:
    """One-sided 95 % upper bound of a rate seen ``k`` times in ``m`` (Clopper-Pearson)."""
    from scipy.stats import beta

    return float(beta.ppf(0.95, k + 1, m - k)) if m and k < m else (1.0 if m else math.nan)


def fd_section(rows: list[dict[str, str]]) -> list[str]:
    """The false-discovery table: per plant and family, and per plant in all."""
    out = ["| plant | family | arms | recordings | false discoveries | what was suggested |",
           "|---|---|---|---:|---:|---|"]  # fmt: skip
    groups: dict[tuple[str, str], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        groups[(r["plant"], r["family"])].append(r)
    totals: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0])
    for (plant, fam), rs in groups.items():
        ok = [r for r in rs if not r.get("error")]
        fd = [r for r in ok if r["false_discovery"] == "True"]
        arms = ", ".join(sorted({r.get("robot") or "irb140" for r in rs}))
        what = "; ".join(f"r{int(r['id']):03d} seed {r['seed']}: {r['suggested']}" for r in fd)
        errs = len(rs) - len(ok)
        what += f" ({errs} failed to run)" if errs else ""
        out.append(f"| {PLANT_TEXT[plant]} | {fam} | {arms} | {len(ok)} | {len(fd)} | {what} |")
        t = totals[plant]
        t[0], t[1], t[2] = t[0] + len(ok), t[1] + len(fd), t[2] + errs
    out += ["", "| plant | recordings | false discoveries | rate, 95 % upper bound | target |",
            "|---|---:|---:|---:|---|"]  # fmt: skip
    for plant, (m, k, _) in totals.items():
        out.append(
            f"| {PLANT_TEXT[plant]} | {m} | {k} | {100 * upper95(k, m):.1f} % | ≤ 1 in 100 |"
        )
    errors = [r for r in rows if r.get("error")]
    if errors:
        out += ["", "Recordings that did not run to a diagnosis:", ""]
        out += [f"- {PLANT_TEXT[r['plant']]} r{int(r['id']):03d} {r['family']} "
                f"{r.get('robot') or 'irb140'} seed {r['seed']}: {_local(r['error'])}" for r in errors]  # fmt: skip
    return out


def _local(text: str) -> str:
    """An error message with the run's folders left out (``/tmp/x/r006/model.toml`` ->
    ``r006/model.toml``)."""
    return re.sub(r"/\S*/([rdg]\d{3}/)", r"\1", text)


def _bin_label(k: int) -> str:
    lo, hi = BINS[k], BINS[k + 1]
    return f"≥ {lo:g}" if math.isinf(hi) else f"{lo:g}-{hi:g}"


def power_section(rows: list[dict[str, str]]) -> list[str]:
    """The detection-rate table: per plant and effect, per size bin, found / planted joints."""
    head = " | ".join(f"{_bin_label(k)} fl" for k in range(len(BINS) - 1))
    out = [f"| plant | effect | {head} | ≥ 2 fl: found | ≥ 2 fl: named first |",
           "|---|---|" + "---:|" * (len(BINS) + 1)]  # fmt: skip
    cells = rates(rows)
    for (plant, effect), cell in sorted(cells.items()):
        big = [r for r in _joint_rows(rows, plant, effect) if float(r["floors"]) >= 2.0]
        found = sum(r["found"] == "True" for r in big)
        first = sum(r["found_first"] == "True" for r in big)
        text = " | ".join(f"{f}/{m}" if m else "–" for f, m in cell)
        rate, first_rate = (f"{found}/{len(big)}", f"{first}/{len(big)}") if big else ("–", "–")
        out.append(f"| {PLANT_TEXT[plant]} | {effect} | {text} | {rate} | {first_rate} |")
    out += ["", "| plant | draws | size measured as | joints at ≥ 2 floors | found | named first |",
            "|---|---:|---|---:|---:|---:|"]  # fmt: skip
    for plant in sorted({r["plant"] for r in rows}):
        n = len({r["id"] for r in rows if r["plant"] == plant})
        for col, text in (("floors", "what the effect adds"), ("excess_floors", "residual growth")):
            big = [r for r in _joint_rows(rows, plant) if float(r.get(col) or 0) >= 2.0
                   and r["effect"] not in ABSORBED]  # fmt: skip
            found = sum(r["found"] == "True" for r in big)
            first = sum(r["found_first"] == "True" for r in big)
            out.append(f"| {PLANT_TEXT[plant]} | {n} | {text} | {len(big)} | {found} | {first} |")
    out += ["", "The second table leaves out " + ", ".join(f"`{e}`" for e in ABSORBED)
            + " (its rows stay in the first): " + "; ".join(ABSORBED.values()) + "."]  # fmt: skip
    return out


def _joint_rows(rows, plant: str | None = None, effect: str | None = None) -> list[dict]:
    return [r for r in rows if not r.get("error") and r.get("joint")
            and (plant is None or r["plant"] == plant)
            and (effect is None or r["effect"] == effect)]  # fmt: skip


def _excess(r: dict[str, str]) -> str:
    """What diagnose saw of the effect on the row's joint, where the run recorded it."""
    v = r.get("excess_floors")
    return f" (its residual grew by {float(v):.2f} floors)" if v not in (None, "") else ""


def failures(rows: list[dict[str, str]]) -> list[str]:
    """Every joint at ≥ 2 floors where the effect was missed or not named first, reproducible."""
    out = []
    for r in _joint_rows(rows):
        if float(r["floors"]) < 2.0 or r["found_first"] == "True":
            continue
        why = "not suggested on this joint" if r["found"] != "True" else f"{r['first']} first"
        if r["effect"] in ABSORBED:
            why += f" ({ABSORBED[r['effect']]})"
        at = (
            f"@{r['planted_joints']}"
            if r["plant"] == "lugre" and r["planted_joints"] != "arm"
            else ""
        )
        cfg = ""
        if r["plant"] == "band" and r["planted_joints"] != "arm":
            key = "link" if r["effect"] == "dynamics" else "share"
            cfg = f" (joints {r['planted_joints']}: `--config` with `[hidden.{r['effect']}]` {key})"
        plant = " --plant lugre" if r["plant"] == "lugre" else ""
        out.append(
            f"- {PLANT_TEXT[r['plant']]}, {r['effect']} size {r['size']}{cfg}, joint {r['joint']} "
            f"at {float(r['floors']):.2f} floors{_excess(r)}, p = {r['p_value'] or '–'}: {why}; "
            "suggested: "
            f"{r['suggested'] or 'nothing'}. `ditherlab simulate excitation{plant} --robot "
            f"{r['robot']} --seed {r['seed']} --no-dither --hidden {r['effect']}:{r['size']}{at}` "
            f"(draw {r['id']}{'' if not r['not_identifiable'] else '; ' + r['not_identifiable']})"
        )
    return out or ["- none"]


def figure(rows: list[dict[str, str]], path: Path) -> None:
    """Power curves: per plant, the share of planted joints found against the size bin."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = rates(rows)
    plants = sorted({p for p, _ in cells})
    fig, axes = plt.subplots(1, max(len(plants), 1), figsize=(6 * max(len(plants), 1), 4.2),
                             squeeze=False, sharey=True)  # fmt: skip
    centres = [math.sqrt(BINS[k] * (BINS[k + 1] if not math.isinf(BINS[k + 1]) else 10.0))
               for k in range(len(BINS) - 1)]  # fmt: skip
    for ax, plant in zip(axes[0], plants, strict=False):
        ax.set_prop_cycle(color=plt.cm.tab20.colors[::2] + plt.cm.tab20.colors[1::2])
        for (p, effect), cell in sorted(cells.items()):
            if p != plant:
                continue
            pts = [(c, f / m) for c, (f, m) in zip(centres, cell, strict=True) if m]
            if pts:
                ax.plot(*zip(*pts, strict=True), marker="o", label=effect)
        ax.axvline(2.0, color="0.6", ls="--", lw=1)
        ax.axhline(0.9, color="0.6", ls=":", lw=1)
        ax.set_xscale("log")
        ax.set_xticks(centres, [_bin_label(k) for k in range(len(centres))], minor=False)
        ax.set_xticks([], minor=True)
        ax.set_xlim(0.25, 12.0)
        ax.set_xlabel("effect size on the joint [noise floors], bins")
        ax.set_title(PLANT_TEXT[plant])
        ax.legend(fontsize=7, ncol=2, loc="lower right", framealpha=0.6)
    axes[0][0].set_ylabel("planted joints found")
    axes[0][0].set_ylim(-0.03, 1.03)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _needs(e) -> str:
    """What recording effect ``e`` needs, from its own declarations."""
    needs = []
    if tuple(e.shows_in) == ("moving",):
        needs.append("motion (it shows only while moving)")
    if e.kind in ("sensor", "external"):
        needs.append("an F/T sensor and pushes")
    if e.needs_dither:
        needs.append("dither on, with measured pushes")
    if hasattr(e, "MIN_PERIODS"):
        needs.append(f"motion over at least {e.MIN_PERIODS:g} of its periods")
    if e.name == "temperature_friction":
        needs.append("a warm-up (logged `temp_j`, or the time from a cold start)")
    if e.name == "ft_drift":
        needs.append("the sensor logged from power-on, over a varying pose")
    return "; ".join(needs) or "varying pose or load"


def recordings_section(rows: list[dict[str, str]]) -> list[str]:
    """Which effects need which recordings: the library's rule and the runs' measurements."""
    from ditherlab.physics.effect_fit import MIN_IDENTIFIABILITY
    from ditherlab.physics.effects import EFFECTS

    out = ["| effect | driven by | needs | found at ≥ 2 floors (built-in / LuGre) | not identifiable in the runs |",
           "|---|---|---|---|---|"]  # fmt: skip
    for name, e in EFFECTS.items():
        rate = []
        for plant in ("band", "lugre"):
            big = [r for r in _joint_rows(rows, plant, name) if float(r["floors"]) >= 2.0]
            rate.append(f"{sum(r['found'] == 'True' for r in big)}/{len(big)}" if big else "–")
        seen = sorted({r["not_identifiable"] for r in rows
                       if r.get("effect") == name and r.get("not_identifiable")})  # fmt: skip
        note = f"{len(seen)} draw(s): {seen[0]}" if seen else ""
        cells = [f"`{name}`", e.driven_by, _needs(e), " / ".join(rate), note]
        out.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    out += ["", f"Beyond these, one rule holds for every effect (`not_identifiable`): after the "
            f"bands and the sliding line have taken what they can, the effect's design must keep "
            f"an identifiability of at least {MIN_IDENTIFIABILITY:g}, i.e. its driver must vary "
            "within a regime — more poses for a gravity-like effect, more speeds for a friction "
            "effect, pushes along more axes for a sensor effect."]  # fmt: skip
    return out


def page(
    fd: list[dict[str, str]], power: list[dict[str, str]], fig_name: str, code: str | None = None
) -> str:
    n_fd = defaultdict(int)
    for r in fd:
        n_fd[r["plant"]] += 1
    draws = defaultdict(set)
    for r in power:
        draws[r["plant"]].add(r["id"])
    sizes = ", ".join(f"{PLANT_TEXT[p]} {n}" for p, n in sorted(n_fd.items()))
    dsizes = ", ".join(f"{PLANT_TEXT[p]} {len(s)}" for p, s in sorted(draws.items()))
    text = [
        "# The diagnosis measured: false discoveries and power",
        "",
        "Written by `scripts/diagnosis_study_page.py` from runs of `bench/bench_false_discovery.py`"
        " and `bench/bench_power.py` (every recording through the CLI: `simulate`, `identify`, "
        "`diagnose --json`). The decision rule is described in [diagnosis](diagnosis.md) "
        '("What a suggestion means").',
        "",
        f"**This run:** {f'ditherlab at {code}; ' if code else ''}clean recordings: {sizes}; "
        f"power draws: {dsizes}.",
        "",
        "## False discoveries on clean recordings",
        "",
        "A clean recording has nothing planted beyond what its model holds; any suggestion is a "
        "false discovery. The families are described in `bench/bench_false_discovery.py`.",
        "",
        *fd_section(fd),
        "",
        "## Power: planted effects against their size",
        "",
        "Each draw plants one effect, with a drawn size on drawn joints, in the recording of a "
        "seed whose clean recording was identified; `diagnose` runs on the planted one with the "
        "clean model. Size on a joint: the RMS of what the effect adds to the model's residual "
        "(the planted recording's logged torque minus the clean one's of the same seed, less "
        "`J(q)^T` times the F/T reading's change and the gravity torque's change where the logged "
        'angles differ) over the joint\'s noise floor (LuGre plant: `meta["sim"]["noise_std"]`;'
        " built-in plant: the floor in `diagnose`'s report). "
        "A cell is *found / planted joints*: the effect suggested on that joint. On the built-in "
        "plant the torque difference holds the servo's answer to the changed motion too; the "
        "growth of the joint's residual from the clean report to the planted one (in the misses "
        "below) is what `diagnose` had to work with.",
        "",
        "The clean models hold what each plant always has and the base model lacks: `inertia` "
        "(both), and on the LuGre plant `stribeck` (its friction law has a static level 1.1-1.7 "
        "times the Coulomb level) and, where the log has the F/T sensor, `ft_drift` (its sensor "
        "warms up from the first sample); these are not planted there. The LuGre plant has no "
        "family of "
        "logged but inert temperatures (it logs `temp_j` only with a warming friction planted).",
        "",
        *power_section(power),
        "",
        f"![Power curves]({fig_name})",
        "",
        "### Every miss at 2 noise floors or more",
        "",
        *failures(power),
        "",
        "## Which effects need which recordings",
        "",
        *recordings_section(power),
        "",
    ]
    return "\n".join(text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fd", type=Path, nargs="+", required=True, help="folders with study.csv")
    ap.add_argument("--power", type=Path, nargs="+", required=True, help="folders with power.csv")
    ap.add_argument("--out", type=Path, default=PAGE)
    ap.add_argument("--code", help="the ditherlab the runs were made with (a version or commit)")
    a = ap.parse_args()
    fd, power = read_rows(a.fd, "study.csv"), read_rows(a.power, "power.csv")
    fig = a.out.with_name(a.out.stem + "-power.png")
    figure(power, fig)
    a.out.write_text(page(fd, power, fig.name, a.code))
    print(f"wrote {a.out} and {fig}")


if __name__ == "__main__":
    main()
