"""2M with stock SB3 DQN / stock ``rl_zoo3 train --algo dqn``: the episode bookkeeping as a callback.

With a :class:`~sb3_gcrl.two_memory.policies.TwoMemoryDQNPolicy` given as ``policy`` (a dotted path in the zoo
YAML), stock DQN already acts through the policy's per-env dispatch (``DQN.predict`` calls ``policy.predict``).
What stock DQN lacks is the end-of-episode work: updating MFEC, the score windows and drawing the next memory.
:class:`TwoMemoryCallback` does it from ``_on_step``, which SB3 calls after ``env.step`` and before the transition
is stored, so ``model._last_obs`` is still the observation the action was taken in.

Differences from :class:`~sb3_gcrl.two_memory.TwoMemoryDQN` (the recommended way, ``sb3-gcrl train --algo
two_memory_dqn``): stock DQN draws one epsilon coin for all envs of a step and uses random actions during
``learning_starts`` for both memories, and its replay buffer cannot filter by source, so ``data_sharing=False``
is refused.
"""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sb3_gcrl.two_memory.dispatch import TwoMemoryAlgorithmMixin, TwoMemoryDispatchMixin
from sb3_gcrl.two_memory.schedules import EPISODIC, PARAMETRIC


class TwoMemoryCallback(BaseCallback):
    """Feeds every step to the 2M policy of a stock off-policy algorithm (episode ends -> MFEC update, scores).

    :param verbose: verbosity.
    """

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

    def _on_training_start(self) -> None:
        policy = self.model.policy
        if policy.acting_memory.size != self.model.n_envs:
            policy.reset_episodes(self.model.n_envs)
        policy.num_timesteps = self.model.num_timesteps

    def _on_step(self) -> bool:
        policy = self.model.policy
        infos = self.locals["infos"]
        dones = self.locals["dones"]
        truncated = np.array([done and info.get("TimeLimit.truncated", False) for done, info in zip(dones, infos)])
        # during DQN's random warm-up predict() is not called, so no memory was drawn yet: draw it now
        policy.assign_memories()
        finished = policy.record_step(
            self.model._last_obs, self.locals["buffer_actions"], self.locals["rewards"], dones, truncated
        )
        policy.num_timesteps = self.model.num_timesteps
        if finished:
            windows = policy.score_windows
            self.logger.record("two_memory/p_ec", policy.last_p_ec)
            for memory, name in ((EPISODIC, "ec"), (PARAMETRIC, "rl")):
                if windows.n_episodes(memory) > 0:
                    self.logger.record(f"two_memory/score_{name}", windows.score(memory))
                self.logger.record(f"two_memory/episodes_{name}", int(policy.episode_counts[memory]))
            self.logger.record("two_memory/eval_memory_is_ec", int(policy.evaluation_memory() == EPISODIC))
        return True
