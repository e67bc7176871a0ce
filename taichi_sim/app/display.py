"""Whether an on-screen window can be opened, asked before GLFW is (it ends the process).

GGUI opens windows with GLFW, which on Linux talks to an X server (a Wayland session provides
one through Xwayland). When ``DISPLAY`` names a server that does not answer, GLFW prints
"cannot initialize GLFW" and exits with status 1, so nothing can catch it: the launcher asks
Xlib first, as GLFW would.
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
