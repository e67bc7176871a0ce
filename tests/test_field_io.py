"""Several fields to and from numpy in one kernel (taichi_sim.field_io), against Taichi's own."""
import numpy as np
import pytest
import taichi as ti

import taichi_sim as ts
from taichi_sim import field_io


@pytest.mark.parametrize("one_kernel", [True, False])
@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_a_round_trip_is_exact_and_reads_as_taichis_own(precision, one_kernel, rng, monkeypatch):
    ts.init(precision=precision)
    # False: a backend without float64, where each field goes through Taichi's own copy
    monkeypatch.setattr(field_io, "_one_kernel", lambda dtype: one_kernel)
    real = ti.f64 if precision == "f64" else ti.f32
    fields = (ti.field(real, shape=5), ti.Vector.field(3, real, shape=(4, 2)), ti.field(ti.i32, shape=7),
              ti.Matrix.field(2, 3, real, shape=3), ti.field(real, shape=()), ti.Vector.field(3, real, shape=()),
              ti.field(ti.i32, shape=()))
    values = (rng.normal(size=5), rng.normal(size=(4, 2, 3)), rng.integers(-2**31, 2**31 - 1, 7),
              rng.normal(size=(3, 2, 3)), rng.normal(size=()), rng.normal(size=3), rng.integers(-2**31, 0, ()))
    field_io.write(*zip(fields, values))
    read = field_io.read(*fields)
    for field, value, got in zip(fields, values, read):
        own = field.to_numpy()
        if not field.shape:  # shape (): also what item access reads
            item = field[None]
            assert np.array_equal(item.to_numpy() if isinstance(item, ti.Matrix) else item, value.astype(own.dtype))
        assert np.array_equal(own, value.astype(own.dtype))  # written where from_numpy would
        assert got.dtype == own.dtype and np.array_equal(got, own)  # read as to_numpy reads
    # without the i32 fields the buffer is float32 in an f32 scene, float64 in an f64 one
    real_only = (fields[0], fields[1], fields[3], fields[4], fields[5])
    field_io.write(*zip(real_only, (-v for v in (values[0], values[1], values[3], values[4], values[5]))))
    for field, got in zip(real_only, field_io.read(*real_only)):
        assert got.dtype == field.to_numpy().dtype and np.array_equal(got, field.to_numpy())
    assert np.array_equal(fields[0].to_numpy(), (-values[0]).astype(fields[0].to_numpy().dtype))


def test_values_of_the_wrong_shape_are_refused(f64):
    vectors = ti.Vector.field(3, ti.f64, shape=4)
    with pytest.raises(ValueError, match=r"values of shape \(4,\) for a field of shape \(4, 3\)"):
        field_io.write((vectors, np.zeros(4)))
    with pytest.raises(ValueError, match=r"values of shape \(2,\) for a field of shape \(3,\)"):
        field_io.write((ti.Vector.field(3, ti.f64, shape=()), np.zeros(2)))
