"""What one of Taichi's own per-field kernels costs: a Python-scope write or read of a 0-D
field, a vector field's ``to_numpy`` and ``from_numpy``, a ``fill``, each done once for 60
fields of their own (so each compiles a kernel or loads it from Taichi's offline cache).
Run it twice with the same, initially empty, cache folder: the first run compiles, the
second loads (docs/first-contact.md, "What an empty cache compiles, by kind").

    rm -rf /tmp/field-kernels
    TI_OFFLINE_CACHE_FILE_PATH=/tmp/field-kernels .venv/bin/python benchmarks/bench_field_kernels.py
    TI_OFFLINE_CACHE_FILE_PATH=/tmp/field-kernels .venv/bin/python benchmarks/bench_field_kernels.py
"""
import time

import numpy as np
import taichi as ti

FIELDS = 60


def per_field_ms(action, fields) -> float:
    start = time.perf_counter()
    for field in fields:
        action(field)
    return 1e3 * (time.perf_counter() - start) / len(fields)


def main() -> None:
    ti.init(arch=ti.cpu, offline_cache=True, log_level=ti.WARN)
    scalars = [ti.field(ti.f64, shape=()) for _ in range(FIELDS)]
    points = [ti.Vector.field(3, ti.f64, shape=()) for _ in range(FIELDS)]
    arrays = [ti.Vector.field(3, ti.f64, shape=100 + i) for i in range(FIELDS)]

    @ti.kernel
    def materialise():
        scalars[0][None] += 0.0

    materialise()  # the memory tree, so that the first field timed does not pay for it
    rows = [
        ("scalar field[None] = v", lambda f: f.__setitem__(None, 1.0), scalars),
        ("scalar field[None]", lambda f: f[None], scalars),
        ("3-vector field[None] = v", lambda f: f.__setitem__(None, [1.0, 2.0, 3.0]), points),
        ("vector field to_numpy", lambda f: f.to_numpy(), arrays),
        ("vector field from_numpy", lambda f: f.from_numpy(np.zeros((f.shape[0], 3))), arrays),
        ("scalar field fill", lambda f: f.fill(0.0), scalars),
    ]
    for label, action, fields in rows:
        print(f"{label:26s} {per_field_ms(action, fields):6.1f} ms a field")


if __name__ == "__main__":
    main()
