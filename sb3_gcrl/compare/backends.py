"""Where the runs of a comparison execute: a local pool of worker processes, or a Ray cluster.

Both backends call :func:`~sb3_gcrl.compare.run.execute_run` once per run in a process of its own with one
torch thread, and both write each result with :func:`~sb3_gcrl.compare.storage.write_run_result` as soon
as the run ends, so an interruption loses only the runs in flight.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from abc import ABC, abstractmethod
from collections import deque
from io import StringIO
from pathlib import Path
from typing import Any, Protocol

from sb3_gcrl.compare.run import RunResult, RunSpec, execute_run
from sb3_gcrl.compare.storage import LOG_FILE, read_run_record, reset_run_dir, write_run_result
from sb3_gcrl.compare.worker import PARENT_PID_ENV, SPEC_FILE, read_progress

#: one job = a run and its folder
Job = tuple[RunSpec, Path]


class RunEvents(Protocol):
    """What a backend reports while it works (implemented by the comparison's progress display)."""

    def on_start(self, spec: RunSpec) -> None: ...

    def on_progress(self, spec: RunSpec, steps: int) -> None: ...

    def on_end(self, spec: RunSpec, status: str, error: str = "", log_path: Path | None = None) -> None:
        """A run ended: ``status`` ``"finished"`` or ``"failed"`` (then ``error`` and the run's ``log_path``)."""


def available_cores() -> int:
    """CPU cores this process may use (affinity-aware where the OS tells)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


class Backend(ABC):
    """Executes jobs and stores their results; must survive the failure of any single run."""

    @abstractmethod
    def run(self, jobs: list[Job], events: RunEvents) -> None:
        """Execute every job, writing each result into its folder when it ends.

        :param jobs: runs to do (their folders are reset first).
        :param events: progress receiver.
        """


class LocalProcessBackend(Backend):
    """At most ``n_workers`` runs at a time, each in a fresh ``python -m sb3_gcrl.compare.worker`` process.

    A process per run isolates runs completely: a crash (even a segfault or an out-of-memory kill) is recorded
    as a failed run and the other runs go on. Workers run detached from the terminal's process group, so Ctrl-C
    reaches only this process, which then stops the runs in flight; their output goes to each run's
    ``train.log``, and they get one thread for torch and OpenMP (faiss, MKL). Workers die with this process,
    even when it is SIGKILLed (:func:`~sb3_gcrl.compare.worker.die_with_parent`).

    :param n_workers: parallel runs; default: the number of available cores.
    :param poll_interval: seconds between checks of the workers.
    """

    def __init__(self, n_workers: int | None = None, poll_interval: float = 0.2) -> None:
        if n_workers is not None and n_workers < 1:
            raise ValueError(f"n_workers must be >= 1, got {n_workers}")
        self.n_workers = n_workers or available_cores()
        self.poll_interval = poll_interval

    def _start(self, spec: RunSpec, run_dir: Path) -> subprocess.Popen:
        reset_run_dir(run_dir)
        (run_dir / SPEC_FILE).write_text(json.dumps(spec.to_dict(), indent=2))
        environment = {
            **os.environ,
            "OMP_NUM_THREADS": "1",
            "MKL_NUM_THREADS": "1",
            "PYTHONUNBUFFERED": "1",
            PARENT_PID_ENV: str(os.getpid()),
        }
        with open(run_dir / LOG_FILE, "ab") as log:  # after the log of the run's earlier parts, if it has any
            return subprocess.Popen(
                [sys.executable, "-m", "sb3_gcrl.compare.worker", str(run_dir)],
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                env=environment,
                start_new_session=True,
            )

    def run(self, jobs: list[Job], events: RunEvents) -> None:
        pending = deque(jobs)
        running: dict[Path, tuple[subprocess.Popen, RunSpec, int]] = {}  # run_dir -> (process, spec, steps seen)
        try:
            while pending or running:
                while pending and len(running) < self.n_workers:
                    spec, run_dir = pending.popleft()
                    running[run_dir] = (self._start(spec, run_dir), spec, 0)
                    events.on_start(spec)
                time.sleep(self.poll_interval)
                for run_dir, (process, spec, seen) in list(running.items()):
                    steps = read_progress(run_dir)
                    if steps > seen:
                        events.on_progress(spec, steps - seen)
                        running[run_dir] = (process, spec, steps)
                    if process.poll() is None:
                        continue
                    del running[run_dir]
                    status, error = self._final_status(process.returncode, spec, run_dir)
                    events.on_end(spec, status, error=error, log_path=run_dir / LOG_FILE)
        finally:
            for process, _, _ in running.values():  # interrupted: stop the runs in flight
                process.terminate()
            for process, _, _ in running.values():
                try:
                    process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    process.kill()

    @staticmethod
    def _final_status(returncode: int, spec: RunSpec, run_dir: Path) -> tuple[str, str]:
        """Status and error of an ended worker's run (a worker that wrote no result is recorded as failed)."""
        record = read_run_record(run_dir)
        if record is not None:
            return str(record["status"]), str(record.get("error") or "")
        # the worker died before writing its result (segfault, out-of-memory kill, import error...)
        how = f"killed by signal {-returncode}" if returncode < 0 else f"exit code {returncode}"
        error = f"worker process ended without a result ({how}); see {run_dir / LOG_FILE}"
        write_run_result(run_dir, RunResult(spec, "failed", error=error))
        return "failed", error


def _ray_worker(spec_data: dict[str, Any], run_dir: str, progress: Any, index: int) -> RunResult:
    """A run as a Ray task; returns the result (with its log) to the driver, which stores it."""
    spec = RunSpec.from_dict(spec_data)
    # RL-Zoo's outputs go into the run folder when this node sees it (local cluster, shared file system)
    zoo_dir = Path(run_dir) if Path(run_dir).is_dir() else Path(tempfile.mkdtemp(prefix="sb3_gcrl_run_"))
    log = StringIO()

    def report(steps: int) -> None:
        with contextlib.suppress(Exception):  # progress is best effort; never fail a run for it
            progress.put_nowait((index, steps))

    result = execute_run(spec, zoo_dir, log, report_progress=report)
    result.log = log.getvalue()
    return result


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as error:
        raise ImportError(
            'The Ray backend needs Ray: pip install "sb3-gcrl[ray]" (or pip install "ray[default]")'
        ) from error
    return ray


class RayBackend(Backend):
    """Send runs to a Ray cluster as tasks of ``cpus_per_run`` CPUs each (``--backend ray``).

    Connects to ``address`` (``"auto"`` = the running cluster, ``ray://host:10001`` = a remote one), or starts a
    local Ray instance when ``address`` is None and Ray is not initialised yet (then shut down at the end).
    Every node must have ``sb3-gcrl`` installed. Results (evaluations, status, log) come back to the driver,
    which writes them; RL-Zoo's own files stay on the worker node unless it shares the output folder.

    :param address: Ray address, or None for a local instance.
    :param num_cpus: CPUs of the local instance (ignored when connecting to a cluster).
    :param cpus_per_run: CPUs reserved per run.
    :param poll_interval: seconds between checks of the tasks.
    """

    def __init__(
        self,
        address: str | None = None,
        num_cpus: int | None = None,
        cpus_per_run: float = 1.0,
        poll_interval: float = 0.5,
    ) -> None:
        self.ray = _import_ray()
        self.address = address
        self.num_cpus = num_cpus
        self.cpus_per_run = cpus_per_run
        self.poll_interval = poll_interval

    def run(self, jobs: list[Job], events: RunEvents) -> None:
        ray = self.ray
        owns_ray = not ray.is_initialized()
        if owns_ray:
            init_kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
            if self.address is None:
                init_kwargs["num_cpus"] = self.num_cpus or available_cores()
                # workers import this package from the same interpreter and path as the driver
                init_kwargs["runtime_env"] = {"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}}
            ray.init(address=self.address, **init_kwargs)
        from ray.util.queue import Queue

        progress = Queue()
        task = ray.remote(num_cpus=self.cpus_per_run, max_retries=0)(_ray_worker)
        in_flight: dict[Any, tuple[RunSpec, Path]] = {}
        try:
            for index, (spec, run_dir) in enumerate(jobs):
                reset_run_dir(run_dir)
                in_flight[task.remote(spec.to_dict(), str(run_dir), progress, index)] = (spec, run_dir)
                events.on_start(spec)
            while in_flight:
                done, _ = ray.wait(list(in_flight), num_returns=1, timeout=self.poll_interval)
                for index, steps in progress.get_nowait_batch(progress.qsize()):
                    events.on_progress(jobs[index][0], steps)
                for ref in done:
                    spec, run_dir = in_flight.pop(ref)
                    try:
                        result = ray.get(ref)
                    except ray.exceptions.RayError as error:  # worker died, task cancelled, ...
                        result = RunResult(spec, "failed", error=f"Ray task failed: {error!r}")
                    write_run_result(run_dir, result)
                    events.on_end(spec, result.status, error=result.error, log_path=run_dir / LOG_FILE)
        finally:
            for ref in in_flight:
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
            with contextlib.suppress(Exception):
                progress.shutdown()
            if owns_ray:
                ray.shutdown()
