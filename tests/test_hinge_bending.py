"""Hinge bending (docs/materials.md, "Bending"): the dihedral (discrete shells) and
shape-operator models from a rest shape that may be curved: gradients and Gauss-Newton blocks
against finite differences, a rolled sheet's energy, a curved rest shape at rest, bad input."""
import numpy as np
import pytest
import taichi as ti
from test_membrane import _per_particle_forces, forces_at, jacobian_matrix, sheet

from taichi_sim.errors import ConfigError
from taichi_sim.forces.membrane import HingeBending, IsometricBending
from taichi_sim.forces.membrane.hinges import hinge_angles, hinge_topology
from taichi_sim.systems.particles import ParticleSystem

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


def rolled_sheet(n=32, size=0.6, radius=0.25):
    """A flat n x n grid of side ``size`` centred on the origin, and a function rolling it onto a
    cylinder of ``radius`` with its axis at ``angle`` to the grid's z axis (isometrically)."""
    x, tri = sheet(n, size)
    x -= np.array([size / 2, 0, size / 2])

    def rolled(angle):
        s = x[:, 0] * np.cos(angle) + x[:, 2] * np.sin(angle)
        t = -x[:, 0] * np.sin(angle) + x[:, 2] * np.cos(angle)
        return np.stack([radius * np.sin(s / radius), radius * (1 - np.cos(s / radius)), t], axis=1)

    return x, tri, rolled


def test_rolling_a_sheet_stores_half_d_kappa_squared_per_area(f64):
    """The 32 x 32 sheet of side 0.6 m rolled onto a cylinder of radius 0.25 m stores (D/2) kappa^2
    per m^2. Dihedral: about a grid axis, short by the boundary column whose hinge is missing
    (1/31 here), and across the cells' diagonals about three times as much, as the isometric
    model (its calibration and its anisotropy on this mesh). Shape operator: in any direction,
    the same short of the boundary triangles (whose free edge is held flat). A flat sheet,
    moved rigidly, stores nothing."""
    n, size, radius, stiffness = 32, 0.6, 0.25, 0.01
    x, tri, rolled = rolled_sheet(n, size, radius)
    continuum = 0.5 * stiffness * size * size / radius ** 2
    ratios = {}
    for model in HINGED:
        system, state = system_with(HingeBending(len(x), tri, x, stiffness, model), len(x), x)
        ratios[model] = [energy_at(system, state, rolled(angle)) / continuum
                         for angle in (0.0, np.pi / 2, np.pi / 4, 0.3)]
        turned = x @ np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]).T + 1.0
        assert energy_at(system, state, turned) == pytest.approx(0.0, abs=1e-12)
    dihedral, shape = ratios["dihedral"], ratios["shape_operator"]
    assert dihedral[0] == pytest.approx(1 - 1 / (n - 1), rel=1e-3) and dihedral[1] == pytest.approx(dihedral[0])
    assert 2.5 < dihedral[2] < 3.0
    assert all(0.96 < r < 1.0 for r in shape) and max(shape) - min(shape) < 0.035


@pytest.mark.parametrize("model", HINGED)
def test_a_curved_rest_shape_stays_at_rest(f64, model):
    """A cylinder patch as loaded is the hinge models' rest: no energy, no force; the isometric
    model, flat at rest, pushes the same patch towards flat."""
    x, tri = cylinder_patch(6)
    system, state = system_with(HingeBending(len(x), tri, x, 0.02, model), len(x), x)
    assert energy_at(system, state, x) == pytest.approx(0.0, abs=1e-15)
    assert np.abs(forces_at(system, state, x)).max() < 1e-12
    flat_rest, flat_state = system_with(IsometricBending(len(x), tri, x, 0.02), len(x), x)
    assert np.abs(forces_at(flat_rest, flat_state, x)).max() > 1e-3
    bent = x.copy()
    bent[:, 1] *= 1.5
    assert energy_at(system, state, bent) > 1e-6


def test_hinge_topology_sides_and_bad_input():
    """Each interior edge once, with its two opposite vertices; a model or ratio out of range is
    refused by its parameter's name."""
    x, tri = sheet(3)
    vertices, faces, face_hinges = hinge_topology(tri)
    assert len(vertices) == 8  # 2 x 2 cells: 4 diagonals, 4 edges between cells
    for h, (a, b, c, d) in enumerate(vertices):
        for f, far in zip(faces[h], (c, d)):
            assert {a, b, far} == set(tri[f]) and h in face_hinges[f]
    assert (face_hinges >= 0).sum() == 2 * len(vertices)
    with pytest.raises(ConfigError, match="bending_model"):
        HingeBending(len(x), tri, x, 0.01, "hinge")
    with pytest.raises(ConfigError, match="bending_poisson_ratio"):
        HingeBending(len(x), tri, x, 0.01, "shape_operator", poisson=0.7)
    with pytest.raises(ConfigError, match="bending_stiffness"):
        HingeBending(len(x), tri, x, -1.0, "dihedral")


def strip_tip_over_beam(model, h, length=0.2, width=0.05, stiffness=0.1, density=0.2, g=9.81):
    """The free cantilever strip of tests/test_membrane.py (two clamped rows of vertices, its
    own weight): the small-deflection tip (the mean over the tip's vertices) over
    Euler-Bernoulli's q L^4 / (8 D b), and the tip's twist (the spread of its deflection, m),
    from the equilibrium of the model's rest Hessian in the normal deflections
    (:func:`~taichi_sim.forces.membrane.hinges.normal_stiffness`)."""
    from scipy.sparse.linalg import spsolve
    from test_membrane import cantilever_strip

    from taichi_sim.forces.membrane import lumped_masses, rest_frames
    from taichi_sim.forces.membrane.hinge_term import hinge_elements
    from taichi_sim.forces.membrane.hinges import normal_stiffness

    x, triangles, clamped = cantilever_strip(length, width, h)
    mass = lumped_masses(len(x), triangles, rest_frames(x, triangles)[1], density)
    matrix = normal_stiffness(x, hinge_elements(triangles, x, stiffness, model))[~clamped][:, ~clamped]
    w = np.zeros(len(x))
    w[~clamped] = spsolve(matrix.tocsc(), (mass * g)[~clamped])
    tip = w[np.isclose(x[:, 0], x[:, 0].max())]
    return tip.mean() / (density * g * (length + h / 2) ** 4 / (8 * stiffness)), np.ptp(tip)


@pytest.mark.parametrize("h", [0.01, 0.005])
def test_a_free_cantilever_strip_deflects_as_euler_bernoulli_with_the_shape_operator(h):
    """The free strip the isometric and the dihedral models let fold along the cells' diagonals
    (about 20 % too far: tests/test_membrane.py) bends as a beam with EI = D b under the shape
    operator (nu = 0), within 5 % (0.1 % measured) at two spacings, and its tip does not twist;
    the dihedral model gives the isometric one's figure (on a flat rest they agree to first
    order)."""
    ratio, twist = strip_tip_over_beam("shape_operator", h)
    assert ratio == pytest.approx(1.0, abs=0.05)
    dihedral, dihedral_twist = strip_tip_over_beam("dihedral", h)
    assert 1.15 < dihedral < 1.25 and twist < 0.01 * dihedral_twist
