"""The study's table on disk: ``NAME.csv`` rewritten (atomically) after every case, read back
to resume. Every row carries the study's name and version and its case's key, so a table from
another study, another version or another configuration is refused, never mixed in."""
from __future__ import annotations

import csv
import json
from pathlib import Path

from ...atomic import write_atomically
from ...errors import ConfigError
from .. import common
from .cases import Case, Study

STUDY, VERSION, CASE = "study", "study_version", "case"
CASE_WALL, CONCURRENCY = "case_wall_s", "concurrency"
# Columns that measure the machine, not the physics: they differ between two runs of one study.
MACHINE_COLUMNS = (CASE_WALL, CONCURRENCY)


def table_path(out_dir: Path, study: Study) -> Path:
    return Path(out_dir) / f"{study.name}.csv"


def columns_of(rows: list[dict]) -> list[str]:
    columns: list[str] = []
    for row in rows:
        for key in row:
            if key not in columns and not key.startswith("_"):
                columns.append(key)
    return columns


def write_table(path: Path, rows: list[dict]) -> None:
    """All ``rows`` to ``path`` as CSV, through a temporary file (a stop never leaves half a
    table). Keys starting with ``_`` stay out."""
    columns = columns_of(rows)

    def write(f):
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: common._csv_value(row.get(k)) for k in columns})

    write_atomically(path, write, binary=False, newline="")


def parse_value(text: str):
    """A CSV cell back to the value written (int, float, bool, list/dict, None for empty, str)."""
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
        return value
    except ValueError:
        pass
    if text[:1] in "[{":
        try:
            return json.loads(text)
        except ValueError:
            pass
    return text


def roundtrip(row: dict) -> dict:
    """``row`` as it reads back from the table (floats exact, NaN as None, lists as lists)."""
    return {k: parse_value(str(common._csv_value(v))) for k, v in row.items() if not k.startswith("_")}


def read_table(path: Path, study: Study, planned: list[Case]) -> dict[str, list[dict]]:
    """The rows of an existing table grouped by case key (empty when there is none).
    ConfigError when it is not this study's, not this version's, or holds cases this plan does
    not have (another configuration)."""
    path = Path(path)
    if not path.exists():
        return {}
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames or []
            raw = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ConfigError(f"{path} is not a readable table ({exc}); use another --out or --fresh") from None
    if not {STUDY, VERSION, CASE} <= set(header):
        raise ConfigError(f"{path} was not written by the sweep engine (an older version?): "
                          f"use another --out, or --fresh to replace it")
    for line in raw:
        if line[STUDY] != study.name or parse_value(line[VERSION]) != study.version:
            raise ConfigError(f"{path} holds a {line[STUDY]!r} table of version {line[VERSION]}, not "
                              f"{study.name!r} version {study.version}: use another --out, or --fresh "
                              f"to replace it")
    keys = {case.key for case in planned}
    done: dict[str, list[dict]] = {}
    for line in raw:
        row = {k: parse_value(v) for k, v in line.items() if k is not None}
        done.setdefault(line[CASE], []).append(row)
    foreign = [key for key in done if key not in keys]
    if foreign:
        raise ConfigError(f"{path} holds {len(foreign)} case(s) this study does not plan (e.g. {foreign[0]}: "
                          f"other options): use another --out, the same options, or --fresh")
    return done
