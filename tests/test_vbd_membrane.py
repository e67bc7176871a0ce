"""vbd on a cloth as a material (docs/vbd.md, "Membranes"): the membrane's and bending's per-vertex
force and block against finite differences, the colouring that keeps a triangle's and a stencil's
vertices apart, the fixed point of the sweeps against implicit Euler's step solved tightly, and
the command line on the membrane presets."""
import numpy as np
import pytest
import taichi as ti

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.convergence import ConvergenceMonitor
from taichi_sim.forces.membrane import IsometricBending, Membrane, MembraneMaterial
from taichi_sim.integrators import create_integrator
from taichi_sim.integrators.positional.vbd.membranes import MembraneTerms
from taichi_sim.reference import membrane_energy
from taichi_sim.systems.particles import ParticleSystem

SQUARE = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.0, 0.2], [0.2, 0.0, 0.2]])
QUAD = [[0, 1, 2], [1, 3, 2]]  # two triangles, one interior edge: one bending stencil


@ti.kernel
def _vertex_terms(terms: ti.template(), y: ti.template(), i: ti.i32, dt: float, force: ti.types.ndarray(),
                  block: ti.types.ndarray()):
    f, h = terms.at(i, y, dt)
    for r in ti.static(range(3)):
        force[r] = f[r]
        for c in ti.static(range(3)):
            block[r, c] = h[r, c]


class Vertex:
    """MembraneTerms.at for one vertex of a small membrane (and bending) system of unit masses."""

    def __init__(self, triangles, material, bending=None):
        n = len(SQUARE)
        self.membrane = Membrane(n, triangles, SQUARE, material)
        self.bending = IsometricBending(n, triangles, SQUARE, bending) if bending is not None else None
        system = ParticleSystem(np.ones(n), np.zeros(n, bool), [t for t in (self.membrane, self.bending) if t])
        self.state = system.make_state()
        self.terms = MembraneTerms(self.membrane, self.bending)

    def __call__(self, i, x, v, dt):
        self.state.from_numpy(np.asarray(x, float), np.asarray(v, float))
        force, block = np.zeros(3), np.zeros((3, 3))
        _vertex_terms(self.terms, self.state, i, dt, force, block)
        return force, block

    def stiffness(self, i, x, v, dt, step=1e-6):
        """-(df_i/dx_i + df_i/dv_i / dt) by central differences of the force :meth:`__call__` gives."""
        out = np.zeros((3, 3))
        for k in range(3):
            for which, scale in ((0, 1.0), (1, 1.0 / dt)):
                plus, minus = np.array(x, float), np.array(x, float)
                vp, vm = np.array(v, float), np.array(v, float)
                (plus, vp)[which][i, k] += step
                (minus, vm)[which][i, k] -= step
                out[:, k] -= scale * (self(i, plus, vp, dt)[0] - self(i, minus, vm, dt)[0]) / (2 * step)
        return out


def nearest_psd(h):
    values, vectors = np.linalg.eigh(0.5 * (h + h.T))
    return (vectors * np.maximum(values, 0.0)) @ vectors.T


@pytest.mark.parametrize("model", ["stvk", "neohookean"])
def test_a_vertex_block_is_its_triangles_hessian_block_with_damping_and_bending(f64, rng, model):
    """Stretched (every block PSD, nothing projected), the block vertex 1 gets from its two
    triangles, their viscous stress and the bending stencil is -(df/dx + df/dv / dt) by finite
    differences, and its force is the terms' own. At rest in velocity: the viscous stress's
    dependence on positions (zero there) is left out of the block, as a dashpot's is."""
    material = MembraneMaterial.from_parameters(model, stretch_modulus=50.0, poisson_ratio=0.3, damping=0.01)
    vertex = Vertex(QUAD, material, bending=1e-3)
    x = SQUARE * [1.5, 1.0, 1.4] + 0.01 * rng.standard_normal(SQUARE.shape)
    v = np.zeros_like(x)
    dt = 0.02
    force, block = vertex(1, x, v, dt)
    assert np.abs(block - block.T).max() < 1e-9 * np.abs(block).max()
    fd = vertex.stiffness(1, x, v, dt)
    np.testing.assert_allclose(block, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
    assert np.linalg.eigvalsh(block).min() > 0.0
    # the force is the membrane's and the bending's (the bending through its operator rows)
    system = ParticleSystem(np.ones(4), np.zeros(4, bool), [vertex.membrane, vertex.bending])
    state = system.make_state()
    state.from_numpy(x, v)
    out = ti.Vector.field(3, ti.f64, shape=4)
    system.forces(state, out)
    np.testing.assert_allclose(force, out.to_numpy()[1], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("model", ["stvk", "neohookean"])
def test_a_compressed_triangles_block_is_projected_to_the_nearest_psd(f64, rng, model):
    """Compressed and bent out of plane, a triangle's own corner block has a negative eigenvalue;
    vbd's block is the nearest PSD matrix to it (its negative eigenvalues set to zero)."""
    material = MembraneMaterial.from_parameters(model, stretch_modulus=50.0, poisson_ratio=0.3)
    vertex = Vertex([[0, 1, 2]], material)
    x = SQUARE * 0.7 + 0.01 * rng.standard_normal(SQUARE.shape)
    v = np.zeros_like(x)
    for i in range(3):
        force, block = vertex(i, x, v, 0.02)
        true = vertex.stiffness(i, x, v, 0.02)
        assert np.linalg.eigvalsh(0.5 * (true + true.T)).min() < -1e-3 * np.abs(true).max()
        np.testing.assert_allclose(block, nearest_psd(true), atol=1e-6 * np.abs(true).max())


def test_the_colouring_keeps_every_triangle_and_stencil_apart(f64):
    scene = ts.build_scene("cloth-membrane", {"nx": 6, "ny": 6})
    vbd = create_integrator("vbd", scene.system)
    colour = np.empty(scene.system.particle_count, int)
    for c in range(vbd.colour_count):
        colour[vbd.order.to_numpy()[vbd.starts[c]:vbd.starts[c + 1]]] = c
    for elements in (scene.system.term("membrane").triangles_np, scene.system.term("bending").vertices_np):
        corners = colour[elements]
        for a in range(corners.shape[1]):
            for b in range(a + 1, corners.shape[1]):
                assert np.all(corners[:, a] != corners[:, b])


@ti.kernel
def _merit(terms: ti.template(), y: ti.template(), dt: float) -> float:
    return terms.merit(y, dt)


@pytest.mark.parametrize("model", ["stvk", "neohookean"])
def test_the_start_tests_merit_is_the_membranes_and_bendings_energy_plus_dt_dissipation(f64, rng, model):
    """MembraneTerms.merit, which the sweeps' start test sums element by element, is the
    membrane's and the bending's energy (recomputed in numpy: taichi_sim.reference) plus dt times
    the viscous dissipation, each triangle and stencil counted once."""
    material = MembraneMaterial.from_parameters(model, stretch_modulus=50.0, poisson_ratio=0.3, damping=0.01)
    vertex = Vertex(QUAD, material, bending=1e-3)
    x = SQUARE * [1.3, 1.0, 0.8] + 0.02 * rng.standard_normal(SQUARE.shape)
    v = rng.standard_normal(SQUARE.shape)
    vertex.state.from_numpy(x, v)
    dt = 0.02
    data = {**vertex.membrane.arrays(), **vertex.bending.arrays()}
    dissipation = vertex.membrane.dissipation(vertex.state)
    assert dissipation > 0 and vertex.bending.energy(vertex.state) > 0
    expected = membrane_energy(data, x) + dt * dissipation
    assert _merit(vertex.terms, vertex.state, dt) == pytest.approx(expected, rel=1e-12)


@ti.kernel
def _solver_merit(vbd: ti.template(), dt: float) -> float:
    return vbd._merit(dt)


@ti.kernel
def _merit_per_vertex(vbd: ti.template(), dt: float) -> float:
    """1/2 |v - v0|_M^2 + U + dt R at vbd's iterate with every term attributed per vertex."""
    total = 0.0
    for i in range(vbd.system.particle_count):
        u, r = vbd.system.potential_and_dissipation_at(i, vbd.point)
        total += u + dt * r
        if vbd.system.free[i]:
            total += 0.5 * vbd.system.mass[i] * (vbd.point.v[i] - vbd.start_v[i]).norm_sqr()
    return total


def test_the_sweeps_start_test_sums_the_membrane_by_element_as_the_vertices_would(f64, rng):
    """VBD._merit (backward Euler's incremental potential, the membrane's and bending's part
    element by element, the rest per vertex) at a random iterate is the same sum with every term
    attributed vertex by vertex (each triangle a third to each corner, each stencil a quarter)."""
    scene = ts.build_scene("cloth-membrane", {"nx": 5, "ny": 5})
    vbd = create_integrator("vbd", scene.system)
    n = scene.system.particle_count
    vbd.point.from_numpy(scene.state.to_numpy()[0] + 0.01 * rng.standard_normal((n, 3)), rng.standard_normal((n, 3)))
    vbd.start_v.from_numpy(rng.standard_normal((n, 3)))
    assert scene.system.term("membrane").dissipation(vbd.point) > 0
    assert _solver_merit(vbd, 0.01) == pytest.approx(_merit_per_vertex(vbd, 0.01), rel=1e-12)


SHEET = {"nx": 8, "ny": 8, "pin": "edge", "density": 1.0, "area_drag": 2.0, "stretch_modulus": 100.0,
         "poisson_ratio": 0.3, "bending_stiffness": 1e-4, "membrane_damping": 0.02}


@pytest.mark.long
@pytest.mark.parametrize("model", ["neohookean", "stvk"])
def test_the_sweeps_converge_to_implicit_euler_on_a_membrane_sheet(f64, model):
    """An 8 x 8 membrane sheet (with bending and viscous damping) hanging from one edge, 10 steps
    of 0.05 s (it swings down): vbd with 400 sweeps ends within 1e-6 m of implicit Euler solved to
    a Newton tolerance of 1e-10 (7e-10 m measured after 20 steps, where 20 sweeps lag 6 cm behind), and its
    run is measured by the error estimate with nothing left out of the residual's model."""
    scene = ts.build_scene("cloth", {**SHEET, "material": model})
    start = scene.state.to_numpy()[0]
    ts.run(scene, create_integrator("implicit_euler", scene.system, newton_tolerance=1e-10), dt=0.05, steps=10,
           energy_every=0)
    exact = scene.state.to_numpy()[0]
    scene.reset()
    vbd = create_integrator("vbd", scene.system, iterations=400)
    assert vbd.unmodelled_forces == ""
    monitor = ConvergenceMonitor(scene, vbd)
    assert monitor.active and not monitor.reason
    result = ts.run(scene, vbd, dt=0.05, steps=10, energy_every=0)
    assert result.status.value == "ok"
    x = scene.state.to_numpy()[0]
    assert np.abs(exact - start).max() > 0.5  # it falls, swinging down
    assert np.abs(x - exact).max() < 1e-6


@pytest.mark.long
@pytest.mark.parametrize("args", [
    ["cloth-membrane", "--set", "nx=6", "--set", "ny=6", "--steps", "3"],
    ["garment", "--set", "material=neohookean", "--set", "rows=4", "--set", "gore_columns=2", "--steps", "2"],
])
def test_the_cli_runs_vbd_on_a_membrane(tmp_path, capsys, args):
    out = tmp_path / "run.npz"
    assert main(["simulate", *args, "--integrator", "vbd", "--out", str(out), "--quiet"]) == 0
    assert out.exists()
    with np.load(out) as run:
        assert np.isfinite(run["x"]).all() and "membrane_triangles" in run and str(run["status"]) == "ok"
