"""The package's functions: each does one job, and a long parameter list is a problem object.

The guideline (CONTRIBUTING.md, "Code guidelines"): a function does one job, in at most
:data:`MAX_BODY` lines of body (after its docstring); when it needs more it is split into steps,
each named for its job. A function takes at most :data:`MAX_PARAMS` parameters (``self`` and
``cls`` not counted, ``*args`` and ``**kwargs`` counted); a longer list becomes a small problem
or options object (a frozen dataclass or NamedTuple) built once and passed whole. This check on
every function replaces a limit on the lines of a module: a long module of short functions is
fine, a short module with one long function is not.

Exempt: the typer commands of ``ditherlab/cli.py`` from the parameter limit (their parameters
are the command's options), the public functions of :data:`USER_OPTIONS` from the parameter
limit (their keyword options are the user's; inside they pass one options object), and the
compiled kernels of :data:`EXCEPTIONS` where splitting measurably costs speed. The source is
read with ``ast``; nothing is imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "ditherlab"
MAX_BODY = 60
MAX_PARAMS = 10

#: ``"module:qualname"`` -> why the function may exceed both limits: compiled kernels only, and
#: the reason states the measurement.
EXCEPTIONS: dict[str, str] = {
    "ditherlab.sim.plant:_kernel": (
        "the simulator's compiled entry takes its four objects' arrays flat "
        "(docs/design/sim-kernel.md): numba's dispatcher types a NamedTuple argument in Python "
        "on every call. Measured: a call on an empty chunk 3.5 us with the arrays flat, 10-12 us "
        "with the objects; the step's CPU time over a 126 s push campaign (6314 calls) 7-10 % "
        "longer with them. Its body is a few lines: the objects rebuilt, the step over the chunk"
    ),
}

#: ``"module:qualname"`` -> why a public function keeps more than :data:`MAX_PARAMS` keyword
#: options (the body limit still holds).
USER_OPTIONS: dict[str, str] = {
    "ditherlab.analysis.identification:identify": (
        "the identification's options, called by keyword from the front door's workflows, the "
        "fleet, the demo and the tests; inside they travel as IdentifyOptions"
    ),
    "ditherlab.analysis.sensitivity:predict": (
        "the prediction's options, called by keyword from robot --sensitivity, the map, the "
        "sweep and the tests; inside they travel as PredictOptions"
    ),
}

#: the module whose typer commands are exempt from the parameter limit
CLI = "ditherlab.cli"


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


class Function:
    """One ``def`` of the package: where it is, its body's length and its parameter count."""

    def __init__(self, module: str, path: Path, qualname: str, node: ast.AST) -> None:
        self.module, self.path, self.qualname, self.node = module, path, qualname, node
        self.key = f"{module}:{qualname}"

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(PKG.parent)}:{self.node.lineno} {self.qualname}"

    @property
    def body_lines(self) -> int:
        """Lines from the first statement after the docstring to the last line of the body."""
        body = self.node.body
        first = body[0]
        is_doc = isinstance(first, ast.Expr) and isinstance(
            getattr(first, "value", None), ast.Constant
        )
        if is_doc and isinstance(first.value.value, str) and len(body) > 1:
            first = body[1]
        return self.node.end_lineno - first.lineno + 1

    @property
    def params(self) -> int:
        """Parameters, ``self``/``cls`` not counted, ``*args``/``**kwargs`` counted."""
        a = self.node.args
        names = [x.arg for x in (*a.posonlyargs, *a.args)]
        n = len(names) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
        return n - (1 if names and names[0] in ("self", "cls") else 0)


def _typer_apps(tree: ast.Module) -> set[str]:
    """Names bound to ``typer.Typer(...)`` at the top of a module."""
    out = set()
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Call):
            f = node.value.func
            if isinstance(f, ast.Attribute) and f.attr == "Typer":
                out |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return out


def _registers(call: ast.AST, apps: set[str]) -> bool:
    """``app.command(...)`` / ``app.callback(...)`` (or without the call) of a typer app."""
    if isinstance(call, ast.Call):
        call = call.func
    return (
        isinstance(call, ast.Attribute)
        and call.attr in ("command", "callback")
        and isinstance(call.value, ast.Name)
        and call.value.id in apps
    )


def typer_commands(tree: ast.Module) -> set[str]:
    """The functions a module registers on its typer apps: decorated with ``@app.command()``
    or ``@app.callback()``, or registered as ``app.command(...)(function)``."""
    apps = _typer_apps(tree)
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            if any(_registers(d, apps) for d in node.decorator_list):
                out.add(node.name)
        elif isinstance(node, ast.Call) and _registers(node.func, apps):
            out |= {a.id for a in node.args if isinstance(a, ast.Name)}
    return out


def functions_of(module: str, path: Path, tree: ast.Module) -> list[Function]:
    """Every function and method of a module, nested ones included, with qualified names."""
    out: list[Function] = []

    def walk(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                out.append(Function(module, path, prefix + child.name, child))
                walk(child, f"{prefix}{child.name}.<locals>.")
            elif isinstance(child, ast.ClassDef):
                walk(child, f"{prefix}{child.name}.")
            else:
                walk(child, prefix)

    walk(tree, "")
    return out


def all_functions() -> tuple[list[Function], set[str]]:
    """Every function of the package, and the keys of the CLI's typer commands."""
    funcs: list[Function] = []
    commands: set[str] = set()
    for path in sorted(PKG.rglob("*.py")):
        mod = module_name(path)
        tree = ast.parse(path.read_text(encoding="utf-8"))
        funcs += functions_of(mod, path, tree)
        if mod == CLI:
            commands |= {f"{mod}:{name}" for name in typer_commands(tree)}
    return funcs, commands


def violations(funcs: list[Function], commands: set[str]) -> list[str]:
    """``file:line name`` and what exceeds, for every function over a limit it is not excused
    from."""
    bad = []
    for f in funcs:
        if f.key in EXCEPTIONS:
            continue
        if f.body_lines > MAX_BODY:
            bad.append(f"{f.where}: body of {f.body_lines} lines (at most {MAX_BODY})")
        if f.params > MAX_PARAMS and f.key not in commands and f.key not in USER_OPTIONS:
            bad.append(f"{f.where}: {f.params} parameters (at most {MAX_PARAMS})")
    return bad


def test_functions_are_short_and_take_few_parameters():
    """No function of the package is longer than MAX_BODY lines or takes more than MAX_PARAMS
    parameters, but for the exemptions above."""
    bad = violations(*all_functions())
    assert not bad, (
        "split each into steps named for their jobs, pass a problem object for a long "
        "parameter list:\n" + "\n".join(bad)
    )


def test_the_exemptions_still_hold():
    """Every entry of EXCEPTIONS and USER_OPTIONS names a function that exists and still
    exceeds the limit it is excused from (a stale entry is removed from the list)."""
    funcs = {f.key: f for f in all_functions()[0]}
    stale = []
    for key in EXCEPTIONS:
        f = funcs.get(key)
        if f is None:
            stale.append(f"{key}: no such function")
        elif f.body_lines <= MAX_BODY and f.params <= MAX_PARAMS:
            stale.append(f"{f.where}: {f.body_lines} lines, {f.params} parameters: within limits")
    for key in USER_OPTIONS:
        f = funcs.get(key)
        if f is None:
            stale.append(f"{key}: no such function")
        elif f.params <= MAX_PARAMS:
            stale.append(f"{f.where}: {f.params} parameters: within the limit")
    assert not stale, "remove these entries:\n" + "\n".join(stale)
    assert all(EXCEPTIONS.values()) and all(USER_OPTIONS.values()), "every entry says why"


def test_the_cli_commands_are_found():
    """The typer commands are recognised (else the exemption would cover nothing, or all)."""
    _, commands = all_functions()
    assert {f"{CLI}:identify", f"{CLI}:replay", f"{CLI}:robot"} <= commands
    assert f"{CLI}:main" not in commands


def test_the_check_can_fail():
    """A long function, a long parameter list and a typer command are told apart on a
    written module."""
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_BODY + 1))
    params = ", ".join(f"a{i}" for i in range(MAX_PARAMS + 1))
    src = (
        "import typer\napp = typer.Typer()\n\n"
        f'def long():\n    """Doc."""\n{body}\n\n'
        f"def many({params}):\n    pass\n\n"
        f"class C:\n    def method(self, {', '.join(f'b{i}' for i in range(MAX_PARAMS))}):\n"
        "        pass\n\n"
        f"@app.command()\ndef command({params}):\n    pass\n\n"
        f"def registered({params}):\n    pass\n\napp.command('r')(registered)\n"
    )
    tree = ast.parse(src)
    funcs = functions_of(CLI, PKG / "cli.py", tree)
    commands = {f"{CLI}:{name}" for name in typer_commands(tree)}
    assert commands == {f"{CLI}:command", f"{CLI}:registered"}
    bad = violations(funcs, commands)
    assert [b.split(": ", 1)[1] for b in bad] == [
        f"body of {MAX_BODY + 1} lines (at most {MAX_BODY})",
        f"{MAX_PARAMS + 1} parameters (at most {MAX_PARAMS})",
    ]
    assert bad[0].startswith("ditherlab/cli.py:4 long") and " many" in bad[1]
