"""Force terms: composable pieces of a particle system's eval_f (DESIGN.md section 4)."""
from __future__ import annotations


class ForceTerm:
    """One additive force term.

    A term is ``@ti.data_oriented`` and provides a ``@ti.func force(self, i, y, mass_i)`` that
    returns the force (N, a 3-vector) on particle ``i`` of state ``y``. The particle system sums
    its terms inside ONE kernel, with ``ti.static`` iteration, so a term that a scene does not
    add costs nothing.
    """

    name = "force"

    def energy(self, y) -> float | None:
        """Potential energy (J) of this term at state ``y``, or None if the term is dissipative."""
        return None
