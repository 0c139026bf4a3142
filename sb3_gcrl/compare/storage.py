"""On-disk layout of a comparison and atomic writes (resume = skip runs whose ``run.json`` says finished).

::

    OUT/
      compare.lock               pid of the compare process using the folder (held with flock while it runs)
      comparison.json            settings of the last invocation
      configs/                   the sections of variants (``ALGO@VARIANT``), which RL-Zoo reads from a file keyed by
                                 the plain env id; named by content (file stem, variant, env, settings digest)
      runs/ENV/METHOD/seed_S/
        evaluations.csv          one row per evaluation (see EVALUATION_COLUMNS)
        all_goals.csv            all-goals success, visitation entropy, coverage at the evaluation points (runs
                                 whose config has an AllGoalsEvalCallback; see ALL_GOALS_COLUMNS)
        run.json                 spec, status, wall time, error; written last (its presence = run ended)
        train.log                stdout/stderr of the run
        visited_goals.npy        achieved goals of the training data (off-policy agents of goal envs)
        zoo/                     RL-Zoo's own outputs (config.yml, args.yml, monitor.csv, model if saved)
        checkpoints/             the newest resumable checkpoint (``--save-freq``), with the run's settings and
                                 evaluations so far; kept when an unfinished run is started again, which continues
                                 from it; removed when the run finishes
      curves.csv scores.csv summary.csv curves.png report.md (+ memory_*.png, visitation_*.png,
      all_goals_curves.csv all_goals_scores.csv all_goals_summary.csv all_goals.png all_goals_entropy.png)
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from sb3_gcrl.common.saving import atomic_write_bytes, atomic_write_text
from sb3_gcrl.compare.evaluation import EVALUATION_COLUMNS
from sb3_gcrl.compare.run import RunResult, RunSpec
from sb3_gcrl.post_exploration.evaluation import ALL_GOALS_COLUMNS

RUN_FILE = "run.json"
VISITED_FILE = "visited_goals.npy"
EVALUATIONS_FILE = "evaluations.csv"
ALL_GOALS_FILE = "all_goals.csv"
LOG_FILE = "train.log"
LOCK_FILE = "compare.lock"
COMPARISON_FILE = "comparison.json"
#: columns every ``evaluations.csv`` must have, with numbers in every row
REQUIRED_EVALUATION_COLUMNS = ("timesteps", "mean_return")
#: columns every ``all_goals.csv`` must have, with numbers in every row
REQUIRED_ALL_GOALS_COLUMNS = ("timesteps", "all_goals_success")


def evaluations_to_csv(evaluations: list[dict[str, float]], columns: tuple[str, ...] = EVALUATION_COLUMNS) -> str:
    """CSV text of evaluation rows.

    :param evaluations: the rows.
    :param columns: the header (:data:`EVALUATION_COLUMNS`, or :data:`ALL_GOALS_COLUMNS` for all-goals rows).
    """
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    writer.writerows(evaluations)
    return buffer.getvalue()


def write_run_result(run_dir: Path, result: RunResult) -> None:
    """Store a run's result: ``evaluations.csv`` (and ``all_goals.csv``) first, then ``run.json`` (the commit
    marker, which records whether the run has all-goals rows), all atomically.

    :param run_dir: the run's folder.
    :param result: what :func:`~sb3_gcrl.compare.run.execute_run` returned.
    """
    atomic_write_text(run_dir / EVALUATIONS_FILE, evaluations_to_csv(result.evaluations))
    if result.all_goals is not None:
        atomic_write_text(run_dir / ALL_GOALS_FILE, evaluations_to_csv(result.all_goals, ALL_GOALS_COLUMNS))
    if result.log:  # runs on Ray return their log (after the earlier parts' one); local runs wrote it in place
        log = run_dir / LOG_FILE
        earlier = log.read_text(errors="replace") if log.is_file() else ""
        atomic_write_text(log, earlier + result.log)
    if result.visited_goals is not None:
        buffer = io.BytesIO()
        np.save(buffer, result.visited_goals)
        atomic_write_bytes(run_dir / VISITED_FILE, buffer.getvalue())
    record = {
        "status": result.status,
        "wall_time_s": result.wall_time_s,
        "cpu_time_s": None if math.isnan(result.cpu_time_s) else result.cpu_time_s,  # None: not measured
        "cpu_split_s": result.cpu_split_s,  # per phase (sb3_gcrl.compare.costs); None: not measured
        "n_evaluations": len(result.evaluations),
        # None: the run has no all-goals evaluation (no all_goals.csv is expected)
        "n_all_goals_evaluations": None if result.all_goals is None else len(result.all_goals),
        "error": result.error,
        "spec": result.spec.to_dict(),
    }
    atomic_write_text(run_dir / RUN_FILE, json.dumps(record, indent=2) + "\n")
    if result.status == "finished":  # its resumable checkpoint is no longer needed
        from sb3_gcrl.common.checkpoints import CHECKPOINTS_DIR

        shutil.rmtree(run_dir / CHECKPOINTS_DIR, ignore_errors=True)


def load_run_record(run_dir: Path) -> tuple[dict[str, Any] | None, str | None]:
    """The run's ``run.json`` and, when the file exists but cannot be used, what is wrong with it.

    :param run_dir: the run's folder.
    :return: ``(record, None)`` for a usable record; ``(None, None)`` when the run never ended (no file);
        ``(None, problem)`` when the file is unreadable, not JSON, or not a record this package writes.
    """
    path = run_dir / RUN_FILE
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None, None
    except (OSError, UnicodeDecodeError) as error:
        return None, f"{path} cannot be read ({error})"
    try:
        record = json.loads(text)
    except json.JSONDecodeError as error:
        return None, f"{path} is not valid JSON ({error})"
    if not isinstance(record, dict):
        return None, f"{path} holds a JSON {type(record).__name__}, not a run record (an object)"
    if record.get("status") not in ("finished", "failed"):
        return None, f"{path} has status {record.get('status')!r} (expected 'finished' or 'failed')"
    if not isinstance(record.get("spec", {}), dict):
        return None, f"{path} has a 'spec' that is not an object"
    if record["status"] == "finished" and not isinstance(record.get("wall_time_s"), (int, float)):
        return None, f"{path} has no numeric 'wall_time_s'"
    return record, None


def read_run_record(run_dir: Path) -> dict[str, Any] | None:
    """The run's ``run.json`` as a dict, or None when the run never ended or the file is unusable
    (see :func:`load_run_record` for what is wrong with it)."""
    return load_run_record(run_dir)[0]


def table_problem(
    path: Path, columns: tuple[str, ...], required: tuple[str, ...], rows: str = "evaluation rows"
) -> str | None:
    """What is wrong with a per-run CSV of evaluation rows, or None when it is usable.

    Usable: a CSV with at least one row and numbers in every row of the ``required`` columns; the other
    ``columns`` may be empty (NaN) but must be numeric.

    :param path: the file.
    :param columns: the columns the file may have (checked when present).
    :param required: the columns it must have, filled.
    :param rows: what its rows are (for the message).
    :return: a sentence naming the file and the problem, or None.
    """
    try:
        table = pd.read_csv(path)
    except FileNotFoundError:
        return f"{path} is missing"
    except (OSError, UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError) as error:
        return f"{path} cannot be parsed as CSV ({type(error).__name__}: {str(error).strip()})"
    missing = [column for column in required if column not in table.columns]
    if missing:
        return f"{path} lacks the column(s) {missing} (its columns: {list(table.columns)})"
    if table.empty:
        return f"{path} has a header but no {rows}"
    for column in [c for c in columns if c in table.columns]:
        numbers = pd.to_numeric(table[column], errors="coerce")
        bad = table[column][numbers.isna() & table[column].notna()]
        if len(bad):
            return f"{path}: column {column!r} holds non-numeric values (row {bad.index[0] + 1}: {bad.iloc[0]!r})"
        if column in required and numbers.isna().any():
            return f"{path}: column {column!r} has empty values (row {int(numbers.isna().to_numpy().argmax()) + 1})"
    return None


def evaluations_problem(path: Path) -> str | None:
    """What is wrong with an ``evaluations.csv`` (:func:`table_problem` with :data:`EVALUATION_COLUMNS`, of which
    :data:`REQUIRED_EVALUATION_COLUMNS` filled), or None when it is usable."""
    return table_problem(path, EVALUATION_COLUMNS, REQUIRED_EVALUATION_COLUMNS)


def all_goals_problem(path: Path) -> str | None:
    """What is wrong with an ``all_goals.csv`` (:func:`table_problem` with :data:`ALL_GOALS_COLUMNS`, of which
    :data:`REQUIRED_ALL_GOALS_COLUMNS` filled), or None when it is usable."""
    return table_problem(path, ALL_GOALS_COLUMNS, REQUIRED_ALL_GOALS_COLUMNS, "all-goals evaluation rows")


def result_files_problem(run_dir: Path, record: dict[str, Any]) -> str | None:
    """What is wrong with the result files of a finished run, or None when they are usable.

    :param run_dir: the run's folder.
    :param record: its ``run.json`` (``n_all_goals_evaluations`` not None: an ``all_goals.csv`` is expected).
    :return: the problem of ``evaluations.csv``, else of the expected ``all_goals.csv``, else None.
    """
    problem = evaluations_problem(run_dir / EVALUATIONS_FILE)
    if problem is None and record.get("n_all_goals_evaluations") is not None:
        problem = all_goals_problem(run_dir / ALL_GOALS_FILE)
    return problem


def is_finished(run_dir: Path, spec: RunSpec, notes: list[str] | None = None) -> bool:
    """True when the run in ``run_dir`` finished with exactly ``spec`` (so it may be skipped).

    A ``run.json``, ``evaluations.csv`` or expected ``all_goals.csv`` that cannot be used makes the run unfinished
    (it is redone).

    :param run_dir: the run's folder.
    :param spec: the run as planned now.
    :param notes: receives a sentence for each unusable file found (the caller says so to the user).
    :raises OtherSettingsError: the folder holds a finished run made with other settings; the message says how
        to proceed (another output folder, or ``--overwrite``).
    """
    record, problem = load_run_record(run_dir)
    if problem is not None and notes is not None:
        notes.append(problem)
    if record is None or record["status"] != "finished":
        return False
    # the config is compared by the digest of the run's section, not its path (an output folder may move with its
    # repository); fields that a run.json of an older version lacks count as their defaults
    defaults = RunSpec.defaults()
    # (nor how often it saved checkpoints, which a finished run no longer needs)
    ignored = ("config", "save_freq")
    stored = {key: value for key, value in {**defaults, **record.get("spec", {})}.items() if key not in ignored}
    # compared in their JSON form: a tuple in hyperparams/env_kwargs comes back from run.json as a list
    wanted = {key: value for key, value in json.loads(json.dumps(spec.to_dict())).items() if key not in ignored}
    if stored != wanted:
        changed = sorted(key for key in set(stored) | set(wanted) if stored.get(key) != wanted.get(key))
        details = ", ".join(f"{key}: {stored.get(key)!r} -> {wanted.get(key)!r}" for key in changed)
        raise OtherSettingsError(run_dir, details)
    problem = result_files_problem(run_dir, record)
    if problem is not None and notes is not None:
        notes.append(problem)
    return problem is None


class OutputInUseError(RuntimeError):
    """Another live process holds the lock of a comparison's output folder."""


class OtherSettingsError(FileExistsError):
    """A run folder holds a finished run made with other settings than the run planned now.

    :param run_dir: the run's folder.
    :param details: the settings that differ, ``key: stored -> wanted``.
    """

    def __init__(self, run_dir: Path, details: str) -> None:
        self.run_dir, self.details = run_dir, details
        super().__init__(
            f"{run_dir} holds a finished run made with other settings ({details}). "
            "Use another --out folder, or pass --overwrite to redo such runs."
        )


@contextlib.contextmanager
def lock_output(output: Path) -> Iterator[Path]:
    """Hold the lock of a comparison's output folder: ``OUT/compare.lock`` with this process's pid.

    The lock is an advisory ``flock`` on that file, which the kernel drops when its holder dies, even by
    SIGKILL: a lock file left by a dead process is taken over. Where ``flock`` does not exist (Windows), the
    pid in the file is checked instead. The file is removed on exit.

    :param output: the comparison folder (created).
    :return: the lock file's path.
    :raises OutputInUseError: a live process holds the lock; the message names its pid and the way out.
    """
    output.mkdir(parents=True, exist_ok=True)
    path = output / LOCK_FILE
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            _acquire(fd, path)
            if _same_file(fd, path):  # not unlinked by a holder that released it meanwhile
                break
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)
    stale = _lock_holder(path)
    if stale is not None and stale != os.getpid():
        print(f"{path}: taking over the lock of process {stale}, which no longer holds it", file=sys.stderr)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield path
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)
        os.close(fd)  # releases the flock


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except FileNotFoundError:
        return False


def _acquire(fd: int, path: Path) -> None:
    """Lock ``fd`` or raise :class:`OutputInUseError` naming the holder's pid."""
    try:
        import fcntl
    except ImportError:  # no flock: trust the pid in the file
        holder = _lock_holder(path)
        if holder is not None and holder != os.getpid() and _pid_alive(holder):
            raise OutputInUseError(_in_use_message(path, holder)) from None
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise OutputInUseError(_in_use_message(path, _lock_holder(path))) from None


def _lock_holder(path: Path) -> int | None:
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def _in_use_message(path: Path, holder: int | None) -> str:
    who = f"process {holder}" if holder is not None else "another process"
    return (
        f"{path.parent} is in use by another sb3-gcrl compare ({who} holds {path}); running a second one on the "
        "same folder would race it. Wait for it to end (or stop it), or use another --output folder."
    )


def reset_run_dir(run_dir: Path) -> None:
    """Remove what an unfinished (or overwritten) run left behind, then recreate the empty folder; its resumable
    checkpoint (:data:`~sb3_gcrl.common.checkpoints.CHECKPOINTS_DIR`) stays, and the run continues from it when it was
    made with the same settings (:func:`~sb3_gcrl.compare.run.execute_run`). Beside a checkpoint the log of the
    earlier parts stays too: the next part appends to it (its probes and evaluations before the checkpoint)."""
    from sb3_gcrl.common.checkpoints import CHECKPOINTS_DIR

    run_dir.mkdir(parents=True, exist_ok=True)
    keep = {CHECKPOINTS_DIR, LOG_FILE} if (run_dir / CHECKPOINTS_DIR).is_dir() else {CHECKPOINTS_DIR}
    for path in run_dir.iterdir():
        if path.name in keep:
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
