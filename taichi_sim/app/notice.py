"""Saying so before the launcher compiles, in plain Python (tested without a window).

Taichi compiles a kernel on the thread that first launches it, and GGUI draws only from the
thread that opened the window, so while a scene is built or first stepped the window cannot
draw: for seconds, up to a minute on a first visit with three panels. :class:`CompileNotice`
holds such work back until a frame that says what is about to happen has been shown, so the
window never freezes without a word. A switch goes in three frames: the click's own frame
(the old scene, with "compiling <scene>..."), the build (the new scene at t = 0, not stepped,
with "... first step"), then the first step, which compiles the methods' kernels.
"""
from __future__ import annotations

#: What :meth:`CompileNotice.plan` tells the launcher to do with a frame.
RUN = "run"  # step and draw as usual
SWITCH = "switch"  # build the requested scene now (its notice has been shown), then draw it unstepped
HOLD = "hold"  # draw without stepping: the step would compile, and its notice is not shown yet


class CompileNotice:
    """The launcher's pending scene switch and the notice of the work that compiles.

    Use per frame: ``plan(session)`` before stepping (RUN, SWITCH or HOLD), draw
    ``text(session)`` in the frame, then ``shown(text)`` once the frame is drawn.
    ``request_scene(name)`` asks for a switch (from the panel or a key, any time in a frame).
    """

    def __init__(self):
        self.scene: str | None = None  # the scene asked for, not built yet
        self._shown: str | None = None  # the notice of the last frame drawn

    def request_scene(self, name: str) -> None:
        """Switch to preset ``name`` once a frame saying so has been shown."""
        self.scene = name

    def text(self, session) -> str | None:
        """The notice for the frame being drawn, or None when nothing is about to compile:
        a requested scene (first visit: it compiles), else the methods whose first step is
        next (a new scene, a method picked for the first time, the launcher's first frame)."""
        if self.scene is not None:
            if session.is_built(self.scene):
                return f"switching to {self.scene}..."
            return (f"compiling {self.scene}... (first visit: Taichi builds its kernels and the "
                    "window waits, up to a minute; later visits are instant)")
        names = [r.name for r in session.about_to_compile()]
        if not names:
            return None
        return (f"compiling {', '.join(dict.fromkeys(names))} for {session.scene_name}: the first "
                "step builds its kernels (the window waits; the step then runs at full speed)")

    def plan(self, session) -> str:
        """What this frame does: SWITCH when a requested scene's notice has been shown (the
        caller builds it and draws it without stepping), HOLD when the step would compile
        and its notice has not been shown, else RUN."""
        if self.scene is not None:
            return SWITCH if self._shown == self.text(session) else RUN
        notice = self.text(session)
        return HOLD if notice is not None and notice != self._shown else RUN

    def take_scene(self) -> str:
        """The requested scene, now being built (the request is done)."""
        name, self.scene = self.scene, None
        return name

    def shown(self, notice: str | None) -> None:
        """Record the notice the frame just drawn showed (None: none)."""
        self._shown = notice
