"""The cloth's self-contact stage (taichi_sim.collide), judged by the exact intersection check."""
import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.collide import SelfCollision
from taichi_sim.errors import ConfigError
from taichi_sim.geometry import self_intersections
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.colliders import SpherePath


def stage_of(scene):
    (stage,) = [e for e in scene.post_step if isinstance(e, SelfCollision)]
    return stage


@pytest.mark.long
def test_a_falling_vertex_rests_on_a_triangle_at_the_thickness(f64):
    b = SceneBuilder()
    b.add_particles(np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [0.2, 0.5, 0.2]], float), 0.01,
                    pinned=np.array([1, 1, 1, 0], bool))
    b.add_triangles(np.array([[0, 2, 1]]))
    b.set_gravity(9.8)
    b.enable_self_collision(0.01, 0.0, 4)
    scene = b.finalize(name="t", params={}, default_dt=1e-3, default_integrator="symplectic_euler")
    result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=600)
    x, v = scene.state.to_numpy()
    assert result.status.value == "ok"
    assert x[3] == pytest.approx([0.2, 0.01, 0.2], abs=1e-9) and abs(v[3, 1]) < 1e-9  # resting, not bouncing
    assert stage_of(scene).contacts_total > 0 and stage_of(scene).overflow_total == 0


@pytest.mark.long
def test_lists_that_fill_up_grow_instead_of_dropping_pairs(f64, monkeypatch):
    from taichi_sim.collide import self_contact
    monkeypatch.setattr(self_contact, "PAIRS_PER_PRIMITIVE", 1)
    monkeypatch.setattr(self_contact, "TOUCHES_PER_VERTEX", 0)
    scene = ts.build_scene("cloth-fold", {"nx": 12, "ny": 12})
    stage, n = stage_of(scene), scene.particle_count
    # XPBD: implicit_euler, whose steps are solved to its tolerance since 2026-11-26, folds this
    # cloth for 2 s without a step that needs impact zones
    ts.run(scene, "xpbd", dt=1 / 60, steps=45)
    assert stage.zone_steps > 0 and stage.overflow_total == 0 and stage.unresolved_total == 0
    assert stage.vt_pairs.shape[0] > n and stage.collided.shape[0] > 0  # they grew
    x, _ = scene.state.to_numpy()
    assert self_intersections(x, scene.mesh.triangles_np).count == 0


def test_a_vertex_crossing_many_cells_in_one_step_is_still_caught(f64):
    """A vertex moving ten triangle sizes in one step: its swept box is longer than the hash's
    cells allow (4 per axis), so the cells grow for that step instead of clipping the box."""
    b = SceneBuilder()
    b.add_particles(np.array([[0, 0.3, 0], [0.1, 0.3, 0], [0, 0.3, 0.1], [0.02, 0.5, 0.02]], float), 0.01,
                    v=np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, -60.0, 0]]),
                    pinned=np.array([1, 1, 1, 0], bool))
    b.add_triangles(np.array([[0, 2, 1]]))
    b.enable_self_collision(0.01, 0.0, 4)
    scene = b.finalize(name="t", params={}, default_dt=1 / 60, default_integrator="symplectic_euler")
    ts.run(scene, "symplectic_euler", dt=1 / 60, steps=1)  # from y = 0.5 to y = -0.5 unchecked
    x, _ = scene.state.to_numpy()
    assert x[3, 1] > 0.3  # stopped above the triangle it would have passed through
    assert stage_of(scene).overflow_total == 0


@pytest.mark.long
@pytest.mark.parametrize("self_collision", [True, False])
def test_a_folding_cloth_does_not_pass_through_itself(f64, self_collision):
    scene = ts.build_scene("cloth-fold", {"nx": 12, "ny": 12, "self_collision": self_collision})
    result = ts.run(scene, "symplectic_euler", dt=1e-3, t_end=1.0, save_every=10)
    assert result.status.value == "ok" and len(result.x_history) == 101
    counts = [self_intersections(x, scene.mesh.triangles_np).count for x in result.x_history]
    if self_collision:
        assert max(counts) == 0
    else:  # the scene does fold through itself without the stage (34 of 101 frames when written)
        assert sum(c > 0 for c in counts) > 10
    assert result.energy.max() <= result.energy[0] * (1 + 1e-9)  # contacts never add energy here


@pytest.mark.long
def test_self_collision_works_with_tearing_and_is_paid_for_only_where_asked(f64):
    torn = ts.build_scene("cloth-tear", {"nx": 10, "ny": 10, "self_collision": True})
    assert ts.run(torn, "symplectic_euler", dt=1e-3, steps=300).status.value == "ok"
    assert torn.features["self_collision"] and stage_of(torn).overflow_total == 0
    plain = ts.build_scene("cloth", {"nx": 6, "ny": 6})
    assert not plain.features["self_collision"]
    assert not any(isinstance(e, SelfCollision) for e in plain.post_step)


def test_bad_parameters_are_named(f64):
    with pytest.raises(ConfigError, match="thickness"):
        ts.build_scene("cloth-fold", {"nx": 4, "ny": 4, "thickness": 0.0})
    with pytest.raises(ConfigError, match="collision_iterations"):
        ts.build_scene("cloth-fold", {"nx": 4, "ny": 4, "collision_iterations": 0})
    with pytest.raises(ConfigError, match="self_friction"):
        ts.build_scene("cloth-fold", {"nx": 4, "ny": 4, "self_friction": -1.0})
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 4})
    for kwargs, name in (({"thickness": float("nan")}, "thickness"), ({"thickness": 0.01, "friction": -1}, "self_friction"),
                         ({"thickness": 0.01, "iterations": 0}, "collision_iterations")):
        with pytest.raises(ValueError, match=name):
            SelfCollision(scene.system, scene.mesh, scene.x0, **kwargs)


@pytest.mark.long
@pytest.mark.parametrize("integrator", ["implicit_euler",
                                        pytest.param("projective_dynamics", marks=pytest.mark.cpu_only)])
def test_a_32_cloth_folds_300_frames_at_one_step_a_frame_without_intersecting(f32, integrator):
    # frame-sized steps (h = 1/60 s) move vertices by centimetres, several times the thickness:
    # only the continuous detection and the impact zones keep this clean (the contact rounds alone
    # left 29-31 of 61 frames of a 12 x 12 fold intersecting)
    scene = ts.build_scene("cloth-fold", {"nx": 32, "ny": 32})
    stage = stage_of(scene)
    kinetic_gain = []

    def watched(state, t, h, call=stage.__call__):
        before = scene.system.kinetic_energy(state)
        changed = call(state, t, h)
        kinetic_gain.append(scene.system.kinetic_energy(state) - before)
        return changed

    scene.post_step[scene.post_step.index(stage)] = watched
    result = ts.run(scene, integrator, dt=1 / 60, steps=300, save_every=1)
    assert result.status.value == "ok" and len(result.x_history) == 301
    counts = [self_intersections(x, scene.mesh.triangles_np).count for x in result.x_history]
    assert max(counts) == 0
    assert min(x[:, 1].min() for x in result.x_history) >= 0.0  # never pressed through the ground
    assert stage.zone_steps > 0 and stage.unresolved_total == 0 and stage.overflow_total == 0
    # inelastic contacts, friction and rigid zones only take kinetic energy away (f32 round-off aside)
    assert len(kinetic_gain) == 300 and max(kinetic_gain) <= 1e-4 * result.energy[0]


@pytest.mark.long
def test_the_cli_says_what_the_stage_did_and_warns_when_it_could_not_keep_its_promise(f64, tmp_path, capsys):
    from taichi_sim.cli import main

    out = tmp_path / "fold.npz"
    assert main(["simulate", "cloth-fold", "--set", "nx=6", "--set", "ny=6", "--integrator", "implicit_euler",
                 "--dt", "0.0166666666666667", "--steps", "40", "--precision", "f64", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "cloth-fold: self-contact:" in captured.out and "impact zones in" in captured.out
    assert "warning" not in captured.err
    scene = ts.build_scene("cloth-fold", {"nx": 4, "ny": 4})
    stage = stage_of(scene)
    assert stage.warning() == ""
    stage.unresolved_total = 2
    assert "2 touch(es) left unresolved" in stage.warning() and "taichi-sim check" in stage.warning()


def test_out_of_zone_rounds_the_whole_cloth_moves_rigidly_and_nothing_intersects(f64, monkeypatch):
    from taichi_sim.collide import self_contact

    monkeypatch.setattr(self_contact, "MAX_ZONE_ROUNDS", 1)  # every step needing zones runs out
    scene = ts.build_scene("cloth-fold", {"nx": 12, "ny": 12})
    result = ts.run(scene, "xpbd", dt=1 / 60, steps=45, save_every=1)  # implicit_euler needs no zones here
    stage = stage_of(scene)
    assert stage.zone_fallbacks > 0 and stage.unresolved_total == 0
    assert "whole cloth rigid" in stage.summary()
    assert max(self_intersections(x, scene.mesh.triangles_np).count for x in result.x_history) == 0


class _Press:
    """Kinematic pins moving down at ``speed`` (m/s) for ``duration`` s, then holding still."""

    def __init__(self, x0, speed: float, duration: float):
        self.x0, self.speed, self.duration = np.asarray(x0, float), speed, duration

    def at(self, t: float):
        x = self.x0.copy()
        x[:, 1] -= self.speed * min(max(t, 0.0), self.duration)
        v = np.zeros_like(x)
        if t < self.duration:
            v[:, 1] = -self.speed
        return x, v

    def fastest_speed(self) -> float:
        return self.speed

    def farthest_travel(self) -> float:
        return self.speed * self.duration


def test_a_pinned_triangle_pressing_a_vertex_onto_the_floor_is_blocked_and_never_passes_it(f64, monkeypatch):
    """The floor rule (no push into the floor for a vertex within the thickness of it) and the
    pins leave the contact nothing to move: it is counted as blocked, the fail-safe runs, and
    the vertex stays under the triangle and on the floor while the triangle comes down to
    0.4 of the thickness above the floor."""
    triangle = np.array([[-0.2, 0.03, -0.2], [-0.2, 0.03, 0.3], [0.3, 0.03, -0.2]])
    b = SceneBuilder()
    b.add_particles(np.vstack([triangle, [[0.0, 0.004, 0.0]]]), 0.01, pinned=np.array([1, 1, 1, 0], bool))
    b.add_triangles(np.array([[0, 1, 2]]))
    b.set_gravity(9.8)
    b.set_plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), restitution=0.0)
    b.enable_self_collision(0.01, 0.0, 4)
    b.add_kinematic([0, 1, 2], _Press(triangle, speed=1.0, duration=0.026))  # from 3 cm down to 4 mm
    scene = b.finalize(name="t", params={}, default_dt=1 / 240, default_integrator="symplectic_euler")
    stage = stage_of(scene)
    seen = []  # (blocked contacts, rounds clean) of each step, as the fail-safe is called
    fail_safe = stage._fail_safe

    def spy(state, h, rounds_clean):
        seen.append((int(stage.blocked[None]), rounds_clean))
        fail_safe(state, h, rounds_clean)

    monkeypatch.setattr(stage, "_fail_safe", spy)
    result = ts.run(scene, "symplectic_euler", dt=1 / 240, steps=24, save_every=1)
    assert result.status.value == "ok"
    assert any(blocked > 0 for blocked, _ in seen)
    assert all(not clean for blocked, clean in seen if blocked > 0)  # a blocked step is never clean
    for x in result.x_history:
        assert x[3, 1] < x[0, 1]  # under the triangle: never passed through it
        assert x[3, 1] >= -1e-12  # and never pushed through the floor


def _press_onto_sphere(keep_out_of_objects: bool, monkeypatch):
    """A pinned triangle pressed down onto a free vertex lying on top of a sphere (r = 0.3 m,
    thickness 0.01 m): the positions of every step, and the stage."""
    triangle = np.array([[-0.2, 0.33, -0.2], [-0.2, 0.33, 0.3], [0.3, 0.33, -0.2]])
    b = SceneBuilder()
    b.add_particles(np.vstack([triangle, [[0.0, 0.304, 0.0]]]), 0.01, pinned=np.array([1, 1, 1, 0], bool))
    b.add_triangles(np.array([[0, 1, 2]]))
    b.set_gravity(9.8)
    b.add_sphere(SpherePath((0.0, 0.0, 0.0)), 0.3)
    b.enable_self_collision(0.01, 0.0, 4)
    b.add_kinematic([0, 1, 2], _Press(triangle, speed=1.0, duration=0.026))  # from 3 cm down to 4 mm
    scene = b.finalize(name="t", params={}, default_dt=1 / 240, default_integrator="symplectic_euler")
    stage = stage_of(scene)
    if not keep_out_of_objects:  # the stage as it was: blind to the sphere
        monkeypatch.setattr(stage, "obstacles", ())
        monkeypatch.setattr(stage.zones, "push_out", None)
    result = ts.run(scene, "symplectic_euler", dt=1 / 240, steps=24, save_every=1)
    assert result.status.value == "ok"
    return result.x_history, stage


@pytest.mark.parametrize("keep_out", [True, False])
def test_a_triangle_pressing_a_vertex_onto_a_sphere_never_pushes_it_in(f64, monkeypatch, keep_out):
    """The objects' rules (``collide/objects.py``): a contact does not push a vertex within the
    thickness of a sphere towards it, and a vertex or zone the stage would leave inside is put
    back on the surface. The vertex stays under the triangle and out of the sphere every step;
    blind to the sphere, the stage presses it 6 mm in (the control, so the test can fail)."""
    history, stage = _press_onto_sphere(keep_out, monkeypatch)
    inside = min(float(np.linalg.norm(x[3])) for x in history) - 0.3
    if keep_out:
        assert inside >= -1e-9, inside
        assert stage.contacts_total > 0
        for x in history:
            assert x[3, 1] < x[0, 1]  # under the triangle: never passed through it
    else:
        assert inside < -1e-3, inside


@pytest.mark.long
@pytest.mark.parametrize("self_collision", [True, False])
def test_cloth_spin_slides_off_its_sphere_without_intersecting(f64, self_collision):
    """The sliding scene (a cloth dragged round by a spinning sphere until it slides off onto
    the ground), 16 x 16 at one step a frame: with the stage (the preset's default) no frame
    has intersecting triangles and no vertex is inside the sphere; without it the cloth passes
    through itself as it slides off (measured: 170 of 241 frames over 4 s)."""
    scene = ts.build_scene("cloth-spin", {"nx": 16, "ny": 16, "self_collision": self_collision})
    result = ts.run(scene, "implicit_euler", dt=1 / 60, steps=120, save_every=1)
    assert result.status.value == "ok"
    counts = [self_intersections(x, scene.mesh.triangles_np).count for x in result.x_history]
    centre, radius = scene.arrays["sphere_center"][0], scene.params["sphere_radius"]
    gap = min(float(np.linalg.norm(x - centre, axis=1).min()) for x in result.x_history) - radius
    if self_collision:
        assert max(counts) == 0 and gap >= -1e-9
        assert stage_of(scene).unresolved_total == 0 and stage_of(scene).overflow_total == 0
    else:
        assert max(counts) > 0


def test_contact_rounds_stop_when_a_round_closes_too_little_of_the_overlap(f64, monkeypatch):
    """Jacobi rounds on a dense pile close little of the contacts' summed overlap each: a round
    leaving more than STALLED_ROUND of the overlap the round before left ends the rounds (the
    fail-safe finishes), and rounds that still close much go on up to ``collision_iterations``."""
    from taichi_sim.collide import self_contact

    # a 24 x 24 fold's rounds close 25-60 % of the overlap each (the 64 x 64 pile's that stall,
    # 7-16 %, take minutes): a stricter share makes both kinds of step happen in seconds
    monkeypatch.setattr(self_contact, "STALLED_ROUND", 0.6)
    scene = ts.build_scene("cloth-fold", {"nx": 24, "ny": 24, "collision_iterations": 8})
    stage = stage_of(scene)
    steps, resolve = [], stage._resolve

    def counted(state, first_round, vt, ee):
        if first_round:
            steps.append([])
        found = resolve(state, first_round, vt, ee)
        steps[-1].append((found, float(stage.overlap[None])))
        return found

    monkeypatch.setattr(stage, "_resolve", counted)
    result = ts.run(scene, "implicit_euler", dt=1 / 60, steps=60, save_every=1)
    assert result.status.value == "ok"
    for rounds in steps:
        overlap = [left for _, left in rounds]
        for k in range(1, len(rounds) - 1):  # every round but the last closed enough to go on
            assert overlap[k] <= self_contact.STALLED_ROUND * overlap[k - 1]
        if len(rounds) < 8:  # stopped early: no contact left, or the last round stalled
            assert rounds[-1][0] == 0 or overlap[-1] > self_contact.STALLED_ROUND * overlap[-2]
    assert any(len(rounds) < 8 and rounds[-1][0] > 0 for rounds in steps)  # stalls happen here
    assert any(len(rounds) > 2 for rounds in steps)  # and rounds that close much go on
    assert max(self_intersections(x, scene.mesh.triangles_np).count for x in result.x_history) == 0
