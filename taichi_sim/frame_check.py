"""`taichi-sim check`: judge a saved run's frames on positions alone, with no solver code.

Three questions, each answered for every saved frame (``x_history``, or the final ``x``):
whether any two triangles of the cloth intersect (:func:`~taichi_sim.geometry.self_intersections`,
exact predicates); whether any vertex lies inside one of the scene's objects
(:func:`~taichi_sim.scene.colliders.shape.inside_objects`, over every registered collider kind:
the moving ones, spheres, capsules and boxes, where the run kept their centres with the frames,
the ground plane always; the collider mesh where the run
kept its pose with the frames, :func:`~taichi_sim.geometry.mesh_inside.mesh_depths`; pinned
vertices, which no collider moves, are left out); and whether an object reaches into a face
between its vertices: points on each triangle (:func:`~taichi_sim.geometry.inside.face_samples`,
25 a triangle) deeper inside an object whose faces are judged (a sphere, capsule or box) than
``FACE_SHARE`` of its thinnest size,
or deeper inside the collider mesh than ``INSIDE_TOLERANCE`` (a mesh has no thinnest size, and
its collider keeps vertices a skin away, so any depth is a body poking between them; triangles
with a pinned corner are left out: a pin inside an object drags its triangles in, which no
collider can undo).
"""
from __future__ import annotations

import os
import zipfile

import numpy as np

from .errors import ConfigError
from .geometry import self_intersections
from .geometry.inside import FACE_DIVISIONS, FACE_SHARE, INSIDE_TOLERANCE, face_samples
from .geometry.mesh_inside import mesh_depths
from .scene.colliders.shape import face_depths, inside_objects, shape, shapes

_MESH_KEYS = ("collider_mesh_vertices", "collider_mesh_triangles", "collider_mesh_center",
              "collider_mesh_vertices_history", "collider_mesh_center_history")


def load_run(path: str) -> dict[str, np.ndarray]:
    """The arrays of a run's npz that the check reads (ConfigError for a file that is not one,
    or a run without a cloth surface)."""
    # np.load reads any file but a zip or .npy as a pickle, and refuses it talking of pickles
    if os.path.isfile(path) and not zipfile.is_zipfile(path):
        raise ConfigError(f"{path} is not a run's npz (not a zip archive): give a file "
                          "written by `taichi-sim simulate --out RUN.npz`")
    wanted = ("triangles", "x", "x_history", "t_history", "t", "scene", "pinned", *_MESH_KEYS,
              *(k for kind in shapes() for k in kind.npz_keys()),
              *(f"{kind.key}_center_history" for kind in shapes() if kind.moving))
    try:
        with np.load(path) as data:
            arrays = {k: data[k] for k in wanted if k in data.files}
    except (OSError, ValueError) as exc:
        raise ConfigError(f"cannot read {path} as a run's npz: {exc}") from None
    if "triangles" not in arrays or "x" not in arrays:
        raise ConfigError(f"{path} has no cloth surface (no `triangles`): only cloth scenes can be checked")
    return arrays


def frames_of(arrays: dict) -> tuple[np.ndarray, np.ndarray, bool]:
    """(frames (S, N, 3), their times (S,), whether they are the saved history)."""
    if "x_history" in arrays:
        return arrays["x_history"], arrays["t_history"], True
    return arrays["x"][None], np.atleast_1d(arrays.get("t", np.nan)), False


def objects_at(arrays: dict, frame: int, history: bool) -> tuple[dict, list[str]]:
    """(The object keys of frame ``frame`` for :func:`inside_objects`, the object kinds left
    unchecked). A saved history checks the objects whose centres it kept; the final frame
    alone is checked against the centres the file holds (those at its end)."""
    out, unchecked = {}, []
    for kind in shapes():
        if not kind.present(arrays):
            continue
        sizes = {k: arrays[k] for k in kind.size_keys}
        center = f"{kind.key}_center"
        if not kind.moving:
            out.update(sizes)
        elif history and f"{center}_history" in arrays:
            out.update(sizes, **{center: arrays[f"{center}_history"][frame]})
        elif not history:
            out.update(sizes, **{center: arrays[center]})
        else:
            unchecked.append(kind.key)
    return out, unchecked


def mesh_at(arrays: dict, frame: int, history: bool) -> tuple[np.ndarray | None, bool]:
    """(The collider mesh's vertices (V, 3) in the world (m) at frame ``frame``, or None; whether
    the file has a collider mesh it cannot place there). A saved history places it by the poses
    kept with the frames (``collider_mesh_center_history``, and ``collider_mesh_vertices_history``
    for a sequence of frames; a rigid mesh's vertices are the file's); the final frame alone by
    the pose the file holds (at its end)."""
    if "collider_mesh_triangles" not in arrays:
        return None, False
    if not history:
        vertices, center = arrays["collider_mesh_vertices"], arrays["collider_mesh_center"]
    elif "collider_mesh_center_history" not in arrays:
        return None, True
    else:
        center = arrays["collider_mesh_center_history"][frame]
        moving = arrays.get("collider_mesh_vertices_history")
        vertices = arrays["collider_mesh_vertices"] if moving is None else moving[frame]
    return np.asarray(vertices, np.float64).reshape(-1, 3) + np.asarray(center, np.float64).reshape(1, 3), False


def _check_mesh_poses(arrays: dict, frames: int, history: bool) -> None:
    """ConfigError for a collider mesh's poses that do not match the frames (a file not written
    by a run)."""
    if not history or "collider_mesh_triangles" not in arrays:
        return
    for key in ("collider_mesh_center_history", "collider_mesh_vertices_history"):
        if key in arrays and len(arrays[key]) != frames:
            raise ConfigError(f"{key} holds {len(arrays[key])} pose(s) for {frames} saved frame(s): "
                              "not a run's npz")


def check_run(arrays: dict, progress=lambda frames: frames) -> tuple[list[str], bool]:
    """(The report's lines, whether every frame passed) for a run's arrays (:func:`load_run`);
    ``progress`` wraps the frames' iteration (a progress bar)."""
    frames, times, history = frames_of(arrays)
    name = str(arrays.get("scene", "run"))
    counts, flat = [], 0
    inside, kinds_seen, unchecked, faces, mesh_faces = [], set(), [], [], []
    _check_mesh_poses(arrays, len(frames), history)
    mesh_triangles = np.asarray(arrays.get("collider_mesh_triangles", np.zeros((0, 3))), np.int64).reshape(-1, 3)
    # pinned vertices stay where their pins put them: no collider moves them
    free = ~np.asarray(arrays["pinned"], bool) if "pinned" in arrays else slice(None)
    face_tris = np.asarray(arrays["triangles"]).reshape(-1, 3)
    if "pinned" in arrays:
        face_tris = face_tris[~np.asarray(arrays["pinned"], bool)[face_tris].any(axis=1)]
    for k, x in enumerate(progress(frames)):
        try:
            report = self_intersections(x, arrays["triangles"])
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        counts.append(report.count)
        flat = max(flat, len(report.degenerate))
        objects, unchecked = objects_at(arrays, k, history)
        found = {kind: int(mask.sum()) for kind, mask in inside_objects(x[free], objects).items()}
        mesh, mesh_unplaced = mesh_at(arrays, k, history)
        if mesh is not None:
            found["collider_mesh"] = int((mesh_depths(x[free], mesh, mesh_triangles) > INSIDE_TOLERANCE).sum())
            mesh_faces.append(_faces_in_mesh(x, face_tris, mesh, mesh_triangles))
        elif mesh_unplaced:
            unchecked.append("collider_mesh")
        kinds_seen.update(found)
        inside.append({kind: n for kind, n in found.items() if n})
        faces.append(_deepest_face_point(x, face_tris, objects))
    counts = np.asarray(counts)
    # zero-area triangles have no inside to pass through: left out, and said so
    note = f" ({flat} zero-area triangle(s) in some frame, not checked)" if flat else ""
    if not counts.any():
        lines = [f"{name}: {len(counts)} frame(s), no triangles intersect{note}"]
    else:
        worst = int(counts.argmax())
        lines = [f"{name}: {int((counts > 0).sum())} of {len(counts)} frame(s) have intersecting triangles; "
                 f"first at t = {times[int(np.argmax(counts > 0))]:.6g} s, most ({counts[worst]} pairs) at "
                 f"t = {times[worst]:.6g} s{note}"]
    names = [_object_name(kind) for kind in sorted(kinds_seen)]
    named = " or ".join([", ".join(names[:-1]), names[-1]] if len(names) > 2 else names)
    bad = [k for k, found in enumerate(inside) if found]
    if kinds_seen and not bad:
        lines.append(f"{name}: no vertex inside the {named} in any frame")
    elif bad:
        worst = max(bad, key=lambda k: sum(inside[k].values()))
        most = ", ".join(f"{n} inside the {_object_name(kind)}" for kind, n in inside[worst].items())
        lines.append(f"{name}: {len(bad)} of {len(inside)} frame(s) have vertices inside an object; first at "
                     f"t = {times[bad[0]]:.6g} s, most ({most}) at t = {times[worst]:.6g} s")
    face_bad = [k for k, found in enumerate(faces) if found is not None and found[1] > FACE_SHARE]
    face_kinds = sorted({found[0] for found in faces if found is not None})
    if face_kinds and not face_bad:
        kinds = " or ".join(_object_name(kind) for kind in face_kinds)
        lines.append(f"{name}: no face reaches into the {kinds} in any frame ({_face_note()})")
    elif face_bad:
        worst = max(face_bad, key=lambda k: faces[k][2])
        kind, _, depth = faces[worst]
        lines.append(f"{name}: {len(face_bad)} of {len(faces)} frame(s) have a face reaching into an object "
                     f"({_face_note()}); first at t = {times[face_bad[0]]:.6g} s, deepest {1000 * depth:.3g} mm "
                     f"inside the {_object_name(kind)} at t = {times[worst]:.6g} s")
    mesh_bad = [k for k, (count, _) in enumerate(mesh_faces) if count]
    mesh_note = f"{_face_points()} points a triangle, deeper than {INSIDE_TOLERANCE:g} m"
    if mesh_faces and not mesh_bad:
        lines.append(f"{name}: no face reaches into the collider mesh in any frame ({mesh_note})")
    elif mesh_bad:
        worst = max(mesh_bad, key=lambda k: mesh_faces[k][1])
        lines.append(f"{name}: {len(mesh_bad)} of {len(mesh_faces)} frame(s) have a face reaching into the collider "
                     f"mesh ({mesh_note}); first at t = {times[mesh_bad[0]]:.6g} s, deepest "
                     f"{1000 * mesh_faces[worst][1]:.3g} mm inside it at t = {times[worst]:.6g} s")
    if unchecked:
        lines.append(f"{name}: the {' and '.join(_object_name(k) for k in unchecked)} not checked: the file keeps "
                     f"no centres with its frames (saved by an older version)")
    return lines, not counts.any() and not bad and not face_bad and not mesh_bad


def _face_points() -> int:
    return (FACE_DIVISIONS + 1) * (FACE_DIVISIONS + 2) // 2 - 3


def _faces_in_mesh(x, triangles, mesh, mesh_triangles) -> tuple[int, float]:
    """(How many of the cloth's ``triangles`` have a point of
    :func:`~taichi_sim.geometry.inside.face_samples` deeper than ``INSIDE_TOLERANCE`` inside the
    collider mesh (vertices ``mesh`` (V, 3) m in the world), the deepest such point's depth (m))."""
    if len(triangles) == 0:
        return 0, 0.0
    depth = mesh_depths(face_samples(x, triangles).reshape(-1, 3), mesh, mesh_triangles)
    deepest = depth.reshape(len(triangles), -1).max(axis=1)
    return int((deepest > INSIDE_TOLERANCE).sum()), float(deepest.max())


def _face_note() -> str:
    return f"{_face_points()} points a triangle, deeper than {100 * FACE_SHARE:g} % of the object's thinnest size"


def _deepest_face_point(x, triangles, objects):
    """(object kind, depth as a share of that object's thinnest size, depth (m)) of the face
    point deepest inside an object whose faces are judged, by that share; None without such
    objects."""
    if len(triangles) == 0:
        return None
    best = None
    for kind, (shares, depths) in face_depths(x, triangles, objects).items():
        k = int(np.argmax(shares))
        if best is None or shares[k] > best[1]:
            best = (kind, float(shares[k]), float(depths[k]))
    return best


def _object_name(kind: str) -> str:
    """How the report names the objects of a kind (its key, or ``collider_mesh``)."""
    return "collider mesh" if kind == "collider_mesh" else shape(kind).label
