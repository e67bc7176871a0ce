"""The launcher never blocks without a word, without a window: the compile notice's order of
frames, the frame clock that leaves compiling frames out of fps and pacing, and the window's
size and place on the screen it opens on. (The same order with a real offscreen window and a
real switch: tests/test_render.py; the screen read from a real X server:
tests/test_launcher_window.py.)"""
import pytest

from taichi_sim.app.display import SCREEN_MARGIN, fit_window
from taichi_sim.app.notice import HOLD, RUN, SWITCH, CompileNotice
from taichi_sim.app.pacing import FrameClock


class FakeRunner:
    def __init__(self, name):
        self.name, self.compiled, self.frozen = name, False, False


class FakeSession:
    """What CompileNotice reads of a Session: the scene, which scenes are built, the runners
    whose next step compiles."""

    def __init__(self):
        self.scene_name, self.built, self.paused = "cloth", {"cloth"}, False
        self.runners = [FakeRunner("rk4")]

    def is_built(self, name):
        return name in self.built

    def about_to_compile(self):
        return [] if self.paused else [r for r in self.runners if not r.frozen and not r.compiled]

    def select_scene(self, name):
        self.scene_name = name
        self.built.add(name)
        self.runners = [FakeRunner("rk4")]


def _frame(notice, session, log, *, click=None):
    """A launcher frame as draw_frame does it: plan, switch or step, the panel (where a click
    may ask for a scene), then the notice drawn and recorded as shown."""
    plan = notice.plan(session)
    log.append(plan)
    if plan == SWITCH:
        session.select_scene(notice.take_scene())
    if plan == RUN:
        for r in session.about_to_compile():
            r.compiled = True  # the step compiles
    if click is not None:
        notice.request_scene(click)
    text = notice.text(session)
    notice.shown(text)
    return text


def test_a_first_visit_is_announced_then_built_unstepped_then_stepped():
    session, notice, log = FakeSession(), CompileNotice(), []
    assert "compiling rk4 for cloth" in _frame(notice, session, log)  # the launcher's first frame
    assert log == [HOLD] and not session.runners[0].compiled  # ... steps nothing
    assert _frame(notice, session, log) is None and log[-1] == RUN and session.runners[0].compiled
    # a click in the panel: the same frame already says what comes
    assert "compiling cloth-sphere... (first visit" in _frame(notice, session, log, click="cloth-sphere")
    assert log[-1] == RUN and session.scene_name == "cloth"  # that frame still ran the old scene
    text = _frame(notice, session, log)
    assert log[-1] == SWITCH and session.scene_name == "cloth-sphere"  # built after the notice was up
    assert text.startswith("compiling rk4 for cloth-sphere: the first step")
    assert not session.runners[0].compiled  # ... and drawn unstepped, saying the step compiles
    assert _frame(notice, session, log) is None and log[-1] == RUN and session.runners[0].compiled
    assert log == [HOLD, RUN, RUN, SWITCH, RUN]


def test_a_built_scene_switches_without_waiting_for_a_compile_and_a_pause_holds_nothing():
    session, notice, log = FakeSession(), CompileNotice(), []
    session.runners[0].compiled = True
    session.built.add("pendulum")
    assert _frame(notice, session, log, click="pendulum") == "switching to pendulum..."
    session.select_scene = lambda name: (setattr(session, "scene_name", name),
                                         setattr(session.runners[0], "compiled", True))
    assert _frame(notice, session, log) is None and session.scene_name == "pendulum"
    assert log == [RUN, SWITCH]
    notice.request_scene("garment")  # a key: asked before the frame, which must show it first
    assert _frame(notice, session, log).startswith("compiling garment... (first visit")
    assert log[-1] == RUN and session.scene_name == "pendulum"
    assert _frame(notice, session, log) is None and log[-1] == SWITCH and session.scene_name == "garment"
    session.runners[0].compiled, session.paused = False, True  # a new method, paused: no step to hold
    assert _frame(notice, session, log) is None and log[-1] == RUN
    session.paused = False
    assert "compiling rk4" in _frame(notice, session, log) and log[-1] == HOLD


def test_the_frame_clock_leaves_compiling_frames_out_of_fps_and_pacing():
    clock = FrameClock(0.0)
    now = 0.0
    for _ in range(100):
        now += 0.02
        assert clock.tick(now) == pytest.approx(0.02)
    assert clock.fps == pytest.approx(50.0, rel=1e-3)
    now += 30.0  # a frame that compiled for 30 s
    assert clock.tick(now, compiled=True) == pytest.approx(0.02)  # paced as the frame before it
    assert clock.fps == pytest.approx(50.0, rel=1e-3)
    now += 0.025
    assert clock.tick(now) == pytest.approx(0.025)  # measured from the compiling frame's end
    assert FrameClock(0.0).tick(5.0, compiled=True) is None  # nothing measured yet


@pytest.mark.parametrize("screen", [(0, 0, 1280, 800), (0, 0, 1366, 768), (0, 0, 1024, 600),
                                    (1920, 0, 1280, 800), (0, 0, 1280, 1024)])
def test_the_window_fits_a_small_screen_with_room_for_its_frame(screen):
    """The whole window, the Status panel at its right edge included, lies on the screen,
    with room left for a title bar, borders and a desktop's panel."""
    (x, y), (w, h) = fit_window((1280, 800), screen)
    sx, sy, sw, sh = screen
    assert sx <= x and x + w <= sx + sw and sy <= y and y + h <= sy + sh
    assert w <= sw - SCREEN_MARGIN[0] and h <= sh - SCREEN_MARGIN[1]
    assert x - sx >= SCREEN_MARGIN[0] // 2 and y - sy >= SCREEN_MARGIN[1] // 2  # the title bar shows
    assert w == min(1280, sw - SCREEN_MARGIN[0]) and h == min(800, sh - SCREEN_MARGIN[1])  # no smaller


def test_a_large_screen_keeps_the_asked_size_centred():
    assert fit_window((1280, 800), (0, 0, 1920, 1080)) == ((320, 140), (1280, 800))
    assert fit_window((1280, 800), (2560, 0, 2560, 1440)) == ((2560 + 640, 320), (1280, 800))
    assert fit_window((640, 400), None) == ((100, 100), (640, 400))  # screen unknown: as asked
