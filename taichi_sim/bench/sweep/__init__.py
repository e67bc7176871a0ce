"""The sweep engine: a study is a list of independent cases, each run in a fresh worker process
(locally, N at a time, or on a Dask cluster), its rows written to the study's table as it ends.

:mod:`.cases` says what a case and a study are, :mod:`.table` reads and writes the table,
:mod:`.worker` is the process that runs one case, :mod:`.local` and :mod:`.dask_pool` are the
two ways to run many, and :mod:`.engine` ties them together (:class:`Sweep`).
"""
from .cases import Case, Study
from .engine import Sweep, default_jobs

__all__ = ["Case", "Study", "Sweep", "default_jobs"]
