"""Common base of the tabular algorithms: an SB3 ``OffPolicyAlgorithm`` on Discrete states and actions."""

from __future__ import annotations

from typing import Any, TypeVar

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import LinearSchedule

from sb3_gcrl.common.runs import ClassNamedRunsMixin
from sb3_gcrl.common.saving import ModelFileMixin
from sb3_gcrl.common.seeding import SeededGeneratorMixin
from sb3_gcrl.common.transitions import TransitionHooksMixin
from sb3_gcrl.common.validation import check_int, check_step_size, check_unit_interval
from sb3_gcrl.tabular.policies import check_tabular_spaces

SelfTabularAlgorithm = TypeVar("SelfTabularAlgorithm", bound="TabularAlgorithm")


def check_tabular_hyperparameters(
    learning_rate: float | Schedule,
    gamma: float,
    exploration_fraction: float,
    exploration_initial_eps: float,
    exploration_final_eps: float,
    buffer_size: int,
    learning_starts: int,
    batch_size: int,
) -> tuple[int, int, int]:
    """Validate the hyper-parameters of a tabular agent; raise an error that names the parameter.

    The learning rate is the step size of ``Q <- Q + lr * (target - Q)``: it must lie in (0, 1] (above 1 each
    update overshoots its target and the table diverges). A schedule is checked at the start and the end of
    training.

    :param learning_rate: step size or schedule of the remaining progress.
    :param gamma: discount factor, in [0, 1].
    :param exploration_fraction: fraction of training over which epsilon decays, in [0, 1].
    :param exploration_initial_eps: initial epsilon, in [0, 1].
    :param exploration_final_eps: final epsilon, in [0, 1].
    :param buffer_size: replay buffer size, >= 1.
    :param learning_starts: random steps before learning, >= 0.
    :param batch_size: transitions per update, >= 1.
    :return: ``buffer_size``, ``learning_starts`` and ``batch_size`` as ints (integral floats such as YAML's
        ``!!float 5e4`` accepted).
    :raises ValueError: for the first parameter out of range.
    :raises TypeError: for an integer parameter that is not a number.
    """
    check_step_size("learning_rate", learning_rate)
    check_unit_interval("gamma", gamma)
    check_unit_interval("exploration_fraction", exploration_fraction)
    check_unit_interval("exploration_initial_eps", exploration_initial_eps)
    check_unit_interval("exploration_final_eps", exploration_final_eps)
    return (
        check_int("buffer_size", buffer_size),
        check_int("learning_starts", learning_starts, minimum=0),
        check_int("batch_size", batch_size),
    )


class TabularAlgorithm(
    SeededGeneratorMixin, ModelFileMixin, ClassNamedRunsMixin, TransitionHooksMixin, OffPolicyAlgorithm
):
    """Off-policy tabular agent with epsilon-greedy exploration drawn per env (SB3's DQN draws one coin per batch).

    The exploration draws come from the algorithm's own generator, the tie-breaking of the greedy actions from the
    policy's (both seeded from ``seed``, saved with the model and continued by ``load``).

    Defaults follow the authors' tabular 2M code (public repo yangzhao-666/2m): replay buffer 5e4, batch 32 every
    8 steps, learning rate 0.01, epsilon 0.1 -> 0.05. Tables live on the CPU whatever ``device`` says.

    :param policy: policy class or alias.
    :param env: env with Discrete observation and action spaces (or its registered id).
    :param learning_rate: step size alpha of the tabular update, in (0, 1] (or a schedule of progress remaining).
    :param buffer_size: replay buffer size.
    :param learning_starts: env steps of uniformly random actions before acting greedily/learning.
    :param batch_size: transitions per tabular update.
    :param gamma: discount factor.
    :param train_freq: update every ``train_freq`` steps.
    :param gradient_steps: updates per training round.
    :param exploration_fraction: fraction of training over which epsilon decays linearly.
    :param exploration_initial_eps: initial epsilon.
    :param exploration_final_eps: final epsilon.
    :param replay_buffer_class: replay buffer class (SB3 default if None).
    :param replay_buffer_kwargs: its kwargs.
    :param stats_window_size: window of the rollout statistics (ep_rew_mean...).
    :param tensorboard_log: tensorboard log directory.
    :param policy_kwargs: policy kwargs.
    :param verbose: verbosity.
    :param seed: random seed.
    :param device: ignored for the tables (CPU); kept for the SB3 signature.
    :param _init_setup_model: build the model at construction.
    """

    policy: BasePolicy

    def __init__(
        self,
        policy: str | type[BasePolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 0.01,
        buffer_size: int = 50_000,
        learning_starts: int = 0,
        batch_size: int = 32,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 8,
        gradient_steps: int = 1,
        exploration_fraction: float = 0.1,
        exploration_initial_eps: float = 0.1,
        exploration_final_eps: float = 0.05,
        replay_buffer_class: Any = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: str = "cpu",
        _init_setup_model: bool = True,
    ) -> None:
        buffer_size, learning_starts, batch_size = check_tabular_hyperparameters(
            learning_rate,
            gamma,
            exploration_fraction,
            exploration_initial_eps,
            exploration_final_eps,
            buffer_size,
            learning_starts,
            batch_size,
        )
        super().__init__(
            policy,
            env,
            learning_rate,
            buffer_size,
            learning_starts,
            batch_size,
            tau=1.0,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device="cpu",
            seed=seed,
            sde_support=False,
            support_multi_env=True,
            supported_action_spaces=(spaces.Discrete,),
        )
        self.exploration_fraction = exploration_fraction
        self.exploration_initial_eps = exploration_initial_eps
        self.exploration_final_eps = exploration_final_eps
        self.exploration_rate = exploration_initial_eps
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        check_tabular_spaces(self.observation_space, self.action_space, type(self).__name__)
        super()._setup_model()
        self.exploration_schedule = LinearSchedule(
            self.exploration_initial_eps, self.exploration_final_eps, self.exploration_fraction
        )

    def _on_step(self) -> None:
        self.exploration_rate = self.exploration_schedule(self._current_progress_remaining)
        self.logger.record("rollout/exploration_rate", self.exploration_rate)

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        n_actions = int(self.action_space.n)  # type: ignore[attr-defined]
        if self.num_timesteps < learning_starts:
            actions = self._rng.integers(n_actions, size=n_envs)
        else:
            actions, _ = self.policy.predict(self._last_obs, deterministic=False)
            actions = np.asarray(actions).reshape(n_envs).copy()
            explore = self._rng.random(n_envs) < self.exploration_rate
            actions[explore] = self._rng.integers(n_actions, size=int(explore.sum()))
        return actions, actions

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "exploration_schedule"]
