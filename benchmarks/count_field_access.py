"""Where the suite compiles Taichi's own per-field kernels: a pytest plugin that records, per
Taichi program, the first Python-scope use of each field (``field[i] = v``, ``field[i]``,
``to_numpy``, ``from_numpy``, ``fill``; each compiles or loads a kernel for that field) with
the line of the package or the tests that made it, and a report over what it recorded
(docs/first-contact.md, "What an empty cache compiles, by kind").

    rm -rf /tmp/access && mkdir /tmp/access
    TS_ACCESS_LOG=/tmp/access PYTHONPATH=benchmarks .venv/bin/python -m pytest -q -n 2 \\
        -p no:cacheprovider -p count_field_access
    .venv/bin/python benchmarks/count_field_access.py /tmp/access

The commands the tests start in processes of their own are not counted.
"""
import atexit
import collections
import glob
import importlib
import json
import os
import sys
import traceback

_ROOTS = ("taichi_sim/", "tests/")
_seen: set = set()
_sites: collections.Counter = collections.Counter()
_inside = [0]  # a vector field's write goes through its read (of host handles): count the outer call


def _call_site() -> str:
    for frame in reversed(traceback.extract_stack(limit=16)[:-2]):
        path = frame.filename.replace(os.sep, "/")
        for root in _ROOTS:
            at = path.rfind("/" + root)
            if at >= 0:
                return f"{path[at + 1:]}:{frame.lineno}"
    return "elsewhere"


def _record(cls, method: str, kind: str) -> None:
    import taichi as ti

    original = getattr(cls, method)

    def recorded(self, *args, **kwargs):
        key = (id(ti.lang.impl.get_runtime().prog), id(self), kind)
        if not _inside[0] and key not in _seen:
            _seen.add(key)
            _sites[(kind, _call_site())] += 1
        _inside[0] += 1
        try:
            return original(self, *args, **kwargs)
        finally:
            _inside[0] -= 1

    setattr(cls, method, recorded)


def _install() -> None:
    fields = importlib.import_module("taichi.lang.field")
    matrices = importlib.import_module("taichi.lang.matrix")
    for cls in (fields.ScalarField, matrices.MatrixField):
        for method, kind in (("__setitem__", "write"), ("__getitem__", "read"), ("to_numpy", "to_numpy"),
                             ("from_numpy", "from_numpy"), ("fill", "fill")):
            _record(cls, method, kind)
    folder = os.environ.get("TS_ACCESS_LOG")
    if folder:
        atexit.register(lambda: _dump(os.path.join(folder, f"access.{os.getpid()}.json")))


def _dump(path: str) -> None:
    with open(path, "w") as handle:
        json.dump([[kind, site, count] for (kind, site), count in _sites.items()], handle)


def pytest_configure(config):
    _install()


def report(folder: str, top: int = 15) -> None:
    sites, kinds = collections.Counter(), collections.Counter()
    for path in glob.glob(os.path.join(folder, "access.*.json")):
        with open(path) as handle:
            for kind, site, count in json.load(handle):
                sites[(kind, site)] += count
                kinds[kind] += count
    if not sites:
        sys.exit(f"nothing recorded in {folder}")
    print("first uses of a field in a program, by kind:", dict(kinds.most_common()))
    print(f"\nthe {top} call sites with most (uses, kind, line):")
    for (kind, site), count in sites.most_common(top):
        print(f"  {count:6d}  {kind:10s}  {site}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: count_field_access.py FOLDER")
    report(sys.argv[1])
