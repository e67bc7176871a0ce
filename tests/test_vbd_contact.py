"""Contact inside vertex block descent (docs/vbd-contact.md): nothing crosses at
speed, a folding cloth never intersects itself, objects keep vertices out and friction holds a
vertex on a slope; bad contact options and tangled starts are refused. Small scenes: kernel
compilation dominates."""

import math

import numpy as np
import pytest
from helpers import step_checked

import taichi_sim as ts
from taichi_sim.errors import ConfigError
from taichi_sim.geometry import self_intersections
from taichi_sim.integrators import create_integrator
from taichi_sim.integrators.positional.vbd import contact as vbd_contact
from taichi_sim.integrators.positional.vbd import kernels as vbd_schedule
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.colliders import SpherePath

H = 1 / 60


def shot_scene():
    """A pinned triangle T1 standing in the plane z = 0 (x in [-1, 1], y in [-1, 0]); a vertex
    0.05 m in front of its face, shot at it at 30 m/s (0.5 m a step); a free triangle T2 in
    the plane x = 0 whose lower edge, 0.05 m above T1's upper edge and across it, falls at
    30 m/s. No gravity: only contact stops them."""
    b = SceneBuilder()
    x = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0],  # T1
                  [0.0, 0.05, -1.0], [0.0, 0.05, 1.0], [0.0, 1.05, 0.0],  # T2
                  [0.3, -0.4, 0.05]])  # the shot vertex
    v = np.zeros_like(x)
    v[3:6, 1] = -30.0
    v[6, 2] = -30.0
    b.add_particles(x, 0.01, v=v, pinned=np.array([1, 1, 1, 0, 0, 0, 0], bool))
    b.add_triangles(np.array([[0, 1, 2], [3, 4, 5]]))
    return b.finalize(name="shot", params={}, default_dt=H, default_integrator="vbd")


@pytest.mark.parametrize("serial", [True, False])
@pytest.mark.parametrize("pieces", [1, 16])
def test_a_vertex_and_an_edge_shot_at_the_mesh_never_pass_it(f64, serial, pieces):
    """Both code paths: one kernel per substep's sweeps (CPU) and one per sweep, the colours as
    parallel loops (a GPU, or a large mesh), with Chebyshev's over-relaxation there; one piece a
    step and up to 16. In pieces the two come into contact within a step and part again: the
    penalty pushes the vertex back out of the contact radius within a piece, about 1.8 m/s
    back from 30 m/s (a restitution of 0.06)."""
    scene = shot_scene()
    vbd = create_integrator("vbd", scene.system, self_contact=True, contact_radius=0.01,
                            chebyshev_rho=0.0 if serial else 0.9, contact_pieces=pieces)
    vbd.serial = serial
    tris = scene.mesh.triangles_np

    closest = []

    def on_their_side(scene):
        x = scene.state.to_numpy()[0]
        assert x[6, 2] > 0.0, "the vertex passed through the triangle"
        assert x[3:5, 1].min() > 0.0, "the edge passed through the other edge"
        assert not len(self_intersections(x, tris).pairs)
        closest.append((x[6, 2], x[3:5, 1].max()))

    step_checked(scene, vbd, H, 12, on_their_side)
    if pieces == 1:
        assert np.min(closest, axis=0).max() < 0.01  # both came into contact, not stopped far off
    else:  # they met within the first step (pairs in the solve) and left slowly
        assert vbd.contact.pairs_total > 0
        speed = np.abs(scene.state.to_numpy()[1][[6, 3, 4], [2, 1, 1]])
        assert speed.max() < 0.1 * 30.0, speed


def test_a_non_finite_state_is_a_diverged_step_with_contact(f64):
    scene = shot_scene()
    vbd = create_integrator("vbd", scene.system, self_contact=True, contact_radius=0.01)
    vbd.bind_contact(scene.contact_inputs())
    x, v = scene.state.to_numpy()
    x[4] = np.nan
    scene.state.from_numpy(x, v)
    report = vbd.step(scene.state, 0.0, H)
    assert report.status.value == "diverged" and not report.accepted


def fold(n: int = 12, **extra):
    """cloth-fold without the post-step self-collision stage and without dashpots or drag
    (conservative: the energy can only fall)."""
    return ts.build_scene("cloth-fold", {"nx": n, "ny": n, "self_collision": False, "jitter": 0.002, **extra})


def step_clean(scene, vbd, steps):
    """Step ``scene`` with ``vbd`` at H, failing on any frame with intersecting triangles;
    returns (the energies (J), the start's first; the stepper)."""
    tris = scene.mesh.triangles_np
    energy = [scene.energy()]

    def clean(scene):
        assert not len(self_intersections(scene.state.to_numpy()[0], tris).pairs)
        energy.append(scene.energy())

    stepper = step_checked(scene, vbd, H, steps, clean)
    return np.asarray(energy), stepper


def test_the_edge_query_finds_every_pair_of_edges_within_the_radius_once(f64):
    """The detection's edge-edge query (edges bucketed once, in their home cell; each pair
    taken from the edge whose home comes first) against every pair of edges tested directly,
    on a crumpled cloth: the same pairs, none twice."""
    from taichi_sim.collide.mesh_check import _segment_distance

    scene = fold(12)
    vbd = create_integrator("vbd", scene.system, self_contact=True, contact_radius=0.02)
    vbd.bind_contact(scene.contact_inputs())
    x, v = scene.state.to_numpy()
    i, j = np.divmod(np.arange(len(x)), 12)  # grid_index: particle i * ny + j
    rng = np.random.default_rng(5)  # rows pressed 14 mm apart, bent and jittered
    crumpled = np.stack([i / 11, 0.02 * np.sin(3.0 * i / 11 + j), 0.014 * j], axis=1) \
        + rng.normal(0.0, 0.003, x.shape)
    scene.state.from_numpy(crumpled, v)
    contact = vbd.contact
    assert contact.refresh(scene.state.x) == 0
    count = int(contact.pair_count[None])
    assert count <= contact.pair_capacity
    ids, kind = contact.pair_ids.to_numpy()[:count], contact.pair_kind.to_numpy()[:count]
    found = [tuple(sorted((tuple(sorted(p[:2])), tuple(sorted(p[2:]))))) for p in ids[kind == 1]]
    assert len(found) == len(set(found))  # none twice
    edges = contact.edges.to_numpy()[:contact.edge_count]
    a, b = np.triu_indices(len(edges), 1)
    apart = ~(edges[a][:, :, None] == edges[b][:, None, :]).any(axis=(1, 2))  # no shared vertex
    a, b = a[apart], b[apart]
    d = _segment_distance(crumpled[edges[a, 0]], crumpled[edges[a, 1]], crumpled[edges[b, 0]], crumpled[edges[b, 1]])
    pair = lambda i, j: tuple(sorted((tuple(sorted(edges[i])), tuple(sorted(edges[j])))))  # noqa: E731
    surely = {pair(i, j) for i, j in zip(a[d < 0.02 - 1e-9], b[d < 0.02 - 1e-9])}
    maybe = {pair(i, j) for i, j in zip(a[d < 0.02 + 1e-9], b[d < 0.02 + 1e-9])}
    assert len(surely) > 500  # a crumple, not a flat sheet
    assert surely <= set(found) <= maybe


def test_a_cloth_folding_on_itself_never_intersects_and_never_gains_energy(f32):
    scene = fold()
    vbd = create_integrator("vbd", scene.system, self_contact=True)
    energy, _ = step_clean(scene, vbd, 90)
    assert np.all(energy <= energy[0] * (1 + 1e-6)), energy.max() - energy[0]
    assert vbd.contact.pairs_total > 0  # the layers met
    assert vbd.run_warning() == ""  # every pair found was kept


def test_with_self_contact_in_the_solve_a_smaller_cloth_sweeps_in_parallel(f32, monkeypatch):
    """A vertex's contact pairs make its block several times a spring's work, so with
    self-contact in the solve the colours become parallel loops from SERIAL_CONTACT_PARTICLES
    particles (times spare threads) on, not from SERIAL_WORK particles plus springs; without
    it the springs' rule stands, and a caller's choice wins over both. The parallel sweeps then
    fold the cloth cleanly."""
    threads = ts.runtime._current["threads"]  # what serial_loops counts
    if not ts.runtime.cpu_backend() or threads < 2:
        pytest.skip("the rule applies to a CPU with a spare thread")
    spare = threads - 1
    scene = fold(12)  # 144 particles
    monkeypatch.setattr(vbd_schedule, "SERIAL_CONTACT_PARTICLES", 144 * spare + 1)
    alone = create_integrator("vbd", scene.system, self_contact=False)
    contact = create_integrator("vbd", scene.system, self_contact=True)
    for vbd in (alone, contact):
        vbd.bind_contact(scene.contact_inputs())
    assert alone.serial and contact.serial  # 144 particles: below either break-even
    monkeypatch.setattr(vbd_schedule, "SERIAL_CONTACT_PARTICLES", 144 * spare)
    assert alone.serial and not contact.serial
    contact.serial = True  # a caller's choice against the rule
    assert contact.serial
    monkeypatch.setattr(vbd_schedule, "SERIAL_CONTACT_PARTICLES", 144 * spare + 1)
    contact.serial = False
    assert not contact.serial
    energy, _ = step_clean(scene, contact, 45)
    assert np.all(energy <= energy[0] * (1 + 1e-6)), energy.max() - energy[0]
    assert contact.contact.pairs_total > 0


def test_pieces_let_a_fold_collapse_at_its_pace_without_intersecting(f32):
    """With one detection a step the bounds hold the collapsing layers back; with up to 16
    pieces a step, each as long as keeps the start guess within the bounds, the fold falls as a
    free one does (16 x 16, 0.5 s: 0.082 against 0.232 m of mean height; symplectic
    Euler at 1 ms: 0.061 m), with no intersecting frame and no energy above the start."""
    heights = {}
    for pieces in (1, 16):
        scene = fold(16)
        vbd = create_integrator("vbd", scene.system, self_contact=True, contact_pieces=pieces)
        energy, _ = step_clean(scene, vbd, 30)
        assert max(energy) <= energy[0] * (1 + 1e-6), max(energy) - energy[0]
        heights[pieces] = float(scene.state.to_numpy()[0][:, 1].mean())
        assert (vbd.pieces > 30 + 30) == (pieces > 1)  # more than a piece a step, only when allowed
    assert heights[16] < 0.15 < heights[1], heights


def test_a_piece_begun_again_keeps_the_warm_starts_acceleration(f64):
    """A piece shortened for the pace is begun a second time with its shorter dt: its guess must
    be the one a first start with that dt makes (the last substep's acceleration along gravity
    included, though start_v already holds the new v0), and its start choice is counted once."""
    scene = fold(8)
    vbd = create_integrator("vbd", scene.system, self_contact=True)
    stepper = step_checked(scene, vbd, H, 3)  # falling: the acceleration along gravity is g
    begin = vbd._bound(scene.state)["begin"]
    v0 = vbd.start_v.to_numpy()
    short = H / 4

    begin(short, 1, H, stepper.t + short, 0)
    once = vbd.delta.to_numpy()
    rests = vbd.rest_starts[None]
    vbd.start_v.from_numpy(v0)  # as the last substep left it
    begin(H, 1, H, stepper.t + H, 0)
    begin(short, 1, H, stepper.t + short, 1)
    np.testing.assert_allclose(vbd.delta.to_numpy(), once, rtol=0, atol=1e-12)
    v = scene.state.to_numpy()[1]
    assert np.abs(once - short * v).max() > 0.5 * 9.8 * short ** 2  # the gravity term is there
    assert vbd.rest_starts[None] - rests == vbd.last_rest[None]


def test_contact_pairs_dropped_for_lack_of_room_are_said(f32, monkeypatch):
    # each vertex keeps one pair: the fold finds more, and the run must say it lost them
    monkeypatch.setattr(vbd_contact, "CONTACTS_PER_VERTEX", 1)
    scene = fold()
    vbd = create_integrator("vbd", scene.system, self_contact=True)
    result = ts.run(scene, vbd, dt=H, steps=90)
    assert vbd.contact.dropped_total > 0
    assert f"vbd: {vbd.contact.dropped_total} contact pair(s) found but dropped from the solve" in vbd.run_warning()
    assert vbd.run_warning() in result.warnings


def test_without_self_contact_the_same_fold_intersects(f32):
    scene = fold()
    vbd = create_integrator("vbd", scene.system)  # objects (the ground) only
    tris = scene.mesh.triangles_np
    crossed = []
    step_checked(scene, vbd, H, 90, lambda s: crossed.append(len(self_intersections(s.state.to_numpy()[0], tris).pairs)))
    assert max(crossed) > 0


def test_a_twisted_cloth_whose_pins_vbd_moves_never_intersects(f32):
    """cloth-twist's turning sides are scripted pins: vbd moves them inside its solve, in
    pieces short enough for their bounds, so the wrung cloth never passes through itself. With
    the pins jumping between steps instead (as before), this 16 x 16 twist intersected in 6 of
    its 90 frames, the first at 1.42 s."""
    scene = ts.build_scene("cloth-twist", {"nx": 16, "ny": 16})
    vbd = create_integrator("vbd", scene.system, contact_pieces=1)  # pieces for the pins only
    pinned = scene.kinematic.ids_np
    _, stepper = step_clean(scene, vbd, 90)
    assert vbd.takeover.parts == {"self_collision", "kinematic"}
    assert vbd.pieces > 90  # the pins needed more than one piece a step somewhere
    where, speed = scene.kinematic.path.at(stepper.t)
    x, v = scene.state.to_numpy()
    assert np.abs(x[pinned] - where).max() < 1e-5  # on the script's path, not a step behind
    assert np.abs(v[pinned] - speed).max() < 1e-4


def test_pins_that_cannot_move_within_their_bounds_end_the_run_as_diverged(f32):
    scene = ts.build_scene("cloth-twist", {"nx": 8, "ny": 8})
    vbd = create_integrator("vbd", scene.system)
    vbd.bind_contact(scene.contact_inputs())
    vbd.pins.plan = lambda x, t, length: 0.0  # as for a pin pressed into the cloth
    result = ts.run(scene, vbd, dt=H, steps=3)
    assert result.status.value == "diverged"
    assert "the scripted pins could not move within their contact bounds" in result.message


def test_objects_in_the_solve_keep_a_draped_cloth_out(f64):
    """A 10 x 10 cloth dropped on a sphere and a box standing on the ground: no vertex ends a
    step inside any of them (nor below the ground), and the post-step object events, kept as a
    fail-safe, have nothing left to do."""
    scene = ts.build_scene("cloth", {"nx": 10, "ny": 10, "pin": "none", "plane": True, "sphere": True,
                                     "sphere_radius": 0.2, "sphere_x": -0.25, "sphere_y": 0.2, "box": True,
                                     "box_x": 0.3, "box_y": 0.15, "box_half_x": 0.15, "box_half_y": 0.15,
                                     "box_half_z": 0.15, "height": 0.6, "object_faces": False})
    vbd = create_integrator("vbd", scene.system)
    stepper = ts.Stepper(scene, vbd, H)
    sphere_c = scene.spheres.centers()[0]
    box_c, half = scene.part("boxes").centers()[0], np.array([0.15, 0.15, 0.15])
    events_moved = 0.0
    for _ in range(60):
        report = vbd.step(scene.state, stepper.t, H)
        assert report.status.value == "ok"
        x = scene.state.to_numpy()[0]
        assert np.linalg.norm(x - sphere_c, axis=1).min() >= 0.2
        inside_box = np.all(np.abs(x - box_c) < half, axis=1)
        assert not inside_box.any()
        assert x[:, 1].min() >= scene.plane.point_np[1]
        stepper.t += H
        scene.after_step(stepper.t, H)
        events_moved = max(events_moved, float(np.abs(scene.state.to_numpy()[0] - x).max()))
    assert events_moved < 1e-9
    assert np.linalg.norm(x - sphere_c, axis=1).min() < 0.2 + 0.02  # it lies on the sphere


def test_a_fold_over_a_box_edge_never_intersects_because_the_face_pass_waits(f32):
    """The box's face pass, run after a step of vbd with self-contact, pushed the faces lying
    across the box's edge past the solve's bounds and tangled the fold (16 x 16: 60 of 91
    frames intersecting, the first at 0.52 s): with self-contact in the solve it does not run,
    and runs again once another method steps the scene."""
    from taichi_sim.scene.colliders.shape import inside_objects

    scene = ts.build_scene("cloth-fold", {"nx": 16, "ny": 16, "height": 1.4, "box": True, "box_y": 0.15,
                                          "box_half_x": 0.3, "box_half_y": 0.15, "box_half_z": 0.3})
    box = scene.part("boxes")
    result = ts.run(scene, "vbd", dt=1 / 60, t_end=0.75, save_every=1, progress=False)
    assert result.status.value == "ok" and box.faces_paused
    assert max(self_intersections(x, scene.mesh.triangles_np).count for x in result.x_history) == 0
    objects = {**scene.arrays, "box_center": result.object_history["box_center_history"][-1]}
    assert not any(mask.any() for mask in inside_objects(result.x_history[-1], objects, 1e-6).values())
    ts.Stepper(scene, "symplectic_euler", 1e-3)
    assert not box.faces_paused


def test_a_vertex_shot_at_a_thin_box_stops_on_its_near_side(f64):
    """A particle at 60 m/s (1 m a step) towards a box 2 cm thick: the penalty alone lets it
    through (its inertial target lies 1 m beyond, past the box's middle, where the nearest face
    is the far one); the cap on each step's approach stops it on the side it came from. No
    post-step events run here."""
    b = SceneBuilder()
    b.add_particles(np.array([[0.0, 0.3, 0.0]]), 0.01, v=np.array([[0.0, -60.0, 0.0]]))
    b.add_box(SpherePath((0.0, 0.0, 0.0)), (0.2, 0.01, 0.2))
    scene = b.finalize(name="box-shot", params={}, default_dt=H, default_integrator="vbd")
    vbd = create_integrator("vbd", scene.system, contact_radius=0.005)
    vbd.bind_contact(scene.contact_inputs())
    for k in range(6):
        assert vbd.step(scene.state, k * H, H).status.value == "ok"
        assert scene.state.to_numpy()[0][0, 1] > 0.01


def test_friction_holds_a_vertex_on_a_slope_and_lets_it_slide_past_its_angle(f64):
    """A particle on a plane tilted 20 degrees: mu = 0.5 > tan 20 holds it (drift under 1 cm in
    1 s); mu = 0.1 lets it slide as 1/2 g (sin - mu cos) t^2, within 10 %."""
    theta = math.radians(20.0)
    normal = np.array([-math.sin(theta), math.cos(theta), 0.0])
    b = SceneBuilder()
    b.add_particles(0.01 * normal.reshape(1, 3), 0.01)  # at the contact radius
    b.set_gravity((0.0, -9.81, 0.0))
    b.set_plane((0.0, 0.0, 0.0), normal, restitution=0.0, friction=0.5)
    scene = b.finalize(name="slope", params={}, default_dt=H, default_integrator="vbd")
    vbd = create_integrator("vbd", scene.system, contact_radius=0.01)
    vbd.bind_contact(scene.contact_inputs())
    for mu, expected in ((0.5, None), (0.1, 0.5 * 9.81 * (math.sin(theta) - 0.1 * math.cos(theta)))):
        scene.plane.friction[None] = mu
        scene.reset()
        vbd.reset()
        start = scene.state.to_numpy()[0][0]
        for k in range(60):
            assert vbd.step(scene.state, k * H, H).status.value == "ok"
        x = scene.state.to_numpy()[0][0]
        along = float(np.linalg.norm((x - start) - (x - start).dot(normal) * normal))
        assert (x - scene.plane.point_np).dot(normal) > 0.0
        if expected is None:
            assert along < 0.01, along
        else:
            assert abs(along - expected) < 0.1 * expected, (along, expected)


@pytest.mark.parametrize("option, value", [
    ("contact_radius", 0.0), ("contact_radius", -1.0), ("contact_stiffness", 0.0),
    ("bound_fraction", 0.5), ("bound_fraction", 0.0), ("friction_epsilon", float("nan")),
    ("contact_refresh", -1), ("self_contact", "yes"), ("contact", 1), ("contact_pieces", 0),
    ("contact_pieces", 2.5), ("object_faces", "no"),
])
def test_bad_contact_options_are_refused_by_name(f64, option, value):
    scene = ts.build_scene("cloth", {"nx": 3, "ny": 3})
    with pytest.raises(ConfigError, match=option):
        create_integrator("vbd", scene.system, **{option: value})


def test_a_contact_radius_the_mesh_cannot_take_and_a_tangled_start_are_refused(f64):
    scene = fold(n=8)  # spacing 1/7 m: non-adjacent parts 0.1 m apart at rest
    vbd = create_integrator("vbd", scene.system, self_contact=True, contact_radius=0.2)
    with pytest.raises(ConfigError, match="contact_radius"):
        vbd.bind_contact(scene.contact_inputs())
    scene = shot_scene()
    x, v = scene.state.to_numpy()
    x[3:6, 1] -= 0.5  # T2's lower edge through T1
    scene.state.from_numpy(x, v)
    tangled = create_integrator("vbd", scene.system, self_contact=True, contact_radius=0.01)
    with pytest.raises(ConfigError, match="starts passing through itself"):
        tangled.bind_contact(scene.contact_inputs())


@pytest.mark.parametrize("option, problem", [
    ("contact_radius=0.2", "contact_radius"),  # above the 8 x 8 grid's 0.101 m between non-adjacent parts
    ("contact_radius=0", "contact_radius"), ("bound_fraction=0.5", "bound_fraction"),
    ("contact_refresh=-1", "contact_refresh"), ("contact_stiffness=-3", "contact_stiffness"),
    ("contact_pieces=0", "contact_pieces"),
])
def test_the_command_line_refuses_bad_contact_options_in_one_line_and_writes_nothing(tmp_path, capsys, option,
                                                                                      problem):
    from taichi_sim.cli import main

    code = main(["simulate", "cloth-fold", "--set", "nx=8", "--set", "ny=8", "--set", "self_collision=0",
                 "--integrator", "vbd", "--option", "self_contact=1", "--option", option, "--dt", "0.02",
                 "--steps", "2", "--out", str(tmp_path / "run.npz"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert problem in err and len(err.splitlines()) == 1 and err.startswith("taichi-sim: error:")
    assert list(tmp_path.iterdir()) == []


def test_a_run_with_contact_in_the_solve_is_measured_with_its_contact(f64):
    # the contact's penalties are part of vbd's equation and of the estimate's model: a run
    # swept to convergence reads as solved (measured without them, it read 0.86 "not converged")
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 4, "pin": "none", "plane": True, "height": 0.05})
    for options in ({}, {"self_contact": True, "contact_radius": 0.01}):
        result = ts.run(scene, create_integrator("vbd", scene.system, iterations=400, **options), dt=1 / 60,
                        steps=3)
        assert result.residual_note == "" and len(result.solver_residual) > 0
        assert result.worst_error_estimate < 1e-6 and not result.warnings
