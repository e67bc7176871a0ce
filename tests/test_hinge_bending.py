"""Hinge bending (docs/materials.md, "Bending"): the dihedral (discrete shells) and
shape-operator models from a rest shape that may be curved: gradients and Gauss-Newton blocks
against finite differences, a rolled sheet's energy, a curved rest shape at rest, bad input."""
import numpy as np
import pytest
import taichi as ti

from taichi_sim.errors import ConfigError
from taichi_sim.forces.membrane import HingeBending, IsometricBending
from taichi_sim.forces.membrane.hinges import hinge_angles, hinge_topology
from taichi_sim.systems.particles import ParticleSystem

from test_membrane import _per_particle_forces, forces_at, jacobian_matrix, sheet

HINGED = ("dihedral", "shape_operator")


def system_with(term, n, x):
    system = ParticleSystem(np.ones(n), np.zeros(n, bool), [term])
    state = system.make_state()
    state.from_numpy(np.asarray(x, float), np.zeros((n, 3)))
    return system, state


def energy_at(system, state, x):
    state.from_numpy(np.asarray(x, float), np.zeros_like(x))
    return system.potential_energy(state)


def cylinder_patch(n=5, radius=0.2, span=0.25):
    """A sheet of n x n vertices on a cylinder of ``radius`` about the z axis (a curved rest)."""
    x, tri = sheet(n, span)
    s, z = x[:, 0] - span / 2, x[:, 2]
    return np.stack([radius * np.sin(s / radius), radius * (1 - np.cos(s / radius)), z], axis=1), tri


def numerical_gradient(f, x, eps=1e-6):
    g = np.zeros_like(x)
    for k in range(x.size):
        step = np.zeros_like(x)
        step.flat[k] = eps
        g.flat[k] = (f(x + step) - f(x - step)) / (2 * eps)
    return g


def test_the_dihedral_angle_and_its_gradient(rng):
    """Signed (a fold one way is minus the other), zero flat, the same with the hinge's two
    sides swapped, and its gradient that of finite differences; finite at a collapsed triangle."""
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0.4, 1, 0], [0.6, -1, 0]])
    v = np.array([[0, 1, 2, 3]])
    assert hinge_angles(x, v)[0][0] == 0.0
    up, down = x.copy(), x.copy()
    up[3, 2], down[3, 2] = 0.3, -0.3
    assert hinge_angles(up, v)[0][0] == pytest.approx(-hinge_angles(down, v)[0][0])
    assert abs(hinge_angles(up, v)[0][0]) == pytest.approx(np.arctan2(0.3, 1.0))
    moved = x + 0.2 * rng.normal(size=x.shape)
    theta, gradient = hinge_angles(moved, v)
    assert hinge_angles(moved, np.array([[1, 0, 3, 2]]))[0][0] == pytest.approx(theta[0])
    numeric = numerical_gradient(lambda y: hinge_angles(y, v)[0][0], moved)
    np.testing.assert_allclose(gradient[0], numeric, atol=1e-8)
    collapsed = x.copy()
    collapsed[2] = [0.5, 0, 0]
    assert np.isfinite(hinge_angles(collapsed, v)[1]).all()


@pytest.mark.parametrize("model", HINGED)
def test_force_is_minus_the_gradient_of_the_energy_from_a_curved_rest(f64, model, rng):
    """At a deformed state, both force paths (eval_f's whole-system pass, the implicit methods'
    per vertex) are minus the energy's gradient by finite differences."""
    x, tri = cylinder_patch()
    term = HingeBending(len(x), tri, x, 0.02, model)
    system, state = system_with(term, len(x), x)
    deformed = x + 0.01 * rng.normal(size=x.shape)
    whole = forces_at(system, state, deformed)
    numeric = -numerical_gradient(lambda y: energy_at(system, state, y), deformed)
    np.testing.assert_allclose(whole, numeric, atol=1e-7 * np.abs(numeric).max())
    out = ti.Vector.field(3, ti.f64, shape=len(x))
    state.from_numpy(deformed, np.zeros_like(x))
    _per_particle_forces(system, state, out)
    np.testing.assert_allclose(out.to_numpy(), whole, atol=1e-12 * np.abs(whole).max())


@pytest.mark.parametrize("model", HINGED)
def test_the_blocks_are_the_hessian_at_rest_and_psd_everywhere(f64, model, rng):
    """At the curved rest shape moved rigidly, where every angle is at rest and Gauss-Newton's
    blocks are the whole Hessian, b df/dx is the force's finite-difference Jacobian; deformed,
    -df/dx stays positive semi-definite, and the diagonal blocks are the matrix's."""
    x, tri = cylinder_patch()
    term = HingeBending(len(x), tri, x, 0.02, model)
    system, state = system_with(term, len(x), x)
    turn = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    placed = x @ turn.T + 0.3
    state.from_numpy(placed, np.zeros_like(x))
    jac = jacobian_matrix(system, state, a=0.0, b=2.0)
    eps = 1e-6
    numeric = np.zeros_like(jac)
    for k in range(placed.size):
        step = np.zeros_like(placed)
        step.flat[k] = eps
        numeric[:, k] = (forces_at(system, state, placed + step) - forces_at(system, state, placed - step)).ravel() / eps
    state.from_numpy(placed, np.zeros_like(x))
    np.testing.assert_allclose(jac, numeric, atol=1e-6 * np.abs(numeric).max())
    state.from_numpy(x + 0.03 * rng.normal(size=x.shape), np.zeros_like(x))
    jac = jacobian_matrix(system, state)
    values = np.linalg.eigvalsh(-jac)
    assert np.allclose(jac, jac.T, atol=1e-12 * np.abs(jac).max()) and values.min() >= -1e-9 * values.max()
