"""Meshes as users hold them -> the Mesh message: a file path (PLY, OBJ + MTL + textures,
glTF + buffers/images, GLB), bytes with their format, or a ``trimesh.Trimesh`` /
``trimesh.Scene`` (exported as GLB with its texture)."""

from __future__ import annotations

import json
import os
import re
import shlex
from pathlib import Path
from typing import Any, Dict, Iterable, List, Mapping, Optional, Tuple, Union

from .v1 import pose_service_pb2 as pb

MeshInput = Union[str, "os.PathLike[str]", bytes, Any]
UNITS_TO_M = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
_FORMATS = {".ply": "ply", ".obj": "obj", ".gltf": "gltf", ".glb": "glb"}


def _check_units(units: Optional[str], fmt: str) -> Optional[str]:
    if units is not None and units not in UNITS_TO_M:
        raise ValueError(f"units {units!r}: expected 'mm', 'cm' or 'm'")
    if units is None and fmt in ("ply", "obj"):
        raise ValueError(f"a {fmt.upper()} mesh needs its length unit: units='mm', 'cm' or 'm' (BOP models are 'mm')")
    return units


def _plain_name(name: str, mesh: Path) -> str:
    if "/" in name or "\\" in name or name in (".", ".."):
        raise ValueError(f"{mesh}: refers to {name!r}; the service takes only files beside the mesh (plain names)")
    return name


def _obj_refs(path: Path) -> List[Tuple[str, Path]]:
    """MTL libraries of an OBJ and the texture maps of those libraries."""
    refs: List[Tuple[str, Path]] = []
    for line in path.read_text(errors="replace").splitlines():
        if line.startswith("mtllib "):
            name = line[len("mtllib ") :].strip()
            refs.append((name, path.parent / name))
    out: List[Tuple[str, Path]] = []
    for name, mtl in refs:
        out.append((name, mtl))
        if not mtl.is_file():
            raise FileNotFoundError(f"{path}: material library {name!r} not found at {mtl}")
        for line in mtl.read_text(errors="replace").splitlines():
            words = line.strip().split(None, 1)
            if len(words) == 2 and words[0].lower().startswith(("map_", "bump", "disp", "decal", "norm")):
                out.append(_map_file(words[1], mtl))
    return out


def _map_file(rest: str, mtl: Path) -> Tuple[str, Path]:
    """The file of an MTL map statement: options (``-s 1 1 1``) first, then the name,
    which may hold spaces."""
    try:
        tokens = shlex.split(rest)
    except ValueError:
        tokens = rest.split()
    # Options take a fixed number of numeric/word arguments; the name is what follows the
    # last option. Names with spaces: rejoin the remaining tokens.
    i = 0
    while i < len(tokens) and tokens[i].startswith("-") and not re.fullmatch(r"-?\d+(\.\d*)?", tokens[i]):
        i += 1
        while i < len(tokens) - 1 and re.fullmatch(r"[-+]?\d+(\.\d*)?([eE][-+]?\d+)?|on|off", tokens[i]):
            i += 1
    name = " ".join(tokens[i:]) if i < len(tokens) else rest.strip()
    return name, mtl.parent / name


def _ply_refs(path: Path) -> List[Tuple[str, Path]]:
    """Texture files named in a PLY header (``comment TextureFile name``)."""
    out: List[Tuple[str, Path]] = []
    with open(path, "rb") as f:
        for raw in f:
            line = raw.decode("latin-1").strip()
            if line.startswith("comment TextureFile "):
                name = line[len("comment TextureFile ") :].strip()
                out.append((name, path.parent / name))
            if line == "end_header":
                break
    return out


def _gltf_refs(path: Path) -> List[Tuple[str, Path]]:
    """External buffers and images of a .gltf (data: URIs are embedded)."""
    doc = json.loads(path.read_text())
    out: List[Tuple[str, Path]] = []
    for item in list(doc.get("buffers", [])) + list(doc.get("images", [])):
        uri = item.get("uri")
        if uri and not uri.startswith("data:"):
            from urllib.parse import unquote

            name = unquote(uri)
            out.append((name, path.parent / name))
    return out


def _resources(refs: Iterable[Tuple[str, Path]], mesh: Path) -> List[pb.Resource]:
    seen: Dict[str, pb.Resource] = {}
    for name, p in refs:
        name = _plain_name(name, mesh)
        if name in seen:
            continue
        if not p.is_file():
            raise FileNotFoundError(f"{mesh}: refers to {name!r}, not found at {p}")
        seen[name] = pb.Resource(name=name, data=p.read_bytes())
    return list(seen.values())


def mesh_from_path(path: Union[str, "os.PathLike[str]"], units: Optional[str]) -> pb.Mesh:
    p = Path(path)
    fmt = _FORMATS.get(p.suffix.lower())
    if fmt is None:
        raise ValueError(f"{p}: unknown mesh format (expected .ply, .obj, .gltf or .glb)")
    units = _check_units(units, fmt)
    refs = {"obj": _obj_refs, "ply": _ply_refs, "gltf": _gltf_refs}.get(fmt, lambda _p: [])(p)
    return pb.Mesh(data=p.read_bytes(), format=fmt, units=units or "", resources=_resources(refs, p))


def mesh_from_bytes(data: bytes, fmt: Optional[str], units: Optional[str], resources: Optional[Mapping[str, bytes]]) -> pb.Mesh:
    if fmt is None:
        fmt = "glb" if data[:4] == b"glTF" else None
        if fmt is None:
            raise ValueError("mesh bytes: give format='ply', 'obj', 'gltf' or 'glb'")
    fmt = fmt.lower().lstrip(".")
    if fmt not in _FORMATS.values():
        raise ValueError(f"mesh format {fmt!r}: expected 'ply', 'obj', 'gltf' or 'glb'")
    units = _check_units(units, fmt)
    res = [pb.Resource(name=n, data=bytes(b)) for n, b in (resources or {}).items()]
    return pb.Mesh(data=bytes(data), format=fmt, units=units or "", resources=res)


def mesh_from_trimesh(obj: Any, units: Optional[str]) -> pb.Mesh:
    """Exports a Trimesh / Scene as GLB (textures and vertex colours embedded). glTF is
    metres by specification, so the geometry is scaled from ``units`` first."""
    if units is None:
        raise ValueError("a trimesh object needs its length unit: units='mm', 'cm' or 'm'")
    _check_units(units, "glb")
    scale = UNITS_TO_M[units]
    if scale != 1.0:
        obj = obj.copy()
        obj.apply_scale(scale)
    data = obj.export(file_type="glb")
    return pb.Mesh(data=bytes(data), format="glb", units="m")


def _is_trimesh(obj: object) -> bool:
    mod = type(obj).__module__
    return mod.startswith("trimesh") and hasattr(obj, "export")


def mesh_message(mesh: MeshInput, units: Optional[str], fmt: Optional[str] = None, resources: Optional[Mapping[str, bytes]] = None) -> pb.Mesh:
    """The Mesh message of any accepted mesh input."""
    if isinstance(mesh, pb.Mesh):
        return mesh
    if isinstance(mesh, (bytes, bytearray, memoryview)):
        return mesh_from_bytes(bytes(mesh), fmt, units, resources)
    if isinstance(mesh, (str, os.PathLike)):
        return mesh_from_path(mesh, units)
    if _is_trimesh(mesh):
        return mesh_from_trimesh(mesh, units)
    raise TypeError(f"mesh: expected a path, bytes, or a trimesh.Trimesh / Scene, not {type(mesh).__name__}")
