"""The package's shape: every folder a layer, dependencies run one way, imports at the top,
unique module names, and the estimator standalone (function size: test_function_size.py).

Reads the source with ``ast`` (nothing is imported): every ``import ditherlab...`` /
``from ditherlab... import`` of a library module, outside ``if TYPE_CHECKING:`` blocks. A new
import cycle, an import that climbs a layer, or a package import hidden in a function fails here
with the module and line named.
"""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "ditherlab"

#: The layers, bottom up: each is a folder of the package, and a module may import its own folder
#: and the folders below, never above. The package root (``ditherlab``: the front door, the CLI)
#: is the top floor.
LAYERS: list[str] = [
    "core",  # errors, names, time-series helpers, linear algebra, schemas, atomic files, tasks
    "estimator",  # eq. (3): problem, backends, intervals; standalone
    "robot",  # kinematics and dynamics over pinocchio; the built-in descriptions
    "data",  # Recording, TorqueModel, Estimates
    "io",  # file formats and vendor mappings -> Recording
    "physics",  # dither, band fits, effects, residual, effect fits
    "sim",  # the built-in simulator
    "sim_lugre",  # a second plant (LuGre friction), sharing no code with sim or physics
    "analysis",  # identification, estimation, detection, diagnosis, sensitivity
    "output",  # report pages, figures, the Rerun view
    "app",  # the workflows behind the commands
]
ROOT = len(LAYERS)  # ditherlab/__init__, __main__, cli, cli_options
#: where imports inside functions are allowed: the package's lazy front door and the CLI (start-up
#: time of ``ditherlab --help``)
LAZY_OK = {"ditherlab", "ditherlab.cli"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PKG.rglob("*.py"))}


def _resolve(mod: str, is_pkg: bool, node: ast.ImportFrom) -> list[str]:
    if node.level:
        base = mod.split(".") if is_pkg else mod.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    if not target.startswith("ditherlab"):
        return []
    return [target] + [f"{target}.{a.name}" for a in node.names]


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def imports(mod: str, path: Path) -> tuple[list[tuple[str, int]], list[tuple[str, int]]]:
    """(top-level imports, imports inside functions) of ditherlab modules: (target, line)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    known = modules()
    is_pkg = path.name == "__init__.py"
    top: list[tuple[str, int]] = []
    inner: list[tuple[str, int]] = []

    def targets(node: ast.AST) -> list[str]:
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names if a.name.startswith("ditherlab")]
        elif isinstance(node, ast.ImportFrom):
            names = _resolve(mod, is_pkg, node)
        else:
            return []
        # keep the longest existing module per import ("from ditherlab.io import read" -> io)
        out = {n for n in names if n in known}
        return sorted(out)

    def walk(node: ast.AST, in_func: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                continue
            if isinstance(child, ast.Import | ast.ImportFrom):
                for t in targets(child):
                    (inner if in_func else top).append((t, child.lineno))
            walk(child, in_func or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef))

    walk(tree, False)
    return top, inner


def layer_of(mod: str) -> int:
    parts = mod.split(".")
    if len(parts) == 1 or (len(parts) == 2 and parts[1] not in LAYERS):
        return ROOT
    assert parts[1] in LAYERS, f"{mod} is in no layer of tests/test_architecture.py"
    return LAYERS.index(parts[1])


def graph() -> dict[str, set[str]]:
    g: dict[str, set[str]] = {}
    for mod, path in modules().items():
        top, _ = imports(mod, path)
        # a package's __init__ is imported by its submodules' imports: "ditherlab.physics.effects.x"
        # importing "ditherlab.physics.effects" (itself a parent) is not an edge back
        g[mod] = {t for t, _ in top if t != mod and not mod.startswith(t + ".")}
    return g


def find_cycle(g: dict[str, set[str]]) -> list[str] | None:
    WHITE, GREY, BLACK = 0, 1, 2
    colour = dict.fromkeys(g, WHITE)
    stack: list[str] = []

    def visit(u: str) -> list[str] | None:
        colour[u] = GREY
        stack.append(u)
        for v in sorted(g.get(u, ())):
            if colour.get(v, BLACK) == GREY:
                return stack[stack.index(v) :] + [v]
            if colour.get(v) == WHITE:
                c = visit(v)
                if c:
                    return c
        stack.pop()
        colour[u] = BLACK
        return None

    for u in sorted(g):
        if colour[u] == WHITE:
            c = visit(u)
            if c:
                return c
    return None


def test_no_import_cycle():
    cycle = find_cycle(graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_finder_finds_a_cycle():
    """The checker itself can fail: a three-module cycle is reported, a chain is not."""
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_dependencies_run_one_way():
    """No module imports a module of a higher layer (LAYERS above)."""
    bad = []
    for mod, path in modules().items():
        top, inner = imports(mod, path)
        for t, line in top + inner:
            if t == mod or mod.startswith(t + "."):
                continue
            if layer_of(t) > layer_of(mod):
                bad.append(f"{path.relative_to(PKG.parent)}:{line}: {mod} imports {t} (higher)")
    assert not bad, "\n".join(bad)


def test_imports_of_the_package_at_the_top():
    """Imports of ditherlab's own modules inside functions only where they buy start-up time."""
    bad = []
    for mod, path in modules().items():
        if mod in LAZY_OK or path.name == "__init__.py":
            continue
        _, inner = imports(mod, path)
        bad += [f"{path.relative_to(PKG.parent)}:{line}: {t}" for t, line in inner]
    assert not bad, "imports inside functions:\n" + "\n".join(bad)


def test_every_folder_is_a_layer():
    """Every folder of the package that holds Python is a listed layer or inside one."""
    folders = {p.relative_to(PKG).parts[0] for p in PKG.rglob("*.py") if p.parent != PKG}
    assert folders == set(LAYERS), f"folders {sorted(folders ^ set(LAYERS))} are not the layers"


def test_module_names_are_unique():
    """No two modules share a file name: a name says which module it is, wherever it is read."""
    seen: dict[str, list[str]] = {}
    for p in PKG.rglob("*.py"):
        if p.name not in ("__init__.py", "__main__.py"):
            seen.setdefault(p.stem, []).append(str(p.relative_to(PKG)))
    clashes = {k: v for k, v in seen.items() if len(v) > 1}
    assert not clashes, f"module names used twice: {clashes}"


def test_the_estimator_stands_alone():
    """``import ditherlab.estimator`` loads only the estimator and the core: no recording, no
    robot, neither pandas nor pinocchio (it runs where only numpy, numba and a QP solver are)."""
    import subprocess
    import sys

    code = (
        "import sys, ditherlab.estimator\n"
        "mods = sorted(m for m in sys.modules if m.startswith('ditherlab.'))\n"
        "print(' '.join(mods)); print('pandas' in sys.modules, 'pinocchio' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=PKG.parent
    ).stdout.split("\n")
    layers = {m.split(".")[1] for m in out[0].split()}
    assert layers <= {"core", "estimator"}, f"the estimator pulls in {sorted(layers)}"
    assert out[1] == "False False", "the estimator imports pandas or pinocchio"
