"""Case functions for the sweep engine's own tests: no Taichi, so a case costs only a Python
start-up (the worker imports them as ``tests.sweep_cases``)."""
import time


def sleep_then_echo(value: int, seconds: float) -> list[dict]:
    time.sleep(seconds)
    return [{"value": value, "square": value * value}]
