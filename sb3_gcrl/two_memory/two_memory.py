"""2M agents (thesis Ch. 5, Algorithm 2): TwoMemoryDQN (MFEC + DQN) and TwoMemorySAC (CEC + SAC, ours)."""

from __future__ import annotations

from typing import Any, ClassVar

from gymnasium import spaces
from stable_baselines3 import DQN, SAC
from stable_baselines3.common.policies import BasePolicy

from sb3_gcrl.two_memory.dispatch import TwoMemoryAlgorithmMixin
from sb3_gcrl.two_memory.policies import (
    PecSpec,
    TwoMemoryDQNPolicy,
    TwoMemoryMinAtarPolicy,
    TwoMemoryMultiInputSACPolicy,
    TwoMemorySACPolicy,
)


class TwoMemoryDQN(TwoMemoryAlgorithmMixin, DQN):
    """Two-memory agent with an MFEC table (2M-EC) and a DQN (2M-RL), thesis Ch. 5 / Algorithm 2.

    Per episode and per env, MFEC acts with probability p_ec, else the Q-network; epsilon-greedy (drawn per env)
    on both. Every transition goes to the replay buffer that trains the DQN on its usual schedule, every finished
    episode updates MFEC (data sharing; ``data_sharing=False`` is ablation 2Mw/oDS: each memory learns only from its
    own episodes). ``predict(deterministic=True)`` uses the memory with the higher mean return over its last
    ``score_window`` training episodes (Eq. 5.6). Logs ``two_memory/*`` (see
    :class:`~sb3_gcrl.two_memory.dispatch.TwoMemoryAlgorithmMixin`).

    Policies: ``"MlpPolicy"`` (SB3 MLP Q-network), ``"MinAtarPolicy"`` (the authors' CNN).
    MFEC settings go in ``policy_kwargs`` (``ec_projection_dim``, ``ec_capacity_per_action``, ``ec_n_neighbors``,
    ``knn_backend``; see :class:`~sb3_gcrl.two_memory.policies.TwoMemoryDQNPolicy`).

    :param policy: policy class or alias.
    :param env: env with a Discrete action space.
    :param p_ec_schedule: p_ec schedule, see :func:`~sb3_gcrl.two_memory.schedules.make_pec_schedule`. ``None``:
        the policy's ``default_p_ec_schedule``, Eq. 5.5 with the thesis's decayed schedule 0.9 -> 0.1 (Table 5.1,
        Sec. 5.5.3) and tau = 5e5 env steps.
    :param data_sharing: share all data between both memories (thesis Sec. 5.4.3).
    :param score_window: n of Eq. 5.6 (50).
    :param ec_gamma: discount of the returns stored in MFEC (None: ``gamma``).
    :param kwargs: every :class:`~stable_baselines3.DQN` argument.
    :raises ValueError: for a non-Discrete action space (use :class:`TwoMemorySAC`), or a 2M switch given in
        ``policy_kwargs``.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": TwoMemoryDQNPolicy,
        "MinAtarPolicy": TwoMemoryMinAtarPolicy,
    }
    policy: TwoMemoryDQNPolicy

    def __init__(
        self,
        policy: str | type[TwoMemoryDQNPolicy],
        env: Any,
        p_ec_schedule: PecSpec | None = None,
        data_sharing: bool = True,
        score_window: int = 50,
        ec_gamma: float | None = None,
        **kwargs: Any,
    ) -> None:
        env = self._check_two_memory_action_space(env, spaces.Discrete, "TwoMemoryDQN", "TwoMemorySAC")
        self._own_two_memory_kwargs(kwargs)
        self.p_ec_schedule = p_ec_schedule
        self.data_sharing = data_sharing
        self.score_window = score_window
        self.ec_gamma = ec_gamma
        init_setup_model = kwargs.pop("_init_setup_model", True)
        super().__init__(policy, env, _init_setup_model=False, **kwargs)
        if init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        if not issubclass(self.policy_class, TwoMemoryDQNPolicy):
            raise ValueError(
                f"TwoMemoryDQN needs a TwoMemoryDQNPolicy (aliases {sorted(self.policy_aliases)}), "
                f"got {self.policy_class.__name__}"
            )
        self._configure_two_memory()
        super()._setup_model()

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        if self._replay_ready():
            super().train(gradient_steps, batch_size)


class TwoMemorySAC(TwoMemoryAlgorithmMixin, SAC):
    """Two-memory agent for continuous actions: a CEC memory (2M-EC, thesis Ch. 4) and SAC (2M-RL).

    Not in the thesis (it combines MFEC with DQN only): the same Algorithm 2 with CEC as the episodic half. Same
    switches (p_ec schedule, data sharing, score window) and logging as :class:`TwoMemoryDQN`. SAC explores with its
    own stochastic policy; EC-run episodes explore as described in
    :class:`~sb3_gcrl.two_memory.policies.TwoMemorySACPolicy`. CEC settings go in ``policy_kwargs``.

    :param policy: policy class or alias (``"MlpPolicy"``, ``"MultiInputPolicy"``).
    :param env: env with a Box action space.
    :param p_ec_schedule: p_ec schedule. ``None``: the policy's ``default_p_ec_schedule``, Eq. 5.5 with 0.9 -> 0.1
        (Table 5.1's decayed schedule) over tau = 5e4 steps (ours: scaled to the 1e5-step budgets of Ch. 4's tasks).
    :param data_sharing: share all data between both memories.
    :param score_window: n of Eq. 5.6.
    :param ec_gamma: discount of the returns stored in CEC (None: ``gamma``).
    :param kwargs: every :class:`~stable_baselines3.SAC` argument.
    :raises ValueError: for a non-Box action space (use :class:`TwoMemoryDQN`), or a 2M switch given in
        ``policy_kwargs``.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": TwoMemorySACPolicy,
        "MultiInputPolicy": TwoMemoryMultiInputSACPolicy,
    }
    policy: TwoMemorySACPolicy

    def __init__(
        self,
        policy: str | type[TwoMemorySACPolicy],
        env: Any,
        p_ec_schedule: PecSpec | None = None,
        data_sharing: bool = True,
        score_window: int = 50,
        ec_gamma: float | None = None,
        **kwargs: Any,
    ) -> None:
        env = self._check_two_memory_action_space(env, spaces.Box, "TwoMemorySAC", "TwoMemoryDQN")
        self._own_two_memory_kwargs(kwargs)
        self.p_ec_schedule = p_ec_schedule
        self.data_sharing = data_sharing
        self.score_window = score_window
        self.ec_gamma = ec_gamma
        init_setup_model = kwargs.pop("_init_setup_model", True)
        super().__init__(policy, env, _init_setup_model=False, **kwargs)
        if init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        if not issubclass(self.policy_class, TwoMemorySACPolicy):
            raise ValueError(f"TwoMemorySAC needs a TwoMemorySACPolicy, got {self.policy_class.__name__}")
        if self.use_sde:
            raise ValueError(
                "TwoMemorySAC does not support use_sde=True (EC-run steps have no SDE noise); set it False"
            )
        self._configure_two_memory()
        super()._setup_model()

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        if self._replay_ready():
            super().train(gradient_steps, batch_size)
