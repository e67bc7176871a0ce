"""Pacing the launcher's simulation to the wall clock, in plain Python (tested without a window).

Each frame the launcher asks :class:`Pacer` how many simulated seconds to advance: as many as
wall seconds went by since the last frame, unless simulating that much would cost more than the
frame budget, judged from what simulation has cost so far (smoothed). Simulated time then
follows the clock whenever the machine can keep up; when it cannot, frames stay short (no
spiral where a slow frame asks for more work in the next one) and :attr:`Pacer.factor` says how
far behind the simulation runs.
"""
from __future__ import annotations

from collections import deque

#: Wall time (s) one frame may spend simulating: when the simulation cannot keep up, drawing
#: still gets a share of every second and the window keeps answering the mouse.
FRAME_BUDGET = 0.05
#: Longest wall interval (s) one frame makes up for: a stall (window dragged, a compile) is
#: skipped rather than simulated in one burst.
MAX_INTERVAL = 0.25
#: Weight of the newest frame in the smoothed cost.
SMOOTHING = 0.25
#: Wall time (s) over which the real-time factor is measured.
FACTOR_WINDOW = 1.0
#: The HUD says how far from real time the simulation runs when the factor is outside 1 +- this.
SHOW_FACTOR_TOLERANCE = 0.05


class Pacer:
    """Chooses each frame's simulated duration so that simulated time follows wall time.

    Args:
        budget: wall time (s) a frame may spend simulating.
        max_interval: longest wall interval (s) a frame makes up for.
        smoothing: weight in (0, 1] of the newest frame in the smoothed cost per simulated
            second.
        window: wall time (s) over which :attr:`factor` is measured.

    Use: ``duration = plan(interval, min_duration)`` before a frame's simulation, then
    ``observe(interval, simulated, wall)`` after it.
    """

    def __init__(self, *, budget: float = FRAME_BUDGET, max_interval: float = MAX_INTERVAL,
                 smoothing: float = SMOOTHING, window: float = FACTOR_WINDOW):
        if not (budget > 0 and max_interval > 0 and 0 < smoothing <= 1 and window > 0):
            raise ValueError("budget, max_interval and window must be > 0 and smoothing in (0, 1]")
        self.budget = float(budget)
        self.max_interval = float(max_interval)
        self.smoothing = float(smoothing)
        self.window = float(window)
        self.cost: float | None = None  # smoothed wall seconds per simulated second
        self.limited = False  # whether the last plan was cut by the budget
        self._warm = False  # the first frame after a reset compiles kernels: it says nothing
        self._history: deque[tuple[float, float]] = deque()  # (wall interval, simulated) per frame

    def reset(self) -> None:
        """Forget the measured cost and the factor (a new scene or integrator costs differently)."""
        self.cost = None
        self.limited = False
        self._warm = False
        self._history.clear()

    def plan(self, interval: float, min_duration: float = 0.0) -> float:
        """Simulated seconds to advance in a frame that follows ``interval`` wall seconds after
        the previous one: ``interval`` (at most ``max_interval``), cut to what ``budget`` wall
        seconds can simulate at the smoothed cost but not below ``min_duration`` (one step, so a
        very slow method still moves) unless the interval itself is shorter."""
        wanted = min(max(float(interval), 0.0), self.max_interval)
        affordable = wanted if self.cost is None or self.cost <= 0 else self.budget / self.cost
        self.limited = affordable < wanted
        # A frame shorter than one step advances less than a step: the runner carries the rest.
        return min(wanted, max(affordable, float(min_duration)))

    def observe(self, interval: float, simulated: float, wall: float) -> None:
        """Record a frame: ``interval`` wall seconds since the previous frame, ``simulated``
        seconds advanced, ``wall`` seconds the simulation took. The first frame that simulates
        anything after construction or :meth:`reset` is not counted (it compiles)."""
        if simulated > 0 and not self._warm:
            self._warm = True
            return
        if simulated > 0 and wall >= 0:
            cost = wall / simulated
            self.cost = cost if self.cost is None else self.cost + self.smoothing * (cost - self.cost)
        if interval > 0:
            self._history.append((float(interval), max(float(simulated), 0.0)))
            total = sum(w for w, _ in self._history)
            while len(self._history) > 1 and total - self._history[0][0] >= self.window:
                total -= self._history.popleft()[0]

    @property
    def factor(self) -> float | None:
        """Simulated seconds per wall second over the last ``window`` wall seconds (1 = real
        time), or None before a full window was seen."""
        wall = sum(w for w, _ in self._history)
        if wall < self.window:
            return None
        return sum(s for _, s in self._history) / wall


def factor_text(factor: float | None) -> str:
    """The HUD's note on the pace: "" at real time (within tolerance) or before it is known,
    else e.g. "0.42x real time"."""
    if factor is None or abs(factor - 1.0) <= SHOW_FACTOR_TOLERANCE:
        return ""
    return f"{factor:.2g}x real time"


class FrameClock:
    """The launcher's clock between frames: the wall interval each frame paces to and the
    frames per second the HUD shows, both leaving out frames that compiled kernels.

    Args:
        now: the wall time (s, ``time.perf_counter()``) the first frame starts.

    Call ``tick(now, compiled=...)`` after each frame is shown; it returns the interval (s) to
    pace the next frame by. A frame that built a scene or took its first step holds the window
    for seconds: counted, it would read as a frame rate near zero, and the pacer's real-time
    factor would fall far behind for a second after it, though nothing ran slowly.
    """

    def __init__(self, now: float):
        self.last = float(now)
        self.interval: float | None = None  # the last frame's wall time that compiled nothing
        self.fps = 0.0  # smoothed frames per second

    def tick(self, now: float, *, compiled: bool = False) -> float | None:
        """The frame that started at the last tick ended at ``now`` (s); ``compiled``: it built
        or first stepped something. Returns the interval to pace the next frame by: this
        frame's, or after a compiling frame the last one before it (None before any)."""
        interval, self.last = float(now) - self.last, float(now)
        if compiled:
            return self.interval
        self.interval = interval
        self.fps = 0.9 * self.fps + 0.1 / max(interval, 1e-6)
        return interval
