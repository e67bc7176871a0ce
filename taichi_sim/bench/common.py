"""What every bench command shares: the output folder, CSV/JSON/PNG writing, machine facts,
timing and order fits, the progress bar."""
from __future__ import annotations

import csv
import datetime
import io
import json
import math
import os
import platform
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from ..atomic import check_can_create, write_atomically
from ..errors import ConfigError


def prepare_out_dir(path: str | os.PathLike) -> Path:
    """Create ``path`` (parents too) and check it is a writable folder; ConfigError otherwise."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {str(out)!r} is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--out {str(out)!r}: cannot create the directory ({exc.strerror})") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise ConfigError(f"--out {str(out)!r}: permission denied")
    check_can_create(out / "bench", out)
    return out


INSTALL_HINT = "./run.sh installs it, or .venv/bin/pip install -e '.[bench]'"


def have_scipy() -> bool:
    try:
        import scipy.integrate  # noqa: F401
    except ImportError:
        return False
    return True


def have_matplotlib() -> bool:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def jsonable(value):
    """``value`` with numpy scalars/arrays made plain and NaN/inf replaced by None (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, (np.bool_,)):
        return bool(value)
    return value


def write_outputs(out_dir: Path, name: str, rows: list[dict], payload: dict,
                  plot: Callable[[Path], None] | None) -> dict[str, Path | None]:
    """Write ``NAME.csv`` (one line per row), ``NAME.json`` (``payload`` plus the rows) and,
    when matplotlib is installed, ``NAME.png`` (``plot(path)``). Each file is written to a
    temporary name first, so a failure leaves no partial file. Returns the paths (png: None
    when not written)."""
    out_dir = Path(out_dir)
    columns: list[str] = []
    for row in rows:
        for key in row:
            if key not in columns:
                columns.append(key)

    def write_csv(f):
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _csv_value(row.get(k)) for k in columns})

    csv_path, json_path, png_path = (out_dir / f"{name}.{ext}" for ext in ("csv", "json", "png"))
    write_atomically(csv_path, write_csv, binary=False, newline="")
    document = jsonable({**payload, "rows": rows})
    write_atomically(json_path, lambda f: json.dump(document, f, indent=1, allow_nan=False), binary=False)
    written_png = None
    if plot is not None and have_matplotlib():
        import matplotlib

        matplotlib.use("Agg")
        buffer = io.BytesIO()
        plot(buffer)
        data = _palette_png(buffer.getvalue())
        write_atomically(png_path, lambda f: f.write(data))
        written_png = png_path
    return {"csv": csv_path, "json": json_path, "png": written_png}


def _palette_png(data: bytes) -> bytes:
    """The PNG re-encoded with a 256-colour palette (a plot has few colours: ~3x smaller)."""
    try:
        from PIL import Image
    except ImportError:
        return data
    image = Image.open(io.BytesIO(data)).convert("RGB")
    out = io.BytesIO()
    image.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(out, format="PNG", optimize=True)
    return out.getvalue()


def _csv_value(value):
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(jsonable(value))
    return "" if value is None else value


def report_written(paths: dict, quiet: bool) -> None:
    """List the files written (unless ``quiet``); a plot that was not drawn is said on stderr
    even when quiet, since a missing file is not a matter of verbosity."""
    if paths.get("png") is None:
        print(f"taichi-sim: no plot written ({paths['json'].stem}.png): matplotlib is not installed "
              f"({INSTALL_HINT})", file=sys.stderr)
    if quiet:
        return
    for kind in ("csv", "json", "png"):
        if paths.get(kind) is not None:
            print(f"wrote {paths[kind]}")


def machine_info() -> dict:
    """Facts about the machine and software a benchmark ran on."""
    info = {"platform": platform.platform(), "machine": platform.machine(), "cpu": _cpu_model(),
            "cpu_count": os.cpu_count(), "memory_gb": _memory_gb(), "python": platform.python_version(),
            "numpy": np.__version__, "date": datetime.datetime.now().isoformat(timespec="seconds")}
    try:
        import taichi

        info["taichi"] = ".".join(str(v) for v in taichi.__version__)
    except Exception:  # pragma: no cover - taichi is a dependency
        pass
    try:
        import scipy

        info["scipy"] = scipy.__version__
    except ImportError:
        info["scipy"] = None
    info["git_commit"] = _git_commit()
    return info


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _memory_gb() -> float | None:
    return round(memory_bytes("MemTotal") / 2**30, 1) if memory_bytes("MemTotal") else None


def memory_bytes(key: str = "MemAvailable") -> int | None:
    """A field of /proc/meminfo in bytes (None where there is no /proc)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _git_commit() -> str | None:
    try:
        root = Path(__file__).resolve().parents[2]
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                             text=True, timeout=5)
        return out.stdout.strip() or None
    except Exception:
        return None


def command_line() -> str:
    """How this process was started, as a shell line (``taichi-sim ...``)."""
    args = sys.argv[1:]
    return "taichi-sim " + " ".join(args) if args else "taichi-sim"


def fit_slope(xs: Iterable[float], ys: Iterable[float]) -> float:
    """Least-squares slope of log(y) against log(x)."""
    xs, ys = np.asarray(list(xs), float), np.asarray(list(ys), float)
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])


def median_and_range(samples: list[float]) -> tuple[float, float, float]:
    return statistics.median(samples), min(samples), max(samples)


def progress_bar(total: int, desc: str, quiet: bool):
    """A tqdm bar on stderr (hidden when quiet or when stderr is not a terminal)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="task", disable=True if quiet else None, leave=False,
                mininterval=0.3, file=sys.stderr)


def format_table(header: list[str], rows: list[list[Any]]) -> str:
    """A plain fixed-width text table."""
    cells = [[str(c) for c in header]] + [[_cell(c) for c in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _cell(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if math.isnan(value):
            return "-"
        if math.isinf(value):
            return "inf"
        return f"{value:.4g}"
    return str(value)
