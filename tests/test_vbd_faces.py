"""The cloth's triangles against objects inside vertex block descent (vbd_faces): a cloth falling
at 3 m/s onto a small sphere, a thin rod and a small box, each narrower than the cloth's spacing
and lying between its vertices, so that no vertex ever comes near them. vbd steps the scene
alone (no post-step events), and geometry written apart from the kernels checks every step."""
import numpy as np
import pytest
from test_object_faces import SIZE, START, N, box_meets_cloth, corners, segment_to_triangles

from taichi_sim.collide.mesh_check import _point_triangle_distance
from taichi_sim.integrators import create_integrator
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.colliders import SpherePath

DT, STEPS, SPEED = 1e-2, 30, 3.0  # 0.03 m a step, more than the objects are thick
BELOW = (START[0], -0.05, START[2])  # under the cloth, between its vertices (see test_object_faces)


def falling_cloth(add_object, speed=SPEED):
    """A free horizontal cloth falling at ``speed`` (m/s) onto an object resting at BELOW; no
    gravity."""
    x = topo.grid_positions(N, N, SIZE, SIZE, origin=(-SIZE / 2, 0.0, -SIZE / 2),
                            u_axis=(1, 0, 0), v_axis=(0, 0, 1))
    b = SceneBuilder()
    b.add_particles(x, 0.01, v=np.tile([0.0, -speed, 0.0], (len(x), 1)))
    ends, kind = topo.grid_springs(N, N)
    b.add_springs(ends, stiffness=50.0, damping=0.0, kind=kind)
    triangles = np.asarray(topo.grid_triangles(N, N)).reshape(-1, 3)
    b.add_triangles(triangles)
    add_object(b, SpherePath(BELOW))
    scene = b.finalize(name="t", params={}, default_dt=DT, default_integrator="vbd")
    return scene, triangles


def upward_crossings(x, tris, point) -> int:
    """Triangles a vertical ray up from ``point`` passes through: a cloth held by the object
    lies over it (1 or more), one that passed through lies under it (0)."""
    return sum(_over(a, b, c, point) for a, b, c in zip(*corners(x, tris)))


def _over(a, b, c, point) -> bool:
    """Whether triangle abc, seen from above, covers point's (x, z) and lies above it there."""
    m = np.array([(b - a)[[0, 2]], (c - a)[[0, 2]]]).T
    if abs(np.linalg.det(m)) < 1e-15:
        return False
    s, t = np.linalg.solve(m, (np.asarray(point) - a)[[0, 2]])
    if s < 0 or t < 0 or s + t > 1:
        return False
    return (a + s * (b - a) + t * (c - a))[1] > point[1]


def fall(scene, check, serial=None, **options):
    vbd = create_integrator("vbd", scene.system, **options)
    vbd.bind_contact(scene.contact_inputs())
    if serial is not None:
        vbd.serial = serial
    assert vbd.contact.has_object_faces == options.get("object_faces", True)
    for k in range(STEPS):
        assert vbd.step(scene.state, k * DT, DT).status.value == "ok"
        check(scene.state.to_numpy()[0])
    return scene.state.to_numpy()[0]


OBJECTS = {
    "sphere": (lambda b, path: b.add_sphere(path, 0.01),
               lambda x, tris: _point_triangle_distance(np.broadcast_to(BELOW, (len(tris), 3)),
                                                        *corners(x, tris)).min() >= 0.01),
    "rod": (lambda b, path: b.add_capsule(path, 0.01, (0.1, 0.0, 0.0)),
            lambda x, tris: segment_to_triangles(np.subtract(BELOW, (0.1, 0, 0)), np.add(BELOW, (0.1, 0, 0)),
                                                 *corners(x, tris)).min() >= 0.01),
    "box": (lambda b, path: b.add_box(path, (0.008, 0.008, 0.008)),
            lambda x, tris: not box_meets_cloth(x, tris, np.asarray(BELOW), np.full(3, 0.008))),
}


@pytest.mark.parametrize("kind, serial", [(kind, None) for kind in sorted(OBJECTS)] + [("box", False)])
def test_an_object_narrower_than_the_spacing_holds_the_faces_that_fall_on_it(f64, kind, serial):
    """serial=False: the kernels of large cloths and GPUs (a query kernel, one per colour)."""
    add, clear = OBJECTS[kind]
    scene, tris = falling_cloth(add)

    def stays_out(x):
        assert clear(x, tris), kind

    x = fall(scene, stays_out, serial=serial)
    assert x[:, 1].min() < -0.2  # the cloth round it fell on past it
    assert upward_crossings(x, tris, BELOW) >= 1  # and over it


def test_with_object_faces_off_the_same_sphere_passes_between_the_vertices(f64):
    add, _ = OBJECTS["sphere"]
    scene, tris = falling_cloth(add)
    x = fall(scene, lambda x: None, object_faces=False)
    assert x[:, 1].max() < -0.85  # every vertex fell freely: nothing held the cloth
    assert upward_crossings(x, tris, BELOW) == 0


@pytest.mark.parametrize("radius, needed", [(0.3, False), (0.05, True), (0.01, True)])
def test_a_sphere_round_enough_for_the_cloth_is_left_to_the_vertices(f64, radius, needed):
    """A face resting on a sphere of radius R dips in at most rho^2 / (2 R): the 0.3 m sphere
    under this cloth (spacing 0.036 m, rho 0.025 m) lets it dip 1.1 mm (1.7 mm stretched by a
    quarter), under half the 5 mm contact radius; a 0.05 m sphere 6.4 mm (10 mm)."""
    scene, _ = falling_cloth(lambda b, path: b.add_sphere(path, radius))
    vbd = create_integrator("vbd", scene.system)
    vbd.bind_contact(scene.contact_inputs())
    assert vbd.contact.radius == 0.005 and vbd.contact.has_object_faces == needed
    scene, _ = falling_cloth(lambda b, path: b.add_box(path, (radius, radius, radius)))
    vbd = create_integrator("vbd", scene.system)
    vbd.bind_contact(scene.contact_inputs())
    assert vbd.contact.has_object_faces  # a box has edges, however large


def test_a_vertex_out_of_reach_moves_at_most_the_bound_fraction_of_its_room(f64):
    """A pair out of reach at the query leaves each corner a ball: the triangle's lower bound
    (the sphere's distance from its centroid less the centroid's spread) times bound_fraction.
    A step longer than that share but shorter than the whole room is cut to the share."""
    import taichi as ti

    scene, tris = falling_cloth(OBJECTS["sphere"][0])
    vbd = create_integrator("vbd", scene.system)
    vbd.bind_contact(scene.contact_inputs())
    contact = vbd.contact
    assert contact.has_object_faces and 0 < contact.fraction < 1
    x = scene.state.x
    resting = ti.Vector.field(3, ti.f64, shape=x.shape[0])  # no guessed move: the reach is 2 r

    @ti.kernel
    def query():
        contact.measure_face_reach(resting)
        contact.query_faces(x, 0.0)

    @ti.kernel
    def share(i: ti.i32, step: ti.types.vector(3, ti.f64)) -> ti.f64:
        return contact.face_scale(i, x, x[i], step, 0.0, 1.0)

    query()
    positions = x.to_numpy()
    a, b, c = (positions[tris[:, j]] for j in range(3))
    g = (a + b + c) / 3
    spread = np.max([np.linalg.norm(p - g, axis=1) for p in (a, b, c)], axis=0)
    lower = np.linalg.norm(g - np.asarray(BELOW), axis=1) - 0.01 - spread
    i = int(tris[np.argmin(lower)][0])  # a corner of the triangle nearest the sphere
    room = lower[(tris == i).any(axis=1)].min()
    assert 2 * contact.radius < room < np.inf  # out of reach: bounded by its ball only
    assert contact.face_room.to_numpy()[i] == pytest.approx(room, rel=1e-9)
    for direction in ((0.0, -1.0, 0.0), (0.6, 0.0, 0.8)):  # toward the sphere, and across it
        step = 0.9 * room * np.asarray(direction)  # inside the room, beyond its share
        assert share(i, step) * 0.9 * room == pytest.approx(contact.fraction * room, rel=1e-9)
    assert share(i, 0.5 * contact.fraction * room * np.array([0.0, -1.0, 0.0])) == 1.0
