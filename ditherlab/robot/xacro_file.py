"""A xacro robot description expanded to URDF text, without ROS (the ``xacro`` package from PyPI,
an optional install: ``pip install 'ditherlab[robots]'``).

Arguments are ``NAME:=VALUE`` (as ``xacro file.xacro NAME:=VALUE``); an argument
``package://PKG:=DIR`` says where the ROS package ``PKG`` is (for ``$(find PKG)`` and for
``package://PKG/...`` mesh names), otherwise packages are found as
:mod:`ditherlab.robot.package_paths` says.
"""

from __future__ import annotations

import contextlib
import io
import threading
from collections.abc import Iterable, Mapping
from pathlib import Path

from ditherlab.core.errors import RobotError, one_line
from ditherlab.robot.example_robots import INSTALL_HINT
from ditherlab.robot.package_paths import find_package

__all__ = ["PACKAGE_PREFIX", "expand_xacro", "is_xacro", "parse_robot_args"]

#: An argument ``package://PKG:=DIR`` maps a ROS package to a folder.
PACKAGE_PREFIX = "package://"

#: xacro keeps its state in module globals: one expansion at a time.
_LOCK = threading.Lock()


def is_xacro(path: str | Path) -> bool:
    """Whether ``path`` names a xacro file (``.xacro``, ``.urdf.xacro``)."""
    return str(path).lower().endswith(".xacro")


def parse_robot_args(
    args: Iterable[str] | Mapping[str, str] | None, where: str = "--robot-arg"
) -> tuple[dict[str, str], dict[str, str]]:
    """``(xacro arguments {name: value}, package map {pkg: folder})`` of ``NAME:=VALUE`` texts
    (a mapping is taken as the arguments); RobotError naming ``where`` for a text without
    ``:=``."""
    if args is None:
        return {}, {}
    items = list(args.items()) if isinstance(args, Mapping) else []
    if not isinstance(args, Mapping):
        for text in args:
            name, sep, value = str(text).partition(":=")
            if not sep or not name.strip():
                raise RobotError(
                    f"{where} {str(text)!r}: expected NAME:=VALUE (a xacro argument) or "
                    f"{PACKAGE_PREFIX}PKG:=DIR (where a ROS package is)"
                )
            items.append((name.strip(), value))
    xargs = {k: str(v) for k, v in items if not k.startswith(PACKAGE_PREFIX)}
    packages = {k[len(PACKAGE_PREFIX) :].strip("/"): str(v) for k, v in items if k not in xargs}
    return xargs, packages


def _finder(base: Path, packages: Mapping[str, str]):
    """xacro's ``$(find PKG)``: the package's folder, or an error naming what was searched."""
    from xacro.substitution_args import SubstitutionException

    def find(pkg: str) -> str:
        folder = find_package(pkg, base, packages)
        if folder is None:
            raise SubstitutionException(
                f"$(find {pkg}): package {pkg!r} not found in the file's tree, "
                "example-robot-data, ROS_PACKAGE_PATH or AMENT_PREFIX_PATH (expected "
                f"--robot-arg {PACKAGE_PREFIX}{pkg}:=DIR)"
            )
        return str(folder)

    return find


def expand_xacro(
    path: str | Path,
    args: Iterable[str] | Mapping[str, str] | None = None,
    where: str = "",
) -> str:
    """The URDF text of the xacro file ``path`` with ``args`` (``NAME:=VALUE`` texts, see
    :func:`parse_robot_args`); RobotError (prefixed ``where``) in one line with xacro's own
    reason when it does not expand, and when xacro is not installed."""
    path = Path(path)
    if not path.is_file():
        raise RobotError(f"{where}robot xacro file '{path}' does not exist")
    xargs, packages = parse_robot_args(args)
    try:
        import xacro
        from xacro import substitution_args
    except ImportError:
        raise RobotError(
            f"{where}robot xacro file '{path}' needs the xacro package, which is not installed "
            f"(expected it installed: {INSTALL_HINT})"
        ) from None
    err = io.StringIO()
    with _LOCK, contextlib.redirect_stderr(err):
        saved = substitution_args._eval_find
        substitution_args._eval_find = _finder(path.resolve().parent, packages)
        try:
            doc = xacro.process_file(str(path), mappings=xargs)
            return doc.toprettyxml(indent="  ")
        except substitution_args.ArgException as e:
            reason = f"argument {one_line(e)} is not set (expected --robot-arg {e}:=VALUE)"
        except Exception as e:  # noqa: BLE001 - xacro raises many kinds; each is one line here
            reason = one_line(e) or type(e).__name__
        finally:
            substitution_args._eval_find = saved
    raise RobotError(f"{where}robot xacro file '{path}' does not expand: {reason}")
