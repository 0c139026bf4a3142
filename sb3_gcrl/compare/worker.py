"""Worker process of the local backend: ``python -m sb3_gcrl.compare.worker RUN_DIR``.

Reads ``RUN_DIR/spec.json``, trains and evaluates the run, and writes its result into ``RUN_DIR``. The parent
starts it with stdout/stderr already redirected to ``RUN_DIR/train.log`` (so every byte of output, import
messages included, lands there) and follows its progress through ``RUN_DIR/progress`` (env steps done,
rewritten atomically about every 1 % of the budget).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

SPEC_FILE = "spec.json"
PROGRESS_FILE = "progress"


def read_progress(run_dir: Path) -> int:
    """Env steps a running worker reported so far (0 before its first report)."""
    try:
        return int((run_dir / PROGRESS_FILE).read_text() or 0)
    except (OSError, ValueError):
        return 0


def main(argv: list[str] | None = None) -> int:
    """Run the job in ``argv[0]``; exit code 0 once its result is written (finished or failed)."""
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
