"""Cloth as a material: constant-strain triangle membranes (StVK, Neo-Hookean) and bending
across interior edges, in physical units (docs/materials.md)."""
from .bending import IsometricBending, check_bending_stiffness
from .geometry import bending_stencils, lumped_masses, omega_max_bound, rest_frames
from .hinge_term import HingeBending
from .hinges import BENDING_MODELS, check_bending_model
from .material import MODELS, MembraneMaterial
from .term import Membrane

__all__ = ["BENDING_MODELS", "HingeBending", "IsometricBending", "MODELS", "Membrane", "MembraneMaterial", "bending_stencils",
           "check_bending_model", "check_bending_stiffness", "lumped_masses", "omega_max_bound", "rest_frames"]
