"""The implicit methods' linear solvers: preconditioned CG (block Jacobi, block SSOR, warm starts,
the in-kernel and the GPU-style loop), the sparse Cholesky solve (one analysis per pattern), the
Newton-Krylov fallback, and the force Jacobians they all rest on. Most tests drive them through
the one-step method (``implicit_euler_linearised``), where the step IS one linear solve."""

import numpy as np
import pytest
import taichi as ti

import taichi_sim as ts
from taichi_sim.forces import ForceTerm
from taichi_sim.integrators import Status, create_integrator
from taichi_sim.integrators.implicit.common import FORCING_CEILING, LINEARISED_CG_TOLERANCE, forcing_tolerance
from taichi_sim.scene.cloth import fixed_particle_cloth

LINEARISED = "implicit_euler_linearised"
STIFF_CLOTH = {"nx": 12, "ny": 12, "stiffness": 1e8, "shear_stiffness": 1e8, "flex_stiffness": 1e8}


@pytest.mark.cpu_only  # the direct solver
def test_direct_and_cg_agree_to_their_tolerances(f64):
    # One step from rest: the step solves A dv = b with b = h f0 (zero on pinned particles) and
    # A - M positive semi-definite, so |A^-1| <= 1/min(m). Two solutions with relative residuals
    # r1, r2 differ by at most (r1 + r2) |b| / min(m).
    h = 1 / 60
    params = {"nx": 10, "ny": 10, "jitter": 0.01}
    velocities, reports = {}, {}
    for solver in ("cg", "direct"):
        scene = ts.build_scene("cloth", params, seed=3)
        force = ti.Vector.field(3, ti.f64, shape=scene.particle_count)
        scene.system.forces(scene.state, force)
        rhs_norm = h * np.linalg.norm(force.to_numpy())
        integrator = create_integrator(LINEARISED, scene.system, linear_solver=solver)
        reports[solver] = integrator.step(scene.state, 0.0, h)
        assert reports[solver].status is Status.OK
        velocities[solver] = scene.state.v.to_numpy()
    # A factorisation in f32 (Taichi's default) could not get the residual below ~1e-7.
    assert reports["direct"].linear_residual < 1e-12
    residuals = reports["cg"].linear_residual + reports["direct"].linear_residual
    bound = residuals * rhs_norm / scene.arrays["mass"].min()
    assert np.linalg.norm(velocities["cg"] - velocities["direct"]) <= bound


@pytest.mark.cpu_only  # the direct solver
def test_direct_solver_analyses_once_per_pattern_and_factorises_every_solve(f64):
    scene = ts.build_scene("cloth", {"nx": 8, "ny": 8})
    integrator = create_integrator(LINEARISED, scene.system, linear_solver="direct")
    ts.run(scene, integrator, dt=1 / 60, steps=5)
    stats = integrator.stats
    assert (stats.solver, stats.analyze_count, stats.factorize_count) == ("cholesky", 1, 5)
    phases = stats.assemble_seconds + stats.analyze_seconds + stats.factorize_seconds + stats.substitute_seconds
    assert min(stats.assemble_seconds, stats.factorize_seconds, stats.substitute_seconds) > 0
    assert stats.solve_seconds >= phases
    scene.system.term("springs").topology_version += 1  # what tearing does
    integrator.step(scene.state, 0.0, 1 / 60)
    assert (stats.analyze_count, stats.factorize_count) == (2, 6)
    integrator.invalidate_pattern()
    integrator.step(scene.state, 0.0, 1 / 60)
    assert (stats.analyze_count, stats.factorize_count) == (3, 7)


@pytest.mark.cpu_only  # the direct solver
def test_tearing_triggers_a_new_analysis_and_the_solve_stays_exact(f64):
    scene = ts.build_scene("cloth", {"nx": 8, "ny": 8, "tear": True, "tear_strain": 0.01, "stiffness": 50.0})
    springs = scene.system.term("springs")
    integrator = create_integrator(LINEARISED, scene.system, linear_solver="direct")
    h, versions = 1 / 60, set()
    for k in range(20):
        versions.add(springs.topology_version)
        report = integrator.step(scene.state, k * h, h)
        assert report.status is Status.OK and report.linear_residual < 1e-12
        scene.after_step((k + 1) * h, h)
    assert springs.alive_count() < springs.spring_count, "the scene should have torn"
    assert integrator.stats.analyze_count == len(versions) > 1


@pytest.mark.cpu_only  # the direct solver
def test_newton_keeps_one_analysis_over_many_steps_and_matches_cg(f64):
    # Exact backward Euler: several factorisations per step, one analysis for the whole run.
    params = {"nx": 8, "ny": 8, "stiffness": 1e4, "shear_stiffness": 1e4, "flex_stiffness": 1e4}
    positions = {}
    for solver in ("direct", "cg"):
        scene = ts.build_scene("cloth", params, seed=0)
        integrator = create_integrator("implicit_euler", scene.system, linear_solver=solver,
                                       newton_tolerance=1e-9)
        assert ts.run(scene, integrator, dt=1 / 60, steps=10).status is Status.OK
        positions[solver] = scene.state.x.to_numpy()
        if solver == "direct":
            stats = integrator.stats
            assert stats.analyze_count == 1 and stats.factorize_count == stats.solves > 10
    # Both solve every step to the Newton tolerance, by different paths (exact solves against
    # Eisenstat-Walker CG solves): after 10 steps the positions differ by ~1e-9 m (measured
    # 8e-10 m; 3e-7 m at newton_tolerance=1e-6, 5e-12 m at 1e-11: it scales with the tolerance).
    assert np.abs(positions["direct"] - positions["cg"]).max() < 1e-7


def _matrix_from_market(path, size: int) -> np.ndarray:
    """The dense (size, size) matrix of a Matrix Market coordinate file (entries summed)."""
    lines = [line for line in path.read_text().splitlines() if line and not line.startswith("%")]
    entries = np.array([line.split() for line in lines[1:]], dtype=float).reshape(-1, 3)
    dense = np.zeros((size, size))
    np.add.at(dense, (entries[:, 0].astype(int) - 1, entries[:, 1].astype(int) - 1), entries[:, 2])
    return dense


def test_assembly_is_the_lower_triangle_of_the_matrix_free_product(f64, rng, tmp_path):
    # The direct solver assembles only the lower triangle (Eigen's LL^T reads only it); with its
    # mirror it must be the A whose product the residual check and CG use: springs stretched
    # and compressed (the clamp acts), dashpots, drag, a pinned set and a torn spring.
    scene = ts.build_scene("cloth", {"nx": 5, "ny": 5, "damping": 0.3, "area_drag": 2.5, "tear": True})
    springs = scene.system.term("springs")
    alive = springs.alive.to_numpy()
    alive[3] = 0
    springs.alive.from_numpy(alive)
    n = scene.particle_count
    state = scene.system.make_state()
    state.from_numpy(scene.x0 + rng.normal(scale=0.05, size=(n, 3)), rng.normal(size=(n, 3)))
    a, b = 1 / 60, 1 / 3600
    builder = ti.linalg.SparseMatrixBuilder(3 * n, 3 * n, max_num_triplets=scene.system.system_matrix_triplet_capacity,
                                            dtype=ti.f64)
    scene.system.assemble_system_matrix(state, a, b, 0.0, builder)
    builder.build().mmwrite(str(tmp_path / "a.mtx"))
    lower = _matrix_from_market(tmp_path / "a.mtx", 3 * n)
    assert not np.triu(lower, 1).any()
    matrix = lower + np.tril(lower, -1).T
    p = rng.normal(size=(n, 3))
    p[scene.arrays["pinned"]] = 0.0
    direction = ti.Vector.field(3, ti.f64, shape=n)
    direction.from_numpy(p)
    out = ti.Vector.field(3, ti.f64, shape=n)
    _system_matrix_product(scene.system, state, direction, out, a, b)
    expected = out.to_numpy().reshape(-1)
    # Pinned rows and columns are the identity's; their unknowns are zero in every solve.
    free = np.repeat(~scene.arrays["pinned"], 3)
    product = (matrix @ p.reshape(-1))[free]
    # mmwrite prints 6 significant digits: each entry is off by at most 5e-6 of itself.
    bound = 5e-6 * (np.abs(matrix) @ np.abs(p.reshape(-1)))[free] + 1e-15
    assert np.all(np.abs(product - expected[free]) <= bound)


@ti.kernel
def _system_matrix_product(system: ti.template(), y: ti.template(), p: ti.template(), out: ti.template(),
                           a: float, b: float):
    for i in out:
        out[i] = system.system_matrix_row(i, y, p, a, b, 0.0)


def test_a_failed_factorisation_is_reported(f64):
    # b < 0 (a negative step squared) turns the springs' stiffness into negative stiffness: A is
    # indefinite and the LL^T factorisation must say so, not return a solution.
    from taichi_sim.integrators.implicit.cholesky import SparseCholesky
    from taichi_sim.integrators.implicit.common import LinearSolverStats

    scene = ts.build_scene("cloth", {"nx": 4, "ny": 4, "stiffness": 1e4})
    n = scene.particle_count
    rhs = ti.Vector.field(3, ti.f64, shape=n)
    solution = ti.Vector.field(3, ti.f64, shape=n)
    rhs.fill(1.0)
    stats = LinearSolverStats("cholesky")
    outcome = SparseCholesky(scene.system, scene.state, rhs, solution).solve(0.0, -1.0, 0.0, 1e-8, 1, stats)
    assert not outcome.converged and not outcome.usable
    assert "not numerically positive definite" in outcome.message
    assert stats.factorize_count == 1


def test_cg_iteration_cap_is_not_converged_with_the_residual(f64):
    # A jittered stiff cloth: the block-Jacobi preconditioner alone is far from A^-1.
    scene = ts.build_scene("cloth", STIFF_CLOTH | {"jitter": 1e-3})
    integrator = create_integrator(LINEARISED, scene.system, cg_max_iterations=1)
    x0, v0 = scene.state.to_numpy()
    report = integrator.step(scene.state, 0.0, 1 / 30)
    assert report.status is Status.NOT_CONVERGED and not report.accepted
    assert report.linear_residual > integrator.cg_tolerance and report.linear_iterations == 1
    assert "cg_max_iterations=1" in report.message and f"{report.linear_residual:.3g}" in report.message
    x, v = scene.state.to_numpy()
    assert np.array_equal(x, x0) and np.array_equal(v, v0), "a failed step must leave the state alone"
    result = ts.run(scene, integrator, dt=1 / 30, steps=3)
    assert result.status is Status.NOT_CONVERGED and "cg_max_iterations=1" in result.message


@ti.kernel
def _force_jacobian_product(system: ti.template(), y: ti.template(), p: ti.template(), out: ti.template(),
                            a: float, b: float):
    for i in out:
        out[i] = system.force_jacobian_product(i, y, p, a, b, 0.0)


class _Probe:
    """A 5x5 cloth with dashpots, drag and a grab spring holding particle 12, and scratch fields
    (allocated once: every new field passed to a kernel compiles a new variant of it)."""

    def __init__(self):
        self.scene = ts.build_scene("cloth", {"nx": 5, "ny": 5, "damping": 0.3, "area_drag": 2.5, "grab": True})
        self.scene.system.term("grab").hold(12, [0.1, 1.2, 0.0])
        n = self.scene.particle_count
        self.state = self.scene.system.make_state()
        self.direction = ti.Vector.field(3, ti.f64, shape=n)
        self.out = ti.Vector.field(3, ti.f64, shape=n)

    def scaled_positions(self, scale: float, rng) -> np.ndarray:
        """Initial positions with every spring scaled by ``scale``, plus 1% noise (m)."""
        x = self.scene.x0
        centre = x.mean(axis=0)
        return centre + scale * (x - centre) + rng.normal(scale=0.01 * 0.25, size=x.shape)

    def random_direction(self, rng) -> np.ndarray:
        """A random (n, 3) direction, zero on pinned particles (as every vector of the solve is)."""
        p = rng.normal(size=self.scene.x0.shape)
        p[self.scene.arrays["pinned"]] = 0.0
        return p

    def jacobian_product(self, x, v, p, a, b) -> np.ndarray:
        """a df/dv p + b df/dx p at (x, v), by the system's analytic Jacobians (N)."""
        self.state.from_numpy(x, v)
        self.direction.from_numpy(p)
        _force_jacobian_product(self.scene.system, self.state, self.direction, self.out, a, b)
        return self.out.to_numpy()

    def forces(self, x, v) -> np.ndarray:
        self.state.from_numpy(x, v)
        self.scene.system.forces(self.state, self.out)
        return self.out.to_numpy()


def test_spring_jacobians_match_central_differences(f64, rng):
    # Springs, dashpots, drag and the grab spring together, through the system's sum.
    # Every spring stretched by 20%: the compression clamp is inactive, so df/dx is exact. The
    # dashpots' dependence on x (left out of df/dx) is proportional to relative velocity, so
    # df/dx is checked at rest; df/dv (dashpots and drag) at random velocities, where f is linear
    # in v. Central differences with eps = 1e-6 have error ~ eps^2 |d3f| + 1e-16 |f| / eps,
    # about 1e-9 of |J p| here.
    probe = _Probe()
    x = probe.scaled_positions(1.2, rng)
    v = rng.normal(size=x.shape)
    p = probe.random_direction(rng)
    eps = 1e-6
    for a, b, velocity in ((0.0, 1.0, np.zeros_like(v)), (1.0, 0.0, v)):
        analytic = probe.jacobian_product(x, velocity, p, a, b)
        plus = probe.forces(x + b * eps * p, velocity + a * eps * p)
        minus = probe.forces(x - b * eps * p, velocity - a * eps * p)
        numeric = (plus - minus) / (2 * eps)
        assert np.linalg.norm(analytic - numeric) <= 1e-6 * np.linalg.norm(numeric)


def test_compressed_spring_jacobian_is_negative_semidefinite(f64, rng):
    # Every spring compressed by 20%: the exact stiffness block has a positive transverse part
    # k (r/|d| - 1) (I - u u^T); the clamp drops it, so p . (df/dx p) <= 0 for every p, keeping
    # M - h df/dv - h^2 df/dx positive definite.
    probe = _Probe()
    x = probe.scaled_positions(0.8, rng)
    v = rng.normal(size=x.shape)
    for _ in range(5):
        p = probe.random_direction(rng)
        product = probe.jacobian_product(x, v, p, 0.0, 1.0)
        assert np.sum(p * product) <= 1e-12 * np.linalg.norm(p) * np.linalg.norm(product)


@ti.data_oriented
class _ForceWithoutJacobian(ForceTerm):
    """A term that declares no Jacobian, so the system falls back to the generic solver."""

    name = "no_jacobian"

    @ti.func
    def force(self, i, y, mass_i, t):
        return ti.Vector.zero(y.x.dtype, 3)


def test_newton_krylov_fallback_reaches_the_same_backward_euler_state(f64):
    # Both paths solve the same backward Euler equations, to relative residual 1e-12.
    h, states = 0.01, []
    for with_jacobian in (True, False):
        scene = ts.build_scene("pendulum", {"particle_count": 3})
        if not with_jacobian:
            scene.system.add_term(_ForceWithoutJacobian())
        integrator = create_integrator("implicit_euler", scene.system, newton_iterations=20,
                                       newton_tolerance=1e-12, cg_tolerance=1e-12)
        assert integrator.stats.solver == ("pcg" if with_jacobian else "gmres")
        assert ts.run(scene, integrator, dt=h, steps=5).status is Status.OK
        states.append(scene.state.to_numpy())
    np.testing.assert_allclose(states[1][0], states[0][0], atol=1e-9)
    np.testing.assert_allclose(states[1][1], states[0][1], atol=1e-7)


def test_wind_and_grab_scenes_use_the_jacobian_path(f64):
    # Wind declares zero Jacobians (not stiff: treated explicitly by the linearised step) and the
    # grab spring exact ones, so these scenes keep CG instead of finite-difference GMRES.
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, "wind": True, "grab": True})
    scene.system.term("grab").hold(20, [0.0, 1.5, 0.0])
    integrator = create_integrator("implicit_euler", scene.system)
    assert integrator.stats.solver == "pcg"
    assert ts.run(scene, integrator, dt=1 / 60, steps=5).status is Status.OK


@ti.kernel
def _cached_and_direct_rows(system: ti.template(), y: ti.template(), p: ti.template(), diagonal: ti.template(),
                            cached: ti.template(), split: ti.template(), direct: ti.template(), a: float, b: float):
    for i in cached:
        diagonal[i] = system.cache_system_matrix_row(i, y, a, b, 0.0)
    for i in cached:
        cached[i] = system.cached_system_matrix_row(i, y, p, a, b, 0.0, diagonal[i])
        split[i] = ti.Vector.zero(ti.f64, 3)
        if system.free[i]:
            split[i] = (diagonal[i] @ p[i] + system.cached_triangle_product(i, p, -1)
                        + system.cached_triangle_product(i, p, 1))
        direct[i] = system.system_matrix_row(i, y, p, a, b, 0.0)


def test_cached_system_matrix_equals_the_direct_evaluation(f64, rng):
    # The cache (A_ii and each spring's coefficients, filled once per Newton iteration) must give
    # the same A p as the gather that rebuilds every spring's block: springs (stretched and
    # compressed, so the clamp acts on some), dashpots, drag, the grab spring, pinned particles
    # and a torn spring.
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, "damping": 0.3, "area_drag": 3.6, "grab": True, "tear": True})
    scene.system.term("grab").hold(14, [0.1, 1.2, 0.0])
    springs = scene.system.term("springs")
    alive = springs.alive.to_numpy()
    alive[7] = 0
    springs.alive.from_numpy(alive)
    scene.system.bind_jacobian_cache()
    n = scene.particle_count
    x = scene.x0 + rng.normal(scale=0.05, size=(n, 3))
    v = rng.normal(size=(n, 3))
    p = rng.normal(size=(n, 3))
    p[scene.arrays["pinned"]] = 0.0
    state = scene.system.make_state()
    state.from_numpy(x, v)
    direction = ti.Vector.field(3, ti.f64, shape=n)
    direction.from_numpy(p)
    diagonal = ti.Matrix.field(3, 3, ti.f64, shape=n)
    cached = ti.Vector.field(3, ti.f64, shape=n)
    split = ti.Vector.field(3, ti.f64, shape=n)  # A_ii p_i + (L p)_i + (U p)_i, as SSOR's sweeps see A
    direct = ti.Vector.field(3, ti.f64, shape=n)
    h = 1 / 60
    _cached_and_direct_rows(scene.system, state, direction, diagonal, cached, split, direct, h, h * h)
    expected = direct.to_numpy()
    assert np.abs(expected).max() > 0
    np.testing.assert_allclose(cached.to_numpy(), expected, rtol=0, atol=1e-13 * np.abs(expected).max())
    np.testing.assert_allclose(split.to_numpy(), expected, rtol=0, atol=1e-13 * np.abs(expected).max())


def test_default_tolerances(f64):
    # Baraff-Witkin's linearised step is first order: its one solve stops at 1e-3. Exact backward
    # Euler on a particle system asks each solve for what its Newton residual warrants (no fixed
    # tolerance) and stops Newton at 1e-3; the midpoint rule, and any method on a system solved
    # by GMRES, solve tightly (their conservation and convergence need it).
    cloth = ts.build_scene("cloth", {"nx": 4, "ny": 4}).system
    circle = ts.build_scene("simple").system
    linearised = create_integrator(LINEARISED, cloth)
    assert linearised.cg_tolerance == LINEARISED_CG_TOLERANCE == 1e-3 and linearised.fixed_cg_tolerance
    exact = create_integrator("implicit_euler", cloth)
    assert not exact.fixed_cg_tolerance and exact.newton_tolerance == 1e-3
    assert create_integrator("implicit_euler", cloth, cg_tolerance=1e-6).fixed_cg_tolerance
    midpoint = create_integrator("implicit_midpoint", cloth)
    assert midpoint.cg_tolerance == 1e-8 and midpoint.fixed_cg_tolerance and midpoint.newton_tolerance == 1e-6
    on_circle = create_integrator("implicit_euler", circle)
    assert on_circle.cg_tolerance == 1e-8 and on_circle.fixed_cg_tolerance and on_circle.newton_tolerance == 1e-6
    assert create_integrator(LINEARISED, circle).cg_tolerance == 1e-8


def test_default_tolerances_in_f32(f32):
    cloth = ts.build_scene("cloth", {"nx": 4, "ny": 4}).system
    assert create_integrator(LINEARISED, cloth).cg_tolerance == 1e-3
    midpoint = create_integrator("implicit_midpoint", cloth)
    assert midpoint.cg_tolerance == 1e-5 and midpoint.newton_tolerance == 1e-5
    assert create_integrator("implicit_euler", cloth).newton_tolerance == 1e-3


def test_forcing_terms_tighten_with_the_residual():
    assert forcing_tolerance(1.0, 1e-3) == FORCING_CEILING
    assert forcing_tolerance(1e-4, 1e-3) == pytest.approx(1e-2)
    assert forcing_tolerance(1e-12, 1e-3) == pytest.approx(1e-4)  # a tenth of the Newton tolerance
    assert forcing_tolerance(float("nan"), 1e-3) == FORCING_CEILING


def test_tight_cg_tolerance_is_met(f64):
    # What the CLI test checked for CG before the one-step default became 1e-3, through the API.
    scene = ts.build_scene("cloth", {"nx": 8, "ny": 8})
    integrator = create_integrator(LINEARISED, scene.system, cg_tolerance=1e-9)
    for k in range(5):
        report = integrator.step(scene.state, k * 0.0166, 0.0166)
        assert report.status is Status.OK and 0 < report.linear_residual <= 1e-9


def _cloth_run(integrator, scene, steps, h=1 / 60):
    iterations = []
    for k in range(steps):
        report = integrator.step(scene.state, k * h, h)
        assert report.status is Status.OK, report.message
        iterations.append(report.linear_iterations)
    return iterations, scene.state.to_numpy()


def test_warm_start_saves_iterations_and_meets_the_tolerance(f64):
    # Starting CG from the velocity change extrapolated from the last two steps: fewer iterations on
    # a smoothly moving cloth (about 0.7 of a cold start here), and each solve still meets the
    # tolerance. One step from the same state, warm and cold: A - M is positive semi-definite, so
    # |A^-1| <= 1/min(m) and two solutions with relative residuals r1, r2 of A dv = b differ by at
    # most (r1 + r2) |b| / min(m).
    params = {"nx": 16, "ny": 16, "stiffness": 1e4, "shear_stiffness": 1e4, "flex_stiffness": 1e4}
    scene = ts.build_scene("cloth", params)
    integrators = {warm: create_integrator(LINEARISED, scene.system, warm_start=warm) for warm in (False, True)}
    iterations = {}
    for warm, integrator in integrators.items():
        scene.reset()
        iterations[warm] = _cloth_run(integrator, scene, 40)[0]
    cold, warm = iterations[False], iterations[True]
    assert warm[0] == cold[0], "the first step has nothing to start from"
    assert sum(warm[1:]) < 0.85 * sum(cold[1:])
    x, v = scene.state.to_numpy()  # after the warm run, at t = 40 h
    # The warm step first: both methods share the system's solver stage, whose extrapolation
    # history is the last steps it solved (after a cold step from this state it would already
    # hold this step's answer).
    changes, bounds, used = {}, [], {}
    for warm in (True, False):
        integrator = integrators[warm]
        scene.state.from_numpy(x, v)
        if not warm:
            integrator.reset()
        report = integrator.step(scene.state, 40 / 60, 1 / 60)
        assert report.status is Status.OK and report.linear_residual <= integrator.cg_tolerance
        changes[warm] = scene.state.v.to_numpy() - v
        used[warm] = report.linear_iterations
        bounds.append(report.linear_residual * np.linalg.norm(integrator._stage.rhs.to_numpy()))
    assert used[True] < used[False]
    difference = np.linalg.norm(changes[True] - changes[False])
    assert 0 < difference <= sum(bounds) / scene.arrays["mass"].min()


def test_runs_are_bit_reproducible_and_a_new_run_starts_cold(f64):
    # The CG iterations sum their dot products serially (a fixed order): the same run twice gives
    # the same bits. A run from t = 0 after one that ended elsewhere does not warm-start from it.
    scene = ts.build_scene("cloth", {"nx": 10, "ny": 10})
    integrator = create_integrator(LINEARISED, scene.system)
    first = _cloth_run(integrator, scene, 8)
    scene.reset()
    second = _cloth_run(integrator, scene, 8)
    assert first[0] == second[0]
    for a, b in zip(first[1], second[1]):
        assert np.array_equal(a.view(np.uint64), b.view(np.uint64))
    integrator.reset()  # also forgets the previous step
    scene.reset()
    assert _cloth_run(integrator, scene, 1)[0] == first[0][:1]


def test_warm_start_with_zero_right_hand_side_gives_zero_change(f64):
    # At rest at the rest length without gravity nothing moves: rhs = 0, and a warm guess left from
    # earlier motion must not leak into the step.
    scene = ts.build_scene("spring", {"gravity": 0.0, "stretch": 0.5})
    integrator = create_integrator(LINEARISED, scene.system)
    _cloth_run(integrator, scene, 3, h=0.01)
    x, v = scene.state.to_numpy()
    x[1] = [0.0, -1.0, 0.0]  # at the rest length, at rest
    scene.state.from_numpy(x, np.zeros_like(v))
    report = integrator.step(scene.state, 0.03, 0.01)
    assert report.status is Status.OK and report.linear_iterations == 0
    x1, v1 = scene.state.to_numpy()
    assert np.array_equal(x1, x) and np.all(v1 == 0.0)


def test_gpu_style_iteration_loop_matches_the_in_kernel_loop(f64):
    # GPU backends run one launch per CG iteration (block Jacobi) instead of the whole solve in one
    # kernel; on the CPU both are available and must take the same iterations to the same solution
    # (the dot products are summed in a different order, so only to rounding).
    results = {}
    for in_kernel in (True, False):
        scene = ts.build_scene("cloth", {"nx": 10, "ny": 10, "jitter": 0.01}, seed=3)
        integrator = create_integrator(LINEARISED, scene.system, cg_tolerance=1e-10,
                                       preconditioner="jacobi")
        integrator._stage.linear.in_kernel_loop = in_kernel
        results[in_kernel] = _cloth_run(integrator, scene, 3)
    (it_kernel, (x_kernel, v_kernel)), (it_python, (x_python, v_python)) = results[True], results[False]
    assert all(abs(a - b) <= 1 for a, b in zip(it_kernel, it_python))
    np.testing.assert_allclose(v_python, v_kernel, rtol=0, atol=1e-8)
    np.testing.assert_allclose(x_python, x_kernel, rtol=0, atol=1e-9)


@pytest.mark.parametrize("precision", ["f32", "f64"])
def test_ssor_and_jacobi_reach_the_same_step_within_their_tolerances(precision):
    # One step from rest, as in test_direct_and_cg_agree_to_their_tolerances: A - M is positive
    # semi-definite, so two solutions with relative residuals r1, r2 differ by at most
    # (r1 + r2) |b| / min(m), b = h f0. SSOR (Eisenstat's trick) reports the true residual
    # |b - A dv| like block Jacobi, and needs fewer iterations.
    ts.init(arch="cpu", precision=precision)
    h = 1 / 60
    params = {"nx": 16, "ny": 16, "jitter": 0.01, "stiffness": 1e4, "shear_stiffness": 1e4, "flex_stiffness": 1e4,
              **fixed_particle_cloth(16, 16)}
    changes, reports = {}, {}
    for preconditioner in ("jacobi", "ssor"):
        scene = ts.build_scene("cloth", params, seed=3)
        force = ti.Vector.field(3, ts.runtime.real(), shape=scene.particle_count)
        scene.system.forces(scene.state, force)
        rhs_norm = h * np.linalg.norm(force.to_numpy().astype(np.float64))
        integrator = create_integrator(LINEARISED, scene.system, preconditioner=preconditioner)
        assert integrator.stats.preconditioner == preconditioner
        reports[preconditioner] = integrator.step(scene.state, 0.0, h)
        assert reports[preconditioner].status is Status.OK
        assert reports[preconditioner].linear_residual <= integrator.cg_tolerance
        changes[preconditioner] = scene.state.v.to_numpy().astype(np.float64)
    assert reports["ssor"].linear_iterations < 0.6 * reports["jacobi"].linear_iterations
    bound = (reports["ssor"].linear_residual + reports["jacobi"].linear_residual) * rhs_norm
    assert np.linalg.norm(changes["ssor"] - changes["jacobi"]) <= bound / scene.arrays["mass"].min()


def test_ssor_is_the_cpu_default_and_meets_tight_tolerances(f64):
    scene = ts.build_scene("cloth", {"nx": 12, "ny": 12, "pin": "edge"})
    integrator = create_integrator("implicit_midpoint", scene.system)
    assert (integrator.stats.solver, integrator.stats.preconditioner) == ("pcg", "ssor")
    for k in range(5):
        report = integrator.step(scene.state, k / 60, 1 / 60)
        assert report.status is Status.OK and report.linear_residual <= integrator.cg_tolerance == 1e-8


