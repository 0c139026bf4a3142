"""Acting side of the 2M agents (thesis Algorithm 2): the policy mixin that runs each env's episode with its memory.

:class:`TwoMemoryDispatchMixin` is mixed into an SB3 policy that holds both memories (tabular, DQN or SAC flavour). It
acts with the memory that runs each env's current episode, keeps the score windows (last ``score_window`` returns per
memory) with the evaluation memory of Eq. 5.6 used by ``predict(deterministic=True)``, and puts them into its
``state_dict`` (``get_extra_state``), so ``save``/``load`` bring back the tables, the network and the score windows
together. Which memory runs an episode is drawn by the :class:`~sb3_gcrl.two_memory.dispatch.TwoMemoryDispatcher`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th

from sb3_gcrl.two_memory.schedules import EPISODIC, PARAMETRIC, UNASSIGNED, ScoreWindows


def _batch_size(observation: th.Tensor | dict[str, th.Tensor]) -> int:
    if isinstance(observation, dict):
        return int(next(iter(observation.values())).shape[0])
    return int(observation.shape[0])


def _device(observation: th.Tensor | dict[str, th.Tensor]) -> th.device:
    if isinstance(observation, dict):
        return next(iter(observation.values())).device
    return observation.device


def _select_rows(observation: th.Tensor | dict[str, th.Tensor], index: th.Tensor) -> Any:
    if isinstance(observation, dict):
        return {key: value[index] for key, value in observation.items()}
    return observation[index]


class TwoMemoryDispatchMixin:
    """Acting side of a 2M policy; mix in before the SB3 policy (``class P(TwoMemoryDispatchMixin, DQNPolicy)``).

    Concrete policies call :meth:`_init_dispatch` after the SB3 policy's ``__init__``, implement
    :meth:`_episodic_actions`, :meth:`_parametric_actions`, :meth:`update_episodic_memory` and, if their episodic
    memory is not a sub-module with its own state, :meth:`_episodic_state` / :meth:`_load_episodic_state`. They list
    their constructor settings in :attr:`ec_parameters` and keep each as an attribute of the same name (saved by
    ``policy.save``). The training-time settings (p_ec schedule, data sharing, ``ec_gamma``,
    ``ec_update_truncated``) are the :class:`~sb3_gcrl.two_memory.dispatch.TwoMemoryDispatcher`'s, not the policy's:
    a policy refuses them with :meth:`~sb3_gcrl.two_memory.dispatch.TwoMemoryDispatcher.refuse_settings`.
    """

    #: constructor arguments of the policy's 2M / EC settings, each kept as an attribute of the same name
    ec_parameters: ClassVar[tuple[str, ...]] = ("score_window",)

    def _init_dispatch(self, score_window: int) -> None:
        """:param score_window: n of Eq. 5.6 (50 in the thesis): the evaluation memory is the one with the higher
        mean return over its last ``score_window`` training episodes.
        """
        self.score_windows = ScoreWindows(score_window)
        self.score_window = self.score_windows.window
        #: memory running each env's current episode (EPISODIC, PARAMETRIC or UNASSIGNED)
        self.acting_memory = np.zeros(0, dtype=np.int8)
        #: episodes run by each memory since construction (saved)
        self.episode_counts = np.zeros(2, dtype=np.int64)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()  # type: ignore[misc]
        data.update({name: getattr(self, name) for name in self.ec_parameters})
        return data

    def set_seed(self, seed: int | None) -> None:
        """Reseed the policy's own random generators (EC tie-breaking / sampling); the acting memories are drawn by
        the :class:`TwoMemoryDispatcher`'s generator. Policies with their own generators override this.

        :param seed: seed.
        """

    # ----------------------------------------------------------------------------------------------- episodes
    def reset_acting_memory(self, n_envs: int) -> None:
        """No env has an acting memory (the envs were reset); the next draw gives every env one.

        :param n_envs: number of training envs.
        """
        self.acting_memory = np.full(n_envs, UNASSIGNED, dtype=np.int8)

    def needs_memories(self) -> bool:
        """Whether some env starts an episode and has no acting memory yet."""
        return bool(np.any(self.acting_memory == UNASSIGNED))

    def assign_memories(self, p_ec: float, rng: np.random.Generator) -> np.ndarray:
        """Draw a memory for every env that starts an episode (Algorithm 2: ``U(0,1) < p_ec`` -> EC).

        :param p_ec: probability that an episode is run by the episodic memory (from the p_ec schedule).
        :param rng: the generator of the draws (the dispatcher's).
        :return: the acting memory of each env.
        """
        unassigned = np.flatnonzero(self.acting_memory == UNASSIGNED)
        if unassigned.size > 0:
            draws = rng.random(unassigned.size) < p_ec
            self.acting_memory[unassigned] = np.where(draws, EPISODIC, PARAMETRIC)
        return self.acting_memory

    def end_episode(self, env_index: int, episode_return: float) -> int:
        """An episode of env ``env_index`` ended: score it (Eq. 5.6 window of its memory), count it, and leave the
        env without a memory until the next draw.

        :param env_index: the env.
        :param episode_return: the episode's undiscounted return.
        :return: the memory that ran the episode.
        """
        memory = int(self.acting_memory[env_index])
        self.score_windows.push(memory, episode_return)
        self.episode_counts[memory] += 1
        self.acting_memory[env_index] = UNASSIGNED
        return memory

    def evaluation_memory(self) -> int:
        """Eq. 5.6: the memory with the higher mean return over its last ``score_window`` training episodes."""
        return self.score_windows.evaluation_memory()

    # ----------------------------------------------------------------------------------------------- acting
    def _predict(self, observation: th.Tensor, deterministic: bool = False) -> th.Tensor:
        """Greedy action of each row's memory: the evaluation memory (Eq. 5.6) if ``deterministic``, else the
        memory running that env's episode. A batch whose size is not the number of training envs (e.g. a single
        observation given to ``predict``), and an env whose next memory is not drawn yet, use the evaluation
        memory: predicting never changes the dispatch (the
        :class:`~sb3_gcrl.two_memory.dispatch.TwoMemoryDispatcher` draws the memories).
        """
        n = _batch_size(observation)
        if deterministic or self.acting_memory.size != n:
            memories = np.full(n, self.evaluation_memory(), dtype=np.int8)
        else:
            memories = self.acting_memory
            if self.needs_memories():
                memories = np.where(memories == UNASSIGNED, self.evaluation_memory(), memories).astype(np.int8)
        # (the tensor's device: ``self.device`` walks all parameters, a measurable cost per env step)
        device = _device(observation)
        if n == 1 or (memories == memories[0]).all():
            # one memory acts for the whole batch (always with one env): no row split and scatter
            act = self._episodic_actions if memories[0] == EPISODIC else self._parametric_actions
            return act(observation, deterministic).to(device)
        actions: th.Tensor | None = None
        for memory, act in ((EPISODIC, self._episodic_actions), (PARAMETRIC, self._parametric_actions)):
            rows = np.flatnonzero(memories == memory)
            if rows.size == 0:
                continue
            index = th.as_tensor(rows, device=device)
            memory_actions = act(_select_rows(observation, index), deterministic)
            if actions is None:
                actions = th.zeros((n, *memory_actions.shape[1:]), dtype=memory_actions.dtype, device=device)
            actions[index] = memory_actions.to(device)
        assert actions is not None
        return actions

    def _episodic_actions(self, observation: th.Tensor, deterministic: bool) -> th.Tensor:
        """Actions of the episodic memory for a batch of (preprocessed-by-``obs_to_tensor``) observations."""
        raise NotImplementedError

    def _parametric_actions(self, observation: th.Tensor, deterministic: bool) -> th.Tensor:
        """Actions of the parametric (RL) memory."""
        raise NotImplementedError

    def _episode_features(self, observations: Any) -> np.ndarray:
        """What is recorded per step for the episodic update (default: the observation; neural 2M policies record
        the memory key, which is smaller and also works for Dict observations)."""
        return np.asarray(observations)

    def update_episodic_memory(self, features: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> None:
        """Write one finished episode into the episodic memory: per step the :meth:`_episode_features`, the
        action and the discounted return."""
        raise NotImplementedError

    # ----------------------------------------------------------------------------------------------- saving
    def _episodic_state(self) -> dict[str, th.Tensor]:
        """Tensors of the episodic memory to save (empty if it is a sub-module that saves itself)."""
        return {}

    def _load_episodic_state(self, state: dict[str, th.Tensor]) -> None:
        """Inverse of :meth:`_episodic_state`."""

    def get_extra_state(self) -> dict[str, th.Tensor]:
        """Score windows and episode counts (plus the episodic memory's tensors) for the ``state_dict``."""
        state = {
            "score_returns": th.from_numpy(self.score_windows.returns.copy()),
            "score_counts": th.from_numpy(self.score_windows.counts.copy()),
            "episode_counts": th.from_numpy(self.episode_counts.copy()),
        }
        state.update(self._episodic_state())
        return state

    def set_extra_state(self, state: dict[str, th.Tensor]) -> None:
        state = dict(state)
        self.score_windows.load_state_dict(
            {"returns": state.pop("score_returns").numpy(), "counts": state.pop("score_counts").numpy()}
        )
        self.episode_counts[...] = state.pop("episode_counts").numpy()
        self._load_episodic_state(state)
