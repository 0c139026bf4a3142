"""2M with stock SB3 DQN / stock ``rl_zoo3 train --algo dqn``: the 2M dispatcher hosted by a callback.

With a :class:`~sb3_gcrl.two_memory.policies.TwoMemoryDQNPolicy` given as ``policy`` (a dotted path in the zoo
YAML), stock DQN already acts through the policy's per-env dispatch (``DQN.predict`` calls ``policy.predict``).
What stock DQN lacks are the hooks through which a 2M algorithm drives its
:class:`~sb3_gcrl.two_memory.dispatch.TwoMemoryDispatcher`. :class:`TwoMemoryCallback` holds one and calls it from
``_on_step``, which SB3 calls after ``env.step`` and before the transition is stored, so ``model._last_obs`` is
still the observation the action was taken in: the same draws, episode ends and logs as
:class:`~sb3_gcrl.two_memory.TwoMemoryDQN`.

Differences from :class:`~sb3_gcrl.two_memory.TwoMemoryDQN` (the recommended way, ``sb3-gcrl train --algo
two_memory_dqn``, which needs no callback): stock DQN draws one epsilon coin for all envs of a step and uses random
actions during ``learning_starts`` for both memories, and its replay buffer cannot filter by source, so data is
always shared.
"""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sb3_gcrl.two_memory.algorithm import TwoMemoryAlgorithmMixin
from sb3_gcrl.two_memory.dispatch import PecSpec, TwoMemoryDispatcher
from sb3_gcrl.two_memory.policy_mixin import TwoMemoryDispatchMixin
from sb3_gcrl.two_memory.schedules import DEFAULT_P_EC_SCHEDULE


class TwoMemoryCallback(BaseCallback):
    """Drives the 2M policy of a stock off-policy algorithm (stock DQN with a ``TwoMemoryDQNPolicy``) through a
    :class:`~sb3_gcrl.two_memory.dispatch.TwoMemoryDispatcher`: draws the acting memories by the p_ec schedule and
    finishes every episode (episodic-memory update, scores, logs).

    Not for the 2M algorithms, which drive their own dispatcher (``learn`` without callbacks). Use one callback for
    successive ``learn`` calls on the same envs: a new one starts every env on a fresh episode record.

    :param p_ec_schedule: p_ec schedule (see :func:`~sb3_gcrl.two_memory.schedules.make_pec_schedule`); ``None``:
        the default of :class:`~sb3_gcrl.two_memory.TwoMemoryDQN`, Eq. 5.5 with 0.9 -> 0.1 and decay 5e5 steps.
        In a zoo YAML: ``callback: [{sb3_gcrl.two_memory.callbacks.TwoMemoryCallback: {p_ec_schedule: ...}}]``.
    :param ec_gamma: discount of the returns stored in the episodic memory (``None``: the algorithm's ``gamma``).
    :param ec_update_truncated: also write time-limit-truncated episodes into the episodic memory.
    :param verbose: verbosity.

    The memories are drawn with the dispatcher's generator, seeded from the model's seed when training first starts
    (as a 2M algorithm seeds its own: the same seed draws the same memories).
    :raises ValueError: for a bad schedule or setting (at construction), or, when training starts, for a 2M algorithm
        or a policy that is not a 2M policy.
    """

    def __init__(
        self,
        p_ec_schedule: PecSpec | None = None,
        ec_gamma: float | None = None,
        ec_update_truncated: bool = True,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        #: the dispatch of Algorithm 2 and the owner of its settings (stock DQN cannot filter its replay buffer by
        #: source, so data is always shared)
        self.dispatcher = TwoMemoryDispatcher(
            DEFAULT_P_EC_SCHEDULE if p_ec_schedule is None else p_ec_schedule,
            data_sharing=True,
            ec_gamma=ec_gamma,
            ec_update_truncated=ec_update_truncated,
        )
        self._obs_at_training_end: Any = None

    @property
    def p_ec(self) -> float:
        """p_ec of the last draw (logged as ``two_memory/p_ec``)."""
        return self.dispatcher.p_ec

    def _init_callback(self) -> None:
        if isinstance(self.model, TwoMemoryAlgorithmMixin):
            raise ValueError(
                f"{type(self.model).__name__} already does the 2M bookkeeping; remove TwoMemoryCallback "
                "(it is only for stock DQN with a TwoMemoryDQNPolicy)"
            )
        if not isinstance(self.model.policy, TwoMemoryDispatchMixin):
            raise ValueError(
                "TwoMemoryCallback needs a 2M policy (e.g. policy: "
                f"sb3_gcrl.two_memory.policies.TwoMemoryMinAtarPolicy), got {type(self.model.policy).__name__}"
            )
        self.dispatcher.use_gamma_by_default(self.model.gamma)
        if self.dispatcher.rng is None:  # (once: successive learn calls continue the draws)
            self.dispatcher.seed(self.model.seed)

    def _on_training_start(self) -> None:
        envs_reset = self.model._last_obs is not self._obs_at_training_end
        self.dispatcher.start(self.model.policy, self.model.n_envs, self.model.num_timesteps, envs_reset)

    def _on_step(self) -> bool:
        self.dispatcher.step(
            self.model.policy,
            self.model._last_obs,
            self.locals["buffer_actions"],
            self.locals["rewards"],
            self.locals["dones"],
            self.locals["infos"],
            self.model.num_timesteps,
            self.logger,
        )
        return True

    def _on_training_end(self) -> None:
        self._obs_at_training_end = self.model._last_obs
