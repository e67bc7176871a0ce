"""Vertex block descent (:class:`VBD`), built of parts it owns: its solve and kernels
(solver.py, its kernels in kernels.py), the springs' terms (springs.py), a membrane's
triangles and bending (membranes.py), the energy cap (energy.py), what a scene puts in
the solve (scene.py: contact, pins), a substep in pieces (pieces.py), the contact terms
(contact.py, faces.py) and their model for the convergence monitor (contact_model.py)."""
from ..colouring import colour_vertices
from .solver import VBD

__all__ = ["VBD", "colour_vertices"]
