"""``Sweep``: run a study's cases (skipping those its table already holds), write the table
after each one, and give back the rows as the table holds them."""
from __future__ import annotations

import math
import os
import shutil
import signal
import sys
import threading
from pathlib import Path

from ...atomic import write_atomically
from ...errors import ConfigError
from .. import common
from .cases import Case, Study
from .pools import DaskPool, LocalPool
from .table import CASE, CASE_WALL, CONCURRENCY, STUDY, VERSION, read_table, roundtrip, table_path, write_table


def default_jobs() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _stop_on_sigterm():
    """Until the returned function is called, SIGTERM stops the study as Ctrl-C does (the case
    processes run in sessions of their own: a killed driver must stop them itself)."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = signal.signal(signal.SIGTERM, _interrupt)
    return lambda: signal.signal(signal.SIGTERM, previous)


class Sweep:
    """One study's run. Construction checks everything a user can get wrong (``jobs``, the
    scheduler's address, the table already in ``out_dir``) and raises ConfigError before any
    case runs or any file is written.

    ``planned``: every case of the study, in table order (all stages: a later stage's cases
    may be planned with empty ``inputs``, their keys do not depend on them). ``fresh``: ignore
    (and replace) the table there; otherwise its finished cases are kept and not run again.
    ``timeout_s``: a case running longer is stopped and recorded as ``timeout``.
    """

    def __init__(self, study: Study, planned: list[Case], out_dir: Path, *, jobs: int | None = None,
                 scheduler: str | None = None, timeout_s: float | None = None, fresh: bool = False,
                 quiet: bool = False):
        if jobs is not None and jobs < 1:
            raise ConfigError(f"--jobs must be >= 1, got {jobs}")
        if jobs is not None and scheduler:
            raise ConfigError("--jobs is for this machine, --scheduler sends the cases to a cluster: give one of them")
        if timeout_s is not None and not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ConfigError(f"--case-timeout must be a finite number > 0, got {timeout_s}")
        keys = [case.key for case in planned]
        if len(set(keys)) != len(keys):
            raise ValueError(f"{study.name}: two planned cases have the same key")
        self.study, self.out_dir, self.timeout_s, self.quiet = study, Path(out_dir), timeout_s, quiet
        self.order = {key: i for i, key in enumerate(keys)}
        self.path = table_path(out_dir, study)
        self.arrays_dir = self.out_dir / f"{study.name}-arrays"
        self.done = {} if fresh else read_table(self.path, study, planned)
        self.pool = DaskPool(scheduler) if scheduler else LocalPool(jobs or default_jobs())
        if fresh:
            self.path.unlink(missing_ok=True)
            shutil.rmtree(self.arrays_dir, ignore_errors=True)
        self.ran: list[str] = []  # keys of the cases this process ran (the tests count them)

    def _arrays_file(self, case: Case) -> Path:
        return self.arrays_dir / f"{case.key}.npz"

    def finished(self, case: Case, needs_arrays: bool = False) -> bool:
        return case.key in self.done and (not needs_arrays or self._arrays_file(case).exists())

    def run(self, cases: list[Case], desc: str, needs_arrays: bool = False) -> list[dict]:
        """Run those of ``cases`` not finished yet; the rows of all of ``cases``, in plan order.
        ``needs_arrays``: a case whose saved arrays are missing runs again."""
        todo = [case for case in cases if not self.finished(case, needs_arrays)]
        if not self.quiet and cases and not todo:
            print(f"{desc}: all {len(cases)} cases already in {self.path}", file=sys.stderr)
        elif not self.quiet and len(todo) < len(cases):
            print(f"{desc}: {len(cases) - len(todo)} of {len(cases)} cases already in {self.path}, "
                  f"running the other {len(todo)} on {self.pool.where}", file=sys.stderr)
        elif not self.quiet and todo:
            print(f"{desc}: {len(todo)} cases on {self.pool.where}", file=sys.stderr)
        if todo:
            outcomes = self.pool.run(todo, self.timeout_s)
            stop = _stop_on_sigterm()
            try:
                with common.progress_bar(len(todo), desc, self.quiet) as bar:
                    for case, outcome, overlap in outcomes:
                        self._record(case, outcome, overlap)
                        bar.update(1)
            except KeyboardInterrupt:
                print(f"taichi-sim: {desc} stopped; {sum(k in self.done for k in (c.key for c in cases))} of "
                      f"{len(cases)} cases are in {self.path}: the same command finishes the others",
                      file=sys.stderr)
                raise
            finally:
                outcomes.close()  # now, not at garbage collection: stop the cases still running
                stop()
        return self.rows(cases)

    def rows(self, cases: list[Case]) -> list[dict]:
        """The table's rows of ``cases`` (those finished), in the order of ``cases``."""
        return [row for case in cases for row in self.done.get(case.key, [])]

    def arrays(self, case: Case) -> dict:
        import numpy as np

        with np.load(self._arrays_file(case)) as data:
            return {k: data[k] for k in data.files}

    def _record(self, case: Case, outcome: dict, overlap: int) -> None:
        if outcome["status"] == "done":
            rows = outcome["rows"] or [{"status": "skipped", "note": "the case had nothing to measure"}]
        else:
            rows = [self.study.failure_row(case, outcome["status"], outcome["note"])]
        if outcome["arrays"]:
            import numpy as np

            self.arrays_dir.mkdir(exist_ok=True)
            write_atomically(self._arrays_file(case), lambda f: np.savez(f, **outcome["arrays"]))
        head = {STUDY: self.study.name, VERSION: self.study.version, CASE: case.key, **case.columns}
        tail = {CASE_WALL: outcome["wall_s"], CONCURRENCY: overlap}
        # As the table will read back: a fresh run and a resumed one hand on the same values.
        self.done[case.key] = [roundtrip({**head, **row, **tail}) for row in rows]
        self.ran.append(case.key)
        ordered = sorted(self.done.items(), key=lambda item: self.order[item[0]])
        write_table(self.path, [row for _, case_rows in ordered for row in case_rows])

    def close(self) -> None:
        self.pool.close()
