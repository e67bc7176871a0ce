"""Why a run stopped and what to do about it: :class:`Failure`, one line for every way a run
ends early, and :func:`failure_advice`."""
from __future__ import annotations

from dataclasses import dataclass

from ..integrators import Status, integrator_class
from ..theory import stable_step_advice

ADVICE = "lower the step or pick a more stable integrator"


def _iterative(integrator: str) -> bool:
    """Whether the method sweeps a fixed number of ``iterations`` per step (xpbd, vbd, ...)."""
    try:
        return "iterations" in integrator_class(integrator).options()
    except Exception:  # advice must never hide the failure it explains
        return False


def failure_advice(scene, integrator: str, status: Status) -> str:
    """What to do about a run of ``integrator`` on ``scene`` that ended with ``status``."""
    if status is Status.DIVERGED:
        advice = stable_step_advice(scene, integrator)
        if not advice and _iterative(integrator):
            # no step limit to name: a fixed number of sweeps leaves a stiff or fine cloth's
            # step unsolved (cloth-stiff at 96 x 96 with xpbd: diverged with 20, ran with 40)
            return ("its fixed iterations leave the step unsolved (stiff springs, fine meshes): raise "
                    "--iterations, or " + ADVICE)
        return f"{advice}: {ADVICE}" if advice else ADVICE
    if status is Status.STIFF:
        return "the problem is stiff: use an implicit method (implicit_euler)"
    if status is Status.STEP_TOO_SMALL:
        return "loosen rtol/atol or use f64"
    return ADVICE


@dataclass(frozen=True)
class Failure:
    """Why and where a run stopped.

    Attributes:
        status: anything but OK.
        step, t: the step that failed, or at which the guard caught the blow-up, and its time (s).
        integrator: its registry name; h: the step size (s) of the failing call.
        detail: what the method or the guard saw ("energy rose to ..."), or "".
        good_step, good_t: the state left in the scene when it was put back to the last one
            that passed the guard (a DIVERGED run); None when the state was left as it was.
        advice: what to do about it (:func:`failure_advice`).
    """

    status: Status
    step: int
    t: float
    integrator: str
    h: float
    detail: str
    good_step: int | None
    good_t: float | None
    advice: str

    @property
    def summary(self) -> str:
        """Short form for a HUD: "diverged at t = 0.24 s (energy rose to ...)"."""
        detail = f" ({self.detail})" if self.detail else ""
        return f"{self.status.value.replace('_', ' ')} at t = {self.t:.4g} s{detail}"

    @property
    def message(self) -> str:
        """One line: what stopped the run, where, with what, the state returned and the advice."""
        detail = f" ({self.detail})" if self.detail else ""
        text = (f"{self.status.value} at step {self.step} (t = {self.t:.6g} s) with {self.integrator}, "
                f"h = {self.h:.3g} s{detail}")
        if self.good_step is not None:
            text += (f"; the state returned is that of step {self.good_step} (t = {self.good_t:.6g} s), "
                     f"the last that passed the blow-up check")
        return f"{text}; {self.advice}"
