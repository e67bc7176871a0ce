"""Triangle meshes from files (OBJ, PLY, STL, OFF, glTF/GLB) made ready to be cloth.

trimesh reads the files; this module welds what a file split (vertices duplicated along UV seams
or normal creases), drops degenerate and duplicate triangles, puts the mesh y-up in metres, and
refuses, with one line naming the file, what cannot be cloth.
"""
from __future__ import annotations

import functools
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ConfigError, InputWarning

FORMATS = ("obj", "ply", "stl", "off", "gltf", "glb")


@dataclass(frozen=True)
class ClothMesh:
    """A triangle mesh ready to be cloth.

    Attributes:
        x: (n, 3) float64 vertex positions (m, y up).
        triangles: (T, 3) int64 vertex ids, no degenerate or repeated triangle.
        groups: named vertex sets (OBJ ``o``/``g`` names, glTF node and mesh names) -> (k,) ids.
        source: where it came from (a path, or a generator's name), for messages.
        removed_degenerate, removed_duplicate: triangles dropped on loading.
        welded: vertices merged into others on loading.
        notes: the one-line warnings given on loading (non-manifold edges, components, removals).
    """

    x: np.ndarray
    triangles: np.ndarray
    groups: dict = field(default_factory=dict)
    source: str = ""
    removed_degenerate: int = 0
    removed_duplicate: int = 0
    welded: int = 0
    notes: tuple = ()

    @property
    def vertex_count(self) -> int:
        return len(self.x)


def load_mesh(path, *, weld: float = 1e-6, scale: float = 1.0, up: str = "y") -> ClothMesh:
    """Read the triangle mesh in ``path`` (a format of :data:`FORMATS`, told by its extension) as
    cloth: coordinates times ``scale`` (file units to m), rotated to y-up when ``up`` is "z",
    vertices closer than ``weld`` (m, after scaling) merged. Raises ConfigError (one line naming
    the file) for what cannot be cloth; warns (:class:`~taichi_sim.errors.InputWarning`, once
    per file version) of what is used anyway. Results are cached by the file's path, size and
    modification time, so the scene's size check and its build read it once."""
    if not (scale > 0 and np.isfinite(scale)):
        raise ConfigError(f"parameter scale: must be > 0 and finite, got {scale}")
    if not (weld >= 0 and np.isfinite(weld)):
        raise ConfigError(f"parameter weld: must be >= 0 and finite, got {weld}")
    if up not in ("y", "z"):
        raise ConfigError(f"parameter up: must be y or z, got {up!r}")
    path = Path(path)
    try:
        stat = path.stat()
    except OSError as exc:
        raise ConfigError(f"mesh file {path}: cannot be read ({exc.strerror or exc})") from None
    if not path.is_file():
        raise ConfigError(f"mesh file {path}: is not a file")
    return _load_cached(str(path.resolve()), stat.st_size, stat.st_mtime_ns, float(weld), float(scale), up)


@functools.lru_cache(maxsize=4)
def _load_cached(path: str, size: int, mtime: int, weld: float, scale: float, up: str) -> ClothMesh:
    name = os.path.basename(path)
    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in FORMATS:
        raise ConfigError(f"mesh file {path}: unknown format {ext!r} (choose from {', '.join(FORMATS)})")
    if size == 0:
        raise ConfigError(f"mesh file {path}: is empty")
    if ext in ("obj", "off", "gltf"):
        with open(path, "rb") as f:
            if b"\0" in f.read(1 << 16):  # what trimesh says of binary here misleads (a missing codec)
                raise ConfigError(f"mesh file {path}: is binary data, not a text {ext.upper()} file")
    if ext == "stl":
        _check_stl(path, size)
    parts = _read_parts(path, ext)
    if not parts:
        raise ConfigError(f"mesh file {path}: has no triangles")
    x = np.concatenate([v for _, v, _ in parts]) * scale
    offsets = np.cumsum([0] + [len(v) for _, v, _ in parts])
    triangles = np.concatenate([f + o for (_, _, f), o in zip(parts, offsets)])
    groups = {}
    for (names, _, f), o in zip(parts, offsets):
        for group in names:
            groups.setdefault(group, []).append(np.unique(f) + o)
    if ext == "obj":
        from scipy.spatial import cKDTree

        raw = np.concatenate([v for _, v, _ in parts])
        tree = cKDTree(np.where(np.isfinite(raw), raw, 0.0))
        for group, at in _obj_groups(path).items():
            distance, ids = tree.query(at)
            groups.setdefault(group, []).append(ids[distance <= 1e-9 * (1.0 + np.abs(at).max())])
    if up == "z":  # rotate -90 deg about x: +z becomes +y, +y becomes -z (a rotation, no mirror)
        x = np.stack([x[:, 0], x[:, 2], -x[:, 1]], axis=1)
    return clean_mesh(x, triangles, {k: np.concatenate(v) for k, v in groups.items()}, weld=weld,
                      source=name)


def _check_stl(path: str, size: int) -> None:
    """ConfigError unless the file is laid out as an STL: binary (an 80-byte header, a uint32
    triangle count, 50 bytes a triangle) or text (``solid`` first). trimesh tries anything else
    as text of an unknown encoding and fails on a codec it lacks (charset_normalizer), which
    says nothing of the file."""
    import struct

    with open(path, "rb") as f:
        head = f.read(512)
    if size >= 84 and size == 84 + 50 * struct.unpack("<I", head[80:84])[0]:
        return
    if head.lstrip().lower().startswith(b"solid") and b"\0" not in head:
        return
    raise ConfigError(f"mesh file {path}: is not a readable STL mesh (neither binary STL, 84 bytes then 50 a "
                      "triangle, nor text STL starting with 'solid')")


def _read_parts(path: str, ext: str) -> list[tuple[tuple[str, ...], np.ndarray, np.ndarray]]:
    """(names, vertices (k, 3), triangles (t, 3)) of each triangle mesh in the file, with scene
    transforms applied; ConfigError for what trimesh cannot read as triangles."""
    import trimesh

    try:
        loaded = trimesh.load(path, file_type=ext, process=False, maintain_order=True)
    except Exception as exc:  # trimesh raises many kinds (ValueError, IndexError, KeyError, ...)
        reason = " ".join(str(exc).split())[:120] or type(exc).__name__
        if isinstance(exc, ImportError):  # a codec trimesh lacks for what it guessed the content was
            reason = f"its content does not parse as {ext.upper()}"
        raise ConfigError(f"mesh file {path}: not a readable {ext.upper()} mesh ({reason})") from None
    parts = []
    if isinstance(loaded, trimesh.Scene):
        for node in loaded.graph.nodes_geometry:
            transform, geometry_name = loaded.graph[node]
            geometry = loaded.geometry[geometry_name]
            if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
                v = trimesh.transform_points(np.asarray(geometry.vertices, float), transform)
                parts.append((tuple(dict.fromkeys((str(node), str(geometry_name)))), v,
                              np.asarray(geometry.faces, np.int64)))
    elif isinstance(loaded, trimesh.Trimesh) and len(loaded.faces):
        parts.append(((), np.asarray(loaded.vertices, float), np.asarray(loaded.faces, np.int64)))
    return parts


def _obj_groups(path: str) -> dict[str, np.ndarray]:
    """The OBJ ``o``/``g`` groups: name -> (k, 3) positions (file units) of the vertices its faces
    use. Positions, not ids: trimesh may reorder and split vertices (UV seams), positions it
    keeps."""
    groups: dict[str, list[int]] = {}
    current: list[str] = []
    vertices: list[tuple[float, float, float]] = []
    count = 0
    with open(path, "rb") as f:
        for raw in f:
            line = raw.decode("utf-8", "replace").split("#", 1)[0].split()
            if not line:
                continue
            if line[0] == "v":
                count += 1
                try:
                    vertices.append(tuple(float(c) for c in line[1:4]))
                except ValueError:
                    vertices.append((np.nan, np.nan, np.nan))
            elif line[0] in ("o", "g") and len(line) > 1:
                current = [" ".join(line[1:])] if line[0] == "o" else line[1:]
            elif line[0] == "f" and current:
                for token in line[1:]:
                    try:
                        i = int(token.split("/")[0])
                    except ValueError:
                        continue
                    for name in current:
                        groups.setdefault(name, []).append(i - 1 if i > 0 else count + i)
    table = np.asarray(vertices, float).reshape(-1, 3)
    found = {}
    for name, ids in groups.items():
        ids = np.unique(np.asarray(ids, np.int64))
        ids = ids[(ids >= 0) & (ids < len(table))]
        found[name] = table[ids][np.isfinite(table[ids]).all(axis=1)]
    return found


def clean_mesh(x, triangles, groups=None, *, weld: float = 0.0, source: str = "mesh") -> ClothMesh:
    """Weld vertices within ``weld`` (m) of each other, drop degenerate triangles (a repeated
    vertex or zero area) and repeated ones (the same three vertices, either winding), drop
    vertices no triangle uses, and check what is left can be cloth. ``groups``: name -> ids
    into ``x``. Warns of removals, non-manifold edges and several components."""
    x = np.asarray(x, float).reshape(-1, 3)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    if len(triangles) == 0:
        raise ConfigError(f"mesh file {source}: has no triangles")
    if triangles.min() < 0 or triangles.max() >= len(x):
        raise ConfigError(f"mesh file {source}: a triangle names a vertex that does not exist")
    if not np.isfinite(x[np.unique(triangles)]).all():
        raise ConfigError(f"mesh file {source}: has NaN or infinite vertex coordinates")
    merged = _weld_map(x, weld) if len(x) > 1 else np.zeros(len(x), np.int64)
    triangles = merged[triangles]
    repeated = (triangles[:, 0] == triangles[:, 1]) | (triangles[:, 1] == triangles[:, 2]) \
        | (triangles[:, 0] == triangles[:, 2])
    a, b, c = (x[triangles[:, k]] for k in range(3))
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    extent = float(np.ptp(x[np.unique(triangles)], axis=0).max()) if len(triangles) else 0.0
    flat = area2 <= 1e-12 * max(extent, 1e-300) ** 2
    degenerate = repeated | flat
    triangles = triangles[~degenerate]
    _, first = np.unique(np.sort(triangles, axis=1), axis=0, return_index=True)
    duplicate = len(triangles) - len(first)
    triangles = triangles[np.sort(first)]
    if len(triangles) == 0:
        raise ConfigError(f"mesh file {source}: has no triangles of nonzero area")
    used = np.unique(triangles)
    renumber = np.full(len(x), -1, np.int64)
    renumber[used] = np.arange(len(used))
    welded = len(np.unique(merged)) if len(x) else 0
    kept_groups = {}
    for name, ids in (groups or {}).items():
        ids = renumber[merged[np.asarray(ids, np.int64)[(ids >= 0) & (ids < len(x))]]]
        kept_groups[name] = np.unique(ids[ids >= 0])
    mesh_x, mesh_t = x[used], renumber[triangles]
    notes = _mesh_notes(source, mesh_t, len(used), int(degenerate.sum()), duplicate)
    for note in notes:
        warnings.warn(note, InputWarning, stacklevel=3)
    return ClothMesh(mesh_x, mesh_t, kept_groups, source, int(degenerate.sum()), duplicate,
                     len(x) - welded, tuple(notes))


def _weld_map(x: np.ndarray, weld: float) -> np.ndarray:
    """(n,) the vertex each vertex merges into: the lowest id of its cluster, where vertices
    within ``weld`` of each other (chains included) form a cluster; exact copies always merge."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    finite = np.isfinite(x).all(axis=1)
    points = np.where(finite[:, None], x, 0.0)
    pairs = cKDTree(points).query_pairs(r=max(weld, 0.0), output_type="ndarray")
    pairs = pairs[finite[pairs[:, 0]] & finite[pairs[:, 1]]] if len(pairs) else pairs.reshape(0, 2)
    n = len(x)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    lowest = np.full(label.max() + 1, n, np.int64)
    np.minimum.at(lowest, label, np.arange(n))
    return lowest[label]


def _mesh_notes(source: str, triangles: np.ndarray, n: int, degenerate: int, duplicate: int) -> list[str]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    notes = []
    if degenerate or duplicate:
        notes.append(f"mesh {source}: removed {degenerate} degenerate and {duplicate} duplicate triangles")
    edges = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    if (counts > 2).any():
        notes.append(f"mesh {source}: {int((counts > 2).sum())} non-manifold edges (shared by more than two "
                     "triangles; no bending spring across them)")
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    components, _ = connected_components(graph, directed=False)
    if components > 1:
        notes.append(f"mesh {source}: {components} separate pieces (they move independently unless "
                     "pinned or colliding)")
    return notes
