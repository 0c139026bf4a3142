"""Policy of the model-based MoReFree agent: world model, pi_G / V_G, pi_E / V_E, distance and ensemble networks.

Everything trained is in this one ``nn.Module`` (so ``model.policy.save/load`` and SB3's ``policy.pth`` hold the whole
agent, world model included), with one optimizer per learner (world model, distance, ensemble, each actor, each
critic), saved by the algorithm as ``policy.<name>_optimizer``.

Acting: :meth:`MoReFreePolicy.predict` follows SB3's signature and returns ``state=None``. Without
``episode_start`` every call is memoryless (the latent is the posterior of the observation held for
``predict_burn_in`` steps from the zero state, which a Markov state observation determines); with
``episode_start`` (``evaluate_policy`` passes it) the policy filters its latent across calls, restarting where
``episode_start`` is True.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule

from sb3_gcrl.morefree.networks import (
    Actor,
    Critic,
    DisagreementEnsemble,
    DynamicalDistance,
    LatentState,
    WorldModel,
    symlog,
)

#: network sizes of the CPU preset (PointUMaze in about 1 h per 50k steps on one core)
CPU_NETWORK = {
    "deter": 64,
    "stoch": 8,
    "classes": 8,
    "hidden": 64,
    "embed_dim": 64,
    "model_layers": 2,
    "actor_hidden": 64,
    "actor_layers": 2,
    "ensemble_size": 3,
}
#: thesis preset (GPU): sized after DreamerV2's DMC settings (PEG's backbone); not checked against PEG's config
THESIS_NETWORK = {
    "deter": 200,
    "stoch": 32,
    "classes": 32,
    "hidden": 200,
    "embed_dim": 200,
    "model_layers": 4,
    "actor_hidden": 400,
    "actor_layers": 4,
    "ensemble_size": 10,
}


def state_vector(obs: dict[str, Any]) -> np.ndarray:
    """Flat state vector of a (batch of) Dict goal observations: ``observation`` then ``achieved_goal``."""
    observation = np.asarray(obs["observation"], dtype=np.float32)
    achieved = np.asarray(obs["achieved_goal"], dtype=np.float32)
    batch = observation.shape[:1] if observation.ndim > 1 else ()
    return np.concatenate([observation.reshape(*batch, -1), achieved.reshape(*batch, -1)], -1)


class MoReFreePolicy(BasePolicy):
    """World model and the two actor-critics of MoReFree (thesis Eq. 3.3), plus the distance and ensemble nets.

    :param observation_space: Dict goal observation space (``observation``, ``achieved_goal``, ``desired_goal``).
    :param action_space: Box action space.
    :param lr_schedule: world-model learning rate (constant; DreamerV2 3e-4).
    :param actor_lr: actor learning rate (DreamerV2 8e-5 for continuous control, 1e-4 here by default).
    :param critic_lr: critic and distance learning rate.
    :param deter: GRU state size.
    :param stoch: categorical latent variables.
    :param classes: classes per variable.
    :param hidden: hidden units of the world model.
    :param embed_dim: observation embedding size.
    :param model_layers: hidden layers of encoder/decoder.
    :param actor_hidden: hidden units of actors, critics, distance and ensemble.
    :param actor_layers: hidden layers of those heads.
    :param ensemble_size: Plan2Explore ensemble members.
    :param kl_balance: DreamerV2 KL balancing.
    :param free_nats: DreamerV2 free nats.
    :param grad_clip: gradient-norm clip of every optimizer (DreamerV2: 100).
    :param predict_burn_in: posterior steps of the memoryless ``predict`` (no ``episode_start``): the observation is
        filtered this many times with a zero action from the zero state, the latent of an agent that has stayed at
        that observation. One step leaves the latent at the zero state's posterior, which pi_G rarely sees in
        imagination (a trained GrowingTree pi_G reached no goal from it; see docs/morefree.md).
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        actor_lr: float = 1e-4,
        critic_lr: float = 3e-4,
        deter: int = 128,
        stoch: int = 16,
        classes: int = 16,
        hidden: int = 128,
        embed_dim: int = 128,
        model_layers: int = 2,
        actor_hidden: int = 128,
        actor_layers: int = 2,
        ensemble_size: int = 5,
        kl_balance: float = 0.8,
        free_nats: float = 1.0,
        grad_clip: float = 100.0,
        predict_burn_in: int = 8,
    ) -> None:
        super().__init__(observation_space, action_space, squash_output=True)
        check_spaces(observation_space, action_space)
        if predict_burn_in < 1:
            raise ValueError(f"predict_burn_in must be >= 1 (one posterior step), got {predict_burn_in}")
        self.predict_burn_in = int(predict_burn_in)
        self.lr_schedule = lr_schedule
        self.actor_lr, self.critic_lr, self.grad_clip = actor_lr, critic_lr, grad_clip
        self.net_kwargs = {
            "deter": deter,
            "stoch": stoch,
            "classes": classes,
            "hidden": hidden,
            "embed_dim": embed_dim,
            "model_layers": model_layers,
            "actor_hidden": actor_hidden,
            "actor_layers": actor_layers,
            "ensemble_size": ensemble_size,
            "kl_balance": kl_balance,
            "free_nats": free_nats,
        }
        self.goal_dim = int(np.prod(observation_space["desired_goal"].shape))
        self.state_dim = int(np.prod(observation_space["observation"].shape)) + int(
            np.prod(observation_space["achieved_goal"].shape)
        )
        action_dim = int(np.prod(action_space.shape))
        self.world_model = WorldModel(
            self.state_dim,
            self.goal_dim,
            action_dim,
            hidden,
            model_layers,
            embed_dim,
            deter,
            stoch,
            classes,
            kl_balance,
            free_nats,
        )
        feat = self.world_model.feat_dim
        self.actor_g = Actor(feat, self.goal_dim, action_dim, actor_hidden, actor_layers)
        self.critic_g = Critic(feat, self.goal_dim, actor_hidden, actor_layers)
        self.critic_g_target = Critic(feat, self.goal_dim, actor_hidden, actor_layers)
        self.actor_e = Actor(feat, 0, action_dim, actor_hidden, actor_layers)
        self.critic_e = Critic(feat, 0, actor_hidden, actor_layers)
        self.critic_e_target = Critic(feat, 0, actor_hidden, actor_layers)
        self.distance = DynamicalDistance(feat, self.goal_dim, actor_hidden, actor_layers)
        self.ensemble = DisagreementEnsemble(feat, action_dim, embed_dim, ensemble_size, actor_hidden, actor_layers)
        self.critic_g_target.load_state_dict(self.critic_g.state_dict())
        self.critic_e_target.load_state_dict(self.critic_e.state_dict())
        self.critic_g_target.requires_grad_(False)
        self.critic_e_target.requires_grad_(False)
        adam = th.optim.Adam
        self.wm_optimizer = adam(self.world_model.parameters(), lr=lr_schedule(1), eps=1e-5)
        self.actor_g_optimizer = adam(self.actor_g.parameters(), lr=actor_lr, eps=1e-5)
        self.critic_g_optimizer = adam(self.critic_g.parameters(), lr=critic_lr, eps=1e-5)
        self.actor_e_optimizer = adam(self.actor_e.parameters(), lr=actor_lr, eps=1e-5)
        self.critic_e_optimizer = adam(self.critic_e.parameters(), lr=critic_lr, eps=1e-5)
        self.distance_optimizer = adam(self.distance.parameters(), lr=critic_lr, eps=1e-5)
        self.ensemble_optimizer = adam(self.ensemble.parameters(), lr=lr_schedule(1), eps=1e-5)
        self._eval_state: LatentState | None = None
        self._eval_action: th.Tensor | None = None

    #: names of the optimizers (attributes ``<name>_optimizer``), saved with the model
    OPTIMIZERS = ("wm", "actor_g", "critic_g", "actor_e", "critic_e", "distance", "ensemble")

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = {"observation_space": self.observation_space, "action_space": self.action_space}
        data.update(
            lr_schedule=self.lr_schedule,
            actor_lr=self.actor_lr,
            critic_lr=self.critic_lr,
            grad_clip=self.grad_clip,
            predict_burn_in=self.predict_burn_in,
            **self.net_kwargs,
        )
        return data

    # --- acting -----------------------------------------------------------------------------------------------
    def states_to_tensor(self, obs: dict[str, Any]) -> tuple[th.Tensor, th.Tensor]:
        """(state vectors, symlog goals) of a batch of Dict observations, as tensors on the policy's device."""
        states = th.as_tensor(state_vector(obs), device=self.device)
        goals = th.as_tensor(np.asarray(obs["desired_goal"], dtype=np.float32), device=self.device)
        return states, symlog(goals.reshape(states.shape[0], -1))

    def filter(
        self, state: LatentState, prev_action: th.Tensor, states: th.Tensor, deterministic: bool = False
    ) -> LatentState:
        """One posterior step of the world model from ``state`` after ``prev_action`` (both zero at a start).

        ``deterministic`` takes the posterior's mode instead of a sample (deterministic actions).
        """
        rssm = self.world_model.rssm
        return rssm.posterior(rssm.step_deter(state, prev_action), self.world_model.embed(states), deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        # memoryless: the latent of this observation held for predict_burn_in steps, from the zero state
        assert isinstance(observation, dict)
        states = th.cat(
            [observation["observation"].float().flatten(1), observation["achieved_goal"].float().flatten(1)], 1
        )
        goals = symlog(observation["desired_goal"].float().flatten(1))
        rssm = self.world_model.rssm
        start = rssm.initial(states.shape[0], states.device)
        no_action = th.zeros(states.shape[0], self.action_space.shape[0], device=states.device)
        post = start
        for _ in range(self.predict_burn_in):
            post = self.filter(post, no_action, states, deterministic)
        return self.actor_g.act(post.feat, goals, deterministic)[0]

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's predict (actions toward the observation's ``desired_goal`` with pi_G); see the module docstring."""
        if episode_start is None:
            return super().predict(observation, state, episode_start, deterministic)
        self.set_training_mode(False)
        obs_tensor, vectorized = self.obs_to_tensor(observation)
        assert isinstance(obs_tensor, dict)
        with th.no_grad():
            states = th.cat(
                [obs_tensor["observation"].float().flatten(1), obs_tensor["achieved_goal"].float().flatten(1)], 1
            )
            goals = symlog(obs_tensor["desired_goal"].float().flatten(1))
            batch = states.shape[0]
            rssm = self.world_model.rssm
            if self._eval_state is None or self._eval_state.deter.shape[0] != batch:
                self._eval_state = rssm.initial(batch, self.device)
                self._eval_action = th.zeros(batch, self.action_space.shape[0], device=self.device)
            assert self._eval_action is not None
            keep = th.as_tensor(~np.asarray(episode_start, dtype=bool).reshape(-1), device=self.device)
            keep = keep.float().unsqueeze(-1)
            prev = LatentState(self._eval_state.deter * keep, self._eval_state.stoch * keep, self._eval_state.logits)
            post = self.filter(prev, self._eval_action * keep, states, deterministic)
            actions = self.actor_g.act(post.feat, goals, deterministic)[0]
            self._eval_state, self._eval_action = post, actions
        out = self.unscale_action(actions.cpu().numpy())
        if not vectorized:
            out = out.squeeze(axis=0)
        return out, None


def check_spaces(observation_space: spaces.Space, action_space: spaces.Space) -> None:
    """Refuse spaces the agent cannot model, naming what it needs.

    :raises TypeError: for a non-goal observation space or a non-Box action space.
    """
    if not isinstance(observation_space, spaces.Dict) or not {"observation", "achieved_goal", "desired_goal"} <= set(
        observation_space.spaces
    ):
        raise TypeError(
            "MoReFree needs a goal env: a Dict observation space with 'observation', 'achieved_goal' and "
            f"'desired_goal' (gymnasium-robotics style), got {observation_space}"
        )
    for key in ("observation", "achieved_goal", "desired_goal"):
        if not isinstance(observation_space[key], spaces.Box):
            raise TypeError(f"MoReFree models vector states: observation_space[{key!r}] must be a Box")
    if observation_space["achieved_goal"].shape != observation_space["desired_goal"].shape:
        raise TypeError("MoReFree needs achieved_goal and desired_goal of the same shape")
    if not isinstance(action_space, spaces.Box) or not action_space.is_bounded():
        raise TypeError(f"MoReFree needs a bounded Box action space (continuous control), got {action_space}")
