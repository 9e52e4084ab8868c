"""The 3D view of a processed session, ``targets.ply`` (docs/formats.md, "targets.ply"), for
Blender, MeshLab and Open3D: an ASCII PLY mesh in the world frame (the marker map's), mm.

Elements: ``vertex`` (``x, y, z`` double, mm; ``red, green, blue`` uchar), ``face``
(``vertex_indices``, triangles) and ``edge`` (``vertex1, vertex2`` int: polylines). What the
vertices are is for the writer's caller to say in ``comments`` (``pipeline.steps.export``: each
target's 95 % ellipsoid as a triangle mesh, each target's point as a lone vertex, the head path
as a chain of edges); the header's first comments give the units and frame.

One writer, ``write_ply``, and one reader, ``read_ply`` (of the files ``write_ply`` writes:
ASCII, these elements and properties).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from estimator.deprecation import renamed_kwargs

from ..errors import UserError
from .atomic import write_text

UNITS_COMMENT = "units: mm; frame: world (the marker map's; OpenCV axes x right, y down, z forward)"


@renamed_kwargs({"colours": "colors"})
@dataclass
class PlyMesh:
    """A coloured mesh with polylines.

    Attributes:
        vertices_mm: (N, 3) world frame, mm.
        colors: (N, 3) uint8 RGB.
        faces: (F, 3) vertex indices of triangles.
        edges: (E, 2) vertex indices of line segments.
        comments: header comments (one line each), after ``UNITS_COMMENT``.
    """

    vertices_mm: np.ndarray
    colors: np.ndarray
    faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), int))
    edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), int))
    comments: list = field(default_factory=list)


def write_ply(path, mesh: PlyMesh) -> None:
    """Write ``mesh`` as an ASCII PLY, atomically."""
    v = np.asarray(mesh.vertices_mm, float).reshape(-1, 3)
    c = np.asarray(mesh.colors, np.uint8).reshape(-1, 3)
    f = np.asarray(mesh.faces, int).reshape(-1, 3)
    e = np.asarray(mesh.edges, int).reshape(-1, 2)
    if len(c) != len(v) or (f.size and (f.min() < 0 or f.max() >= len(v))) or (e.size and (e.min() < 0 or
                                                                                            e.max() >= len(v))):
        raise ValueError("write_ply: colours must match the vertices and faces and edges index them")
    head = ["ply", "format ascii 1.0", f"comment {UNITS_COMMENT}", *(f"comment {x}" for x in mesh.comments),
            f"element vertex {len(v)}", "property double x", "property double y", "property double z",
            "property uchar red", "property uchar green", "property uchar blue",
            f"element face {len(f)}", "property list uchar int vertex_indices",
            f"element edge {len(e)}", "property int vertex1", "property int vertex2", "end_header"]
    body = [f"{x:.4f} {y:.4f} {z:.4f} {r} {g} {b}" for (x, y, z), (r, g, b) in zip(v, c.tolist(), strict=True)]
    body += [f"3 {a} {b} {d}" for a, b, d in f.tolist()]
    body += [f"{a} {b}" for a, b in e.tolist()]
    write_text(path, "\n".join(head + body) + "\n")


def read_ply(path) -> PlyMesh:
    """The mesh of a PLY written by ``write_ply``.

    Raises:
        UserError: a missing file, or one that is not such a PLY (one line).
    """
    try:
        lines = open(path, encoding="ascii").read().splitlines()
        end = lines.index("end_header")
        head = lines[:end]
        if head[:2] != ["ply", "format ascii 1.0"]:
            raise ValueError("not an ASCII PLY")
        counts = {ln.split()[1]: int(ln.split()[2]) for ln in head if ln.startswith("element ")}
        comments = [ln[len("comment "):] for ln in head if ln.startswith("comment ")]
        nv, nf, ne = counts["vertex"], counts["face"], counts["edge"]
        rows = lines[end + 1:]
        if len(rows) < nv + nf + ne:
            raise ValueError(f"{len(rows)} data lines, the header announces {nv + nf + ne}")
        vert = np.array([r.split() for r in rows[:nv]], float).reshape(-1, 6)
        faces = np.array([r.split()[1:] for r in rows[nv:nv + nf]], int).reshape(-1, 3)
        edges = np.array([r.split() for r in rows[nv + nf:nv + nf + ne]], int).reshape(-1, 2)
    except FileNotFoundError:
        raise UserError(f"{path}: no such file; run 'wearable-gaze process' again") from None
    except (OSError, ValueError, KeyError, IndexError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a targets.ply ({exc}); run 'wearable-gaze process' again (--force)") from None
    return PlyMesh(vert[:, :3], vert[:, 3:].astype(np.uint8), faces, edges, comments[1:])
