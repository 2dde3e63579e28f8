"""Fixtures of the pipeline tests: a fixture that fails a test which leaves a worker process
or a pipeline thread running, and ``arun``, which also fails one that leaves a task running.

Tests run coroutines with ``arun`` (``asyncio.run`` plus the task check), never an asyncio
plug-in.  Worker processes are real (forkserver children running the real fitter).
"""

from __future__ import annotations

from procs import (  # noqa: F401 - fixtures, shared with reliability
    arun, hookable_workers, no_leftover_workers)
