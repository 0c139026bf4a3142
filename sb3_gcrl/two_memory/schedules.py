"""Schedules for p_ec, the probability that the next episode is run by the episodic memory (thesis Sec. 5.4.2).

A schedule is called once per episode and per env, when that env starts an episode, with the number of env steps
taken so far and the :class:`ScoreWindows` of both memories. It returns p_ec in [0, 1].

- :class:`ExponentialSchedule` is Eq. 5.5, ``p_ec = p_e + (p_s - p_e) * exp(-i / tau)``. With ``p_s > p_e`` it is the
  thesis's *decayed* schedule (2Mw/DS), with ``p_s < p_e`` its *increasing* one (2Mw/IS).
- :class:`ConstantSchedule` is the *constant* schedule (2Mw/CS).
- :class:`AdaptiveSchedule` is ours (the thesis lists adaptive switching as future work, Sec. 5.6); see its docstring.
"""

from __future__ import annotations

import inspect
import math
from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from sb3_gcrl.common.validation import check_float, check_int, check_unit_interval

#: index of the episodic-control memory (2M-EC) in score windows and dispatch arrays
EPISODIC = 0
#: index of the parametric (RL) memory (2M-RL)
PARAMETRIC = 1
#: marks an env whose next episode has not been given a memory yet
UNASSIGNED = -1
MEMORY_NAMES = ("ec", "rl")
#: default p_ec schedule of the 2M agents: Eq. 5.5 with the thesis's decayed schedule 0.9 -> 0.1 (Table 5.1, the
#: best schedule in Sec. 5.5.3); tau = 5e5 env steps as in the authors' MinAtar runs (the thesis gives no tau)
DEFAULT_P_EC_SCHEDULE: dict[str, Any] = {"type": "decayed", "start": 0.9, "end": 0.1, "decay": 500_000}


class ScoreWindows:
    """Returns of the last ``window`` training episodes run by each memory (thesis Sec. 5.4.2, n = 50).

    Stored in preallocated ring buffers so that pushing a return is O(1) and the state can be saved as arrays.

    :param window: number of recent episodes that define a memory's score (the thesis fixes n = 50).
    """

    def __init__(self, window: int = 50) -> None:
        self.window = check_int("score_window", window)
        self.returns = np.zeros((2, window), dtype=np.float64)
        #: episodes ever pushed per memory (the ring position is ``count % window``)
        self.counts = np.zeros(2, dtype=np.int64)

    def push(self, memory: int, episode_return: float) -> None:
        """Record the (undiscounted) return of an episode run by ``memory`` (EPISODIC or PARAMETRIC)."""
        self.returns[memory, self.counts[memory] % self.window] = episode_return
        self.counts[memory] += 1

    def n_episodes(self, memory: int) -> int:
        """Episodes in the window of ``memory`` (at most ``window``)."""
        return int(min(self.counts[memory], self.window))

    def score(self, memory: int) -> float:
        """Mean return over the window (s^ec / s^rl of Eq. 5.6); ``-inf`` before the memory ran any episode."""
        n = self.n_episodes(memory)
        if n == 0:
            return -math.inf
        return float(self.returns[memory, :n].mean())

    def evaluation_memory(self) -> int:
        """Eq. 5.6: PARAMETRIC if s^rl >= s^ec else EPISODIC (ties and 'no data for either' go to RL)."""
        return PARAMETRIC if self.score(PARAMETRIC) >= self.score(EPISODIC) else EPISODIC

    def state_dict(self) -> dict[str, np.ndarray]:
        return {"returns": self.returns.copy(), "counts": self.counts.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        returns = np.asarray(state["returns"], dtype=np.float64)
        if returns.shape != self.returns.shape:
            raise ValueError(f"saved score windows have shape {returns.shape}, expected {self.returns.shape}")
        self.returns[...] = returns
        self.counts[...] = np.asarray(state["counts"], dtype=np.int64)


class PecSchedule(ABC):
    """Base class of p_ec schedules: ``schedule(num_timesteps, scores) -> p_ec``."""

    @abstractmethod
    def __call__(self, num_timesteps: int, scores: ScoreWindows) -> float: ...


class ExponentialSchedule(PecSchedule):
    """Eq. 5.5: ``p_ec = end + (start - end) * exp(-num_timesteps / decay)``.

    :param start: p^s, p_ec at step 0.
    :param end: p^e, the asymptote.
    :param decay: tau of Eq. 5.5 in env steps (the authors use 5e5 on MinAtar, 2e4 on WindyGrid).
    """

    def __init__(self, start: float, end: float, decay: float) -> None:
        self.start = check_unit_interval("start", start)
        self.end = check_unit_interval("end", end)
        self.decay = check_float("decay (tau of Eq. 5.5, in env steps)", decay, 0.0, exclusive_minimum=True)

    def __call__(self, num_timesteps: int, scores: ScoreWindows) -> float:
        return self.end + (self.start - self.end) * math.exp(-num_timesteps / self.decay)

    def __repr__(self) -> str:
        return f"ExponentialSchedule(start={self.start}, end={self.end}, decay={self.decay})"


class ConstantSchedule(PecSchedule):
    """Constant p_ec (ablation 2Mw/CS). ``p_ec=1`` gives pure EC acting, ``p_ec=0`` pure RL acting.

    :param p_ec: the probability of running an episode with the episodic memory.
    """

    def __init__(self, p_ec: float) -> None:
        self.p_ec = check_unit_interval("p_ec", p_ec)

    def __call__(self, num_timesteps: int, scores: ScoreWindows) -> float:
        return self.p_ec

    def __repr__(self) -> str:
        return f"ConstantSchedule(p_ec={self.p_ec})"


class AdaptiveSchedule(PecSchedule):
    """Adaptive p_ec from the two memories' recent returns (our design; the thesis leaves it as future work).

    ``p_ec = p_min + (p_max - p_min) * sigmoid((s_ec - s_rl) / (temperature * (spread + 1e-8)))`` where s_ec, s_rl
    are the window means of Eq. 5.6 and ``spread`` is the standard deviation of the returns in both windows
    pooled. Dividing by the spread makes the rule invariant to the reward scale and sign (the authors' rule
    ``0.25 * sum(G_ec) / sum(G_rl) + 0.25`` breaks with negative or zero returns, e.g. WindyGrid's -1 per step).
    A memory whose recent returns are clearly better runs more episodes, but never all of them: the floor
    ``p_min`` / ceiling ``p_max`` keep both scores up to date so that a late-improving RL memory is noticed. Until
    each memory has ``min_episodes`` scored episodes p_ec is ``warmup_p_ec``.

    :param p_min: lowest p_ec.
    :param p_max: highest p_ec.
    :param temperature: larger values make the switch softer.
    :param min_episodes: episodes per memory before the adaptive rule applies.
    :param warmup_p_ec: p_ec before that.
    """

    def __init__(
        self,
        p_min: float = 0.05,
        p_max: float = 0.95,
        temperature: float = 1.0,
        min_episodes: int = 5,
        warmup_p_ec: float = 0.5,
    ) -> None:
        self.p_min = check_unit_interval("p_min", p_min)
        self.p_max = check_unit_interval("p_max", p_max)
        if self.p_min > self.p_max:
            raise ValueError(f"p_min ({p_min}) must be <= p_max ({p_max})")
        self.temperature = check_float("temperature", temperature, 0.0, exclusive_minimum=True)
        self.min_episodes = check_int("min_episodes", min_episodes)
        self.warmup_p_ec = check_unit_interval("warmup_p_ec", warmup_p_ec)

    def __call__(self, num_timesteps: int, scores: ScoreWindows) -> float:
        n_ec, n_rl = scores.n_episodes(EPISODIC), scores.n_episodes(PARAMETRIC)
        if min(n_ec, n_rl) < min(self.min_episodes, scores.window):
            return self.warmup_p_ec
        pooled = np.concatenate([scores.returns[EPISODIC, :n_ec], scores.returns[PARAMETRIC, :n_rl]])
        z = (scores.score(EPISODIC) - scores.score(PARAMETRIC)) / (self.temperature * (pooled.std() + 1e-8))
        return self.p_min + (self.p_max - self.p_min) / (1.0 + math.exp(-float(np.clip(z, -50.0, 50.0))))

    def __repr__(self) -> str:
        return (
            f"AdaptiveSchedule(p_min={self.p_min}, p_max={self.p_max}, temperature={self.temperature}, "
            f"min_episodes={self.min_episodes}, warmup_p_ec={self.warmup_p_ec})"
        )


#: the ``type`` of a dict spec of :func:`make_pec_schedule` -> the schedule class it builds
SCHEDULE_TYPES: dict[str, type[PecSchedule]] = {
    "decayed": ExponentialSchedule,
    "increasing": ExponentialSchedule,
    "exponential": ExponentialSchedule,
    "constant": ConstantSchedule,
    "adaptive": AdaptiveSchedule,
}


def _schedule_forms() -> str:
    types = "|".join(f"'{kind}'" for kind in SCHEDULE_TYPES)
    return f"pass a PecSchedule, a number in [0, 1] (constant), 'adaptive', or a dict {{'type': {types}, ...kwargs}}"


def make_pec_schedule(spec: PecSchedule | float | str | dict[str, Any]) -> PecSchedule:
    """Build a p_ec schedule from a YAML/CLI-friendly spec.

    Accepted: a :class:`PecSchedule`; a number (constant); ``"adaptive"``; or a dict with ``type`` in
    :data:`SCHEDULE_TYPES` plus the class's kwargs, e.g. ``{"type": "decayed", "start": 0.5, "end": 0.1,
    "decay": 5e5}``. ``decayed`` requires start >= end and ``increasing`` start <= end, so a swapped pair is caught.

    :param spec: the schedule specification.
    :return: the schedule.
    :raises ValueError: naming the accepted forms (an unknown ``type`` lists the valid ones, a wrong key lists the
        class's arguments), or a value out of range.
    """
    if isinstance(spec, PecSchedule):
        return spec
    if isinstance(spec, (int, float, np.integer, np.floating)) and not isinstance(spec, bool):
        return ConstantSchedule(float(spec))
    if isinstance(spec, str) and spec == "adaptive":
        return AdaptiveSchedule()
    if not isinstance(spec, dict):
        raise ValueError(f"Cannot build a p_ec schedule from {spec!r}: {_schedule_forms()}")
    kwargs = dict(spec)
    kind = kwargs.pop("type", None)
    if kind not in SCHEDULE_TYPES:
        raise ValueError(
            f"Cannot build a p_ec schedule from {spec!r}: unknown type {kind!r}, valid types are "
            f"{', '.join(SCHEDULE_TYPES)}"
        )
    schedule_class = SCHEDULE_TYPES[kind]
    signature = inspect.signature(schedule_class)
    try:
        signature.bind(**kwargs)
    except TypeError as error:
        raise ValueError(
            f"Cannot build a p_ec schedule from {spec!r}: type {kind!r} takes {', '.join(signature.parameters)} "
            f"({error})"
        ) from None
    schedule = schedule_class(**kwargs)
    if kind == "decayed" and schedule.start < schedule.end:  # type: ignore[attr-defined]
        raise ValueError(f"a decayed p_ec schedule needs start >= end, got {spec}; use type 'increasing'")
    if kind == "increasing" and schedule.start > schedule.end:  # type: ignore[attr-defined]
        raise ValueError(f"an increasing p_ec schedule needs start <= end, got {spec}; use type 'decayed'")
    return schedule
