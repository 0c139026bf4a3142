"""On-disk layout of a comparison and atomic writes (resume = skip runs whose ``run.json`` says finished).

::

    OUT/
      comparison.json            settings of the last invocation
      runs/ENV/METHOD/seed_S/
        evaluations.csv          one row per evaluation (see EVALUATION_COLUMNS)
        run.json                 spec, status, wall time, error; written last (its presence = run ended)
        train.log                stdout/stderr of the run
        visited_goals.npy        achieved goals of the training data (2-D goal spaces of off-policy agents)
        zoo/                     RL-Zoo's own outputs (config.yml, args.yml, monitor.csv, model if saved)
      curves.csv scores.csv summary.csv curves.png report.md (+ memory_*.png, visitation_*.png)
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from sb3_gcrl.compare.evaluation import EVALUATION_COLUMNS
from sb3_gcrl.compare.run import RunResult, RunSpec

RUN_FILE = "run.json"
VISITED_FILE = "visited_goals.npy"
EVALUATIONS_FILE = "evaluations.csv"
LOG_FILE = "train.log"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename, so readers never see half a file.

    :param path: destination.
    :param data: content.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as file:
            file.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    """:func:`atomic_write_bytes` for text (UTF-8)."""
    atomic_write_bytes(path, text.encode())


def evaluations_to_csv(evaluations: list[dict[str, float]]) -> str:
    """CSV text of evaluation rows (header = :data:`EVALUATION_COLUMNS`)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(EVALUATION_COLUMNS), lineterminator="\n")
    writer.writeheader()
    writer.writerows(evaluations)
    return buffer.getvalue()


def write_run_result(run_dir: Path, result: RunResult) -> None:
    """Store a run's result: ``evaluations.csv`` first, then ``run.json`` (the commit marker), both atomically.

    :param run_dir: the run's folder.
    :param result: what :func:`~sb3_gcrl.compare.run.execute_run` returned.
    """
    atomic_write_text(run_dir / EVALUATIONS_FILE, evaluations_to_csv(result.evaluations))
    if result.log:  # runs on Ray return their log; local runs wrote it in place
        atomic_write_text(run_dir / LOG_FILE, result.log)
    if result.visited_goals is not None:
        buffer = io.BytesIO()
        np.save(buffer, result.visited_goals)
        atomic_write_bytes(run_dir / VISITED_FILE, buffer.getvalue())
    record = {
        "status": result.status,
        "wall_time_s": result.wall_time_s,
        "n_evaluations": len(result.evaluations),
        "error": result.error,
        "spec": result.spec.to_dict(),
    }
    atomic_write_text(run_dir / RUN_FILE, json.dumps(record, indent=2) + "\n")


def read_run_record(run_dir: Path) -> dict[str, Any] | None:
    """The run's ``run.json`` as a dict, or None when the run never ended (or the file is unreadable)."""
    try:
        return json.loads((run_dir / RUN_FILE).read_text())
    except (OSError, json.JSONDecodeError):
        return None


def is_finished(run_dir: Path, spec: RunSpec) -> bool:
    """True when the run in ``run_dir`` finished with exactly ``spec`` (so it may be skipped).

    :raises FileExistsError: the folder holds a finished run made with other settings; the message says how
        to proceed (another output folder, or ``--overwrite``).
    """
    record = read_run_record(run_dir)
    if record is None or record.get("status") != "finished" or not (run_dir / EVALUATIONS_FILE).is_file():
        return False
    # the config is compared by content digest, not path (an output folder may move with its repository);
    # fields that a run.json of an older version lacks count as their defaults
    defaults = RunSpec.defaults()
    stored = {key: value for key, value in {**defaults, **record.get("spec", {})}.items() if key != "config"}
    # compared in their JSON form: a tuple in hyperparams/env_kwargs comes back from run.json as a list
    wanted = {key: value for key, value in json.loads(json.dumps(spec.to_dict())).items() if key != "config"}
    if stored != wanted:
        changed = sorted(key for key in set(stored) | set(wanted) if stored.get(key) != wanted.get(key))
        details = ", ".join(f"{key}: {stored.get(key)!r} -> {wanted.get(key)!r}" for key in changed)
        raise FileExistsError(
            f"{run_dir} holds a finished run made with other settings ({details}). "
            "Use another --out folder, or pass --overwrite to redo such runs."
        )
    return True


def reset_run_dir(run_dir: Path) -> None:
    """Remove what an unfinished (or overwritten) run left behind, then recreate the empty folder."""
    if run_dir.exists():
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True)
