"""Cloth as a material (docs/materials.md): the ``material`` parameters every cloth shares,
and what a membrane cloth needs besides its triangles: its material, masses from its area and
the default step an explicit method can take on it."""
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..forces.membrane import (
    BENDING_MODELS,
    MembraneMaterial,
    bending_stencils,
    lumped_masses,
    omega_max_bound,
    rest_frames,
)
from ..forces.membrane.hinges import bound_weights, check_poisson
from ..forces.springs.spectrum import _round_down, symplectic_euler_limit
from .builder import SceneBuilder
from .params import Param
from .scene import Scene

MATERIALS = ("springs", "stvk", "neohookean")
#: The method a membrane cloth runs when its preset's own default is a positional method that
#: holds springs only and refuses a membrane (Integrator.takes_elastic_models; vbd takes one).
MEMBRANE_INTEGRATOR = "implicit_euler"
POSITIONAL = ("xpbd", "projective_dynamics")

MATERIAL_PARAMS: tuple[Param, ...] = (
    Param("material", "springs", "", "springs (the spring net of the other parameters), or a membrane of "
          "triangles in physical units, the same at any resolution: stvk (Saint Venant-Kirchhoff) or "
          "neohookean (a stable Neo-Hookean, for large compression)", choices=MATERIALS),
    Param("stretch_modulus", 0.0, "N/m", "membrane stretch modulus E t (N/m); 0: youngs_modulus x "
          "material_thickness", minimum=0.0),
    Param("youngs_modulus", 1e6, "Pa", "membrane Young's modulus E, used with material_thickness when "
          "stretch_modulus is 0", minimum=0.0, exclusive=True),
    Param("material_thickness", 1e-3, "m", "membrane thickness t (the contact distance is the parameter "
          "thickness)", minimum=0.0, exclusive=True),
    Param("poisson_ratio", 0.3, "", "membrane Poisson's ratio nu, in (-1, 0.5)"),
    Param("bending_stiffness", 1e-4, "N m", "membrane bending stiffness D across the interior edges; 0: none",
          minimum=0.0),
    Param("bending_model", "isometric", "", "membrane bending: isometric (quadratic, rest shape flat, "
          "fastest), dihedral (discrete shells: the rest shape as loaded) or shape_operator (a curvature "
          "tensor per triangle from its three hinges: the rest shape as loaded, the same in every "
          "direction on any mesh)", choices=BENDING_MODELS),
    Param("bending_poisson_ratio", 0.0, "", "the shape_operator plate's bending Poisson's ratio, in [0, 0.5)",
          minimum=0.0),
    Param("membrane_damping", 1e-3, "s", "membrane viscous damping time: the strain rate's stress is this "
          "times the elastic stress of the same strain", minimum=0.0),
)


def membrane_material(p: dict[str, Any]) -> MembraneMaterial | None:
    """The membrane of the cloth parameters ``p``, or None for ``material=springs``."""
    if p["material"] == "springs":
        return None
    stretch = p["stretch_modulus"] if p["stretch_modulus"] > 0 else None
    return MembraneMaterial.from_parameters(
        p["material"], stretch_modulus=stretch, youngs_modulus=p["youngs_modulus"],
        thickness=p["material_thickness"], poisson_ratio=p["poisson_ratio"], damping=p["membrane_damping"])


def membrane_bending(p: dict[str, Any], bending: float | None = None) -> dict[str, Any]:
    """The bending keywords of :meth:`SceneBuilder.set_membrane` from the cloth parameters ``p``
    (``bending``, N m: instead of ``p["bending_stiffness"]``)."""
    return {"bending": p["bending_stiffness"] if bending is None else bending,
            "bending_model": p["bending_model"], "bending_poisson": check_poisson(p["bending_poisson_ratio"])}


def refuse_springs_only(p: dict[str, Any]) -> None:
    """ConfigError for the options that act on springs, with a membrane material."""
    if p.get("tear"):
        raise ConfigError(f"parameter tear: tearing breaks springs; material={p['material']} has none")


def add_membrane_cloth(b: SceneBuilder, p: dict[str, Any], x: np.ndarray, triangles: np.ndarray, pinned,
                       material: MembraneMaterial) -> np.ndarray:
    """Add a membrane cloth to ``b``: particles at ``x`` ((n, 3) m, also the rest shape) with
    masses lumped from the triangles' areas at ``p["density"]`` (kg/m^2), ``pinned``, the
    ``triangles`` and the membrane with ``p["bending_stiffness"]``. Returns the masses (kg)."""
    refuse_springs_only(p)
    _, area = rest_frames(x, triangles)  # ConfigError naming a zero-area triangle
    mass = lumped_masses(len(x), triangles, area, p["density"])
    if not np.all(mass > 0):
        raise ConfigError(f"membrane: vertex {int(np.flatnonzero(~(mass > 0))[0])} is in no triangle (no mass)")
    b.add_particles(x, mass, pinned=pinned)
    b.add_triangles(triangles)
    b.set_membrane(material, **membrane_bending(p))
    return mass


def membrane_explicit_step(scene: Scene, material: MembraneMaterial, bending: float, dt: float,
                           share: float = 0.9) -> float:
    """``dt`` (s), or ``share`` of symplectic Euler's stable step on the membrane where that is
    shorter (rounded down to 2 digits): omega_max from Gershgorin's bound at rest
    (:func:`~taichi_sim.forces.membrane.omega_max_bound`), the damping rate from the viscous
    stress (damping time x omega_max^2) and the drag."""
    arrays = scene.arrays
    mass, pinned = np.asarray(arrays["mass"], float), np.asarray(arrays["pinned"], bool)
    triangles = arrays["membrane_triangles"]
    inverse, area = rest_frames(scene.rest_x, triangles)
    stencils = (None, None)
    if bending > 0 and "hinge_vertices" in arrays:
        width = 4 if str(arrays["bending_model"]) == "dihedral" else 6
        stencils = bound_weights(scene.rest_x, arrays["hinge_vertices"], arrays["bending_elements"],
                                 arrays["bending_moduli"], width, bending)
    elif bending > 0:
        stencils = bending_stencils(scene.rest_x, triangles)
    omega = omega_max_bound(mass, pinned, triangles, inverse, area, material.mu, material.lam, *stencils,
                            bending=bending)
    if omega <= 0:
        return dt
    free = ~pinned
    gamma = material.damping * omega * omega + float(arrays.get("drag", 0.0)) / mass[free].min()
    limit = share * symplectic_euler_limit(omega, gamma)
    return _round_down(limit) if dt > limit else dt


def finish_membrane_scene(scene: Scene, preset, p: dict[str, Any], material: MembraneMaterial,
                          explicit: tuple[str, ...], share: float) -> Scene:
    """A membrane cloth's default method and steps: a positional default that refuses a
    membrane (:data:`POSITIONAL`) becomes :data:`MEMBRANE_INTEGRATOR` (vbd stays); an explicit default, and an explicit method asked for by name,
    get a step below their stable limit on the membrane."""
    if scene.default_integrator in POSITIONAL:
        scene.default_integrator = MEMBRANE_INTEGRATOR
    explicit_dt = preset.explicit_dt if preset.explicit_dt is not None else scene.default_dt
    scene.explicit_dt = membrane_explicit_step(scene, material, p["bending_stiffness"], explicit_dt, share)
    if scene.default_integrator in explicit:
        scene.default_dt = scene.explicit_dt
    return scene
