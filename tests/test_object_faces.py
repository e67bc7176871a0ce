"""Cloth faces against objects smaller than the cloth's spacing: a small sphere, a thin rod and a
small box pressed into a cloth at several of their sizes per step. Checked in every step by
geometry written apart from the kernels (numpy distances, exact triangle intersection tests)."""
import numpy as np
import pytest
from helpers import step_checked

from taichi_sim.collide.mesh_check import _point_triangle_distance, _segment_distance
from taichi_sim.geometry.intersections import _triangles_intersect
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.colliders import SpherePath
from taichi_sim.scene.colliders.faces import ALLOWED_OVERLAP

# faces may end a step overlapping an object by ALLOWED_OVERLAP of its thinnest size (plus the
# march's touching distance, 1e-4 of it)
CLEAR = 1.0 - ALLOWED_OVERLAP - 2e-4
# what the test allows, with room for other machines' threads (measured: 0.51 % of the sphere's
# radius at most in these 30 steps, ALLOWED_OVERLAP and the touching distance; the gather is
# serial at this size, so the run repeats exactly)
WRAPPED_CLEAR = 0.98

N, SIZE, DT = 15, 0.5, 1e-2   # spacing 0.5 / 14 = 0.036 m
SPEED = 3.0                   # 0.03 m per step: three times the objects' 0.01 m half thickness
# above a point a third of the spacing from the nearest row of vertices (0.012 m) and 0.017 m
# from the nearest vertex: objects narrower than that pass between vertices, touching none
START = (2 * SIZE / (N - 1) / 3, 0.05, SIZE / (N - 1) / 3)


def pressed_cloth(add_object, faces=True, pinned=None, velocity=(0.0, -SPEED, 0.0), start=START):
    """A free horizontal cloth (``pinned``: an (n,) bool mask) with an object moving at
    ``velocity`` from ``start`` through its middle."""
    x = topo.grid_positions(N, N, SIZE, SIZE, origin=(-SIZE / 2, 0.0, -SIZE / 2),
                            u_axis=(1, 0, 0), v_axis=(0, 0, 1))
    b = SceneBuilder()
    b.add_particles(x, 0.01, pinned=pinned)
    ends, kind = topo.grid_springs(N, N)
    b.add_springs(ends, stiffness=5.0, damping=0.0, kind=kind)
    triangles = topo.grid_triangles(N, N)
    if faces:
        b.add_triangles(triangles)
    add_object(b, SpherePath(start, velocity=velocity))
    scene = b.finalize(name="t", params={}, default_dt=DT, default_integrator="symplectic_euler")
    return scene, np.asarray(triangles).reshape(-1, 3)


def run_checked(scene, steps, centre, check):
    step_checked(scene, "symplectic_euler", DT, steps, lambda scene: check(scene.state.to_numpy()[0], centre()))
    return scene.state.to_numpy()[0]


def corners(x, triangles):
    return x[triangles[:, 0]], x[triangles[:, 1]], x[triangles[:, 2]]


# --- a sphere of radius 0.01 m --------------------------------------------------------------

@pytest.mark.parametrize("faces", [True, False])
def test_a_sphere_smaller_than_the_spacing_does_not_pass_through_a_cloth(f64, faces):
    radius = 0.01
    scene, tris = pressed_cloth(lambda b, path: b.add_sphere(path, radius), faces)

    def stays_out(x, c):
        a, b, e = corners(x, tris)
        gap = _point_triangle_distance(np.broadcast_to(c, a.shape), a, b, e).min()
        assert gap >= WRAPPED_CLEAR * radius

    if faces:
        x = run_checked(scene, 30, lambda: scene.spheres.centers()[0], stays_out)
        assert x[:, 1].min() < -0.85  # carried 0.9 m down with it, never passed
        assert scene.spheres.face_contacts_total > 0
    else:  # vertices only: it passes between them, through a face, and the cloth never moves
        x = run_checked(scene, 30, lambda: scene.spheres.centers()[0], lambda x, c: None)
        assert np.abs(x[:, 1]).max() == 0.0 and scene.spheres.centers()[0][1] < -0.8


# --- a rod: a capsule of radius 0.01 m and length 0.2 m --------------------------------------

def segment_to_triangles(p, q, a, b, e):
    """(T,) distances from segment pq to each triangle abe; 0 where it pierces one."""
    tri_count = len(a)
    p_, q_ = np.broadcast_to(p, a.shape), np.broadcast_to(q, a.shape)
    d = np.minimum(_point_triangle_distance(p_, a, b, e), _point_triangle_distance(q_, a, b, e))
    for u, v in ((a, b), (b, e), (e, a)):
        d = np.minimum(d, _segment_distance(u, v, p_, q_))
    n = np.cross(b - a, e - a)
    hp, hq = np.einsum("ij,ij->i", p_ - a, n), np.einsum("ij,ij->i", q_ - a, n)
    crosses = hp * hq < 0
    s = np.where(crosses, hp / np.where(crosses, hp - hq, 1.0), 0.0)
    point = p_ + s[:, None] * (q_ - p_)
    inside = np.ones(tri_count, bool)
    for u, v in ((a, b), (b, e), (e, a)):
        inside &= np.einsum("ij,ij->i", np.cross(v - u, point - u), n) >= 0
    return np.where(crosses & inside, 0.0, d)


@pytest.mark.parametrize("faces", [True, False])
def test_a_rod_thinner_than_the_spacing_does_not_pass_through_a_cloth(f64, faces):
    # the rod lies along x, between two rows of vertices
    radius, half = 0.01, np.array([0.1, 0.0, 0.0])
    scene, tris = pressed_cloth(lambda b, path: b.add_capsule(path, radius, tuple(half)), faces)

    def stays_out(x, c):
        gap = segment_to_triangles(c - half, c + half, *corners(x, tris)).min()
        assert gap >= WRAPPED_CLEAR * radius

    if faces:
        x = run_checked(scene, 30, lambda: scene.part("capsules").centers()[0], stays_out)
        assert x[:, 1].min() < -0.85
    else:
        x = run_checked(scene, 30, lambda: scene.part("capsules").centers()[0], lambda x, c: None)
        assert np.abs(x[:, 1]).max() == 0.0


# --- pinned corners -------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["sphere", "capsule", "box"])
def test_a_face_beside_a_pin_is_pushed_gently(f64, kind):
    # an object rising at 1 m/s into the cloth just beside a pinned vertex: the faces it meets
    # have a pinned corner that takes none of the push. Shared by weight over mass, the free
    # corners' share grew as 1 / their weight (velocities of 1e3 to 1e7 m/s); they must stay
    # of the order of the object's speed
    middle = (N // 2) * N + N // 2
    pinned = np.zeros(N * N, bool)
    pinned[middle] = True
    add = {"sphere": lambda b, path: b.add_sphere(path, 0.025),
           "capsule": lambda b, path: b.add_capsule(path, 0.025, (0.02, 0.0, 0.0)),
           "box": lambda b, path: b.add_box(path, (0.025, 0.025, 0.025))}[kind]
    for offset in (1e-4, 5e-4, 2e-3):
        scene, _ = pressed_cloth(add, pinned=pinned, velocity=(0.0, 1.0, 0.0), start=(offset, -0.04, 0.3 * offset))
        def gentle(scene):
            speed = np.linalg.norm(scene.state.to_numpy()[1], axis=1).max()
            assert speed < 10.0, (kind, offset, speed)

        step_checked(scene, "symplectic_euler", DT, 8, gentle)


# --- a box of half extent 0.008 m -----------------------------------------------------------

def box_triangles(centre, half):
    """(12, 3, 3) the faces of an axis-aligned box, two triangles each."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    v = centre + signs * half
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return np.array([[v[a], v[b], v[c]] for a, b, c, d in quads for a, b, c in ((a, b, c), (a, c, d))])


def box_meets_cloth(x, tris, centre, half) -> bool:
    inside = np.all(np.abs(x - centre) < half, axis=1).any()
    faces = np.stack(corners(x, tris), axis=1)
    box = box_triangles(centre, half)
    t1 = np.repeat(faces, len(box), axis=0)
    t2 = np.tile(box, (len(faces), 1, 1))
    return bool(inside or _triangles_intersect(t1, t2).any())


@pytest.mark.parametrize("faces", [True, False])
def test_a_small_box_is_stopped_by_the_face_it_hits(f64, faces):
    # a box's corner and edges meet the face's inside, where no vertex is (between samples the
    # box would jump clean over the cloth, so "carried" is the test; the intersection check
    # guards the steps in contact)
    half = np.full(3, 0.008)
    scene, tris = pressed_cloth(lambda b, path: b.add_box(path, tuple(half)), faces)
    shrunk = half * CLEAR  # (an overlap d along a unit axis u needs |u|_1 d >= d of each half extent)

    def stays_out(x, c):
        assert not box_meets_cloth(x, tris, c, shrunk)

    x = run_checked(scene, 4, lambda: scene.part("boxes").centers()[0], stays_out)
    bottom = scene.part("boxes").centers()[0][1] - half[1]
    if faces:
        assert x[:, 1].min() <= bottom + 1e-9  # carried on its leading face
    else:  # vertices only: it passes between them in one step, touching nothing
        assert np.abs(x[:, 1]).max() < 1e-12 and bottom < -0.07
