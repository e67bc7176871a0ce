"""What an empty kernel cache costs the suite: the compiled kernels a run left in a Taichi
offline-cache folder, counted by kind, and the per-file difference between two runs' JUnit
reports (docs/first-contact.md, "What an empty cache compiles, by kind").

    rm -rf /tmp/cold && mkdir /tmp/cold
    TI_OFFLINE_CACHE_FILE_PATH=/tmp/cold TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES=1073741824 \\
        .venv/bin/python -m pytest -q -n 2 -p no:cacheprovider --junitxml=/tmp/cold.xml
    TI_OFFLINE_CACHE_FILE_PATH=/tmp/cold TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES=1073741824 \\
        .venv/bin/python -m pytest -q -n 2 -p no:cacheprovider --junitxml=/tmp/warm.xml
    .venv/bin/python benchmarks/suite_compile_report.py kernels /tmp/cold
    .venv/bin/python benchmarks/suite_compile_report.py files /tmp/cold.xml /tmp/warm.xml

A cache entry (``*.tic``, Taichi 1.7's LLVM CPU cache) holds a kernel's metadata as JSON and
its LLVM IR; the first task name in the metadata names the kernel.
"""
import collections
import os
import re
import sys
import xml.etree.ElementTree as ElementTree

# Taichi's own kernels, by the Python-scope call that compiles one per field (or per field
# component, for a vector field's accessors).
TAICHI_KINDS = {
    "snode_writer": "field[i] = value (Python scope)",
    "snode_reader": "field[i] (Python scope)",
    "ext_arr_to_matrix": "from_numpy",
    "ext_arr_to_tensor": "from_numpy",
    "matrix_to_ext_arr": "to_numpy",
    "tensor_to_ext_arr": "to_numpy",
    "fill_field": "fill",
}


def kernel_name(entry: bytes) -> str:
    """The kernel an entry compiles: its first task's name without Taichi's numbering."""
    tasks = entry.find(b'"tasks":[')
    match = re.search(rb'"name":"([^"]+)"', entry[tasks:]) if tasks >= 0 else None
    if match is None:
        return "?"
    name = match.group(1).decode()
    for pattern in (r"_c\d+_\d+_kernel.*", r"_\d+_kernel.*", r"_kernel_\d+.*"):
        name = re.sub(pattern, "", name)
    return name


def report_kernels(folder: str, top: int = 25) -> None:
    entries, size = collections.Counter(), collections.Counter()
    for file in os.listdir(folder):
        if file.endswith(".tic"):
            with open(os.path.join(folder, file), "rb") as handle:
                data = handle.read()
            name = kernel_name(data)
            entries[name] += 1
            size[name] += len(data)
    total = sum(entries.values())
    if not total:
        sys.exit(f"no cache entries (*.tic) in {folder}")
    print(f"{total} entries, {len(entries)} kernels by name, {sum(size.values()) / 1e6:.0f} MB")
    kinds = collections.Counter()
    for name, count in entries.items():
        kinds[TAICHI_KINDS.get(name, "the package's kernels")] += count
    print("\nby kind:")
    for kind, count in kinds.most_common():
        print(f"  {count:6d}  {100 * count / total:4.1f} %  {kind}")
    print(f"\nthe {top} kernels with most entries (entries, MB, name):")
    for name, count in entries.most_common(top):
        print(f"  {count:6d}  {size[name] / 1e6:5.1f}  {name}")


def file_times(report: str) -> collections.Counter:
    times = collections.Counter()
    for case in ElementTree.parse(report).iter("testcase"):
        times[case.get("classname")] += float(case.get("time") or 0.0)
    return times


def report_files(cold_report: str, warm_report: str, top: int = 15) -> None:
    cold, warm = file_times(cold_report), file_times(warm_report)
    print(f"tests' time: {sum(cold.values()):.0f} s cold, {sum(warm.values()):.0f} s warm "
          f"(both workers together)")
    print(f"\nthe {top} files the empty cache costs most (cold - warm, cold, warm; seconds):")
    for name in sorted(cold, key=lambda n: warm.get(n, 0.0) - cold[n])[:top]:
        print(f"  {cold[name] - warm.get(name, 0.0):6.1f}  {cold[name]:6.1f}  {warm.get(name, 0.0):6.1f}  {name}")


def main(argv: list[str]) -> None:
    if len(argv) == 2 and argv[0] == "kernels":
        report_kernels(argv[1])
    elif len(argv) == 3 and argv[0] == "files":
        report_files(argv[1], argv[2])
    else:
        sys.exit("usage: suite_compile_report.py kernels CACHE_FOLDER | files COLD.xml WARM.xml")


if __name__ == "__main__":
    main(sys.argv[1:])
