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
