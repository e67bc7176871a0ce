"""Hot loops on one thread for small systems: the choice, and that it changes no result."""
import numpy as np
import pytest
import taichi as ti

import taichi_sim as ts
from taichi_sim import runtime
from taichi_sim.integrators import create_integrator
from taichi_sim.integrators.positional import xpbd
from taichi_sim.loops import anchor


def test_the_choice_depends_on_the_backend_the_threads_and_the_size(monkeypatch):
    def choose(backend, threads, items, break_even=None):
        monkeypatch.setitem(runtime._current, "backend", backend)
        monkeypatch.setitem(runtime._current, "threads", threads)
        return runtime.serial_loops(items, break_even)

    limit = runtime.SERIAL_WORK
    assert choose("x64", 2, limit - 1) and not choose("x64", 2, limit)
    assert choose("x64", 1, 10 ** 9)  # one thread: every loop is serial anyway
    assert not choose("x64", 16, limit // 10)  # 15 spare threads: a tenth of the limit is past it
    assert choose("arm64", 3, 100, break_even=201) and not choose("arm64", 3, 100, break_even=200)
    for gpu in ("cuda", "vulkan", "metal"):
        assert not choose(gpu, 2, 1)  # a serial loop on a GPU is one GPU thread


@pytest.mark.parametrize("integrator,wind", [
    ("symplectic_euler", True), ("symplectic_euler", False), ("rk4", True), ("rk4", False),
    ("euler", False), ("xpbd", True), pytest.param("projective_dynamics", True, marks=pytest.mark.cpu_only)])
def test_serial_and_parallel_loops_give_the_same_trajectory(f64, monkeypatch, integrator, wind):
    """No loop that runs serial for small systems reduces into a shared value or reads what
    another iteration writes, so the order of its iterations cannot change the result; nor do
    the anchors that let the serial loops vectorise (without wind every force is local after
    the spring pass, and symplectic Euler takes its one-loop, anchored update). Equal to
    rounding, not always bit for bit: Taichi compiles with fast-math, which lets LLVM reassociate
    a sum in a vectorised loop, and on an AMD EPYC rk4's velocities differed in the last bit (35
    of 432 components after 30 steps, 4e-16 relative) where an Intel Xeon gave the same bits. A
    loop that read another iteration's writes would part by far more."""
    if runtime._current["threads"] <= 1:
        pytest.skip("one thread: every loop runs serial")
    dt = 1 / 60 if integrator in ("xpbd", "projective_dynamics") else 1e-3
    runs = []
    for serial in (True, False):
        monkeypatch.setattr(runtime, "SERIAL_WORK", 10 ** 12 if serial else 0)
        monkeypatch.setattr(xpbd, "SERIAL_SPRINGS", 10 ** 12 if serial else 0)
        # the grid's spring pass is serial on every CPU; parallel as on a GPU
        monkeypatch.setattr(runtime, "cpu_backend", lambda: serial)
        scene = ts.build_scene("cloth", {"nx": 12, "ny": 12, "wind": wind})
        method = create_integrator(integrator, scene.system)
        assert scene.system.serial_loops is serial
        assert all(term.serial_loops is serial for term in scene.system.terms)
        assert scene.springs.serial_pass is serial
        if integrator == "xpbd":
            assert method.serial is serial
        result = ts.run(scene, method, dt=dt, steps=30)
        assert result.status.value == "ok"
        runs.append(scene.state.to_numpy())
    for serial_run, parallel_run in zip(runs[0], runs[1]):  # positions, velocities
        scale = max(1.0, float(np.abs(parallel_run).max()))
        assert np.abs(serial_run - parallel_run).max() <= 1e-12 * scale


def test_a_grid_s_springs_leave_the_system_s_choice_to_its_particles(monkeypatch):
    """A grid's spring pass runs serial on a CPU anyway, so only the particles count towards
    the system's choice; a spring list (a cloth that tears) counts its springs."""
    monkeypatch.setitem(runtime._current, "threads", 2)
    grid = ts.build_scene("cloth", {"nx": 12, "ny": 12})
    listed = ts.build_scene("cloth", {"nx": 12, "ny": 12, "tear": True})
    assert grid.springs.serial_pass and not listed.springs.serial_pass
    particles = grid.system.particle_count
    monkeypatch.setattr(runtime, "SERIAL_WORK", particles + 1)  # past the particles, short of the springs
    assert ts.build_scene("cloth", {"nx": 12, "ny": 12}).system.serial_loops
    assert not ts.build_scene("cloth", {"nx": 12, "ny": 12, "tear": True}).system.serial_loops


def test_an_anchor_changes_no_field_of_any_shape(f64):
    """An anchor stores a field's first element to itself: every field keeps its values."""
    fields = [ti.field(ti.f64, shape=()), ti.Vector.field(3, ti.f64, shape=7),
              ti.field(ti.i32, shape=(3, 4)), ti.Vector.field(2, ti.f64, shape=(2, 3, 4))]
    values = [np.asarray(4.5), np.arange(21.0).reshape(7, 3), np.arange(12).reshape(3, 4),
              np.linspace(-1.0, 1.0, 48).reshape(2, 3, 4, 2)]
    for field, value in zip(fields, values):
        field.from_numpy(value)

    @ti.kernel
    def anchored_double():
        ti.loop_config(serialize=True)
        for _ in range(1):
            for field in ti.static(fields):
                anchor(field)
            for i in range(7):
                fields[1][i] = 2.0 * fields[1][i]

    anchored_double()
    values[1] = 2.0 * values[1]
    for field, value in zip(fields, values):
        assert np.array_equal(field.to_numpy(), value)


def acted(scene) -> dict:
    """Wrap each post-step event of ``scene`` to count the steps in which it changed something
    (the state, or the system: a torn spring); returns the counts by event class."""
    counts: dict = {}

    def watch(event):
        def call(state, t, h):
            before = state.to_numpy()
            changed = event(state, t, h)
            moved = not all(np.array_equal(b, a) for b, a in zip(before, state.to_numpy()))
            key = type(event).__name__
            counts[key] = counts.get(key, 0) + int(bool(changed) or moved)
            return changed
        return call

    scene.post_step[:] = [watch(event) for event in scene.post_step]
    return counts


@pytest.mark.parametrize("name,params", [
    ("cloth-sphere", {"capsule": True, "plane_height": 0.25}),
    ("cloth-tear", {"plane": False, "box": True, "box_y": 0.9, "box_half_y": 0.05, "sphere_y": 1.25, "sphere_speed": 2.0})])
def test_the_colliders_and_tearing_give_the_same_trajectory_serial_and_parallel(f64, monkeypatch, name, params):
    """The post-step events' loops (a sphere, a capsule, a box, the ground plane, their kept step
    starts, tearing) touch one particle or one spring an iteration, so running them on one
    thread changes no bit of a run in which every one of them acts."""
    if runtime._current["threads"] <= 1:
        pytest.skip("one thread: every loop runs serial")
    runs = []
    for serial in (True, False):
        monkeypatch.setattr(runtime, "SERIAL_WORK", 10 ** 12 if serial else 0)
        scene = ts.build_scene(name, {"nx": 12, "ny": 12, **params})
        colliders = [event for event in scene.post_step if hasattr(event, "serial")]
        assert len(colliders) >= 2 and all(event.serial is serial for event in colliders)
        assert all(event.start.serial is serial for event in colliders if hasattr(event, "start"))
        assert scene.system.serial_loops is serial  # the tearing springs' loop follows the system
        counts = acted(scene)
        result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=600)
        assert result.status.value == "ok"
        assert len(counts) == len(scene.post_step) and min(counts.values()) > 0, counts
        runs.append((*scene.state.to_numpy(), scene.arrays.get("alive")))
    for serial_run, parallel_run in zip(*runs):
        assert serial_run is None and parallel_run is None or np.array_equal(serial_run, parallel_run)
