"""Several Taichi fields read into numpy, or written from it, by one kernel.

Taichi's ``Field.to_numpy`` and ``from_numpy`` compile a kernel for each field they are given,
the first time a scene of that size and make-up is built, and load it from the kernel cache
in every later process; a part that reads or writes several fields at once does it here with
one kernel for all of them (docs/design.md, "Compile time"). The values travel
through one buffer, float32 when every field is f32 and float64 otherwise (which holds every
f32, f64 and i32 value exactly); where a float64 buffer is needed on a backend that may lack
float64 (Vulkan, Metal), each field is copied by Taichi's own kernel instead.

Fields of shape () (a part's scalars and vectors: a thickness, a plane's point) go through here
too: from Python, ``field[None] = value`` compiles a kernel of Taichi's own for each such field,
and for a vector one per component (``snode_writer``), so a part that sets several of them at
once does it with :func:`write` (docs/design-front-ends.md, "Compile time").
"""

import math

import numpy as np
import taichi as ti
from taichi.lang.matrix import MatrixField

from . import runtime


def _layout(fields) -> tuple:
    """Per field: (offset into the buffer, the field's shape, its element's shape)."""
    rows, offset = [], 0
    for field in fields:
        shape = tuple(int(s) for s in field.shape)
        element = ()
        if isinstance(field, MatrixField):  # a vector field is one of n x 1 (ndim 1)
            element = (field.n, field.m) if field.ndim == 2 else (field.n,)
        rows.append((offset, shape, element))
        offset += math.prod(shape + element)
    return tuple(rows), offset


@ti.func
def _flat(index, shape: ti.template()):
    """Row-major position of ``index`` in a field of ``shape``."""
    flat = 0
    for d in ti.static(range(len(shape))):
        flat = flat * shape[d] + index[d]
    return flat


@ti.func
def _put(out: ti.template(), at, value, element: ti.template(), real: ti.template()):
    """Store one field element (a scalar, vector or matrix of ``element`` shape) at ``out[at:]``."""
    if ti.static(len(element) == 0):
        out[at] = ti.cast(value, real)
    elif ti.static(len(element) == 1):
        for c in ti.static(range(element[0])):
            out[at + c] = ti.cast(value[c], real)
    else:
        for r, c in ti.static(ti.ndrange(element[0], element[1])):
            out[at + r * element[1] + c] = ti.cast(value[r, c], real)


@ti.func
def _take(data: ti.template(), at, field: ti.template(), index: ti.template(), element: ti.template()):
    """Store ``data[at:]`` in ``field[index]`` (an element of ``element`` shape; index None: a
    field of shape ())."""
    if ti.static(len(element) == 0):
        field[index] = ti.cast(data[at], field.dtype)
    elif ti.static(len(element) == 1):
        for c in ti.static(range(element[0])):
            field[index][c] = ti.cast(data[at + c], field.dtype)
    else:
        for r, c in ti.static(ti.ndrange(element[0], element[1])):
            field[index][r, c] = ti.cast(data[at + r * element[1] + c], field.dtype)


@ti.kernel
def _gather(fields: ti.template(), layout: ti.template(), out: ti.types.ndarray(ndim=1), real: ti.template()):
    for k in ti.static(range(len(fields))):
        offset, shape, element = ti.static(layout[k])
        width = ti.static(math.prod(element))
        if ti.static(len(shape) == 0):  # shape (): one element, no loop
            _put(out, offset, fields[k][None], element, real)
        else:
            for index in ti.grouped(fields[k]):
                _put(out, offset + _flat(index, shape) * width, fields[k][index], element, real)


@ti.kernel
def _scatter(fields: ti.template(), layout: ti.template(), data: ti.types.ndarray(ndim=1)):
    for k in ti.static(range(len(fields))):
        offset, shape, element = ti.static(layout[k])
        width = ti.static(math.prod(element))
        if ti.static(len(shape) == 0):
            _take(data, offset, fields[k], None, element)
        else:
            for index in ti.grouped(fields[k]):
                _take(data, offset + _flat(index, shape) * width, fields[k], index, element)


def _views(buffer: np.ndarray, layout: tuple):
    """Each field's part of ``buffer``, shaped as its values (field shape + element shape)."""
    for offset, shape, element in layout:
        yield buffer[offset:offset + math.prod(shape + element)].reshape(shape + element)


def _numpy_dtype(field):
    return np.dtype(ti.lang.util.to_numpy_type(field.dtype))


def _buffer_dtype(fields):
    """float32 when every field is (exact, and no conversion for an f32 scene), else float64."""
    return np.dtype(np.float32) if all(field.dtype == ti.f32 for field in fields) else np.dtype(np.float64)


def _one_kernel(buffer_dtype) -> bool:
    """Whether the backend has the buffer's type: float32 everywhere, float64 surely on the CPU
    and CUDA."""
    if not runtime.is_initialized():
        return False
    return buffer_dtype == np.float32 or runtime.cpu_backend() or runtime.backend() == "cuda"


def read(*fields) -> tuple[np.ndarray, ...]:
    """Copies of ``fields``' values, one numpy array each of shape (field shape + element
    shape) in the field's own dtype, as ``to_numpy`` gives, read by one kernel launch."""
    layout, size = _layout(fields)
    dtype = _buffer_dtype(fields)
    if not _one_kernel(dtype):
        return tuple(field.to_numpy() for field in fields)
    buffer = np.empty(size, dtype)
    _gather(tuple(fields), layout, buffer, ti.f32 if dtype == np.float32 else ti.f64)
    return tuple(view.astype(_numpy_dtype(field), copy=False) for field, view in zip(fields, _views(buffer, layout)))


def write(*pairs) -> None:
    """Write each ``(field, values)`` pair, ``values`` anything numpy reads as an array of the
    field's shape plus its element's shape, with one kernel launch (as ``from_numpy`` each)."""
    fields = tuple(field for field, _ in pairs)
    layout, size = _layout(fields)
    dtype = _buffer_dtype(fields)
    buffer = np.empty(size, dtype)
    views = list(_views(buffer, layout))
    for (field, values), view in zip(pairs, views):
        values = np.asarray(values, dtype)
        if values.shape != view.shape:
            raise ValueError(f"field_io.write: values of shape {values.shape} for a field of shape {view.shape}")
        view[...] = values
    if not _one_kernel(dtype):
        for field, view in zip(fields, views):
            field.from_numpy(view.astype(_numpy_dtype(field)))
        return
    _scatter(fields, layout, buffer)
