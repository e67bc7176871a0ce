"""Hinge bending in scenes (docs/materials.md, "Bending"): the bending_model parameter on the
grid and mesh cloths, the reference energy, vbd's colouring, the explicit step's bound and
bad input."""
import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.errors import ConfigError
from taichi_sim.forces.membrane import HingeBending, IsometricBending
from taichi_sim.forces.membrane.hinges import bound_weights, hinge_angles
from taichi_sim.integrators import create_integrator
from taichi_sim.reference import membrane_energy

TINY = {"nx": 6, "ny": 5, "material": "stvk", "bending_stiffness": 0.01}


@pytest.mark.parametrize("model", ["dihedral", "shape_operator"])
def test_the_bending_model_reaches_the_term_and_the_reference_energy_agrees(f64, rng, model):
    """bending_model picks the term; the scene's arrays recompute its energy in numpy
    (taichi_sim.reference, what the extremes audit reads) at a crumpled state."""
    assert isinstance(ts.build_scene("cloth", TINY).system.term("bending"), IsometricBending)
    scene = ts.build_scene("cloth", {**TINY, "bending_model": model, "bending_poisson_ratio": 0.2})
    term = scene.system.term("bending")
    assert isinstance(term, HingeBending) and term.model == model
    assert term.poisson == 0.2
    x = scene.state.to_numpy()[0] + 0.02 * rng.normal(size=(scene.system.particle_count, 3))
    scene.state.from_numpy(x, np.zeros_like(x))
    bending = term.energy(scene.state)
    assert bending > 1e-6
    total = membrane_energy(scene.arrays, x)
    assert total - scene.system.term("membrane").energy(scene.state) == pytest.approx(bending, rel=1e-10)


def test_vbd_colours_a_shape_operators_six_vertices_apart(f64):
    """A shape-operator element reaches its triangle and the far vertices of its three
    neighbours: vbd's colouring keeps all six in different colours."""
    scene = ts.build_scene("cloth-membrane", {"nx": 6, "ny": 6, "bending_model": "shape_operator"})
    vbd = create_integrator("vbd", scene.system)
    colour = np.empty(scene.system.particle_count, int)
    for c in range(vbd.colour_count):
        colour[vbd.order.to_numpy()[vbd.starts[c]:vbd.starts[c + 1]]] = c
    term = scene.system.term("bending")
    assert term.vertices_np.shape[1] == 6
    corners = colour[term.vertices_np]
    for a in range(6):
        for b in range(a + 1, 6):
            distinct = term.vertices_np[:, a] != term.vertices_np[:, b]  # a boundary element's padding
            assert np.all(corners[distinct, a] != corners[distinct, b])


@pytest.mark.parametrize("model, width", [("dihedral", 4), ("shape_operator", 6)])
def test_the_explicit_steps_bound_holds_the_bendings_rest_stiffness(model, width):
    """|K_rs| <= D w_r w_s for every element's rest Hessian (the Gershgorin bound the explicit
    step is cut by) on a curved mesh."""
    from test_hinge_bending import cylinder_patch

    from taichi_sim.forces.membrane.hinge_term import hinge_elements

    x, tri = cylinder_patch(6)
    stiffness = 0.03
    arrays = hinge_elements(tri, x, stiffness, model)
    stencil, weights = bound_weights(x, arrays["hinge_vertices"], arrays["bending_elements"],
                                     arrays["bending_moduli"], width, stiffness)
    _, gradient = hinge_angles(x, arrays["hinge_vertices"])
    for e, hinges in enumerate(arrays["bending_elements"]):
        rows = np.zeros((3, len(x), 3))
        for k, h in enumerate(hinges):
            if h >= 0:
                np.add.at(rows[k], arrays["hinge_vertices"][h], gradient[h])
        hessian = np.einsum("kvi,kl,lwj->vwij", rows, arrays["bending_moduli"][e], rows)
        bound = np.zeros((len(x), len(x)))
        distinct = np.unique(stencil[e], return_index=True)[1]
        for r in distinct:
            for s in distinct:
                bound[stencil[e, r], stencil[e, s]] = stiffness * weights[e, r] * weights[e, s]
        assert np.all(np.abs(hessian).max(axis=(2, 3)) <= bound * (1 + 1e-9) + 1e-15)


@pytest.mark.parametrize("params, culprit", [
    ({"bending_model": "hinge"}, "bending_model"),
    ({"bending_model": "shape_operator", "bending_poisson_ratio": 0.5}, "bending_poisson_ratio"),
    ({"bending_poisson_ratio": -0.1}, "bending_poisson_ratio"),
])
def test_bad_bending_input_is_one_line_and_exit_2(params, culprit, tmp_path, capsys):
    with pytest.raises(ConfigError, match=culprit):
        ts.build_scene("cloth", {**TINY, **params})
    out = tmp_path / "run.npz"
    argv = ["simulate", "cloth", "--set", "material=stvk", "--t-end", "0.01", "--out", str(out)]
    for key, value in params.items():
        argv += ["--set", f"{key}={value}"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert culprit in err and len(err.splitlines()) == 1 and not out.exists()


@pytest.mark.long
def test_the_free_cantilever_strip_simulated_to_rest_is_the_beam_with_the_shape_operator(f64, tmp_path):
    """The strip of tests/test_membrane.py's free-cantilever test (0.2 x 0.05 m at 0.01 m, D = 0.1
    N m, 0.2 kg/m^2, E t = 1e4 N/m) as a mesh cloth with bending_model=shape_operator, to rest
    under implicit Euler (10 s steps, the direct solver on the Gauss-Newton blocks): its tip
    within 5 % of Euler-Bernoulli's q L^4 / (8 D b) (0.3 % short measured: w/L = 2 %), untwisted,
    where the isometric model's falls 20 % further."""
    from test_membrane import free_strip_at_rest

    tip, beam = free_strip_at_rest(tmp_path, bending_model="shape_operator")
    assert tip.mean() / beam == pytest.approx(1.0, abs=0.05) and np.ptp(tip) < 1e-5


@pytest.mark.long
@pytest.mark.parametrize("model", ["dihedral", "shape_operator"])
def test_vbd_converges_to_implicit_euler_with_hinge_bending(f64, model):
    """An 8 x 8 StVK sheet hanging from one edge with stiff hinge bending (D = 1e-3 N m), 10
    steps of 0.05 s: vbd with 400 sweeps, each vertex solving with its elements' force and
    Gauss-Newton block at the iterate, ends within 1e-6 m of implicit Euler solved to a Newton
    tolerance of 1e-10 (the fixed point of both is the backward Euler step)."""
    params = {"nx": 8, "ny": 8, "pin": "edge", "density": 1.0, "stretch_modulus": 100.0, "poisson_ratio": 0.3,
              "bending_stiffness": 1e-3, "membrane_damping": 0.0, "material": "stvk", "bending_model": model}
    scene = ts.build_scene("cloth", params)
    start = scene.state.to_numpy()[0]
    ts.run(scene, create_integrator("implicit_euler", scene.system, newton_tolerance=1e-10), dt=0.05, steps=10,
           energy_every=0)
    exact = scene.state.to_numpy()[0]
    scene.reset()
    result = ts.run(scene, create_integrator("vbd", scene.system, iterations=400), dt=0.05, steps=10, energy_every=0)
    assert result.status.value == "ok"
    assert np.abs(exact - start).max() > 0.3
    assert np.abs(scene.state.to_numpy()[0] - exact).max() < 1e-6
