"""A substep of vbd with contact in its solve, in pieces.

Each piece detects the contact pairs at its start (where the cloth is free of intersections),
starts from the bounded guess and sweeps. The bounds keep every vertex within bound_fraction of
its distance to its nearest contact partner until the next detection, so a vertex whose start
guess (x0 + dt v0 + dt^2 a) lies farther is cut back to its bound, and a cloth whose parts close
on each other faster than that per detection falls behind (docs/lab/vbd.md, "The fold's pace"). A
substep is therefore cut short where

* the scene's scripted pins would move further than their bounds (:mod:`.vbd_pins`; always);
* the start guess would leave the bounds, with ``contact_pieces`` > 1: the piece is begun
  again, shortened once to where the guesses of all but ``PACE_SHARE`` of the free vertices
  would fit (a few vertices jiggling in a settled pile do not cut every step into pieces;
  theirs are cut as before), at most ``contact_pieces`` pieces a substep for this (the pins'
  pieces come on top, up to ``MAX_PIECES``).

Each piece is a backward Euler step of its own length, where the motion needs it, and a
substep is one piece where it does not. The contact penalty keeps the substep's stiffness in
every piece (``SolveContact.penalty_dt``): scaled by a piece's own length, its push-out gave
energy to a folding cloth.
"""

MAX_PIECES = 256  # pieces of one substep before the step is given up (pins the cloth cannot let by)
PACE_FIT = 0.9  # a piece shortened for the pace aims its guess at this share of the bounds
PACE_SHARE = 0.005  # ... for all but this share of the free vertices (a few jiggling in a pile)
# what a substep returns instead of its non-finite particle count when it cannot go on
LOST_PAIRS = -1  # a detection could miss pairs (positions non-finite or beyond its hash)
PINS_STUCK = -2  # the scripted pins found no piece they fit in
FAILURES = {
    LOST_PAIRS: "vbd: the contact detection lost pairs (positions non-finite or too far apart for its hash)",
    PINS_STUCK: f"vbd: the scripted pins could not move within their contact bounds in {MAX_PIECES} pieces "
                "of a substep (a pin pressed into the cloth): lower --dt",
}


class ContactPieces:
    """Mixin of :class:`~.vbd.VBD`: its substep with contact in the solve (reads ``contact``,
    ``pins``, ``contact_pieces``, ``has_self_contact``, ``warm_start``, ``iterations``,
    ``serial``; counts ``pieces``; keeps ``_last_dt``, the last piece's length)."""

    def _contact_substep(self, kernels, state, dt, t_end, use_acceleration, previous_dt, last: bool = False) -> int:
        """A substep with contact in the solve, in one piece or more: each piece detects at its
        start (free of intersections), starts from the bounded guess and sweeps, detecting
        again every ``contact_refresh`` sweeps. A piece ends early where the scripted pins need
        it (:mod:`.vbd_pins`) and, with ``contact_pieces`` > 1, where the guess would leave the
        bounds (:meth:`_plan_piece`). ``last``: the step's last substep, whose last piece the
        convergence monitor measures (its start and length). Returns the non-finite particles,
        or ``LOST_PAIRS`` or ``PINS_STUCK`` (:data:`FAILURES` says why)."""
        contact = self.contact
        contact.penalty_dt[None] = dt
        t, remaining = t_end - dt, dt
        for done in range(MAX_PIECES):
            if contact.refresh(state.x):
                return LOST_PAIRS
            if self.solved_start is not None and last:
                self.solved_start.copy_from(state)  # each piece is a backward Euler step of its own
            piece = self._plan_piece(kernels, state, t, remaining, use_acceleration, previous_dt,
                                     self.contact_pieces - done)
            if piece <= 0.0:
                return PINS_STUCK
            if self.solved_start is not None and last:
                self.solved_h = piece
            bad = self._sweep_piece(kernels, piece, t + piece)
            self.pieces += 1
            self._last_dt = piece
            if bad or piece == remaining:
                return bad
            t, remaining = t + piece, remaining - piece
            use_acceleration, previous_dt = int(self.warm_start), piece
        return PINS_STUCK

    def _plan_piece(self, kernels, state, t, remaining, use_acceleration, previous_dt, pieces_left) -> float:
        """Start the next piece (from time t, at most ``remaining`` s) and return its length:
        as long as the scripted pins allow, then, with pieces left to spend, shortened so that
        the start guess stays within the contact bounds (each vertex's move from the detection
        within bound_fraction of its nearest partner's distance), which the sweeps would
        otherwise cut. 0.0 when the pins find no length."""
        piece = self._fit_pins(state, t, remaining)
        if piece <= 0.0:
            return 0.0
        kernels["begin"](piece, use_acceleration, previous_dt, t + piece, 0)
        if pieces_left > 1 and self.has_self_contact:
            over = self.contact.overshoot_above(PACE_SHARE)
            if over > 1.0:
                shorter = max(piece * PACE_FIT / over, remaining / pieces_left)
                if shorter < piece:
                    piece = self._fit_pins(state, t, shorter)
                    if piece <= 0.0:
                        return 0.0
                    kernels["begin"](piece, use_acceleration, previous_dt, t + piece, 1)
        return piece

    def _fit_pins(self, state, t, length) -> float:
        """``length`` itself, or at most half of it where the scripted pins need a shorter piece
        (0.0: no length fits)."""
        return length if self.pins is None else self.pins.plan(state.x, t, length)

    def _sweep_piece(self, kernels, dt, t_end) -> int:
        """The sweeps of a begun piece of dt seconds, detecting again every ``contact_refresh``
        sweeps, then its end; returns the non-finite particles, or ``LOST_PAIRS`` when a
        detection could miss pairs."""
        contact = self.contact
        every = contact.refresh_every or self.iterations
        done, omega = 0, 1.0
        while done < self.iterations:
            if done and contact.refresh(self.point.x):
                return LOST_PAIRS
            count = min(every, self.iterations - done)
            if self.serial:
                kernels["sweeps"](dt, t_end, done, count)
            else:
                for sweep in range(done, done + count):
                    omega = self._omega(sweep, omega)
                    self._sweep(kernels, dt, t_end, omega, sweep)
            done += count
        return kernels["end"](dt)
