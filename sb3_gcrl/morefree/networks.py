"""Networks of the model-based MoReFree agent (thesis Ch. 3, Sec. 3.3.2), as PEG's state-input agent builds them.

PEG (Hu et al., 2023), the backbone the thesis extends, is LEXA / DreamerV2 with state inputs. Its point-maze
configuration fixes what is built here:

* :class:`RSSM`: recurrent state-space model with a *Gaussian* stochastic state (``stoch`` dimensions, std
  ``2 sigmoid(x / 2) + 0.1``) and DreamerV2's layer-normalised GRU (:class:`GRUCell`) as deterministic state;
  KL balancing 0.8 with free nats applied to the batch-average KL (DreamerV2 ``free_avg``).
* :class:`WorldModel`: ELU MLP encoder and decoder (no normalisation) around the RSSM over the state vector
  ``[observation, achieved_goal]`` (symlog-squashed, DreamerV3's input transform), unit-variance Gaussian
  reconstruction. No reward head: MoReFree never learns from the env's reward (Table 3.1).
* :class:`DynamicalDistance`: LEXA / PEG's temporal distance (steps between two states divided by the imagination
  horizon), read on *goal-space* inputs: the achieved goal decoded from a latent state, and the goal (PEG's
  ``gc_input: state`` path). It cannot see where in a rollout a latent state lies, only where it is.
* :class:`DisagreementEnsemble`: Plan2Explore's ensemble of one-step models of the next stochastic state; the
  standard deviation across members, averaged over dimensions, is pi_E's intrinsic reward. The members are one
  batched module (a batched matmul per layer, not a loop over members).
* :class:`Actor`: DreamerV2's truncated normal on [-1, 1] (:class:`TruncatedNormal`, mean ``tanh(x)``, std in
  [0.1, 2.1]) with the entropy of that distribution; :class:`Critic`: an ELU MLP value regressed on
  lambda-returns.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch as th
import torch.nn.functional as F
from torch import nn

from sb3_gcrl.morefree.functional import (
    future_pairs,
    gaussian_std,
    goal_embedding,
    mlp,
    symlog,
    truncated_normal_entropy,
)


class LatentState(NamedTuple):
    """An RSSM state: deterministic ``deter`` (..., D), stochastic sample ``stoch`` (..., S) and its Gaussian."""

    deter: th.Tensor
    stoch: th.Tensor
    mean: th.Tensor
    std: th.Tensor

    @property
    def feat(self) -> th.Tensor:
        """Features the heads read: ``[deter, stoch]``."""
        return th.cat([self.deter, self.stoch], -1)

    def detach(self) -> LatentState:
        return LatentState(*(x.detach() for x in self))

    def flatten(self) -> LatentState:
        """Merge all leading dimensions into one batch dimension."""
        return LatentState(*(x.reshape(-1, x.shape[-1]) for x in self))

    def rows(self, index: th.Tensor) -> LatentState:
        """The states at batch rows ``index`` of a flat state."""
        return LatentState(*(x[index] for x in self))

    def expand(self, n: int) -> LatentState:
        """A flat state of one row repeated ``n`` times."""
        return LatentState(*(x.expand(n, *x.shape[1:]).contiguous() for x in self))


class GRUCell(nn.Module):
    """DreamerV2's GRU cell: one linear layer over ``[input, state]``, LayerNorm, update gate biased by -1.

    :param input_size: input size.
    :param size: state size.
    """

    def __init__(self, input_size: int, size: int) -> None:
        super().__init__()
        self.linear = nn.Linear(input_size + size, 3 * size, bias=False)
        self.norm = nn.LayerNorm(3 * size)

    def forward(self, x: th.Tensor, state: th.Tensor) -> th.Tensor:
        reset, cand, update = self.norm(self.linear(th.cat([x, state], -1)).float()).chunk(3, -1)
        cand = th.tanh(th.sigmoid(reset) * cand)
        update = th.sigmoid(update - 1.0)
        return update * cand + (1 - update) * state


class RSSM(nn.Module):
    """Recurrent state-space model with Gaussian latents (DreamerV2 / PEG for state inputs).

    :param action_dim: action size (actions in [-1, 1]).
    :param embed_dim: size of the observation embedding.
    :param deter: size of the GRU state h (PEG: 200).
    :param stoch: size of the Gaussian stochastic state z (PEG: 50).
    :param hidden: hidden units of the input, prior and posterior layers (PEG: 200).
    :param min_std: lower bound of the latent std (DreamerV2: 0.1).
    """

    def __init__(
        self,
        action_dim: int,
        embed_dim: int,
        deter: int = 200,
        stoch: int = 50,
        hidden: int = 200,
        min_std: float = 0.1,
    ) -> None:
        super().__init__()
        self.deter_dim, self.stoch_dim, self.min_std = deter, stoch, min_std
        self.feat_dim = deter + stoch
        self.img_in = nn.Sequential(nn.Linear(stoch + action_dim, hidden), nn.ELU())
        self.gru = GRUCell(hidden, deter)
        self.prior_net = nn.Sequential(nn.Linear(deter, hidden), nn.ELU(), nn.Linear(hidden, 2 * stoch))
        # the posterior's first layer over [deter, embed], split so the embedding part runs once per sequence
        self.post_deter = nn.Linear(deter, hidden)
        self.post_embed = nn.Linear(embed_dim, hidden, bias=False)
        self.post_out = nn.Linear(hidden, 2 * stoch)

    def initial(self, batch: int, device: th.device | str) -> LatentState:
        """The all-zero state that starts every sequence (and follows every physical reset)."""
        deter = th.zeros(batch, self.deter_dim, device=device)
        stoch = th.zeros(batch, self.stoch_dim, device=device)
        return LatentState(deter, stoch, stoch, stoch)

    def _stats(self, raw: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        mean, std = raw.float().chunk(2, -1)
        return mean, gaussian_std(std, self.min_std)

    @staticmethod
    def _sample(mean: th.Tensor, std: th.Tensor, mode: bool) -> th.Tensor:
        return mean if mode else mean + std * th.randn_like(std)

    def step_deter(self, state: LatentState, action: th.Tensor) -> th.Tensor:
        """h_t = GRU(h_{t-1}, [z_{t-1}, a_{t-1}])."""
        return self.gru(self.img_in(th.cat([state.stoch, action], -1)), state.deter)

    def prior(self, deter: th.Tensor, mode: bool = False) -> LatentState:
        """z_t ~ p(z_t | h_t) for deterministic states ``deter`` (any leading shape)."""
        mean, std = self._stats(self.prior_net(deter))
        return LatentState(deter, self._sample(mean, std, mode), mean, std)

    def img_step(self, state: LatentState, action: th.Tensor, mode: bool = False) -> LatentState:
        """Prior step: h_t = GRU(h_{t-1}, z_{t-1}, a_{t-1}), z_t ~ p(z_t | h_t)."""
        return self.prior(self.step_deter(state, action), mode)

    def posterior(
        self, deter: th.Tensor, embed: th.Tensor, mode: bool = False, embed_proj: th.Tensor | None = None
    ) -> LatentState:
        """z ~ q(z | h, e) for a deterministic state ``deter`` already stepped.

        :param embed_proj: ``post_embed(embed)`` when already computed (the observe loop projects whole sequences).
        """
        proj = self.post_embed(embed) if embed_proj is None else embed_proj
        mean, std = self._stats(self.post_out(F.elu(self.post_deter(deter) + proj)))
        return LatentState(deter, self._sample(mean, std, mode), mean, std)

    def observe(
        self, embed: th.Tensor, actions: th.Tensor, is_first: th.Tensor, state: LatentState | None = None
    ) -> tuple[LatentState, tuple[th.Tensor, th.Tensor]]:
        """Filter a batch of sequences (time-major ``(T, B, ...)``); state and previous action are zeroed where
        ``is_first``. ``actions[t]`` is the action taken *before* observation ``t``.

        Only the GRU and the posterior run step by step; the prior's statistics (for the KL) are computed for all
        steps at once afterwards.

        :return: posteriors with tensors of shape ``(T, B, ...)`` and the prior's (mean, std) at every step.
        """
        steps, batch = embed.shape[:2]
        state = self.initial(batch, embed.device) if state is None else state
        keep = (~is_first).to(embed.dtype).unsqueeze(-1)
        proj = self.post_embed(embed)
        actions = actions * keep
        posts = []
        for t in range(steps):
            prev = LatentState(state.deter * keep[t], state.stoch * keep[t], state.mean, state.std)
            state = self.posterior(self.step_deter(prev, actions[t]), embed[t], embed_proj=proj[t])
            posts.append(state)
        post = LatentState(*(th.stack(x) for x in zip(*posts)))
        return post, self._stats(self.prior_net(post.deter))

    @staticmethod
    def kl(mean_q: th.Tensor, std_q: th.Tensor, mean_p: th.Tensor, std_p: th.Tensor) -> th.Tensor:
        """KL(q || p) of diagonal Gaussians, summed over the last dimension."""
        var_ratio = (std_q / std_p).pow(2)
        return 0.5 * (var_ratio + ((mean_q - mean_p) / std_p).pow(2) - 1 - var_ratio.log()).sum(-1)

    def kl_loss(
        self, post: LatentState, prior: tuple[th.Tensor, th.Tensor], balance: float, free_nats: float
    ) -> tuple[th.Tensor, th.Tensor]:
        """DreamerV2 KL balancing with free nats on the average KL (``free_avg``).

        ``balance`` weighs the prior's term ``KL(sg(q) || p)``, ``1 - balance`` the posterior's ``KL(q || sg(p))``;
        each term is ``max(mean KL, free_nats)``.

        :return: (loss, mean KL).
        """
        mean_p, std_p = prior
        prior_term = self.kl(post.mean.detach(), post.std.detach(), mean_p, std_p).mean()
        post_term = self.kl(post.mean, post.std, mean_p.detach(), std_p.detach()).mean()
        loss = balance * prior_term.clamp(min=free_nats) + (1 - balance) * post_term.clamp(min=free_nats)
        return loss, prior_term.detach()


class WorldModel(nn.Module):
    """Encoder, RSSM and decoder over state observations (``observation`` + ``achieved_goal``, symlog-squashed).

    :param obs_dim: size of the flat state vector (observation followed by achieved goal).
    :param goal_dim: size of the goal (the last ``goal_dim`` values of the state vector).
    :param action_dim: action size.
    :param hidden: units of the encoder / decoder layers (PEG: 400); the embedding is the encoder's last layer.
    :param layers: layers of encoder and decoder (PEG: 3).
    :param deter: GRU state size (PEG: 200).
    :param stoch: Gaussian latent size (PEG: 50).
    :param rssm_hidden: hidden units of the RSSM's layers (PEG: 200).
    :param kl_balance: DreamerV2's KL balancing weight (0.8).
    :param free_nats: free nats on the average KL (PEG: 1.0).
    :param kl_scale: weight of the KL term (1.0).
    """

    def __init__(
        self,
        obs_dim: int,
        goal_dim: int,
        action_dim: int,
        hidden: int = 400,
        layers: int = 3,
        deter: int = 200,
        stoch: int = 50,
        rssm_hidden: int = 200,
        kl_balance: float = 0.8,
        free_nats: float = 1.0,
        kl_scale: float = 1.0,
    ) -> None:
        super().__init__()
        if layers < 1:
            raise ValueError(f"the world model needs at least one encoder / decoder layer, got model_layers={layers}")
        self.obs_dim, self.goal_dim = obs_dim, goal_dim
        self.kl_balance, self.free_nats, self.kl_scale = kl_balance, free_nats, kl_scale
        # PEG's encoder: ELU layers, the last one's activations are the embedding
        self.encoder = nn.Sequential(mlp(obs_dim, hidden, hidden, layers - 1), nn.ELU())
        self.rssm = RSSM(action_dim, hidden, deter, stoch, rssm_hidden)
        self.decoder = mlp(self.rssm.feat_dim, obs_dim, hidden, layers)

    @property
    def feat_dim(self) -> int:
        return self.rssm.feat_dim

    def embed(self, states: th.Tensor) -> th.Tensor:
        """Embedding of raw state vectors (symlog applied here)."""
        return self.encoder(symlog(states))

    def decode_goal(self, feat: th.Tensor) -> th.Tensor:
        """The achieved goal of a latent state, in symlog space (where goals are compared)."""
        return self.decoder(feat)[..., self.obs_dim - self.goal_dim :].float()

    def loss(
        self, states: th.Tensor, actions: th.Tensor, is_first: th.Tensor
    ) -> tuple[th.Tensor, LatentState, dict[str, th.Tensor]]:
        """World-model loss on time-major sequences: Gaussian reconstruction (-log N(x; x_hat, 1), constants
        dropped) plus the balanced KL.

        :return: (loss, posteriors ``(T, B, ...)``, detached metrics).
        """
        post, prior = self.rssm.observe(self.embed(states), actions, is_first)
        recon_loss = 0.5 * (self.decoder(post.feat).float() - symlog(states)).pow(2).sum(-1).mean()
        kl_loss, kl = self.rssm.kl_loss(post, prior, self.kl_balance, self.free_nats)
        loss = recon_loss + self.kl_scale * kl_loss
        return loss, post, {"recon_loss": recon_loss.detach(), "kl": kl}


class TruncatedNormal:
    """Normal(loc, scale) truncated to [low, high], reparameterised by the inverse CDF (DreamerV2's actor).

    Samples are clipped ``clip`` inside the bounds with straight-through gradients, as DreamerV2's
    ``TruncNormalDist``; :meth:`entropy` is the truncated distribution's. ``loc`` must lie inside the bounds (the
    actor's ``tanh`` mean does), so the normaliser ``Z`` stays above 0.5 x the tail mass and is well conditioned.
    """

    def __init__(self, loc: th.Tensor, scale: th.Tensor, low: float = -1.0, high: float = 1.0, clip: float = 1e-6):
        self.loc, self.scale, self.low, self.high, self.clip = loc, scale, low, high, clip
        self.alpha = (low - loc) / scale
        self.beta = (high - loc) / scale
        self.cdf_alpha = th.special.ndtr(self.alpha)
        self.z = (th.special.ndtr(self.beta) - self.cdf_alpha).clamp(min=1e-6)

    @property
    def mode(self) -> th.Tensor:
        """The most likely action: ``loc`` (inside the bounds)."""
        return self.loc

    def rsample(self) -> th.Tensor:
        """A reparameterised sample."""
        u = th.rand_like(self.loc)
        p = (self.cdf_alpha + u * self.z).clamp(1e-6, 1 - 1e-6)
        x = self.loc + self.scale * th.special.ndtri(p)
        clipped = x.clamp(self.low + self.clip, self.high - self.clip)
        return x + (clipped - x).detach()

    def entropy(self) -> th.Tensor:
        """Entropy of each dimension: ``log(sqrt(2 pi e) scale Z) + (alpha phi(alpha) - beta phi(beta)) / (2 Z)``."""
        return truncated_normal_entropy(self.scale, self.z, self.alpha, self.beta)


class GoalConditionedMLP(nn.Module):
    """An ELU MLP over ``[features, goal embedding]`` (:func:`goal_embedding` of width ``feat_dim``), or over the
    features alone when ``goal_dim`` is 0.

    :param feat_dim: latent feature size.
    :param goal_dim: goal size (0: no goal).
    :param out_dim: output size.
    :param hidden: hidden units.
    :param layers: hidden layers.
    """

    def __init__(self, feat_dim: int, goal_dim: int, out_dim: int, hidden: int, layers: int) -> None:
        super().__init__()
        self.goal_embed = goal_embedding(goal_dim, feat_dim)
        self.net = mlp(feat_dim * (2 if goal_dim else 1), out_dim, hidden, layers)

    def forward(self, feat: th.Tensor, goal: th.Tensor | None = None) -> th.Tensor:
        if self.goal_embed is not None:
            assert goal is not None, "a goal-conditioned network needs a goal"
            feat = th.cat([feat, self.goal_embed(goal)], -1)
        return self.net(feat).float()


class Actor(nn.Module):
    """Truncated-normal policy on [-1, 1] (DreamerV2 / PEG): mean ``tanh(x)``, std ``2 sigmoid(s / 2) + min_std``.

    :param feat_dim: latent feature size.
    :param goal_dim: goal size (0 for pi_E).
    :param action_dim: action size.
    :param hidden: hidden units (PEG: 400).
    :param layers: hidden layers (PEG: 4).
    :param min_std: lower bound of the std (DreamerV2: 0.1).
    """

    def __init__(
        self, feat_dim: int, goal_dim: int, action_dim: int, hidden: int, layers: int, min_std: float = 0.1
    ) -> None:
        super().__init__()
        self.net = GoalConditionedMLP(feat_dim, goal_dim, 2 * action_dim, hidden, layers)
        self.min_std = min_std

    def forward(self, feat: th.Tensor, goal: th.Tensor | None = None) -> TruncatedNormal:
        mean, std = self.net(feat, goal).chunk(2, -1)
        return TruncatedNormal(th.tanh(mean), gaussian_std(std, self.min_std))

    def act(
        self, feat: th.Tensor, goal: th.Tensor | None = None, deterministic: bool = False
    ) -> tuple[th.Tensor, th.Tensor]:
        """Action in [-1, 1] (a reparameterised sample, or the mode) and the distribution's entropy."""
        dist = self(feat, goal)
        action = dist.mode if deterministic else dist.rsample()
        return action, dist.entropy().sum(-1)


class Critic(nn.Module):
    """Scalar value of latent features (and a goal for V_G): an ELU MLP regressed on lambda-returns (PEG)."""

    def __init__(self, feat_dim: int, goal_dim: int, hidden: int, layers: int) -> None:
        super().__init__()
        self.net = GoalConditionedMLP(feat_dim, goal_dim, 1, hidden, layers)

    def forward(self, feat: th.Tensor, goal: th.Tensor | None = None) -> th.Tensor:
        return self.net(feat, goal).squeeze(-1)


class DynamicalDistance(nn.Module):
    """LEXA / PEG's temporal distance between two points of goal space: steps between them / ``horizon``.

    The input is ``[achieved goal, goal]`` (symlog goal space), the output linear (PEG regresses the normalised
    step count with a linear head).

    :param goal_dim: goal size.
    :param hidden: hidden units (PEG: 400).
    :param layers: hidden layers (PEG: 4).
    """

    def __init__(self, goal_dim: int, hidden: int, layers: int) -> None:
        super().__init__()
        self.net = mlp(2 * goal_dim, 1, hidden, layers)

    def forward(self, achieved: th.Tensor, goal: th.Tensor) -> th.Tensor:
        return self.net(th.cat([achieved, goal], -1)).squeeze(-1).float()

    def loss(
        self, achieved: th.Tensor, goal: th.Tensor, steps: th.Tensor, unit: float, weight: th.Tensor | None = None
    ) -> th.Tensor:
        """Mean squared error of ``D(achieved, goal)`` against ``steps / unit`` (optionally weighted rows)."""
        error = (self(achieved, goal) - steps.to(achieved.dtype) / unit).pow(2)
        if weight is None:
            return error.mean()
        return (weight * error).sum() / weight.sum().clamp(min=1.0)

    def trajectory_loss(
        self,
        goals: th.Tensor,
        n_pairs: int,
        unit: float,
        neg_fraction: float = 0.0,
        groups: th.Tensor | None = None,
    ) -> th.Tensor:
        """LEXA / PEG's regression on pairs of points along trajectories ``goals (T, N, G)`` (detached).

        A pair ``(i, j)``, ``i <= j``, of one trajectory, drawn uniformly from all such pairs, has the target
        ``(j - i) / unit``. ``neg_fraction * n_pairs`` extra pairs take their goal from a trajectory of another
        group (a different replayed sequence), with the target ``(unit + 1) / unit``: farther than any trained
        positive (PEG's negatives).

        :param goals: achieved goals along the trajectories.
        :param n_pairs: positive pairs sampled.
        :param unit: steps that make distance 1.
        :param neg_fraction: negatives per positive pair (PEG's ``dd_neg_sampling_factor``).
        :param groups: ``(N,)`` group of each trajectory (``None``: each trajectory its own group).
        :return: the regression loss.
        """
        steps, n_traj = goals.shape[:2]
        device = goals.device
        grid_i, grid_j = future_pairs(steps, device)
        pick = th.randint(0, grid_i.shape[0], (n_pairs,), device=device)
        i, j = grid_i[pick], grid_j[pick]
        traj = th.randint(0, n_traj, (n_pairs,), device=device)
        loss = self.loss(goals[i, traj], goals[j, traj], j - i, unit)
        n_neg = int(round(neg_fraction * n_pairs))
        if n_neg > 0:
            groups = th.arange(n_traj, device=device) if groups is None else groups
            cur = th.randint(0, n_traj, (n_neg,), device=device)
            other = th.randint(0, n_traj, (n_neg,), device=device)
            usable = (groups[cur] != groups[other]).to(goals.dtype)
            ti = th.randint(0, steps, (n_neg,), device=device)
            tj = th.randint(0, steps, (n_neg,), device=device)
            far = th.full((n_neg,), unit + 1.0, device=device)
            loss = loss + self.loss(goals[ti, cur], goals[tj, other], far, unit, usable)
        return loss


class EnsembleLinear(nn.Module):
    """``size`` independent linear layers applied as one batched matmul: ``(K, N, in) -> (K, N, out)``."""

    def __init__(self, size: int, in_dim: int, out_dim: int) -> None:
        super().__init__()
        bound = 1 / math.sqrt(in_dim)  # nn.Linear's default initialisation, per member
        self.weight = nn.Parameter(th.empty(size, in_dim, out_dim).uniform_(-bound, bound))
        self.bias = nn.Parameter(th.empty(size, 1, out_dim).uniform_(-bound, bound))

    def forward(self, x: th.Tensor) -> th.Tensor:
        return th.baddbmm(self.bias, x, self.weight)


class DisagreementEnsemble(nn.Module):
    """Plan2Explore: ``size`` ELU MLPs predict the next stochastic state from (features, action).

    :param feat_dim: latent feature size.
    :param action_dim: action size.
    :param target_dim: size of the predicted stochastic state.
    :param size: members (PEG: 10).
    :param hidden: hidden units (PEG: 400).
    :param layers: hidden layers (PEG: 4).
    """

    def __init__(self, feat_dim: int, action_dim: int, target_dim: int, size: int, hidden: int, layers: int) -> None:
        super().__init__()
        if size < 2:
            raise ValueError(f"the disagreement of an ensemble needs at least 2 members, got ensemble_size={size}")
        self.size = size
        dims = [feat_dim + action_dim] + [hidden] * layers + [target_dim]
        self.layers = nn.ModuleList(EnsembleLinear(size, a, b) for a, b in zip(dims[:-1], dims[1:]))

    def forward(self, feat: th.Tensor, action: th.Tensor) -> th.Tensor:
        """Predictions ``(size, *batch, target_dim)`` for inputs of any leading shape."""
        x = th.cat([feat, action], -1)
        batch = x.shape[:-1]
        x = x.reshape(1, -1, x.shape[-1]).expand(self.size, -1, -1)
        for k, layer in enumerate(self.layers):
            x = layer(x)
            if k < len(self.layers) - 1:
                x = F.elu(x)
        return x.reshape(self.size, *batch, x.shape[-1]).float()

    def loss(self, feat: th.Tensor, action: th.Tensor, target: th.Tensor, weight: th.Tensor | None = None) -> th.Tensor:
        """Gaussian (unit variance) regression of every member on ``target`` (inputs detached by the caller).

        :param weight: optional ``(*batch,)`` 0/1 weights of the rows.
        """
        error = 0.5 * (self(feat, action) - target.unsqueeze(0)).pow(2).sum(-1).mean(0)
        if weight is None:
            return error.mean()
        return (weight * error).sum() / weight.sum().clamp(min=1.0)

    def disagreement(self, feat: th.Tensor, action: th.Tensor) -> th.Tensor:
        """Intrinsic reward: standard deviation across members, averaged over the predicted dimensions."""
        return self(feat, action).std(0).mean(-1)
