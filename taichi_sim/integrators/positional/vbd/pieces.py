"""A substep of vbd with contact in its solve, in pieces.

Each piece detects the contact pairs at its start (where the cloth is free of intersections),
starts from the bounded guess and sweeps. The bounds keep every vertex within bound_fraction of
its distance to its nearest contact partner until the next detection, so a vertex whose start
guess (x0 + dt v0 + dt^2 a) lies farther is cut back to its bound, and a cloth whose parts close
on each other faster than that per detection falls behind (docs/lab/vbd.md, "The fold's pace"). A
substep is therefore cut short where

* the scene's scripted pins would move further than their bounds (:mod:`.pins`; always);
* the start guess would leave the bounds, with ``contact_pieces`` > 1: the piece is begun
  again, shortened once to where the guesses of all but ``pace_share`` of the free vertices
  would fit (a few vertices jiggling in a settled pile do not cut every step into pieces;
  theirs are cut as before: a cut vertex stops short of the step's solution, so under a
  ``--tolerance`` the share is what vbd's work follows, down to none), at most ``contact_pieces`` pieces a substep for this (the pins'
  pieces come on top, up to ``MAX_PIECES``).

Each piece is a backward Euler step of its own length, where the motion needs it, and a
substep is one piece where it does not. The contact penalty keeps the substep's stiffness in
every piece (``SolveContact.penalty_dt``): scaled by a piece's own length, its push-out gave
energy to a folding cloth.
"""

import numpy as np

MAX_PIECES = 256  # pieces of one substep before the step is given up (pins the cloth cannot let by)
PACE_FIT = 0.9  # a piece shortened for the pace aims its guess at this share of the bounds
PACE_SHARE = 0.005  # ... for all but this share of the free vertices (a few jiggling in a pile): the default
MESH_RETRIES = 3  # shortenings of a piece where a moving collider mesh pushes a vertex past its bounds
# what a substep returns instead of its non-finite particle count when it cannot go on
LOST_PAIRS = -1  # a detection could miss pairs (positions non-finite or beyond its hash)
PINS_STUCK = -2  # the scripted pins found no piece they fit in
FAILURES = {
    LOST_PAIRS: "vbd: the contact detection lost pairs (positions non-finite or too far apart for its hash)",
    PINS_STUCK: f"vbd: the scripted pins could not move within their contact bounds in {MAX_PIECES} pieces "
                "of a substep (a pin pressed into the cloth): lower --dt",
}


class PieceSchedule:
    """The substeps of :class:`~.solver.VBD` with contact in the solve, cut into pieces (module
    docstring); counts the ``pieces`` run and keeps ``last_length``, the last piece's (s).

    Args:
        most: the most pieces (``contact_pieces``) a substep may be cut into for the start
            guess to fit the bounds (the scripted pins' pieces come on top).
        pace_share: the share of the free vertices whose start guess may still leave its bound
            (then cut to it) without a shorter piece (vbd's ``pace_share``, read at each substep).
    """

    def __init__(self, most: int, pace_share: float = PACE_SHARE):
        self.most = most
        self.pace_share = pace_share
        self.pieces = 0  # pieces run since construction
        self.last_length = 0.0  # the last piece's length (s): the next one's previous_dt
        self.refreshes = 1  # self-contact detections a piece

    def substep(self, kernels: dict, sweeps, state, iterate, contact, pins, *, dt: float, t_end: float,
                use_acceleration: int, previous_dt: float, iterations: int, warm_start: bool,
                record=None) -> int:
        """One substep of dt seconds ending at ``t_end`` (s), in one piece or more: each piece
        detects at its start (free of intersections), starts from the bounded guess and sweeps,
        detecting again every ``contact_refresh`` sweeps. A piece ends early where the scripted
        pins need it (:mod:`.pins`) and, with ``most`` > 1, where the guess would leave the
        bounds (:meth:`_plan`).

        Args:
            kernels: the solve's kernels over ``state`` (``begin``, ``end``).
            sweeps: ``sweeps(kernels, dt, t_end, first, count)`` runs the sweeps first ..
                first + count - 1 of a begun piece.
            state: the state stepped (positions read by the detection and the pins).
            iterate: the solve's iterate positions ((n,) vec3 field, m), where a detection
                within a piece looks.
            contact: the solve's :class:`~.contact.SolveContact`.
            pins: the scripted pins the solve moves (:class:`~.pins.DrivenPins`), or None.
            use_acceleration, previous_dt: the first piece's warm start (the last substep's
                length, s); the later pieces start from the piece before.
            iterations: sweeps per piece.
            warm_start: the solve's option (later pieces warm-start from the one before).
            record: None, or ``record(state, length)`` at each piece's start, before its sweeps
                (the convergence monitor measures the step's last piece).

        Returns the non-finite particles, or ``LOST_PAIRS`` or ``PINS_STUCK`` (:data:`FAILURES`
        says why)."""
        contact.penalty_dt[None] = dt
        # the self-contact detections in a piece (each moves the bounds on): a moving mesh's pace
        self.refreshes = max(1, iterations // contact.refresh_every) if contact.refresh_every else 1
        t, remaining = t_end - dt, dt
        for done in range(MAX_PIECES):
            if contact.refresh(state.x):
                return LOST_PAIRS
            piece = self._plan(kernels, state, contact, pins, t, remaining, use_acceleration, previous_dt,
                               self.most - done)
            if piece <= 0.0:
                return PINS_STUCK
            if record is not None:
                record(state, piece)  # each piece is a backward Euler step of its own
            bad = self._sweep(kernels, sweeps, iterate, contact, piece, t + piece, iterations)
            self.pieces += 1
            self.last_length = piece
            if bad or piece == remaining:
                return bad
            t, remaining = t + piece, remaining - piece
            use_acceleration, previous_dt = int(warm_start), piece
        return PINS_STUCK

    def _plan(self, kernels, state, contact, pins, t, remaining, use_acceleration, previous_dt,
              pieces_left) -> float:
        """Begin the next piece (from time t, at most ``remaining`` s) and return its length:
        as long as the scripted pins allow, then, with pieces left to spend, shortened so that
        the start guess stays within the contact bounds (each vertex's move from the detection
        within bound_fraction of its nearest partner's distance), which the sweeps would
        otherwise cut. 0.0 when the pins find no length."""
        piece = _fit_pins(pins, state, t, remaining)
        if piece <= 0.0:
            return 0.0
        body = contact.body
        if body is not None:
            x = state.x.to_numpy()
            speed = float(np.linalg.norm(state.v.to_numpy(), axis=1).max())
            shorter = body.piece_length(x, t, piece, remaining / pieces_left)
            if shorter < piece:
                piece = _fit_pins(pins, state, t, shorter)
                if piece <= 0.0:
                    return 0.0
            body.detect(state.x, t, t + piece, speed * piece, x)
            # the body moves further near a vertex than its pace, or pushes one further than
            # its bounds allow: both shrink with the piece
            for _ in range(MESH_RETRIES):
                over = max(body.crowding(self.refreshes), body.pace())
                shorter = max(piece * PACE_FIT / max(over, 1e-30), remaining / pieces_left)
                if over <= 1.0 or shorter >= piece:
                    break
                piece = _fit_pins(pins, state, t, shorter)
                if piece <= 0.0:
                    return 0.0
                body.detect(state.x, t, t + piece, speed * piece, x)
        kernels["begin"](piece, use_acceleration, previous_dt, t + piece, 0)
        if pieces_left > 1 and contact.self_contact:
            over = contact.overshoot_above(self.pace_share)
            if over > 1.0:
                shorter = max(piece * PACE_FIT / over, remaining / pieces_left)
                if shorter < piece:
                    piece = _fit_pins(pins, state, t, shorter)
                    if piece <= 0.0:
                        return 0.0
                    if body is not None:
                        body.detect(state.x, t, t + piece, speed * piece, x)
                    kernels["begin"](piece, use_acceleration, previous_dt, t + piece, 1)
        return piece

    @staticmethod
    def _sweep(kernels, sweeps, iterate, contact, dt, t_end, iterations) -> int:
        """The sweeps of a begun piece of dt seconds, detecting again every ``contact_refresh``
        sweeps (at the ``iterate``), then its end; returns the non-finite
        particles, or ``LOST_PAIRS`` when a detection could miss pairs."""
        every = contact.refresh_every or iterations
        done = 0
        while done < iterations:
            if done and contact.refresh(iterate):
                return LOST_PAIRS
            count = min(every, iterations - done)
            sweeps(kernels, dt, t_end, done, count)
            done += count
        return kernels["end"](dt)


def _fit_pins(pins, state, t, length) -> float:
    """``length`` itself, or at most half of it where the scripted pins need a shorter piece
    (0.0: no length fits)."""
    return length if pins is None else pins.plan(state.x, t, length)
