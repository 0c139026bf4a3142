"""2M with stock SB3 DQN / stock ``rl_zoo3 train --algo dqn``: the algorithm's part of 2M as a callback.

With a :class:`~sb3_gcrl.two_memory.policies.TwoMemoryDQNPolicy` given as ``policy`` (a dotted path in the zoo
YAML), stock DQN already acts through the policy's per-env dispatch (``DQN.predict`` calls ``policy.predict``).
What stock DQN lacks is what :class:`~sb3_gcrl.two_memory.dispatch.TwoMemoryAlgorithmMixin` does: the p_ec schedule,
drawing each env's memory when its episode starts, and the end-of-episode work (updating MFEC and the score windows).
:class:`TwoMemoryCallback` does it from ``_on_step``, which SB3 calls after ``env.step`` and before the transition
is stored, so ``model._last_obs`` is still the observation the action was taken in.

Differences from :class:`~sb3_gcrl.two_memory.TwoMemoryDQN` (the recommended way, ``sb3-gcrl train --algo
two_memory_dqn``): stock DQN draws one epsilon coin for all envs of a step and uses random actions during
``learning_starts`` for both memories, and its replay buffer cannot filter by source, so ``data_sharing=False``
is refused.
"""

from __future__ import annotations

from stable_baselines3.common.callbacks import BaseCallback

from sb3_gcrl.two_memory.dispatch import (
    PecSpec,
    TwoMemoryAlgorithmMixin,
    TwoMemoryDispatchMixin,
    current_p_ec,
    draw_memories,
    record_two_memory_logs,
    truncated_ends,
)
from sb3_gcrl.two_memory.schedules import DEFAULT_P_EC_SCHEDULE, make_pec_schedule


class TwoMemoryCallback(BaseCallback):
    """Drives the 2M policy of a stock off-policy algorithm: draws the acting memories by the p_ec schedule and feeds
    every step to the policy (episode ends -> MFEC update, scores).

    :param p_ec_schedule: p_ec schedule (see :func:`~sb3_gcrl.two_memory.schedules.make_pec_schedule`); ``None``:
        the default of :class:`~sb3_gcrl.two_memory.TwoMemoryDQN`, Eq. 5.5 with 0.9 -> 0.1 and decay 5e5 steps.
        In a zoo YAML: ``callback: [{sb3_gcrl.two_memory.callbacks.TwoMemoryCallback: {p_ec_schedule: ...}}]``.
    :param verbose: verbosity.
    """

    def __init__(self, p_ec_schedule: PecSpec | None = None, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.p_ec_schedule = make_pec_schedule(DEFAULT_P_EC_SCHEDULE if p_ec_schedule is None else p_ec_schedule)
        #: p_ec of the last draw (logged as ``two_memory/p_ec``)
        self.p_ec = 0.0

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
        if not self.model.policy.data_sharing:
            raise ValueError(
                "data_sharing=False needs the replay buffer to drop EC transitions, which stock DQN cannot do; "
                "use sb3-gcrl train --algo two_memory_dqn (TwoMemoryDQN) for that ablation"
            )
        if self.model.policy.ec_gamma is None:
            # the policy's ec_gamma default is the algorithm's gamma, as with TwoMemoryDQN
            self.model.policy.set_ec_gamma(self.model.gamma)
        self.p_ec = current_p_ec(self.p_ec_schedule, self.model.num_timesteps, self.model.policy)

    def _draw(self) -> None:
        _, self.p_ec = draw_memories(self.p_ec_schedule, self.model.num_timesteps, self.model.policy, self.p_ec)

    def _on_training_start(self) -> None:
        policy = self.model.policy
        if policy.acting_memory.size != self.model.n_envs:
            policy.reset_episodes(self.model.n_envs)
        self._draw()

    def _on_step(self) -> bool:
        policy = self.model.policy
        infos, dones = self.locals["infos"], self.locals["dones"]
        self._draw()  # (a no-op unless the envs were reset since)
        finished = policy.record_step(
            self.model._last_obs,
            self.locals["buffer_actions"],
            self.locals["rewards"],
            dones,
            truncated_ends(dones, infos),
        )
        if finished:
            record_two_memory_logs(self.logger, policy, self.p_ec, None)
            self._draw()  # the envs that start an episode get their memory before the next action
        return True
