"""The serial sweeps' active set (taichi_sim/integrators/positional/vbd/active.py): a vertex that
moves marks the vertices whose blocks read it, settled vertices are passed by, and the answer
stays that of the full sweeps. Small scenes: kernel compilation dominates."""

import numpy as np
import pytest
import taichi as ti
from helpers import step_checked

import taichi_sim as ts
from taichi_sim.geometry import self_intersections
from taichi_sim.integrators import create_integrator

H = 1 / 60


def fold(n: int = 12):
    """cloth-fold without the post-step self-collision stage (the solve's self-contact instead)."""
    return ts.build_scene("cloth-fold", {"nx": n, "ny": n, "self_collision": False, "jitter": 0.002})


def test_a_vertex_that_moves_marks_itself_its_element_neighbours_and_its_contact_partners(f64):
    scene = fold(12)
    vbd = create_integrator("vbd", scene.system, self_contact=True)
    step_checked(scene, vbd, H, 45)  # landed: the layers touch
    contact, active = vbd.contact, vbd.active
    counts = np.minimum(contact.vertex_pair_count.to_numpy(), contact.per_vertex)
    pair_ids, pair_slots = contact.pair_ids.to_numpy(), contact.vertex_pairs.to_numpy()
    ends = scene.system.term("springs").ends_np

    def marked(i):
        """What a move of vertex i must mark: itself, its springs' other ends, its pairs' vertices."""
        partners = {int(j) for s in pair_slots[i, :counts[i]] for j in pair_ids[s]}
        springs = {int(j) for a, b in ends for j in (a, b) if i in (a, b)}
        return partners | springs | {i}, len(partners - springs - {i})

    i = max(np.flatnonzero(counts), key=lambda i: marked(i)[1])  # the most partners beyond its springs
    expected_set, beyond = marked(i)
    assert beyond > 0
    expected = np.zeros(scene.system.particle_count, bool)
    expected[list(expected_set)] = True

    @ti.kernel
    def move(i: ti.i32, distance: ti.f64):
        for j in range(scene.system.particle_count):
            active.stale[j] = 0
        active.moved(i, distance, contact, True)

    move(i, 2 * vbd.skip_move)
    np.testing.assert_array_equal(active.stale.to_numpy().astype(bool), expected)
    move(i, 0.5 * vbd.skip_move)  # a settled step marks nothing
    assert not active.stale.to_numpy().any()
    # the threshold is read as the sweeps run (a run's tolerance lowers it): the same move
    # marks once it is lowered below it
    vbd.skip_move = 0.25 * vbd.skip_move
    move(i, 2 * vbd.skip_move)
    np.testing.assert_array_equal(active.stale.to_numpy().astype(bool), expected)


def test_the_active_set_passes_settled_vertices_by_and_keeps_the_fold(f32):
    """A 16 x 16 fold over its first second (the fall, the landing, the pile): the active set
    solves well under half the vertex steps of the full sweeps, and the fold keeps its pace
    (mean height within 5 mm at every quarter second) with no intersecting frame."""
    heights, solves = {}, {}
    for skip in (0.0, 1e-5):
        scene = fold(16)
        vbd = create_integrator("vbd", scene.system, self_contact=True, skip_move=skip)
        tris = scene.mesh.triangles_np
        marks = []

        def check(scene, marks=marks):
            x = scene.state.to_numpy()[0]
            assert not len(self_intersections(x, tris).pairs)
            marks.append(float(x[:, 1].mean()))

        step_checked(scene, vbd, H, 60, check)
        heights[skip] = np.asarray(marks[14::15])
        full = vbd.pieces * vbd.iterations * scene.system.particle_count
        solves[skip] = full if vbd.active is None else int(vbd.active.solves[None])
        assert (vbd.active is None) == (skip == 0.0)
    assert solves[1e-5] < 0.5 * solves[0.0], solves
    np.testing.assert_allclose(heights[1e-5], heights[0.0], atol=5e-3)


@pytest.mark.parametrize("options, scene_params", [
    ({"chebyshev_rho": 0.5}, {}),
    ({"augmented": True}, {}),
    ({}, {"wind": True}),  # wind pushes a vertex by its triangles' corners
    ({"skip_move": 0.0}, {}),
])
def test_no_active_set_where_a_sweep_moves_every_vertex_or_a_force_reads_others(f64, options, scene_params):
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, **scene_params})
    assert create_integrator("vbd", scene.system, **options).active is None
    assert create_integrator("vbd", scene.system).active is not None or scene_params


@pytest.mark.parametrize("preset, used", [("cloth-fold", True), ("cloth-twist", False), ("cloth-spin", False)])
def test_the_active_set_passes_vertices_by_only_where_nothing_else_moves(f64, preset, used):
    # A turning pin or a spinning sphere changes a vertex's block with no cloth vertex moving:
    # a vertex passed by would miss it (a kicking leg reached into a skirt's faces so).
    scene = ts.build_scene(preset, {"nx": 8, "ny": 8})
    vbd = create_integrator("vbd", scene.system)
    scene.hand_over(vbd.bind_contact(scene.contact_inputs()))
    assert vbd.has_self_contact and vbd.active is not None
    assert vbd.uses_active_set is used
    assert ("skip_move" in dict(vbd.work_options)) is used
    step_checked(scene, vbd, H, 2)
    assert (int(vbd.active.solves[None]) > 0) is used  # the sweeps counted through the set or not
