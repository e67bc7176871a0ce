"""Exact solutions and small utilities shared by the tests."""
import math

import numpy as np

import taichi_sim as ts
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.cloth import fixed_particle_cloth


def spring_exact(scene, t):
    """Exact (y, v_y) of the bob of the `spring` scene (a 1-D harmonic oscillator, no drag)."""
    p = scene.params
    k, m, g = p["stiffness"], p["particle_mass"], p["gravity"]
    omega = math.sqrt(k / m)
    sag = m * g / k
    amplitude = p["stretch"] - sag
    y = -(p["rest_length"] + sag) - amplitude * math.cos(omega * t)
    v = amplitude * omega * math.sin(omega * t)
    return y, v, omega


def fitted_order(hs, errors):
    """Least-squares slope of log(error) against log(h)."""
    return float(np.polyfit(np.log(hs), np.log(errors), 1)[0])


def run_fixed(scene, name, dt, t_end, **options):
    integrator = ts.create_integrator(name, scene.system, **options)
    scene.reset()
    return ts.run(scene, integrator, dt=dt, t_end=t_end, energy_every=0)


def step_checked(scene, integrator, dt, steps, check=None):
    """Step ``scene`` ``steps`` times with a :class:`taichi_sim.Stepper` (the house order: post-step
    events, the integrator's reset when they change the system, the blow-up guard), calling
    ``check(scene)`` after every step; any failure fails the test. The method steps at its own
    settings (no work raised for a tolerance: the tests judge its solve). Returns the stepper."""
    stepper = ts.Stepper(scene, integrator, dt, raise_work=False)
    while stepper.steps < steps:
        stepper.step()
        assert stepper.failure is None, stepper.failure.message
        if check is not None:
            check(scene)
    return stepper


class OffscreenWindows:
    """Fixtures for a test module that draws offscreen: one Taichi runtime for the module (CPU,
    f64) and a fresh window of ``size`` per test, destroyed after it (0.06 s each).

    One window shared by a module's tests made each test's frame depend on what earlier tests
    drew on it, and so on xdist's order of tests. GGUI supports one window at a time (closing
    one breaks the others), and a window must be destroyed while its runtime lives (one
    collected after ti.init crashes). Use as ``runtime, window, own_windows =
    OffscreenWindows(SIZE).fixtures()`` at module level.
    """

    def __init__(self, size):
        self.size = size
        self.current = None

    def release(self) -> None:
        if self.current is not None:
            window, self.current = self.current, None
            window.destroy()

    def _skip_without_vulkan(self) -> None:
        import pytest

        from taichi_sim.render import vulkan

        problem = vulkan.vulkan_problem()
        if problem:
            pytest.skip(f"no usable Vulkan: {problem}")

    def fixtures(self):
        import pytest

        from taichi_sim.render import open_window

        @pytest.fixture(scope="module")
        def runtime():
            ts.init(arch="cpu", precision="f64")
            yield
            self.release()

        @pytest.fixture
        def window(runtime):
            self.release()
            self._skip_without_vulkan()
            self.current = open_window("taichi_sim tests", self.size)
            yield self.current
            self.release()

        @pytest.fixture
        def own_windows(runtime):
            """For tests that open their own windows or call ti.init again."""
            self.release()
            self._skip_without_vulkan()

        return runtime, window, own_windows


def cloth(n: int, k: float, **extra) -> dict:
    """Parameters of an n x n cloth with structural stiffness k (N/m; shear k/2, flex k/5) and
    the tests' particles: 0.01 kg and 0.005 N s/m each at any n (fixed_particle_cloth)."""
    return {"nx": n, "ny": n, "stiffness": k, "shear_stiffness": k / 2, "flex_stiffness": k / 5,
            **fixed_particle_cloth(n, n), **extra}


def swinging(scene) -> None:
    """Give the scene's free particles a non-trivial velocity (m/s)."""
    v = np.zeros_like(scene.x0)
    v[:, 1] = 0.5 * np.sin(np.arange(len(v)))
    v[scene.static_arrays["pinned"]] = 0.0
    scene.state.from_numpy(scene.x0, v)


def cloth_builder(n=16, size=0.5, height=0.0, stiffness=5.0, mass=0.01):
    """A free horizontal n x n cloth of side ``size`` (m) at ``height``, soft enough for
    symplectic Euler at h = 10 ms."""
    x = topo.grid_positions(n, n, size, size, origin=(-size / 2, height, -size / 2),
                            u_axis=(1, 0, 0), v_axis=(0, 0, 1))
    b = SceneBuilder()
    b.add_particles(x, mass)
    ends, kind = topo.grid_springs(n, n)
    b.add_springs(ends, stiffness=stiffness, damping=0.0, kind=kind)
    b.add_triangles(topo.grid_triangles(n, n))
    return b


def slow_first_step(monkeypatch, integrator, seconds: float = 0.3) -> list:
    """Make ``integrator``'s first step (after each clearing of the returned list) take
    ``seconds`` longer, as compiling would; the list counts the calls."""
    import time

    step, calls = integrator.step, []

    def slow_first(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            time.sleep(seconds)
        return step(*args, **kwargs)

    monkeypatch.setattr(integrator, "step", slow_first)
    return calls
