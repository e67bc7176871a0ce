"""Triangle membranes and isometric bending (docs/materials.md): patch tests against the
analytic plane-stress response, rigid motions, gradients and Hessians against finite
differences, PSD blocks, bad input."""
import numpy as np
import pytest
import taichi as ti
from scipy.optimize import brentq

from taichi_sim.errors import ConfigError
from taichi_sim.forces.membrane import IsometricBending, Membrane, MembraneMaterial, rest_frames
from taichi_sim.forces.membrane.material import neohookean, neohookean_hessian, project_psd, stvk, stvk_hessian
from taichi_sim.systems.particles import ParticleSystem

MODELS = ("stvk", "neohookean")
HESSIANS = {stvk: stvk_hessian, neohookean: neohookean_hessian}
L = 0.2  # m: the patch triangle's legs


def system_of(x, triangles, material, bending=None, pinned=None):
    """A particle system of unit masses with the membrane (and bending) term, its state at ``x``."""
    n = len(x)
    terms = [Membrane(n, triangles, x, material)]
    if bending is not None:
        terms.append(IsometricBending(n, triangles, x, bending))
    system = ParticleSystem(np.ones(n), np.zeros(n, bool) if pinned is None else pinned, terms)
    state = system.make_state()
    state.from_numpy(np.asarray(x, float), np.zeros((n, 3)))
    return system, state


def forces_at(system, state, x, v=None):
    state.from_numpy(np.asarray(x, float), np.zeros_like(x) if v is None else v)
    # one output field per system: a new field would compile the force kernel again
    out = system.__dict__.setdefault("_test_out", ti.Vector.field(3, ti.f64, shape=len(x)))
    system.forces(state, out)
    return out.to_numpy()


@ti.kernel
def _jacobian_columns(system: ti.template(), y: ti.template(), p: ti.template(), out: ti.template(),
                      a: float, b: float):
    system.prepare_jacobian(y, a, b, 0.0)
    for i in range(out.shape[0]):
        out[i] = system.force_jacobian_product(i, y, p, a, b, 0.0)


@ti.kernel
def _diagonal_blocks(system: ti.template(), y: ti.template(), out: ti.template(), a: float, b: float):
    system.prepare_jacobian(y, a, b, 0.0)
    for i in range(out.shape[0]):
        out[i] = system.system_matrix_diagonal_block(i, y, a, b, 0.0)


def jacobian_matrix(system, state, a=0.0, b=1.0):
    """The dense 3n x 3n matrix a df/dv + b df/dx from the products with unit vectors."""
    n = system.particle_count
    p, out = system.__dict__.setdefault("_test_fields", (ti.Vector.field(3, ti.f64, shape=n),
                                                         ti.Vector.field(3, ti.f64, shape=n)))
    columns = []
    for k in range(3 * n):
        unit = np.zeros((n, 3))
        unit.flat[k] = 1.0
        p.from_numpy(unit)
        _jacobian_columns(system, state, p, out, a, b)
        columns.append(out.to_numpy().ravel())
    return np.array(columns).T


def patch(x_deformed=None):
    """One right triangle with legs L along x and z, at rest in the x-z plane."""
    x = np.array([[0.0, 0.0, 0.0], [L, 0.0, 0.0], [0.0, 0.0, L]])
    return x, np.array([[0, 1, 2]])


# -- parameters -------------------------------------------------------------------------------

def test_plane_stress_moduli_from_youngs_modulus_and_thickness():
    m = MembraneMaterial.from_parameters("stvk", youngs_modulus=2e6, thickness=5e-4, poisson_ratio=0.25)
    assert m.stretch_modulus == pytest.approx(1000.0)
    assert m.mu == pytest.approx(1000.0 / 2.5)
    assert m.lam == pytest.approx(1000.0 * 0.25 / (1 - 0.0625))
    same = MembraneMaterial.from_parameters("stvk", stretch_modulus=1000.0, poisson_ratio=0.25)
    assert (same.mu, same.lam) == pytest.approx((m.mu, m.lam))


@pytest.mark.parametrize("kwargs, culprit", [
    ({"youngs_modulus": 0.0, "thickness": 1e-3}, "youngs_modulus"),
    ({"youngs_modulus": -5.0, "thickness": 1e-3}, "youngs_modulus"),
    ({"youngs_modulus": 1e6, "thickness": 0.0}, "thickness"),
    ({"stretch_modulus": float("nan")}, "stretch_modulus"),
    ({"stretch_modulus": float("inf")}, "stretch_modulus"),
    ({"stretch_modulus": 100.0, "poisson_ratio": 0.5}, "poisson_ratio"),
    ({"stretch_modulus": 100.0, "poisson_ratio": -1.0}, "poisson_ratio"),
    ({"stretch_modulus": 100.0, "damping": -1.0}, "membrane_damping"),
])
def test_bad_material_parameters_are_refused_by_name(kwargs, culprit):
    with pytest.raises(ConfigError, match=culprit):
        MembraneMaterial.from_parameters("stvk", **kwargs)


def test_a_zero_area_rest_triangle_is_refused_by_number():
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 1], [2, 0, 0]])
    with pytest.raises(ConfigError, match=r"triangle 1 \(vertices \[1, 0, 3\]\) has zero area"):
        rest_frames(x, [[0, 1, 2], [1, 0, 3]])


# -- patch tests ------------------------------------------------------------------------------

def uniaxial_stretch(model, mu, lam, stretch):
    """The transverse stretch that leaves the membrane free across (uniaxial stress) and the
    longitudinal first Piola-Kirchhoff stress P_xx (N/m) then, in closed form per model."""
    if model == "stvk":
        e_xx = 0.5 * (stretch ** 2 - 1)
        e_zz = -lam * e_xx / (2 * mu + lam)
        return np.sqrt(1 + 2 * e_zz), stretch * ((2 * mu + lam) * e_xx + lam * e_zz)

    lam_nh = lam + mu  # Smith et al.'s reparametrisation (2D)

    def transverse_stress(s):  # P_zz = mu s + (lam_nh (J - 1) - mu) stretch, J = stretch s
        return mu * s + (lam_nh * (stretch * s - 1) - mu) * stretch
    s = brentq(transverse_stress, 0.2, 1.5, xtol=1e-15)
    return s, mu * stretch + (lam_nh * (stretch * s - 1) - mu) * s


@pytest.mark.parametrize("model", MODELS)
def test_uniaxial_stress_gives_the_analytic_traction(f64, model):
    """Stretched by 1.1 along x and free to contract along z, the patch's corner on the x leg
    feels the traction P_xx times its share L/2 of the edge, back along -x, the corner on the z
    leg nothing; at a strain of 1e-5 both models give E t x strain."""
    material = MembraneMaterial.from_parameters(model, youngs_modulus=4e5, thickness=2.5e-3, poisson_ratio=0.3)
    x, tri = patch()
    system, state = system_of(x, tri, material)
    for stretch, expected_small in ((1.1, None), (1 + 1e-5, 1000.0 * 1e-5)):
        s, p_xx = uniaxial_stretch(model, material.mu, material.lam, stretch)
        deformed = x * np.array([stretch, 1.0, s])
        f = forces_at(system, state, deformed)
        np.testing.assert_allclose(f[1], [-0.5 * L * p_xx, 0, 0], atol=1e-12 * 1000.0 * L)  # rounding of the 1000 N/m modulus
        np.testing.assert_allclose(f[2], 0.0, atol=1e-12 * 1000.0 * L)  # rounding of the 1000 N/m modulus
        np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-12 * 1000.0 * L)  # rounding of the 1000 N/m modulus
        if expected_small is not None:
            assert p_xx == pytest.approx(expected_small, rel=2e-5)


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@pytest.mark.parametrize("model", MODELS)
def test_a_rigid_motion_of_a_curved_mesh_gives_no_force_and_no_energy(f64, model, rng):
    """Four triangles folded out of plane (each rests flattened in its own frame), turned and
    moved as one body."""
    x = np.array([[0, 0, 0], [0.3, 0.05, 0], [0.3, 0.1, 0.3], [0, -0.05, 0.3], [0.15, 0.3, 0.15]])
    tri = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    material = MembraneMaterial.from_parameters(model, stretch_modulus=500.0, poisson_ratio=0.4, damping=0.01)
    system, state = system_of(x, tri, material)
    moved = x @ random_rotation(rng).T + rng.normal(size=3)
    f = forces_at(system, state, moved)
    np.testing.assert_allclose(f, 0.0, atol=1e-11)
    assert system.potential_energy(state) == pytest.approx(0.0, abs=1e-14)
    spin = np.cross(rng.normal(size=3), moved)  # a rigid rotation's velocities: no strain rate
    np.testing.assert_allclose(forces_at(system, state, moved, spin), 0.0, atol=1e-11)


# -- derivatives ------------------------------------------------------------------------------

def sheet(n=4, size=0.3):
    g = np.linspace(0.0, size, n)
    x = np.stack(np.meshgrid(g, [0.0], g, indexing="ij"), axis=-1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    tri = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return x, tri


@pytest.mark.parametrize("model", MODELS)
def test_force_is_minus_the_gradient_of_the_energy(f64, model, rng):
    x, tri = sheet()
    material = MembraneMaterial.from_parameters(model, stretch_modulus=800.0, poisson_ratio=0.35)
    system, state = system_of(x, tri, material, bending=0.02)
    deformed = x + 0.04 * rng.normal(size=x.shape)
    f = forces_at(system, state, deformed)
    eps = 1e-6
    gradient = np.zeros_like(x)
    for k in range(x.size):
        plus, minus = deformed.copy(), deformed.copy()
        plus.flat[k] += eps
        minus.flat[k] -= eps
        state.from_numpy(plus, np.zeros_like(x))
        up = system.potential_energy(state)
        state.from_numpy(minus, np.zeros_like(x))
        gradient.flat[k] = (up - system.potential_energy(state)) / (2 * eps)
    np.testing.assert_allclose(f, -gradient, atol=1e-6 * np.abs(f).max())
    # the energy each vertex is given adds up to the whole
    state.from_numpy(deformed, np.zeros_like(x))
    assert system.health(state, (0, 0, 0)).energy == pytest.approx(system.potential_energy(state), rel=1e-12)


@ti.kernel
def _material(model: ti.template(), hessian_of: ti.template(), f: ti.types.ndarray(), mu: float, lam: float,
              stress: ti.types.ndarray(), hessian: ti.types.ndarray(), projected: ti.types.ndarray()) -> float:
    f0 = ti.Vector([f[0], f[1], f[2]])
    f1 = ti.Vector([f[3], f[4], f[5]])
    psi, p0, p1 = ti.static(model)(f0, f1, mu, lam)
    h = ti.static(hessian_of)(f0, f1, mu, lam)
    hp = project_psd(h)
    for k in ti.static(range(3)):
        stress[k] = p0[k]
        stress[3 + k] = p1[k]
    for r in range(6):
        for c in range(6):
            hessian[r, c] = h[r, c]
            projected[r, c] = hp[r, c]
    return psi


def material_at(model, f, mu=300.0, lam=120.0):
    stress, hessian, projected = np.zeros(6), np.zeros((6, 6)), np.zeros((6, 6))
    psi = _material(model, HESSIANS[model], np.asarray(f, float), mu, lam, stress, hessian, projected)
    return psi, stress, hessian, projected


@pytest.mark.parametrize("model", (stvk, neohookean), ids=MODELS)
def test_material_stress_and_hessian_match_finite_differences(f64, model, rng):
    for scale in (1.15, 0.7):  # stretched, compressed
        f = (scale * np.eye(3)[:, :2] + 0.1 * rng.normal(size=(3, 2))).T.ravel()
        psi, stress, hessian, projected = material_at(model, f)
        eps = 1e-6
        for k in range(6):
            plus, minus = f.copy(), f.copy()
            plus[k] += eps
            minus[k] -= eps
            assert stress[k] == pytest.approx((material_at(model, plus)[0] - material_at(model, minus)[0])
                                              / (2 * eps), rel=1e-6, abs=1e-6)
            column = (material_at(model, plus)[1] - material_at(model, minus)[1]) / (2 * eps)
            np.testing.assert_allclose(hessian[:, k], column, rtol=1e-5, atol=1e-5 * np.abs(hessian).max())
        # the projection: symmetric, PSD, the nearest such matrix (same eigenvectors, negatives cut)
        values, vectors = np.linalg.eigh(hessian)
        np.testing.assert_allclose(projected, (vectors * np.maximum(values, 0)) @ vectors.T,
                                   atol=1e-9 * np.abs(values).max())


@pytest.mark.parametrize("model", MODELS)
def test_jacobian_blocks_match_finite_differences_of_the_force_where_the_hessian_is_psd(f64, model, rng):
    """A sheet stretched by 20 % in both directions (every element's Hessian is PSD there, so
    projection changes nothing) with bending and the viscous stress, at rest (the viscous
    stress's dependence on positions, zero there, is left out of the Jacobian as the springs'
    dashpots' is): a df/dv + b df/dx from the products against central differences of the
    force, and the system's diagonal blocks against it."""
    x, tri = sheet()
    material = MembraneMaterial.from_parameters(model, stretch_modulus=800.0, poisson_ratio=0.3, damping=0.02)
    pinned = np.zeros(len(x), bool)
    system, state = system_of(x, tri, material, bending=0.05, pinned=pinned)
    deformed = 1.2 * x + 0.003 * rng.normal(size=x.shape)
    v = np.zeros_like(x)
    state.from_numpy(deformed, v)
    a, b = 0.3, 0.7
    matrix = jacobian_matrix(system, state, a, b)
    eps = 1e-6
    numeric = np.zeros_like(matrix)
    for k in range(x.size):
        for weight, field in ((b, "x"), (a, "v")):
            plus_x, minus_x, plus_v, minus_v = deformed.copy(), deformed.copy(), v.copy(), v.copy()
            (plus_x if field == "x" else plus_v).flat[k] += eps
            (minus_x if field == "x" else minus_v).flat[k] -= eps
            df = forces_at(system, state, plus_x, plus_v) - forces_at(system, state, minus_x, minus_v)
            numeric[:, k] += weight * df.ravel() / (2 * eps)
    np.testing.assert_allclose(matrix, numeric, atol=1e-6 * np.abs(numeric).max())
    np.testing.assert_allclose(matrix, matrix.T, atol=1e-10 * np.abs(matrix).max())
    state.from_numpy(deformed, v)
    blocks = ti.Matrix.field(3, 3, ti.f64, shape=len(x))
    _diagonal_blocks(system, state, blocks, a, b)
    for i, block in enumerate(blocks.to_numpy()):  # m I - (a df/dv + b df/dx) on the diagonal
        np.testing.assert_allclose(block, np.eye(3) - matrix[3 * i:3 * i + 3, 3 * i:3 * i + 3],
                                   atol=1e-9 * np.abs(matrix).max())


@pytest.mark.parametrize("model", MODELS)
def test_jacobian_is_negative_semidefinite_under_compression(f64, model, rng):
    """Crumpled to 60 % (StVK's stress is compressive, Neo-Hookean's J-term indefinite): the
    projected blocks keep -df/dx positive semi-definite, so Newton's matrix stays SPD."""
    x, tri = sheet()
    material = MembraneMaterial.from_parameters(model, stretch_modulus=800.0, poisson_ratio=0.3)
    system, state = system_of(x, tri, material)
    state.from_numpy(0.6 * x + 0.02 * rng.normal(size=x.shape), np.zeros_like(x))
    stiffness = -jacobian_matrix(system, state)
    values = np.linalg.eigvalsh(0.5 * (stiffness + stiffness.T))
    assert values.min() >= -1e-9 * values.max()


# -- bending ----------------------------------------------------------------------------------

def test_bending_a_sheet_into_a_cylinder_stores_half_d_kappa_squared_per_area(f64):
    """A flat 32 x 32 grid of side 0.6 m rolled onto a cylinder of radius 0.25 m about either
    grid axis stores (D/2) kappa^2 per m^2, short by the boundary strip the edge stencils do not
    reach (about 3 % here, 1.6 % at 64 x 64); rolled across the cells' diagonals, about three
    times as much (the per-edge model's anisotropy on this mesh; docs/materials.md). A flat
    sheet, moved rigidly, stores nothing."""
    n, size, radius, stiffness = 32, 0.6, 0.25, 0.01
    x, tri = sheet(n, size)
    x -= np.array([size / 2, 0, size / 2])
    system = ParticleSystem(np.ones(len(x)), np.zeros(len(x), bool),
                            [IsometricBending(len(x), tri, x, stiffness)])
    state = system.make_state()
    continuum = 0.5 * stiffness * size * size / radius ** 2

    def rolled(angle):
        s = x[:, 0] * np.cos(angle) + x[:, 2] * np.sin(angle)
        t = -x[:, 0] * np.sin(angle) + x[:, 2] * np.cos(angle)
        return np.stack([radius * np.sin(s / radius), radius * (1 - np.cos(s / radius)), t], axis=1)

    ratios = []
    for angle in (0.0, np.pi / 2, np.pi / 4):
        state.from_numpy(rolled(angle), np.zeros_like(x))
        ratios.append(system.potential_energy(state) / continuum)
    assert 0.95 < ratios[0] < 1.0 and ratios[1] == pytest.approx(ratios[0], rel=1e-9)
    assert 2.5 < ratios[2] < 3.0
    state.from_numpy(x @ np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]).T + 1.0, np.zeros_like(x))
    assert system.potential_energy(state) == pytest.approx(0.0, abs=1e-12)


@ti.kernel
def _cached_rows(system: ti.template(), y: ti.template(), p: ti.template(), diagonal: ti.template(),
                 out: ti.template(), lower: ti.template(), upper: ti.template(), a: float, b: float):
    system.prepare_jacobian(y, a, b, 0.0)
    for i in range(out.shape[0]):
        diagonal[i] = system.cache_system_matrix_row(i, y, a, b, 0.0)
    for i in range(out.shape[0]):
        out[i] = system.cached_system_matrix_row(i, y, p, a, b, 0.0, diagonal[i])
        lower[i] = system.cached_triangle_product(i, p, -1)
        upper[i] = system.cached_triangle_product(i, p, 1)


@pytest.mark.parametrize("model", MODELS)
def test_cached_rows_and_the_assembled_matrix_are_the_system_matrix(f64, model, rng):
    """What CG and its Gauss-Seidel sweeps read (the cached rows, each triangle's side of the
    diagonal) and what the direct solver factorises (the assembled lower triangle) are
    A = M - a df/dv - b df/dx, with a pinned vertex's row and column the identity's."""
    x, tri = sheet()
    material = MembraneMaterial.from_parameters(model, stretch_modulus=800.0, poisson_ratio=0.3, damping=0.02)
    pinned = np.zeros(len(x), bool)
    pinned[[0, 5]] = True
    system, state = system_of(x, tri, material, bending=0.05, pinned=pinned)
    system.bind_jacobian_cache()
    deformed = 0.9 * x + 0.02 * rng.normal(size=x.shape)
    state.from_numpy(deformed, np.zeros_like(x))
    a, b = 0.3, 0.7
    free = np.repeat(~pinned, 3)
    expected = np.eye(3 * len(x)) - jacobian_matrix(system, state, a, b)  # unit masses
    expected[~free, :] = 0.0
    expected[:, ~free] = 0.0
    expected[~free, ~free] = 1.0
    n = len(x)
    p_np = rng.normal(size=(n, 3))
    p_np[pinned] = 0.0  # as every vector of the solve
    fields = [ti.Vector.field(3, ti.f64, shape=n) for _ in range(4)]
    p, out, lower, upper = fields
    diagonal = ti.Matrix.field(3, 3, ti.f64, shape=n)
    p.from_numpy(p_np)
    state.from_numpy(deformed, np.zeros_like(x))
    _cached_rows(system, state, p, diagonal, out, lower, upper, a, b)
    product = expected @ p_np.ravel()
    np.testing.assert_allclose(out.to_numpy().ravel(), product, atol=1e-9 * np.abs(product).max())
    sides = lower.to_numpy() + upper.to_numpy() + np.einsum("nij,nj->ni", diagonal.to_numpy(), p_np)
    np.testing.assert_allclose(sides.ravel()[free], product[free], atol=1e-9 * np.abs(product).max())
    builder = ti.linalg.SparseMatrixBuilder(3 * n, 3 * n, max_num_triplets=system.system_matrix_triplet_capacity,
                                            dtype=ti.f64)
    system.assemble_system_matrix(state, a, b, 0.0, builder)
    lower_triangle = builder.build()
    dense = np.array([lower_triangle @ column for column in np.eye(3 * n)]).T
    np.testing.assert_allclose(dense, np.tril(expected), atol=1e-9 * np.abs(expected).max())


@ti.kernel
def _per_particle_forces(system: ti.template(), y: ti.template(), out: ti.template()):
    for i in range(out.shape[0]):
        f, scale, rounding = system.force_and_scale(i, y, 0.0)
        out[i] = f


@pytest.mark.parametrize("model", MODELS)
def test_the_per_particle_force_is_the_whole_system_force(f64, model, rng):
    """What the implicit methods evaluate vertex by vertex (``force``: each incident triangle
    from the vertex) is what eval_f sums from the triangle-parallel buffer (``precompute``)."""
    x, tri = sheet()
    material = MembraneMaterial.from_parameters(model, stretch_modulus=800.0, poisson_ratio=0.2, damping=0.05)
    system, state = system_of(x, tri, material, bending=0.03)
    deformed, v = x + 0.03 * rng.normal(size=x.shape), rng.normal(size=x.shape)
    whole = forces_at(system, state, deformed, v)
    out = ti.Vector.field(3, ti.f64, shape=len(x))
    _per_particle_forces(system, state, out)
    np.testing.assert_allclose(out.to_numpy(), whole, rtol=1e-12, atol=1e-12 * np.abs(whole).max())


def cantilever_strip(length, width, h, clamp_rows=2):
    """A flat strip (x along its length, z across it) whose first ``clamp_rows`` columns of
    vertices, spacing h, are clamped at x <= 0: (positions (n, 3) m, triangles, clamped (n,))."""
    from taichi_sim.scene import cloth as topo

    nx, ny = int(round(length / h)) + clamp_rows, int(round(width / h)) + 1
    x = topo.grid_positions(nx, ny, (nx - 1) * h, width, origin=(-(clamp_rows - 1) * h, 0.0, 0.0),
                            u_axis=(1, 0, 0), v_axis=(0, 0, 1))
    return x, topo.grid_triangles(nx, ny), x[:, 0] < 1e-12


def free_strip_at_rest(tmp_path, **params):
    """The 0.2 x 0.05 m strip at 0.01 m (D = 0.1 N m, 0.2 kg/m^2, StVK with E t = 1e4 N/m) as a
    mesh cloth clamped by its first two columns, ``params`` added, to rest under implicit Euler
    (10 s steps, the direct solver): (its tip's deflections (m), one a vertex of the free end;
    Euler-Bernoulli's q L^4 / (8 D b), L from the clamped rows' midpoint)."""
    import taichi_sim as ts
    from taichi_sim.scene.garment import write_obj
    from taichi_sim.scene.mesh_import import ClothMesh

    length, h, stiffness, density = 0.2, 0.01, 0.1, 0.2
    x, triangles, clamped = cantilever_strip(length, 0.05, h)
    path = tmp_path / "strip.obj"
    write_obj(ClothMesh(x + [0.0, 0.5, 0.0], triangles, {}, "strip"), path)
    scene = ts.build_scene("mesh", {"file": str(path), "pin": f"box:-1,0,-1,{h / 2},1,1", "material": "stvk",
                                    "stretch_modulus": 1e4, "bending_stiffness": stiffness, "density": density,
                                    "membrane_damping": 0.0, "drag": 0.0, **params})
    assert scene.arrays["pinned"].sum() == clamped.sum() == 12
    result = ts.run(scene, ts.create_integrator("implicit_euler", scene.system, linear_solver="direct"), dt=10.0,
                    steps=4, energy_every=0)
    assert result.status.value == "ok"
    xs, v = scene.state.to_numpy()
    assert np.abs(v).max() < 1e-6  # at rest
    tip = 0.5 - xs[np.isclose(x[:, 0], x[:, 0].max()), 1]
    return tip, density * 9.81 * (length + h / 2) ** 4 / (8 * stiffness)


@pytest.mark.parametrize("cells", [20, 40])
def test_a_cantilever_bent_cylindrically_deflects_as_euler_bernoulli(cells):
    """The bending's scale in N m: a strip clamped by two rows of vertices, loaded by its own
    weight and bent cylindrically (its deflection w the same across its width), has the tip
    deflection q L^4 / (8 D b) of a beam with EI = D b, q = rho g b, for the length L from the
    midpoint of the clamped rows (the stencil across the first free edge sees the clamp there):
    the small-deflection solve of the bending energy's exact quadratic form (its Hessian is
    constant) from the stencils and lumped masses the term uses."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.linalg import spsolve

    from taichi_sim.forces.membrane import bending_stencils, lumped_masses

    length, width, h = 0.2, 0.05, 0.2 / cells
    stiffness, density, g = 0.1, 0.2, 9.81
    x, triangles, clamped = cantilever_strip(length, width, h)
    mass = lumped_masses(len(x), triangles, rest_frames(x, triangles)[1], density)
    vertices, weights = bending_stencils(x, triangles)
    stencil = csr_matrix((weights.ravel(), (np.repeat(np.arange(len(vertices)), 4), vertices.ravel())),
                         shape=(len(vertices), len(x)))
    column = np.round((x[:, 0] - x[:, 0].min()) / h).astype(int)  # w per column: a cylindrical bend
    spread = csr_matrix((np.ones(len(x)), (np.arange(len(x)), column)))
    matrix = stiffness * (spread.T @ stencil.T @ stencil @ spread)
    load = spread.T @ (mass * g)
    free = np.bincount(column, ~clamped) > 0
    w = spsolve(matrix[free][:, free].tocsc(), load[free])
    tip = w[-1]
    beam = density * g * (length + h / 2) ** 4 / (8 * stiffness)
    assert tip == pytest.approx(beam, rel=0.01)


@pytest.mark.long
def test_a_free_cantilever_strip_is_softer_than_euler_bernoulli_by_its_diagonal_folds(f64, tmp_path):
    """A 0.2 x 0.05 m strip (D = 0.1 N m, 0.2 kg/m^2, E t = 1e4 N/m) clamped by two rows of
    vertices at one short edge, to rest under its own weight (implicit Euler, 10 s steps): its
    tip falls w/L = 2.6 %, 20 % further than Euler-Bernoulli's q L^4 / (8 D b) (L from the
    clamped rows' midpoint), at this 0.01 m spacing as at 0.00125 m (held to a cylindrical
    bend the same stencils give the beam within 1 %: above). Not within the 5 % a plate would
    give: part of a bend about the grid's axis is taken by the edges along the cells'
    diagonals, and a free strip relieves them by folding its cells along those diagonals,
    which the constant-strain membrane allows without stretching (a stiffer
    membrane, up to E t = 1e9 N/m, changes it by a point). docs/materials.md."""
    tip, beam = free_strip_at_rest(tmp_path)
    assert tip.mean() / 0.2 < 0.05
    assert 1.15 < tip.mean() / beam < 1.25


def test_the_corner_layout_gives_each_corner_its_triangles_deformation_gradient(f64, rng):
    """Membrane.corner_layout (what vbd's vertex solve reads): every triangle appears once
    under each of its vertices, and at any positions (x_j - x_i) g_j^T + (x_k - x_i) g_k^T is
    the triangle's F = Ds Dm^-1, the corner's u is dF/dx_i and A its rest area."""
    x = np.array([[0, 0, 0], [0.3, 0.05, 0], [0.3, 0.1, 0.3], [0, -0.05, 0.3], [0.15, 0.3, 0.15]])
    tri = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    material = MembraneMaterial.from_parameters("neohookean", stretch_modulus=500.0, poisson_ratio=0.4)
    membrane = Membrane(len(x), tri, x, material)
    offsets, others, rest = membrane.corner_layout()
    inverse, area = rest_frames(x, tri)
    moved = x + 0.05 * rng.normal(size=x.shape)
    seen = set()
    for i in range(len(x)):
        for e in range(offsets[i], offsets[i + 1]):
            j, k = others[e]
            (t,) = [t for t, corners in enumerate(tri) if set(corners) == {i, j, k}]
            assert (t, i) not in seen
            seen.add((t, i))
            a, b, c = tri[t]
            F = np.stack([moved[b] - moved[a], moved[c] - moved[a]], axis=1) @ inverse[t]
            gj, gk, u = rest[e, 0:2], rest[e, 2:4], rest[e, 4:6]
            np.testing.assert_allclose(np.outer(moved[j] - moved[i], gj) + np.outer(moved[k] - moved[i], gk), F,
                                       atol=1e-12)
            nudged = moved.copy()
            nudged[i] += [1e-3, -2e-3, 0.5e-3]
            G = np.stack([nudged[b] - nudged[a], nudged[c] - nudged[a]], axis=1) @ inverse[t]
            np.testing.assert_allclose(G - F, np.outer([1e-3, -2e-3, 0.5e-3], u), atol=1e-12)
            assert rest[e, 6] == pytest.approx(area[t])
    assert len(seen) == 3 * len(tri)
