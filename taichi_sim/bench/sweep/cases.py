"""What a study is made of: cases as data, and the study that names, versions and plans them."""
from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field
from typing import Any, Callable


def canonical(value: Any) -> str:
    """``value`` as JSON with sorted keys and floats written exactly (the case's identity)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=float)


@dataclass(frozen=True)
class Case:
    """One independent unit of a study.

    ``function``: ``"module:name"`` of the function the worker calls with ``**params`` and
    ``**inputs``; it returns a list of row dicts (or ``(rows, arrays)``, arrays a dict of numpy
    arrays the driver saves beside the table). ``params``: plain JSON values that decide the
    result; they name the case (:attr:`key`), so a study re-planned with other parameters has
    other cases. ``inputs``: data handed to the function that follows from the params (a
    reference solution computed by an earlier stage); not part of the name. ``columns``: what
    the table shows about the case on every one of its rows (scene, integrator, ...), also on a
    row that records a timeout or a crash.
    """

    function: str
    params: dict
    columns: dict
    inputs: dict = field(default_factory=dict)

    @property
    def key(self) -> str:
        digest = hashlib.sha1(canonical([self.function, self.params]).encode()).hexdigest()[:12]
        name = "-".join(str(v) for v in self.columns.values())
        return re.sub(r"[^A-Za-z0-9._=+-]+", "_", name).strip("_") + "-" + digest

    def payload(self) -> str:
        """What the worker reads on stdin."""
        return canonical({"function": self.function, "params": self.params, "inputs": self.inputs})


def _failure_row(case: Case, status: str, note: str) -> dict:
    return {"status": status, "note": note}


@dataclass
class Study:
    """A named, versioned study: ``name`` names its table (``NAME.csv``), ``version`` changes
    when its rows change meaning, so an old table is refused instead of mixed in.
    ``failure_row(case, status, note)``: the study's row for a case that timed out or crashed
    (``status`` is ``timeout`` or ``error``)."""

    name: str
    version: int
    failure_row: Callable[[Case, str, str], dict] = _failure_row
