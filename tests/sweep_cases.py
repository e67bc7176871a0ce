"""Case functions for the sweep engine's own tests: no Taichi, so a case costs only a Python
start-up (the worker imports them as ``tests.sweep_cases``)."""
import os
import time


def sleep_then_echo(value: int, seconds: float) -> list[dict]:
    time.sleep(seconds)
    return [{"value": value, "square": value * value}]


def echo_after(value: int, wait_for: str, mark: str, gap: float) -> list[dict]:
    """Once the file ``wait_for`` exists ('' waits for nothing), wait ``gap`` seconds more,
    create ``mark`` and return: cases chained this way end in the chain's order, at least
    ``gap`` apart, however slowly the machine starts their processes (a minute at most, so a
    chain that cannot run all at once fails, not hangs). The gap outlasts a case's exit and the
    sweep's collecting it, which the marks alone would not."""
    deadline = time.monotonic() + 60.0
    while wait_for and not os.path.exists(wait_for):
        if time.monotonic() > deadline:
            raise TimeoutError(f"{wait_for} never appeared")
        time.sleep(0.01)
    time.sleep(gap)
    with open(mark, "w"):
        pass
    return [{"value": value, "square": value * value}]


def echo_with_arrays(value: int) -> tuple[list[dict], dict]:
    """A row and an array, as a study's reference stage returns them."""
    import numpy as np

    return [{"value": value}], {"values": np.full(3, float(value))}
