"""Areas of interest in room coordinates, ``aois.json`` (docs/aois.md; schema
``schemas/aois.schema.json``): a list of named areas, each one of

- ``box``: ``center_mm`` [x, y, z], ``size_mm`` [sx, sy, sz] (full sizes along the box's axes),
  ``rotation_deg`` [rx, ry, rz] (about the world's x, then y, then z axis; default none);
- ``sphere``: ``center_mm``, ``radius_mm``;
- ``polygon``: ``corners_mm`` (at least 3 [x, y, z] on one plane, in order), an opaque surface;
- ``marker``: ``id`` (a marker of the marker map: its square, grown by ``margin_mm`` on each side);
- ``markers``: ``ids`` (the plane of those markers: the convex hull of their corners, grown by
  ``margin_mm``);
- ``mesh``: ``path`` (a closed triangle mesh, .ply or .obj, in the map's frame, mm; relative to
  the AOI file);

with an optional ``group``, ``depth_tolerance_mm`` (how far in front of a solid or a surface a
gazed point may lie and still be on it) and, for a box, sphere or mesh, ``transparent`` (a region
of space rather than a solid object: it holds the points inside it). World frame (the marker
map's), mm. One reader, ``read_aois``, and one writer, ``write_aois``; the areas' geometry from a
marker map is made in ``pipeline/steps/aoi.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import UserError
from .jsonio import fail, inside, load_json, write_json

KINDS = ("box", "sphere", "polygon", "marker", "markers", "mesh")
"""The kinds of area, as their keys in aois.json."""


@dataclass(frozen=True)
class AoiSpec:
    """One area as the file gives it.

    Attributes:
        name: its name (unique in the file).
        group: its group, or None.
        kind: one of ``KINDS``.
        params: the kind's object from the file (mm, degrees), with the area's
            ``transparent`` and ``depth_tolerance_mm`` when the file gives them.
        vertices_mm, faces: a mesh's (V, 3) vertices, mm, and (F, 3) triangles; None for others.
        mesh_path: a mesh's file (the AOI file's folder joined with its ``path``); None for others.
    """

    name: str
    group: str | None
    kind: str
    params: dict = field(default_factory=dict)
    vertices_mm: np.ndarray | None = None
    faces: np.ndarray | None = None
    mesh_path: Path | None = None


def read_aois(path) -> list[AoiSpec]:
    """The areas of ``path`` (aois.json), checked against its schema; names unique; meshes read.

    Raises:
        UserError: one line naming the file, the field and how to fix it.
    """
    path = Path(path)
    obj = load_json(path, "aois")
    out, seen = [], set()
    for i, a in enumerate(obj["aois"]):
        if a["name"] in seen:
            raise fail(path, "aois", ["aois", i, "name"], f"the name {a['name']!r} is used twice; give each "
                                                          "area its own name")
        seen.add(a["name"])
        kind = next(k for k in KINDS if k in a)
        if a.get("transparent") and kind not in ("box", "sphere", "mesh"):
            raise fail(path, "aois", ["aois", i, "transparent"], f"a {kind} is a surface, which cannot be "
                                                                 "transparent; remove the field")
        extra = {k: a[k] for k in ("transparent", "depth_tolerance_mm") if k in a}
        spec = AoiSpec(a["name"], a.get("group"), kind, dict(a[kind]) | extra)
        if kind == "mesh":
            mesh = inside(path.parent, a["mesh"]["path"], path, "aois", ["aois", i, "mesh", "path"])
            v, f = read_mesh(mesh)
            spec = AoiSpec(spec.name, spec.group, kind, spec.params, v, f, mesh)
        out.append(spec)
    return out


def write_aois(path, specs: list[AoiSpec]) -> None:
    """Write ``specs`` as aois.json (meshes by their ``path``, which must exist beside it)."""
    rows = []
    for s in specs:
        own = {k: v for k, v in s.params.items() if k not in ("transparent", "depth_tolerance_mm")}
        extra = {k: v for k, v in s.params.items() if k in ("transparent", "depth_tolerance_mm")}
        row = {"name": s.name, **({"group": s.group} if s.group else {}), s.kind: own, **extra}
        rows.append(row)
    write_json(path, {"version": 1, "aois": rows})


def read_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) vertices, mm, and (F, 3) triangle indices of a .obj (``v`` and ``f`` lines;
    polygons split into fans) or .ply (through Open3D) file.

    Raises:
        UserError: a missing, unreadable or empty mesh.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such mesh file; check the AOI's mesh path (relative to the AOI file)")
    if path.suffix.lower() == ".obj":
        v, f = _read_obj(path)
    else:
        from estimator._open3d import import_open3d  # large; only for .ply meshes

        m = import_open3d().io.read_triangle_mesh(str(path))
        v, f = np.asarray(m.vertices, float), np.asarray(m.triangles, int)
    if len(v) < 4 or len(f) < 4:
        raise UserError(f"{path}: a mesh AOI needs a closed surface of at least 4 triangles, found {len(f)}; "
                        "export the object as a closed mesh")
    if f.max() >= len(v) or f.min() < 0:
        raise UserError(f"{path}: a face refers to vertex {int(f.max()) + 1} of {len(v)}; export the mesh again")
    return v, f


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    verts, faces = [], []
    for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        parts = line.split()
        try:
            if parts[:1] == ["v"]:
                verts.append([float(x) for x in parts[1:4]])
            elif parts[:1] == ["f"]:
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                faces += [[idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1)]
        except ValueError:
            raise UserError(f"{path}, line {n}: {line.strip()[:60]!r} is not a vertex or face; "
                            "export the mesh again") from None
    return np.asarray(verts, float).reshape(-1, 3), np.asarray(faces, int).reshape(-1, 3)
