import os

import numpy as np
import pytest

import taichi_sim as ts

# The arch of the f64 / f32 fixtures: the CPU, as CI runs; TAICHI_SIM_TEST_ARCH=gpu runs the
# tests that take them on a GPU (docs/throughput.md, "On a GPU"). Tests that init on their own
# stay on the CPU.
TEST_ARCH = os.environ.get("TAICHI_SIM_TEST_ARCH", "cpu")

# Taichi's kernel cache for the suite (its subprocesses inherit it): a folder of its own, so the
# suite neither evicts a user's kernels nor loses its own. The suite compiles about 10 000
# kernels (cache entries), 234 MB; under Taichi's default cap of 100 MB the cache evicted a
# quarter at a time (least recently used) and the next run compiled most of them again
# (docs/first-contact.md, "The suite's time").
os.environ.setdefault("TI_OFFLINE_CACHE_FILE_PATH",
                      os.path.join(os.path.expanduser("~"), ".cache", "taichi_sim", "test-kernels"))
os.environ.setdefault("TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES", str(1 << 30))
# The suite compiles its kernels "quick" (Taichi's opt_level 0: its IR optimiser's two costliest
# passes left out), which takes about a fifth off an empty-cache run; the answers are the
# optimised code's to rounding, which tests/test_compile_levels.py checks method by method, and
# the tests that compare two runs bit for bit compile "optimised" themselves
# (docs/first-contact.md, "The suite's time").
os.environ.setdefault("TAICHI_SIM_COMPILE", "quick")


@pytest.fixture
def f64():
    """Fresh Taichi runtime in f64 (fields from earlier tests are freed), on TEST_ARCH."""
    ts.init(arch=TEST_ARCH, precision="f64")


@pytest.fixture
def f32():
    ts.init(arch=TEST_ARCH, precision="f32")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def pytest_configure(config):
    config.addinivalue_line("markers", "long: takes tens of seconds; scheduled first")
    config.addinivalue_line("markers", "cpu_only: tests something the CPU backend alone has (skipped on "
                            "TAICHI_SIM_TEST_ARCH=gpu)")


def pytest_collection_modifyitems(config, items):
    """The long tests first: with one worker per core (pytest-xdist), a long test that starts
    last keeps the whole run waiting for it while the other worker idles."""
    items.sort(key=lambda item: item.get_closest_marker("long") is None)
    if TEST_ARCH != "cpu":
        skip = pytest.mark.skip(reason=f"CPU backend only (TAICHI_SIM_TEST_ARCH={TEST_ARCH})")
        for item in items:
            if item.get_closest_marker("cpu_only") is not None:
                item.add_marker(skip)
