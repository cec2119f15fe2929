"""Where a robot description's ROS packages are on this machine: ``$(find pkg)`` in a xacro file
and ``package://pkg/...`` in a URDF's mesh file names, without ROS.

A package ``pkg`` is found, in this order, in

1. the package map the user gave (``--robot-arg pkg:=DIR`` on the command line: an argument
   that names a folder),
2. the description file's own tree: the nearest enclosing folder called ``pkg`` or holding a
   ``package.xml`` whose ``<name>`` is ``pkg``, or a sibling folder called ``pkg`` of one of them,
3. example-robot-data's share folder when it is installed (its URDFs name meshes
   ``package://example-robot-data/robots/...``),
4. ``ROS_PACKAGE_PATH`` (folders holding packages) and ``AMENT_PREFIX_PATH`` (``PREFIX/share/pkg``).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path

from ditherlab.robot.example_robots import share_root

__all__ = ["find_package", "resolve_uri"]

_NAME = re.compile(r"<name>\s*([^<\s]+)\s*</name>")


def _package_name(folder: Path) -> str | None:
    """The ``<name>`` of ``folder/package.xml``, or None."""
    try:
        text = (folder / "package.xml").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    m = _NAME.search(text)
    return m.group(1) if m else None


def _in_tree(pkg: str, base: Path) -> Path | None:
    """``pkg`` in the tree of ``base`` (a folder): an enclosing folder named ``pkg`` or whose
    package.xml names it, or a child folder ``pkg`` of an enclosing folder."""
    for folder in [base, *base.parents]:
        if folder.name == pkg or _package_name(folder) == pkg:
            return folder
        if (folder / pkg).is_dir():
            return folder / pkg
    return None


def _env_roots() -> Iterable[Path]:
    """``ROS_PACKAGE_PATH`` folders and ``AMENT_PREFIX_PATH``'s ``PREFIX/share`` folders."""
    for entry in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
        if entry:
            yield Path(entry)
    for entry in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if entry:
            yield Path(entry) / "share"


def find_package(
    pkg: str, base: Path | None = None, package_map: Mapping[str, str | Path] | None = None
) -> Path | None:
    """The folder of ROS package ``pkg`` (see the module's search order), or None.

    Parameters
    ----------
    pkg : the package name (``ur_description``)
    base : the folder of the description file that names the package (its own tree is searched)
    package_map : ``{pkg: folder}`` the user gave
    """
    if package_map and pkg in package_map:
        return Path(package_map[pkg]).expanduser()
    if base is not None:
        found = _in_tree(pkg, Path(base).resolve())
        if found is not None:
            return found
    root = share_root()
    if root is not None and (root / pkg).is_dir():
        return root / pkg
    for folder in _env_roots():
        if (folder / pkg).is_dir():
            return folder / pkg
    return None


def resolve_uri(
    uri: str, base: Path | None = None, package_map: Mapping[str, str | Path] | None = None
) -> Path | None:
    """The file a URDF names (a mesh's ``filename``): ``package://pkg/rel`` (its package found
    by :func:`find_package`), ``file:///abs``, an absolute path, or a path relative to ``base``;
    None when it cannot be found on this machine."""
    if uri.startswith("package://"):
        pkg, _, rel = uri[len("package://") :].partition("/")
        folder = find_package(pkg, base, package_map)
        path = None if folder is None else folder / rel
    elif uri.startswith("file://"):
        path = Path(uri[len("file://") :])
    else:
        path = Path(uri)
        if not path.is_absolute() and base is not None:
            path = Path(base) / path
    return path if path is not None and path.is_file() else None
