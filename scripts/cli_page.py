"""Write the reference of every ``ditherlab`` command into docs/cli.md, after its marker line.

Usage (from the repository root)::

    python scripts/cli_page.py            # rewrite docs/cli.md in place
    python scripts/cli_page.py --check    # exit 1 when docs/cli.md is not up to date

The text comes from the typer app itself (``ditherlab.cli.app``, turned into its click command
by ``typer.main.get_command``): per command its usage line, its help, its arguments and its
options with type, default and help, in the order the app registers them. Everything above the
marker line of docs/cli.md is hand-written and kept; everything after it is replaced.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "cli.md"
MARKER = "<!-- generated below by scripts/cli_page.py -->"


def load_group():
    """The click group of the ``ditherlab`` typer app and a context factory."""
    sys.path.insert(0, str(ROOT))
    import typer
    import typer.main

    from ditherlab.cli import app

    group = typer.main.get_command(app)
    click = getattr(typer, "_click", None)
    if click is None:  # a typer that depends on click instead of vendoring it
        import click  # type: ignore[no-redef]
    root = click.Context(group, info_name="ditherlab")

    def context(cmd, name):
        return click.Context(cmd, info_name=name, parent=root)

    return group, context


def cell(text) -> str:
    """``text`` as one Markdown table cell."""
    text = " ".join(str(text).split())
    return text.replace("|", "\\|") or "–"


def type_label(param, ctx) -> str:
    """How the parameter's value is written: ``flag``, or its type as the help shows it."""
    if getattr(param, "is_flag", False):
        return "flag"
    try:
        label = param.display_type(ctx)
    except (AttributeError, TypeError):
        label = getattr(getattr(param, "type", None), "name", "") or ""
    label = str(label).strip("<>")
    if label.startswith("list[") and label.endswith("]"):  # a repeated value: its item's type
        label = label[5:-1]
    label = {"Path": "path", "int range": "int", "float range": "float"}.get(label, label)
    lo, hi = getattr(param, "min", None), getattr(param, "max", None)
    if lo is not None or hi is not None:
        label += f", {'' if lo is None else f'≥ {lo}'}{'' if hi is None else f' ≤ {hi}'}"
    return label


def names(param) -> str:
    """The option's spellings: ``--out``, ``-o``; a boolean pair as ``--dither / --no-dither``."""
    opts = sorted(param.opts, key=lambda o: (not o.startswith("--"), o))
    text = ", ".join(f"`{o}`" for o in opts)
    if param.secondary_opts:
        text += " / " + ", ".join(f"`{o}`" for o in param.secondary_opts)
    return text


def default_text(param) -> str:
    """The default as the command line shows it ('' for none, 'required')."""
    if param.required:
        return "required"
    d = param.default
    if d is None or d == [] or d == ():
        return ""
    if isinstance(d, bool) and param.secondary_opts:
        return f"`{param.opts[0] if d else param.secondary_opts[0]}`"
    if isinstance(d, bool):
        return "" if not d else "on"
    return f"`{d}`"


def command_text(name: str, cmd, ctx) -> str:
    """One command's section."""
    pieces = cmd.collect_usage_pieces(ctx) if hasattr(cmd, "collect_usage_pieces") else []
    usage = re.sub(r"\{(\w+)\}", lambda m: m.group(1).upper(), " ".join(pieces))
    lines = [f"## `ditherlab {name}`", ""]
    lines += [" ".join((cmd.help or "").split()), ""]
    lines += ["```text", f"ditherlab {name} {usage}".rstrip(), "```", ""]
    args = [p for p in cmd.params if p.param_type_name == "argument"]
    opts = [p for p in cmd.params if p.param_type_name == "option" and p.name != "help"]
    if args:
        lines += ["| argument | value | required | meaning |", "|---|---|---|---|"]
        for p in args:
            many = " (one or more)" if getattr(p, "nargs", 1) == -1 else ""
            req = "yes" if p.required else "no"
            lines.append(
                f"| `{p.name}` | {cell(type_label(p, ctx))}{many} | {req} | {cell(p.help or '')} |"
            )
        lines.append("")
    if opts:
        lines += ["| option | value | default | meaning |", "|---|---|---|---|"]
        for p in opts:
            rep = " (repeatable)" if getattr(p, "multiple", False) else ""
            lines.append(
                f"| {names(p)} | {cell(type_label(p, ctx))}{rep} | {default_text(p) or '–'} "
                f"| {cell(p.help or '')} |"
            )
        lines.append("")
    return "\n".join(lines)


def render(page: str) -> str:
    """The page with everything after the marker replaced by the generated reference."""
    if MARKER not in page:
        raise SystemExit(f"cli_page: {PAGE} has no line {MARKER!r}")
    group, context = load_group()
    parts = [
        command_text(name, cmd, context(cmd, name))
        for name, cmd in group.commands.items()
        if not getattr(cmd, "hidden", False)
    ]
    return page.split(MARKER, 1)[0] + MARKER + "\n\n" + "\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="only check the page is current")
    args = parser.parse_args(argv)
    old = PAGE.read_text(encoding="utf-8")
    new = render(old)
    if args.check:
        if new != old:
            print(f"{PAGE.relative_to(ROOT)} is out of date: run python scripts/cli_page.py")
            return 1
        return 0
    if new != old:
        PAGE.write_text(new, encoding="utf-8")
    print(f"wrote {PAGE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
