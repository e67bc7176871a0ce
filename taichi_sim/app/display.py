"""Whether an on-screen window can be opened, asked before GLFW is (it ends the process), and
how large it can be on the screen it opens on.

GGUI opens windows with GLFW, which on Linux talks to an X server (a Wayland session provides
one through Xwayland). When ``DISPLAY`` names a server that does not answer, GLFW prints
"cannot initialize GLFW" and exits with status 1, so nothing can catch it: the launcher asks
Xlib first, as GLFW would. GGUI offers no way to read the screen's size either (GLFW's calls
are not exported by Taichi's library), so :func:`screen_area` asks Xlib and XRandR too.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys


def display_problem() -> str | None:
    """None when an on-screen window can be opened here, else a short reason ("no display
    (DISPLAY / WAYLAND_DISPLAY unset)", "cannot open the X display ':77'")."""
    display = os.environ.get("DISPLAY")
    if not display:
        if os.environ.get("WAYLAND_DISPLAY"):
            return None  # no X to ask: let GLFW try
        return "no display (DISPLAY / WAYLAND_DISPLAY unset)"
    if not sys.platform.startswith("linux"):
        return None
    name = ctypes.util.find_library("X11") or "libX11.so.6"
    try:
        xlib = ctypes.CDLL(name)
    except OSError:
        return f"cannot load Xlib ({name}) to open the X display {display!r}"
    xlib.XOpenDisplay.restype = ctypes.c_void_p
    xlib.XOpenDisplay.argtypes = [ctypes.c_char_p]
    xlib.XCloseDisplay.argtypes = [ctypes.c_void_p]
    handle = xlib.XOpenDisplay(display.encode())
    if not handle:
        return f"cannot open the X display {display!r}"
    xlib.XCloseDisplay(handle)
    return None


class _Monitor(ctypes.Structure):
    """XRandR's XRRMonitorInfo."""

    _fields_ = [("name", ctypes.c_ulong), ("primary", ctypes.c_int), ("automatic", ctypes.c_int),
                ("noutput", ctypes.c_int), ("x", ctypes.c_int), ("y", ctypes.c_int),
                ("width", ctypes.c_int), ("height", ctypes.c_int), ("mwidth", ctypes.c_int),
                ("mheight", ctypes.c_int), ("outputs", ctypes.c_void_p)]


def screen_area() -> tuple[int, int, int, int] | None:
    """The screen a new window opens on, as (x, y, width, height) pixels in the desktop's
    coordinates: the primary monitor as XRandR reports it (the first one without a primary),
    else the X screen's whole size; None where it cannot be known (no X display, Wayland
    without Xwayland, another system)."""
    display = os.environ.get("DISPLAY")
    if not display or not sys.platform.startswith("linux"):
        return None
    try:
        xlib = ctypes.CDLL(ctypes.util.find_library("X11") or "libX11.so.6")
    except OSError:
        return None
    xlib.XOpenDisplay.restype = ctypes.c_void_p
    xlib.XOpenDisplay.argtypes = [ctypes.c_char_p]
    xlib.XCloseDisplay.argtypes = [ctypes.c_void_p]
    for name in ("XDefaultScreen", "XDisplayWidth", "XDisplayHeight"):
        getattr(xlib, name).argtypes = [ctypes.c_void_p] + ([ctypes.c_int] if name != "XDefaultScreen" else [])
    xlib.XDefaultRootWindow.restype = ctypes.c_ulong
    xlib.XDefaultRootWindow.argtypes = [ctypes.c_void_p]
    handle = xlib.XOpenDisplay(display.encode())
    if not handle:
        return None
    try:
        monitor = _primary_monitor(handle, xlib.XDefaultRootWindow(handle))
        if monitor is not None:
            return monitor
        screen = xlib.XDefaultScreen(handle)
        return 0, 0, int(xlib.XDisplayWidth(handle, screen)), int(xlib.XDisplayHeight(handle, screen))
    finally:
        xlib.XCloseDisplay(handle)


def _primary_monitor(handle, root) -> tuple[int, int, int, int] | None:
    """XRandR's primary (else first) active monitor, or None without XRandR 1.5."""
    try:
        xrandr = ctypes.CDLL(ctypes.util.find_library("Xrandr") or "libXrandr.so.2")
        get = xrandr.XRRGetMonitors
    except (OSError, AttributeError):
        return None
    get.restype = ctypes.POINTER(_Monitor)
    get.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.POINTER(ctypes.c_int)]
    xrandr.XRRFreeMonitors.argtypes = [ctypes.POINTER(_Monitor)]
    count = ctypes.c_int(0)
    monitors = get(handle, root, 1, ctypes.byref(count))
    if not monitors:
        return None
    try:
        found = [monitors[k] for k in range(count.value) if monitors[k].width > 0 and monitors[k].height > 0]
        if not found:
            return None
        m = next((m for m in found if m.primary), found[0])
        return int(m.x), int(m.y), int(m.width), int(m.height)
    finally:
        xrandr.XRRFreeMonitors(monitors)


#: Pixels a window leaves free of its screen, across (the frame's borders) and down (a title
#: bar above, a desktop's panel or taskbar below): a window as large as the screen hides its
#: edges under them.
SCREEN_MARGIN = (16, 96)


def fit_window(size: tuple[int, int], screen: tuple[int, int, int, int] | None
               ) -> tuple[tuple[int, int], tuple[int, int]]:
    """Where a window of ``size`` = (width, height) pixels opens on ``screen`` = (x, y, width,
    height) (:func:`screen_area`), and its size: each side cut to the screen less
    :data:`SCREEN_MARGIN`, centred in it (the margin split evenly at least). Returns
    ((x, y), (width, height)); without a known screen, ``size`` as asked at GGUI's usual
    (100, 100)."""
    width, height = int(size[0]), int(size[1])
    if screen is None:
        return (100, 100), (width, height)
    x, y, screen_w, screen_h = screen
    room_w, room_h = screen_w - SCREEN_MARGIN[0], screen_h - SCREEN_MARGIN[1]
    width, height = max(1, min(width, room_w)), max(1, min(height, room_h))
    return (x + max(SCREEN_MARGIN[0] // 2, (screen_w - width) // 2),
            y + max(SCREEN_MARGIN[1] // 2, (screen_h - height) // 2)), (width, height)
