"""The figures the README and docs quote, kept as files the benches write.

A bench that measures a figure the pages quote calls :func:`record`, which writes
``docs/figures/NAME.json``: the figure as the pages print it (``text``), its value and unit,
what was measured, the command that measured it, the machine and the date. The pages quote it
between marks::

    <!-- figure: suite_time -->9 min 37 s<!-- /figure -->

and the README's table of headline figures between ``<!-- figures: table -->`` and
``<!-- /figures -->`` (each figure recorded with ``headline=True``, in name order).
``python benchmarks/figures.py render`` rewrites every mark from the files;
``python benchmarks/figures.py check`` (and ``tests/test_figures.py``) fails where a page
differs from its file, so a page cannot quote a figure no bench wrote.
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import re
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIGURES = ROOT / "docs" / "figures"
FIELDS = ("name", "text", "value", "unit", "what", "command", "machine", "load", "date", "headline")
NAME = re.compile(r"^[a-z][a-z0-9_]*$")
# one quoted figure: the name, then the text the page shows
MARK = re.compile(r"<!-- figure: ([a-z][a-z0-9_]*) -->(.*?)<!-- /figure -->", re.S)
TABLE = re.compile(r"(<!-- figures: table -->\n)(.*?)(<!-- /figures -->)", re.S)


def machine() -> str:
    """This machine in words: CPU model and the CPUs this process may use, e.g.
    ``"2 vCPUs, AMD EPYC 9B45"``."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{cpus} vCPUs, {model}"


def load_average() -> float:
    """The machine's load average over the last minute: sampled when a bench starts, it says
    what else ran beside it."""
    return round(os.getloadavg()[0], 1) if hasattr(os, "getloadavg") else float("nan")


def record(name: str, text: str, value: float, unit: str, *, what: str, command: str,
           load: float | None = None, headline: bool = False, folder: Path = FIGURES) -> Path:
    """Write figure ``name`` (``folder/NAME.json``, whole or not at all).

    Args:
        name: lower-case identifier the pages quote (``suite_time``).
        text: the figure as the pages print it (``"9 min 37 s"``).
        value: the figure as a number, in ``unit``.
        unit: its unit (``"s"``, ``"steps/s"``).
        what: what was measured, one sentence (the table's first column).
        command: the command that measured it, to be run from the repository's root.
        load: the load average when the bench started (:func:`load_average`; None: now; a
            figure taken by hand before its bench existed writes ``float("nan")``: not recorded).
        headline: whether the README's table of headline figures lists it.
    """
    if not NAME.match(name):
        raise ValueError(f"figure name must be lower-case letters, digits and _, got {name!r}")
    if not text or "<!--" in text or "\n" in text:
        raise ValueError(f"figure text must be one line of text, got {text!r}")
    entry = {"name": name, "text": text, "value": float(value), "unit": unit, "what": what,
             "command": command, "machine": machine(), "load": load_average() if load is None else (None if math.isnan(load) else load), "date": datetime.date.today().isoformat(),
             "headline": bool(headline)}
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / f"{name}.json"
    handle, tmp = tempfile.mkstemp(dir=folder, prefix=f".{name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "w") as out:
            json.dump(entry, out, indent=1)
            out.write("\n")
        os.replace(tmp, target)
    except BaseException:
        os.unlink(tmp)
        raise
    return target


def load(folder: Path = FIGURES) -> dict[str, dict]:
    """Every figure in ``folder`` by name; a file whose fields are not :data:`FIELDS` or whose
    name differs from its file's raises ValueError naming the file."""
    figures = {}
    for path in sorted(folder.glob("*.json")):
        entry = json.loads(path.read_text())
        if set(entry) != set(FIELDS) or entry["name"] != path.stem:
            raise ValueError(f"{path}: a figure has the fields {', '.join(FIELDS)} and its file's name")
        figures[entry["name"]] = entry
    return figures


def table(figures: dict[str, dict]) -> str:
    """The README's table of headline figures (Markdown, ending in a newline)."""
    rows = ["| what | figure | measured by | machine, load, date |", "|---|---|---|---|"]
    for entry in sorted(figures.values(), key=lambda e: e["name"]):
        if entry["headline"]:
            rows.append(f"| {entry['what']} | **{entry['text']}** | `{entry['command']}` | "
                        f"{entry['machine']}, {_load_text(entry['load'])}, {entry['date']} |")
    return "\n".join(rows) + "\n"


def _load_text(load) -> str:
    return "load not recorded" if load is None else f"load {load:g}"


def render(page: str, figures: dict[str, dict]) -> str:
    """``page`` (Markdown) with every mark rewritten from ``figures``; a mark naming no figure
    raises ValueError."""
    def quote(match):
        name = match.group(1)
        if name not in figures:
            raise ValueError(f"the page quotes figure {name!r}, which no file in docs/figures/ holds")
        return f"<!-- figure: {name} -->{figures[name]['text']}<!-- /figure -->"

    page = MARK.sub(quote, page)
    return TABLE.sub(lambda m: m.group(1) + table(figures) + m.group(3), page)


def pages() -> list[Path]:
    return [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))


def stale(figures: dict[str, dict] | None = None) -> list[str]:
    """The pages (relative paths) whose marks differ from the figures' files."""
    figures = load() if figures is None else figures
    return [str(p.relative_to(ROOT)) for p in pages() if render(p.read_text(), figures) != p.read_text()]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("action", choices=["render", "check"],
                        help="render: rewrite the pages' marks from docs/figures/; check: list stale pages")
    args = parser.parse_args(argv)
    figures = load()
    if args.action == "check":
        behind = stale(figures)
        for page in behind:
            print(f"{page}: a quoted figure differs from docs/figures/ (python benchmarks/figures.py render)")
        return 1 if behind else 0
    for path in pages():
        text = path.read_text()
        new = render(text, figures)
        if new != text:
            path.write_text(new)
            print(f"rewrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
