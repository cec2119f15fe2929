"""Write the table of the effect library into docs/effects.md, after its marker line.

Usage (from the repository root)::

    python scripts/effects_page.py            # rewrite docs/effects.md in place
    python scripts/effects_page.py --check    # exit 1 when docs/effects.md is not up to date

Everything above the marker line of docs/effects.md is hand-written and kept; everything after
it is replaced by one row per registered effect, in the order diagnosis tries them: its name,
its physics (the effect's one-line ``physics`` statement, else the first sentence of the
class docstring), its driving variables (``driven_by``), its parameters (the linear ones, then the searched one) with
their units where the effect declares them (an optional ``units`` mapping, parameter -> unit),
whether one parameter set is shared by all joints, and where it acts (``kind``); then one
row per physical range of a fitted parameter (``Effect.bounds``): the range and its source.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "effects.md"
MARKER = "<!-- generated below by scripts/effects_page.py -->"
#: where the registry lives
REGISTRY_MODULE = "ditherlab.physics.effects.library"
KIND_TEXT = {
    "torque": "joint torque",
    "external": "external torque (how the servo shows `J^T F`)",
    "sensor": "F/T sensor reading",
}


def load_registry() -> tuple[str, dict]:
    """The module path and the ``EFFECTS`` registry (name -> effect instance)."""
    sys.path.insert(0, str(ROOT))
    module = importlib.import_module(REGISTRY_MODULE)
    return REGISTRY_MODULE.rsplit(".", 1)[0], dict(module.EFFECTS)


def cell(text: str) -> str:
    """``text`` as one Markdown table cell: reStructuredText literals as code, no pipes or
    line breaks."""
    text = " ".join(str(text).split())
    text = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", text)  # :func:`x` -> `x`
    text = text.replace("``", "`").replace("|", "\\|")
    return text or "–"


def first_sentence(doc: str | None) -> str:
    """The first sentence of a docstring's first paragraph ('' without a docstring)."""
    if not doc:
        return ""
    para = " ".join(doc.strip().split("\n\n")[0].split())
    m = re.match(r"(.+?[.!?])(\s|$)", para)
    return m.group(1) if m else para


def parameters(effect) -> str:
    """The effect's parameters with their units where declared."""
    hyper = effect.hyper
    names = [*effect.linear, *((hyper,) if isinstance(hyper, str) else hyper or ())]
    units = dict(getattr(effect, "units", None) or {})
    out = [f"`{n}` [{units[n]}]" if n in units else f"`{n}`" for n in names]
    return ", ".join(out) if out else "the base set chosen on the data"


def table(registry: dict) -> str:
    """The Markdown table of the registry."""
    rows = [
        "| effect | physics | driven by | parameters | per joint or shared | acts on |",
        "|---|---|---|---|---|---|",
    ]
    for name, e in registry.items():
        physics = e.physics or first_sentence(type(e).__doc__)
        rows.append(
            "| "
            + " | ".join(
                (
                    f"`{name}`",
                    cell(physics),
                    cell(e.driven_by),
                    cell(parameters(e)),
                    "shared" if e.shared else "per joint",
                    cell(KIND_TEXT.get(e.kind, e.kind)),
                )
            )
            + " |"
        )
    return "\n".join(rows)


def ranges_table(registry: dict) -> str:
    """The Markdown table of every effect's physical ranges (``Effect.bounds``) and sources."""
    rows = [
        "| effect | parameter | unit | physical range | nominal | source |",
        "|---|---|---|---|---|---|",
    ]
    for name, e in registry.items():
        for b in e.bounds:
            rows.append(
                "| "
                + " | ".join(
                    (
                        f"`{name}`",
                        f"`{b.param}`",
                        cell(b.unit),
                        cell(b.text),
                        "" if b.nominal is None else f"{b.nominal:g}",
                        cell(b.source),
                    )
                )
                + " |"
            )
    return "\n".join(rows)


def render(page: str, module: str, registry: dict) -> str:
    """The page with everything after the marker replaced by the generated table."""
    if MARKER not in page:
        raise SystemExit(f"effects_page: {PAGE} has no line {MARKER!r}")
    head = page.split(MARKER, 1)[0]
    body = (
        f"\n\n{len(registry)} effects, from the registry in `{module}`, in the order "
        "diagnosis tries them.\n\n"
        + table(registry)
        + "\n\n### Physical ranges\n\nEvery fitted parameter has a physical range: `identify "
        "--add` refuses a fit outside it (one line naming the effect, parameter, joint, value and "
        "range; nothing is written), and diagnosis does not suggest the effect on a joint it "
        "fits only with an unphysical value, and lists that value. A per-joint fit just outside a "
        "range is held at its edge, the other parameters re-fitted, where the data do not "
        "reject the edge (a likelihood-ratio test at 5 %); a shared fit whose range bounds several "
        "parameters together (a rotation's angle) is moved to the edge along its own direction "
        "under the same test; only a value the data insist on is unphysical. A parameter with a nominal value (the robot description's own) that the "
        "data cannot move — its term, across the whole range, stays below three noise sigmas on "
        "every scored sample — is held at that value.\n\n" + ranges_table(registry) + "\n"
    )
    return head + MARKER + body


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="only check the page is current")
    args = parser.parse_args(argv)
    module, registry = load_registry()
    old = PAGE.read_text(encoding="utf-8")
    new = render(old, module, registry)
    if args.check:
        if new != old:
            print(f"{PAGE.relative_to(ROOT)} is out of date: run python scripts/effects_page.py")
            return 1
        return 0
    if new != old:
        PAGE.write_text(new, encoding="utf-8")
    print(f"wrote {PAGE.relative_to(ROOT)} ({len(registry)} effects from {module})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
