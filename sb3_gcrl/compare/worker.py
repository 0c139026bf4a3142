"""Worker process of the local backend: ``python -m sb3_gcrl.compare.worker RUN_DIR``.

Reads ``RUN_DIR/spec.json``, trains and evaluates the run, and writes its result into ``RUN_DIR``. The parent
starts it with stdout/stderr already redirected to ``RUN_DIR/train.log`` (so every byte of output, import
messages included, lands there) and follows its progress through ``RUN_DIR/progress`` (env steps done,
rewritten atomically about every 1 % of the budget). A worker dies with its parent (:func:`die_with_parent`), so a
killed ``compare`` leaves no orphan runs writing into the folder that the next ``compare`` resumes.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

SPEC_FILE = "spec.json"
PROGRESS_FILE = "progress"
#: environment variable through which the parent passes its pid to the worker
PARENT_PID_ENV = "SB3_GCRL_COMPARE_PARENT_PID"
#: ``prctl`` option: signal sent to this process when its parent dies (Linux, <linux/prctl.h>)
PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int | None = None, poll_interval: float = 1.0) -> None:
    """End this process as soon as its parent process dies (even by SIGKILL).

    On Linux the kernel sends SIGKILL on the parent's death (``prctl(PR_SET_PDEATHSIG)``); elsewhere a daemon
    thread polls the parent's pid. A parent that died before this call is noticed too.

    :param parent_pid: the parent's pid (default: the current parent).
    :param poll_interval: seconds between checks of the watchdog thread (where ``prctl`` is unavailable).
    """
    parent_pid = os.getppid() if parent_pid is None else int(parent_pid)
    armed = False
    if sys.platform.startswith("linux"):
        import ctypes

        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
    if os.getppid() != parent_pid:  # the parent died before the watch was armed
        os._exit(1)
    if armed:
        return

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_interval)
        os._exit(1)

    threading.Thread(target=watch, name="die-with-parent", daemon=True).start()


def read_progress(run_dir: Path) -> int:
    """Env steps a running worker reported so far (0 before its first report)."""
    try:
        return int((run_dir / PROGRESS_FILE).read_text() or 0)
    except (OSError, ValueError):
        return 0


def main(argv: list[str] | None = None) -> int:
    """Run the job in ``argv[0]``; exit code 0 once its result is written (finished or failed)."""
    parent = os.environ.get(PARENT_PID_ENV)
    die_with_parent(int(parent) if parent else None)
    from sb3_gcrl.compare.run import RunSpec, execute_run
    from sb3_gcrl.compare.storage import atomic_write_text, write_run_result

    run_dir = Path((sys.argv[1:] if argv is None else argv)[0])
    spec = RunSpec.from_dict(json.loads((run_dir / SPEC_FILE).read_text()))
    done = 0

    def report(steps: int) -> None:
        nonlocal done
        done += steps
        atomic_write_text(run_dir / PROGRESS_FILE, str(done))

    result = execute_run(spec, run_dir, sys.stdout, report_progress=report)
    write_run_result(run_dir, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
