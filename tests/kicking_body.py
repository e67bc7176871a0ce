"""A body that kicks, and cloth to hang on it, written as files the CLI reads: a torso and two
legs as closed triangle meshes (capsules), the right leg turning forward about its hip by
``KICK_ANGLE`` in ``KICK_TIME`` seconds, one OBJ per frame (``body_000.obj`` ...); a skirt (a cone
sewn from panels, the garment scene's) around its hips; a paddle (a thin closed box) that turns
about a horizontal axis through a hanging sheet. Used by test_vbd_mesh_contact.py and, at full size, by the measurement
in docs/meshes.md (``python tests/kicking_body.py kick/skirt.obj 'kick/body_*.obj'``)."""
import math
import os
import sys

import numpy as np
import trimesh

KICK_ANGLE = math.radians(60.0)
KICK_TIME = 1.0 / 3.0
HIP = (0.075, 0.92, 0.0)  # the right hip joint (m); the left one mirrored in x
LEG_RADIUS, LEG_LENGTH = 0.065, 0.7
TORSO_RADIUS, TORSO_HEIGHT, TORSO_CENTRE = 0.12, 0.4, (0.0, 1.25, 0.0)


def _capsule(radius: float, height: float, sections: int) -> trimesh.Trimesh:
    """A closed capsule along y centred at the origin (``height`` its cylinder's length), with
    ``sections`` points a ring and rings about as far apart along it as around (a limb bends
    and moves along its length, so its surface has vertices there)."""
    cap = max(2, sections // 4)  # rings per hemisphere, the pole excluded
    along = max(1, int(round(height / (2 * math.pi * radius / sections))))
    heights, radii = [], []
    for k in range(cap):  # bottom cap, from near the pole up to the equator
        a = -math.pi / 2 + math.pi / 2 * (k + 1) / cap
        heights.append(-height / 2 + radius * math.sin(a))
        radii.append(radius * math.cos(a))
    for k in range(1, along):
        heights.append(-height / 2 + height * k / along)
        radii.append(radius)
    for k in range(cap):  # top cap, from the equator up to near the pole
        a = math.pi / 2 * k / cap
        heights.append(height / 2 + radius * math.sin(a))
        radii.append(radius * math.cos(a))
    turn = np.linspace(0.0, 2 * math.pi, sections, endpoint=False)
    rings = [np.stack([r * np.cos(turn), np.full(sections, h), r * np.sin(turn)], axis=1)
             for h, r in zip(heights, radii)]
    vertices = np.concatenate([[[0.0, -height / 2 - radius, 0.0]], *rings, [[0.0, height / 2 + radius, 0.0]]])
    faces = []
    top = len(vertices) - 1
    for j in range(sections):
        faces.append((0, 1 + j, 1 + (j + 1) % sections))
    for k in range(len(rings) - 1):
        a, b = 1 + k * sections, 1 + (k + 1) * sections
        for j in range(sections):
            j1 = (j + 1) % sections
            faces += [(a + j, b + j, b + j1), (a + j, b + j1, a + j1)]
    last = 1 + (len(rings) - 1) * sections
    for j in range(sections):
        faces.append((last + j, top, last + (j + 1) % sections))
    mesh = trimesh.Trimesh(vertices, np.asarray(faces), process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def body_frames(sections: int = 12, fps: float = 30.0, hold: float = 0.1):
    """(frames (F, V, 3) m, triangles (T, 3)): the torso, the left leg, the right leg turning
    forward (towards +z) by KICK_ANGLE over KICK_TIME, then held for ``hold`` s; ``sections``
    around each capsule (its vertex count grows as its square)."""
    torso = _capsule(TORSO_RADIUS, TORSO_HEIGHT, sections)
    torso.apply_translation(TORSO_CENTRE)
    legs = []
    for side in (-1.0, 1.0):
        leg = _capsule(LEG_RADIUS, LEG_LENGTH, sections)
        # its top cap's centre at the hip joint
        leg.apply_translation((side * HIP[0], HIP[1] - LEG_LENGTH / 2, HIP[2]))
        legs.append(leg)
    parts = [torso, legs[0], legs[1]]
    triangles, offset = [], 0
    for part in parts:
        triangles.append(np.asarray(part.faces) + offset)
        offset += len(part.vertices)
    still = np.concatenate([np.asarray(p.vertices) for p in parts[:2]])
    right = np.asarray(legs[1].vertices)
    frames = []
    count = int(round(KICK_TIME * fps))
    for k in range(count + int(round(hold * fps)) + 1):
        angle = KICK_ANGLE * min(k / count, 1.0)
        c, s = math.cos(angle), math.sin(angle)
        local = right - HIP
        turned = np.stack([local[:, 0], c * local[:, 1] + s * local[:, 2], -s * local[:, 1] + c * local[:, 2]],
                          axis=1)  # about x, the foot (-y) goes to +z
        frames.append(np.concatenate([still, turned + HIP]))
    return np.stack(frames), np.concatenate(triangles)


def write_obj(path: str, vertices: np.ndarray, triangles: np.ndarray) -> None:
    with open(path, "w") as f:
        f.writelines(f"v {a:.7f} {b:.7f} {c:.7f}\n" for a, b, c in vertices)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in triangles)


def write_frames(folder: str, frames: np.ndarray, triangles: np.ndarray, name: str = "body") -> str:
    """One OBJ per frame in ``folder``; returns the glob pattern the CLI's collider_mesh takes."""
    os.makedirs(folder, exist_ok=True)
    for k, vertices in enumerate(frames):
        write_obj(os.path.join(folder, f"{name}_{k:03d}.obj"), vertices, triangles)
    return os.path.join(folder, f"{name}_*.obj")


def write_skirt(path: str, **size) -> int:
    """The garment scene's skirt (its defaults, or smaller by ``size``) as an OBJ; returns its
    vertex count."""
    from taichi_sim.scene.garment import skirt_mesh
    from taichi_sim.scene.garment import write_obj as write_cloth

    mesh = skirt_mesh(**size)
    write_cloth(mesh, path)
    return mesh.vertex_count


def paddle_frames(fps: float = 60.0, turns: float = 0.5, duration: float = 0.25, arm: float = 0.45,
                  width: float = 0.12, thickness: float = 0.03, axis=(0.0, 0.3, 0.0)):
    """(frames, triangles): a paddle, a closed box ``width`` (x) by ``arm`` by ``thickness`` (m),
    from ``axis`` out along -z, turning about the x axis through ``axis`` by ``turns`` turns
    over ``duration`` s (-z, then +y, then +z: through the plane z = 0 above the axis)."""
    box = trimesh.creation.box(extents=(width, thickness, arm))
    box.apply_translation((0.0, 0.0, -arm / 2))
    v = np.asarray(box.vertices)
    frames = []
    count = int(round(duration * fps))
    for k in range(count + 1):
        a = 2 * math.pi * turns * k / count
        c, s = math.cos(a), math.sin(a)
        frames.append(np.stack([v[:, 0], c * v[:, 1] - s * v[:, 2], s * v[:, 1] + c * v[:, 2]], axis=1) + axis)
    return np.stack(frames), np.asarray(box.faces)


def write_sheet(path: str, n: int = 16, size: float = 0.5, top: float = 1.0) -> None:
    """A square sheet of n x n vertices in the plane z = 0, ``size`` (m) wide, its top edge at
    y = ``top``, as an OBJ (a cloth to hang)."""
    u = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(u, top - size / 2 + u[::-1] * -1.0)
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    ids = np.arange(n * n).reshape(n, n)
    a, b, c, d = ids[:-1, :-1].ravel(), ids[:-1, 1:].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel()
    write_obj(path, vertices, np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]))


if __name__ == "__main__":  # the full-size skirt and body: python tests/kicking_body.py SKIRT.obj 'DIR/body_*.obj' [SECTIONS]
    skirt_path, pattern = sys.argv[1], sys.argv[2]
    frames, triangles = body_frames(sections=int(sys.argv[3]) if len(sys.argv) > 3 else 28)
    folder, name = os.path.dirname(pattern) or ".", os.path.basename(pattern).split("_*")[0]
    write_frames(folder, frames, triangles, name=name)
    vertices = write_skirt(skirt_path)
    print(f"{pattern}: {len(frames)} frames of {frames.shape[1]} vertices; {skirt_path}: {vertices} vertices")
