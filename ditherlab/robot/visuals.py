"""A URDF's mesh visuals, found on this machine: what ``view`` draws on each link.

A recording embeds its URDF text, not its meshes; the meshes are looked up where the
description names them (``package://`` through :mod:`~ditherlab.robot.package_paths`, relative
to the description file ``meta["robot"]["path"]``). Rerun draws STL, OBJ and glTF meshes; a
link whose visual mesh is of another kind (Collada ``.dae``) is drawn with its collision mesh
when that one is of a kind Rerun draws. A link without a mesh found keeps its axes alone.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ditherlab.robot.package_paths import resolve_uri

__all__ = ["MESH_TYPES", "MeshVisual", "mesh_visuals"]

#: The mesh files Rerun draws, by suffix (lower case): their media types.
MESH_TYPES = {
    ".stl": "model/stl",
    ".obj": "model/obj",
    ".glb": "model/gltf-binary",
    ".gltf": "model/gltf+json",
}


class MeshVisual(NamedTuple):
    """One mesh of a link, placed in the link's frame.

    Attributes
    ----------
    link : the URDF link
    path : the mesh file on this machine
    xyz : (3,) [m] the mesh's origin in the link frame
    rpy : (3,) [rad] its roll, pitch, yaw (fixed axes x, y, z)
    scale : (3,) the mesh's scale per axis (its units to m)
    rgba : (4,) in [0, 1], or None (the mesh's own colour)
    """

    link: str
    path: Path
    xyz: np.ndarray
    rpy: np.ndarray
    scale: np.ndarray
    rgba: np.ndarray | None


def _floats(text: str | None, default: tuple[float, ...]) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.split()]) if text else np.array(default)
    except ValueError:
        v = np.array(default)
    return v if v.shape == (len(default),) and np.all(np.isfinite(v)) else np.array(default)


def _colors(root: ET.Element) -> dict[str, np.ndarray]:
    """The robot's named materials with a colour: name -> rgba (4,)."""
    out = {}
    for m in root.findall("material"):
        c = m.find("color")
        if m.get("name") and c is not None:
            out[m.get("name", "")] = _floats(c.get("rgba"), (0.7, 0.7, 0.7, 1.0))
    return out


def _mesh(
    link: ET.Element, tag: str, base: Path | None, packages: Mapping[str, str] | None
) -> list[tuple[ET.Element, ET.Element, Path]]:
    """(element, mesh, file) of the link's ``tag`` (visual / collision) meshes Rerun draws,
    found on this machine."""
    out = []
    for el in link.findall(tag):
        mesh = el.find("geometry/mesh")
        if mesh is None or not mesh.get("filename"):
            continue
        path = resolve_uri(mesh.get("filename", ""), base, packages)
        if path is not None and path.suffix.lower() in MESH_TYPES:
            out.append((el, mesh, path))
    return out


def mesh_visuals(
    urdf: str, base: Path | None = None, packages: Mapping[str, str] | None = None
) -> list[MeshVisual]:
    """The meshes of every link of the URDF text ``urdf`` that are found here (its visual
    meshes, else its collision meshes; see the module); ``base`` is the folder of the
    description file, ``packages`` a ``{pkg: folder}`` map. Empty when none is found."""
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError:
        return []
    colors, out = _colors(root), []
    for link in root.findall("link"):
        found = _mesh(link, "visual", base, packages) or _mesh(link, "collision", base, packages)
        for el, mesh, path in found:
            origin = el.find("origin")
            mat = el.find("material")
            rgba = None
            if mat is not None:
                c = mat.find("color")
                rgba = _floats(c.get("rgba"), (0.7,) * 3 + (1.0,)) if c is not None else None
                rgba = rgba if rgba is not None else colors.get(mat.get("name", ""))
            out.append(
                MeshVisual(
                    link.get("name", ""),
                    path,
                    _floats(None if origin is None else origin.get("xyz"), (0.0, 0.0, 0.0)),
                    _floats(None if origin is None else origin.get("rpy"), (0.0, 0.0, 0.0)),
                    _floats(mesh.get("scale"), (1.0, 1.0, 1.0)),
                    rgba,
                )
            )
    return out
