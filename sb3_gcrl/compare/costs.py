"""Where a run's CPU time goes: gradient updates, evaluations, probes and checkpoints, the rest being data collection.

:class:`PhaseClock` times what a run calls, without changing it: the algorithm's ``train`` (patched on its class for
the run, then restored, so that nothing of the clock is saved with the model) and the ``on_step`` of the run's
evaluation, probe and checkpoint callbacks.
"""

from __future__ import annotations

import contextlib
import functools
import math
import time
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import pandas as pd

#: timed phases; the rest of a run's CPU time is "collect" (env steps, acting, the other callbacks, set-up)
PHASES = ("train", "evaluate", "probe", "checkpoint")
#: every phase of :meth:`PhaseClock.split`, in report order
ALL_PHASES = ("train", "collect", *PHASES[1:])


class PhaseClock:
    """CPU time (the process's, all threads) spent inside the timed callables, per phase.

    A call made while another timed call runs counts to the outer one only (an evaluation that calls ``train`` is
    evaluation).
    """

    def __init__(self) -> None:
        self.cpu_s = dict.fromkeys(PHASES, 0.0)
        self._running = False

    def timed(self, phase: str, function: Callable[..., Any]) -> Callable[..., Any]:
        """``function``, with its CPU time added to ``phase``.

        :param phase: one of :data:`PHASES`.
        :param function: the callable to time.
        """
        if phase not in PHASES:
            raise ValueError(f"phase must be one of {PHASES}, got {phase!r}")

        @functools.wraps(function)
        def timed_call(*args: Any, **kwargs: Any) -> Any:
            if self._running:
                return function(*args, **kwargs)
            self._running = True
            start = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                self.cpu_s[phase] += time.process_time() - start
                self._running = False

        return timed_call

    @contextlib.contextmanager
    def timing_method(self, owner: type, name: str, phase: str) -> Iterator[None]:
        """Time ``owner.name`` (a method, looked up through the class hierarchy) while the context lasts.

        :param owner: the class whose instances' calls are timed (e.g. ``type(model)``).
        :param name: the method's name; a class without it has nothing to time (e.g. a tabular agent that learns
            while it collects: all its time is ``collect``).
        :param phase: one of :data:`PHASES`.
        """
        if not callable(getattr(owner, name, None)):
            yield
            return
        own = name in vars(owner)
        original = vars(owner)[name] if own else None
        setattr(owner, name, self.timed(phase, getattr(owner, name)))
        try:
            yield
        finally:
            if own:
                setattr(owner, name, original)
            else:
                delattr(owner, name)

    def time_callback(self, callback: Any, phase: str) -> None:
        """Time the ``on_step`` of one callback object (an instance attribute: callbacks are not saved).

        :param callback: an SB3 callback.
        :param phase: one of :data:`PHASES`.
        """
        callback.on_step = self.timed(phase, callback.on_step)

    def split(self, total_cpu_s: float) -> dict[str, float]:
        """The run's CPU time per phase of :data:`ALL_PHASES`; ``collect`` is the rest of ``total_cpu_s``.

        :param total_cpu_s: the run's CPU time.
        """
        phases = {**self.cpu_s, "collect": max(0.0, total_cpu_s - sum(self.cpu_s.values()))}
        return {phase: phases[phase] for phase in ALL_PHASES}


class RunTimer:
    """A run's wall and CPU time (its process's, all threads) and its :class:`PhaseClock`, carried over checkpoints.

    A run continued from a checkpoint adds what its steps up to the checkpoint cost (:meth:`state`, saved with the
    checkpoint; :meth:`resume`), so its totals are those of the steps it is made of; the work lost between the last
    checkpoint and an interruption is not counted.
    """

    def __init__(self) -> None:
        self.clock = PhaseClock()
        self._wall_start = time.perf_counter()
        self._cpu_start = time.process_time()

    def elapsed(self) -> tuple[float, float]:
        """Wall and CPU seconds so far, a resumed run's earlier ones included."""
        return time.perf_counter() - self._wall_start, time.process_time() - self._cpu_start

    def state(self) -> dict[str, Any]:
        """What :meth:`resume` takes: the time so far and the phases' CPU time (JSON-friendly)."""
        wall, cpu = self.elapsed()
        return {"wall_time_s": wall, "cpu_time_s": cpu, "cpu_phase_s": dict(self.clock.cpu_s)}

    def resume(self, state: Mapping[str, Any] | None) -> None:
        """Count the time of a run's earlier part (a :meth:`state` saved with its checkpoint) as this run's.

        :param state: a saved :meth:`state`; ``None`` (a checkpoint that holds none) adds nothing.
        """
        if state is None:
            return
        self._wall_start -= float(state["wall_time_s"])
        self._cpu_start -= float(state["cpu_time_s"])
        for phase, seconds in state["cpu_phase_s"].items():
            self.clock.cpu_s[phase] += float(seconds)


def callback_phase(callback: Any) -> str | None:
    """The phase a run's callback belongs to: ``"evaluate"`` (the run's evaluations, all-goals evaluations),
    ``"probe"`` (a diagnostics callback), ``"checkpoint"``, or None (part of collecting data).

    :param callback: an SB3 callback.
    """
    from sb3_gcrl.common.checkpoints import RunCheckpointCallback
    from sb3_gcrl.compare.evaluation import EvaluationRecorder
    from sb3_gcrl.morefree.diagnostics import MoReFreeDiagnosticsCallback
    from sb3_gcrl.post_exploration.evaluation import AllGoalsEvalCallback

    if isinstance(callback, (EvaluationRecorder, AllGoalsEvalCallback)):
        return "evaluate"
    if isinstance(callback, MoReFreeDiagnosticsCallback):
        return "probe"
    if isinstance(callback, RunCheckpointCallback):
        return "checkpoint"
    return None


def flat_callbacks(callbacks: list[Any]) -> Iterator[Any]:
    """The callbacks of a run one by one, ``CallbackList``s opened (in order, depth first).

    :param callbacks: the run's callbacks (RL-Zoo's ``exp_manager.callbacks``).
    """
    from stable_baselines3.common.callbacks import CallbackList

    for callback in callbacks:
        if isinstance(callback, CallbackList):
            yield from flat_callbacks(callback.callbacks)
        else:
            yield callback


def time_callbacks(clock: PhaseClock, callbacks: list[Any]) -> None:
    """Time every evaluation, probe and checkpoint callback among ``callbacks`` (``CallbackList``s searched).

    :param clock: the run's clock.
    :param callbacks: the run's callbacks (RL-Zoo's ``exp_manager.callbacks``).
    """
    for callback in flat_callbacks(callbacks):
        if (phase := callback_phase(callback)) is not None:
            clock.time_callback(callback, phase)


def cost_section(run_times: pd.DataFrame) -> list[str]:
    """Markdown of a report's "Cost" section: what a run of each method cost, wall and CPU time (medians, ranges and
    sums over finished runs), and its CPU time by phase where the runs recorded it.

    :param run_times: one row per finished run: ``method``, ``wall_time_s``, ``cpu_time_s`` and ``cpu_<phase>_s``.
    :return: the section's lines (none without runs).
    """
    if not len(run_times):
        return []

    def seconds(values: pd.Series) -> str:
        values = values.dropna()
        if not len(values):
            return "not recorded"
        spread = f" ({values.min():,.0f}-{values.max():,.0f})" if len(values) > 1 else ""
        return f"{values.median():,.0f} s{spread}"

    lines = [
        "## Cost",
        "",
        "Per run, the median (range) over the finished runs, as the run's worker measured it (imports excluded; CPU "
        "time: the run's process, all threads; runs of earlier versions did not record it).",
        "",
        "| method | runs | wall time per run | CPU time per run | CPU time, all runs |",
        "| --- | --- | --- | --- | --- |",
    ]
    for method, group in run_times.groupby("method", sort=False):
        total = group["cpu_time_s"].sum(min_count=1)
        total_text = "not recorded" if math.isnan(total) else f"{total / 3600:.2f} h"
        if group["cpu_time_s"].isna().any() and not math.isnan(total):
            total_text += f" ({group['cpu_time_s'].notna().sum()} of {len(group)} runs)"
        lines.append(
            f"| {method} | {len(group)} | {seconds(group['wall_time_s'])} | {seconds(group['cpu_time_s'])} "
            f"| {total_text} |"
        )
    lines.append("")
    split = [f"cpu_{phase}_s" for phase in ALL_PHASES]
    measured = run_times.dropna(subset=split)
    if len(measured):
        lines += [
            "CPU time per run by phase, median over the runs that recorded it: *train* the gradient updates "
            "(the algorithm's `train`, a compilation included), *evaluate* the evaluations, *probe* the diagnostics "
            "callback, *checkpoint* the resumable checkpoints, *collect* the rest (env steps, acting, the other "
            "callbacks, set-up).",
            "",
            f"| method | runs | {' | '.join(ALL_PHASES)} |",
            "| --- | --- |" + " --- |" * len(ALL_PHASES),
        ]
        for method, group in measured.groupby("method", sort=False):
            total = group["cpu_time_s"].median()
            cells = []
            for column in split:
                value = group[column].median()
                share = f" ({value / total:.0%})" if total > 0 else ""
                cells.append(f"{value:,.0f} s{share}")
            lines.append(f"| {method} | {len(group)} | {' | '.join(cells)} |")
        lines.append("")
    return lines
