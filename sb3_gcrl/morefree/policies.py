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

from collections.abc import Iterable
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule

from sb3_gcrl.common.validation import check_float, check_int, check_optional_int, check_unit_interval
from sb3_gcrl.morefree.networks import (
    Actor,
    Critic,
    DisagreementEnsemble,
    DynamicalDistance,
    LatentState,
    WorldModel,
    symlog,
)


def make_optimizer(params: Iterable[th.nn.Parameter], lr: float, weight_decay: float) -> th.optim.Optimizer:
    """DreamerV2's optimizer: Adam (eps 1e-5) with decoupled weight decay; one fused kernel per step (CPU and CUDA)."""
    return th.optim.AdamW(params, lr=lr, eps=1e-5, weight_decay=weight_decay, fused=True)


#: network sizes of the CPU preset (see docs/morefree.md for its speed and what it learns)
CPU_NETWORK: dict[str, int] = {
    "deter": 64,
    "stoch": 16,
    "rssm_hidden": 64,
    "model_hidden": 128,
    "model_layers": 2,
    "head_hidden": 128,
    "head_layers": 2,
    "ensemble_size": 5,
    "ensemble_hidden": 64,
}
#: thesis preset (GPU): PEG's state-input point-maze configuration (Gaussian latents 50 + GRU 200, encoder and
#: decoder 3 x 400, actors, critics, distance and ensemble 4 x 400, 10 ensemble members)
THESIS_NETWORK: dict[str, int] = {
    "deter": 200,
    "stoch": 50,
    "rssm_hidden": 200,
    "model_hidden": 400,
    "model_layers": 3,
    "head_hidden": 400,
    "head_layers": 4,
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

    Defaults are PEG's state-input point-maze configuration (:data:`THESIS_NETWORK`, learning rates of its config).

    :param observation_space: Dict goal observation space (``observation``, ``achieved_goal``, ``desired_goal``).
    :param action_space: Box action space.
    :param lr_schedule: world-model learning rate (constant; PEG 3e-4).
    :param actor_lr: learning rate of pi_G and pi_E (PEG 8e-5).
    :param critic_lr: learning rate of V_G and V_E (PEG 8e-5).
    :param distance_lr: learning rate of the dynamical distance (PEG 8e-5).
    :param ensemble_lr: learning rate of the Plan2Explore ensemble (PEG 3e-4).
    :param weight_decay: decoupled weight decay of every optimizer (DreamerV2 1e-6).
    :param deter: GRU state size (PEG 200).
    :param stoch: Gaussian latent size (PEG 50).
    :param rssm_hidden: hidden units of the RSSM's layers (PEG 200).
    :param model_hidden: units of the encoder / decoder layers (PEG 400); the embedding has this size.
    :param model_layers: layers of encoder and decoder (PEG 3).
    :param head_hidden: hidden units of actors, critics, distance and ensemble members (PEG 400).
    :param head_layers: hidden layers of those heads (PEG 4).
    :param ensemble_size: Plan2Explore ensemble members (PEG 10).
    :param ensemble_hidden: hidden units of each ensemble member (``None``: ``head_hidden``, as PEG).
    :param kl_balance: DreamerV2 KL balancing (0.8).
    :param free_nats: free nats on the average KL (PEG 1.0).
    :param grad_clip: gradient-norm clip of every optimizer (DreamerV2 100).
    :param predict_burn_in: posterior steps of the memoryless ``predict`` (no ``episode_start``): the observation is
        filtered this many times with a zero action from the zero state, the latent of an agent that has stayed at
        that observation. One step leaves the latent at the zero state's posterior, which pi_G rarely sees in
        imagination.
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        actor_lr: float = 8e-5,
        critic_lr: float = 8e-5,
        distance_lr: float = 8e-5,
        ensemble_lr: float = 3e-4,
        weight_decay: float = 1e-6,
        deter: int = 200,
        stoch: int = 50,
        rssm_hidden: int = 200,
        model_hidden: int = 400,
        model_layers: int = 3,
        head_hidden: int = 400,
        head_layers: int = 4,
        ensemble_size: int = 10,
        ensemble_hidden: int | None = None,
        kl_balance: float = 0.8,
        free_nats: float = 1.0,
        grad_clip: float = 100.0,
        predict_burn_in: int = 8,
    ) -> None:
        super().__init__(observation_space, action_space, squash_output=True)
        check_spaces(observation_space, action_space)
        self.predict_burn_in = check_int("predict_burn_in", predict_burn_in)  # at least one posterior step
        rates = {
            name: check_float(name, value, minimum=0.0, exclusive_minimum=True)
            for name, value in {
                "actor_lr": actor_lr,
                "critic_lr": critic_lr,
                "distance_lr": distance_lr,
                "ensemble_lr": ensemble_lr,
            }.items()
        }
        grad_clip = check_float("grad_clip", grad_clip, minimum=0.0, exclusive_minimum=True)
        sizes = {
            name: check_int(name, value)
            for name, value in {
                "deter": deter,
                "stoch": stoch,
                "rssm_hidden": rssm_hidden,
                "model_hidden": model_hidden,
                "model_layers": model_layers,
                "head_hidden": head_hidden,
            }.items()
        }
        head_hidden, stoch = sizes["head_hidden"], sizes["stoch"]
        head_layers = check_int("head_layers", head_layers, minimum=0)
        ensemble_size = check_int("ensemble_size", ensemble_size, minimum=2)  # disagreement = spread of members
        ensemble_hidden = check_optional_int("ensemble_hidden", ensemble_hidden)
        weight_decay = check_float("weight_decay", weight_decay, minimum=0.0)
        kl_balance = check_unit_interval("kl_balance", kl_balance)
        free_nats = check_float("free_nats", free_nats, minimum=0.0)
        self.lr_schedule = lr_schedule
        self.learning_rates = rates
        self.weight_decay, self.grad_clip = float(weight_decay), float(grad_clip)
        self.net_kwargs = {
            **sizes,
            "head_layers": head_layers,
            "ensemble_size": ensemble_size,
            "ensemble_hidden": ensemble_hidden,
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
            hidden=sizes["model_hidden"],
            layers=sizes["model_layers"],
            deter=sizes["deter"],
            stoch=sizes["stoch"],
            rssm_hidden=sizes["rssm_hidden"],
            kl_balance=kl_balance,
            free_nats=free_nats,
        )
        feat = self.world_model.feat_dim
        self.actor_g = Actor(feat, self.goal_dim, action_dim, head_hidden, head_layers)
        self.critic_g = Critic(feat, self.goal_dim, head_hidden, head_layers)
        self.critic_g_target = Critic(feat, self.goal_dim, head_hidden, head_layers)
        self.actor_e = Actor(feat, 0, action_dim, head_hidden, head_layers)
        self.critic_e = Critic(feat, 0, head_hidden, head_layers)
        self.critic_e_target = Critic(feat, 0, head_hidden, head_layers)
        self.distance = DynamicalDistance(self.goal_dim, head_hidden, head_layers)
        ensemble_width = head_hidden if ensemble_hidden is None else int(ensemble_hidden)
        self.ensemble = DisagreementEnsemble(feat, action_dim, stoch, ensemble_size, ensemble_width, head_layers)
        self.critic_g_target.load_state_dict(self.critic_g.state_dict())
        self.critic_e_target.load_state_dict(self.critic_e.state_dict())
        self.critic_g_target.requires_grad_(False)
        self.critic_e_target.requires_grad_(False)
        learners = {
            "wm": (self.world_model, lr_schedule(1)),
            "actor_g": (self.actor_g, actor_lr),
            "critic_g": (self.critic_g, critic_lr),
            "actor_e": (self.actor_e, actor_lr),
            "critic_e": (self.critic_e, critic_lr),
            "distance": (self.distance, distance_lr),
            "ensemble": (self.ensemble, ensemble_lr),
        }
        for name, (module, lr) in learners.items():
            setattr(self, f"{name}_optimizer", make_optimizer(module.parameters(), lr, self.weight_decay))
        self._eval_state: LatentState | None = None
        self._eval_action: th.Tensor | None = None

    #: names of the optimizers (attributes ``<name>_optimizer``), saved with the model
    OPTIMIZERS = ("wm", "actor_g", "critic_g", "actor_e", "critic_e", "distance", "ensemble")

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = {"observation_space": self.observation_space, "action_space": self.action_space}
        data.update(
            lr_schedule=self.lr_schedule,
            weight_decay=self.weight_decay,
            grad_clip=self.grad_clip,
            predict_burn_in=self.predict_burn_in,
            **self.learning_rates,
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

    def hold_latent(self, states: th.Tensor, deterministic: bool = False) -> LatentState:
        """The latent of state vectors ``states`` held for ``predict_burn_in`` steps with a zero action, from the zero
        state: the memoryless latent of :meth:`predict` and of PEG's planning start."""
        start = self.world_model.rssm.initial(states.shape[0], states.device)
        no_action = th.zeros(states.shape[0], self.action_space.shape[0], device=states.device)
        post = start
        for _ in range(self.predict_burn_in):
            post = self.filter(post, no_action, states, deterministic)
        return post

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        # memoryless: the latent of this observation held for predict_burn_in steps, from the zero state
        assert isinstance(observation, dict)
        states = th.cat(
            [observation["observation"].float().flatten(1), observation["achieved_goal"].float().flatten(1)], 1
        )
        goals = symlog(observation["desired_goal"].float().flatten(1))
        return self.actor_g.act(self.hold_latent(states, deterministic).feat, goals, deterministic)[0]

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
            prev = self._eval_state
            prev = LatentState(prev.deter * keep, prev.stoch * keep, prev.mean, prev.std)
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
