import numpy as np
import pytest

import taichi_sim as ts


@pytest.fixture
def f64():
    """Fresh Taichi runtime on the CPU in f64 (fields from earlier tests are freed)."""
    ts.init(arch="cpu", precision="f64")


@pytest.fixture
def f32():
    ts.init(arch="cpu", precision="f32")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def pytest_configure(config):
    config.addinivalue_line("markers", "long: takes tens of seconds; scheduled first")


def pytest_collection_modifyitems(config, items):
    """The long tests first: with one worker per core (pytest-xdist), a long test that starts
    last keeps the whole run waiting for it while the other worker idles."""
    items.sort(key=lambda item: item.get_closest_marker("long") is None)
