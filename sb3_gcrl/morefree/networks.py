"""Networks of the model-based MoReFree agent (thesis Ch. 3, Sec. 3.3.2): a compact DreamerV2-style world model.

* :class:`RSSM`: recurrent state-space model (DreamerV2): a GRU deterministic state ``h`` and a categorical
  stochastic state ``z`` (``stoch`` groups of ``classes`` one-hot values, straight-through gradients), prior
  ``p(z_t | h_t)`` and posterior ``q(z_t | h_t, e_t)``, KL balancing.
* :class:`WorldModel`: MLP encoder and decoder of the state observation (``observation`` and ``achieved_goal``
  concatenated, symlog-squashed) around the RSSM. There is no reward head: MoReFree never learns from the env's
  reward (Table 3.1); its reward is the learned dynamical distance.
* :class:`DynamicalDistance`: predicts the number of steps (divided by the imagination horizon) between a latent
  state and a goal (LEXA / PEG's temporal-distance reward, Hartikainen et al. 2019).
* :class:`DisagreementEnsemble`: Plan2Explore's ensemble of one-step predictors of the next observation
  embedding; the variance across members is pi_E's intrinsic reward (Sekar et al., 2020).
* :class:`Actor` (tanh-Gaussian) and :class:`Critic` (scalar value), optionally goal-conditioned.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import NamedTuple

import torch as th
import torch.nn.functional as F
from torch import nn
from torch.distributions import Normal


def symlog(x: th.Tensor) -> th.Tensor:
    """sign(x) log(1 + |x|): squashes state vectors of any scale to a range an MLP handles (DreamerV3)."""
    return th.sign(x) * th.log1p(th.abs(x))


def symexp(x: th.Tensor) -> th.Tensor:
    """Inverse of :func:`symlog`."""
    return th.sign(x) * th.expm1(th.abs(x))


def mlp(in_dim: int, out_dim: int, hidden: int, layers: int, activation: type[nn.Module] = nn.ELU) -> nn.Sequential:
    """An MLP with ``layers`` hidden layers of ``hidden`` units, LayerNorm and ``activation`` (DreamerV2 style).

    :param in_dim: input size.
    :param out_dim: output size.
    :param hidden: hidden units per layer.
    :param layers: number of hidden layers (0: one linear layer).
    :param activation: activation class.
    :return: the network.
    """
    modules: list[nn.Module] = []
    size = in_dim
    for _ in range(layers):
        modules += [nn.Linear(size, hidden), nn.LayerNorm(hidden), activation()]
        size = hidden
    modules.append(nn.Linear(size, out_dim))
    return nn.Sequential(*modules)


@contextmanager
def frozen(*modules: nn.Module) -> Iterator[None]:
    """Let gradients flow *through* ``modules`` without accumulating in their parameters (imagination)."""
    params = [p for m in modules for p in m.parameters() if p.requires_grad]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in params:
            p.requires_grad_(True)


class LatentState(NamedTuple):
    """An RSSM state: deterministic ``deter`` (..., D), one-hot ``stoch`` (..., S*C), ``logits`` (..., S, C)."""

    deter: th.Tensor
    stoch: th.Tensor
    logits: th.Tensor

    @property
    def feat(self) -> th.Tensor:
        """Features the heads read: ``[deter, stoch]``."""
        return th.cat([self.deter, self.stoch], -1)

    def detach(self) -> LatentState:
        return LatentState(self.deter.detach(), self.stoch.detach(), self.logits.detach())

    def flatten(self) -> LatentState:
        """Merge all leading dimensions into one batch dimension."""
        return LatentState(
            self.deter.reshape(-1, self.deter.shape[-1]),
            self.stoch.reshape(-1, self.stoch.shape[-1]),
            self.logits.reshape(-1, *self.logits.shape[-2:]),
        )


def stack_states(states: list[LatentState], dim: int = 0) -> LatentState:
    """Stack a list of states along a new dimension ``dim``."""
    return LatentState(*(th.stack([getattr(s, k) for s in states], dim) for k in LatentState._fields))


class RSSM(nn.Module):
    """DreamerV2 recurrent state-space model with categorical latents.

    :param action_dim: action size (actions in [-1, 1]).
    :param embed_dim: size of the observation embedding.
    :param deter: size of the GRU state h.
    :param stoch: number of categorical variables in z.
    :param classes: classes per categorical variable.
    :param hidden: hidden units of the input/prior/posterior layers.
    :param unimix: mixture with the uniform distribution in the categorical probabilities (keeps KL finite).
    """

    def __init__(
        self,
        action_dim: int,
        embed_dim: int,
        deter: int = 128,
        stoch: int = 16,
        classes: int = 16,
        hidden: int = 128,
        unimix: float = 0.01,
    ) -> None:
        super().__init__()
        self.deter_dim, self.stoch, self.classes, self.unimix = deter, stoch, classes, unimix
        self.stoch_dim = stoch * classes
        self.feat_dim = deter + self.stoch_dim
        self.img_in = nn.Sequential(nn.Linear(self.stoch_dim + action_dim, hidden), nn.LayerNorm(hidden), nn.ELU())
        self.gru = nn.GRUCell(hidden, deter)
        self.prior_net = mlp(deter, self.stoch_dim, hidden, 1)
        self.post_net = mlp(deter + embed_dim, self.stoch_dim, hidden, 1)

    def initial(self, batch: int, device: th.device) -> LatentState:
        """The all-zero state that starts every sequence (and follows every physical reset)."""
        zeros = th.zeros(batch, self.deter_dim, device=device)
        return LatentState(
            zeros,
            th.zeros(batch, self.stoch_dim, device=device),
            th.zeros(batch, self.stoch, self.classes, device=device),
        )

    def _logits(self, raw: th.Tensor) -> th.Tensor:
        logits = raw.reshape(*raw.shape[:-1], self.stoch, self.classes)
        if self.unimix > 0:
            probs = (1 - self.unimix) * F.softmax(logits, -1) + self.unimix / self.classes
            logits = th.log(probs)
        return logits

    def _sample(self, logits: th.Tensor, mode: bool = False) -> th.Tensor:
        # one-hot sample (or the mode) with straight-through gradients
        probs = F.softmax(logits, -1)
        if mode:
            index = probs.argmax(-1)
        else:  # Gumbel-max: a categorical sample, faster than multinomial on small batches
            noise = th.rand_like(logits).clamp_(min=1e-9)
            index = (logits.detach() - th.log(-th.log(noise))).argmax(-1)
        sample = F.one_hot(index, self.classes).to(probs.dtype)
        sample = sample + probs - probs.detach()
        return sample.reshape(*sample.shape[:-2], self.stoch_dim)

    def img_step(self, state: LatentState, action: th.Tensor) -> LatentState:
        """Prior step: h_t = GRU(h_{t-1}, z_{t-1}, a_{t-1}), z_t ~ p(z_t | h_t)."""
        deter = self.step_deter(state, action)
        logits = self._logits(self.prior_net(deter))
        return LatentState(deter, self._sample(logits), logits)

    def obs_step(
        self, state: LatentState, action: th.Tensor, embed: th.Tensor, mode: bool = False
    ) -> tuple[LatentState, LatentState]:
        """Posterior step: the prior step, then z_t ~ q(z_t | h_t, e_t) (the mode if ``mode``); (post, prior)."""
        prior = self.img_step(state, action)
        return self.posterior(prior.deter, embed, mode), prior

    def posterior(self, deter: th.Tensor, embed: th.Tensor, mode: bool = False) -> LatentState:
        """z ~ q(z | h, e) for a deterministic state ``deter`` already stepped (no prior computed)."""
        logits = self._logits(self.post_net(th.cat([deter, embed], -1)))
        return LatentState(deter, self._sample(logits, mode), logits)

    def step_deter(self, state: LatentState, action: th.Tensor) -> th.Tensor:
        """h_t = GRU(h_{t-1}, z_{t-1}, a_{t-1}) only (filtering needs no prior sample)."""
        return self.gru(self.img_in(th.cat([state.stoch, action], -1)), state.deter)

    def observe(
        self, embed: th.Tensor, actions: th.Tensor, is_first: th.Tensor, state: LatentState | None = None
    ) -> tuple[LatentState, LatentState]:
        """Filter a batch of sequences (time-major ``(T, B, ...)``); state and previous action are zeroed where
        ``is_first``. ``actions[t]`` is the action taken *before* observation ``t``.

        :return: (posteriors, priors), each with tensors of shape ``(T, B, ...)``.
        """
        steps, batch = embed.shape[:2]
        state = self.initial(batch, embed.device) if state is None else state
        posts, priors = [], []
        for t in range(steps):
            keep = (~is_first[t]).to(embed.dtype).unsqueeze(-1)
            state = LatentState(state.deter * keep, state.stoch * keep, state.logits)
            state, prior = self.obs_step(state, actions[t] * keep, embed[t])
            posts.append(state)
            priors.append(prior)
        return stack_states(posts), stack_states(priors)

    def kl_loss(self, post: LatentState, prior: LatentState, balance: float, free_nats: float) -> th.Tensor:
        """DreamerV2 KL balancing: ``balance * KL(sg(q) || p) + (1 - balance) * KL(q || sg(p))``, free nats."""

        def kl(lhs: th.Tensor, rhs: th.Tensor) -> th.Tensor:
            return (F.softmax(lhs, -1) * (F.log_softmax(lhs, -1) - F.log_softmax(rhs, -1))).sum((-2, -1))

        rep = kl(post.logits.detach(), prior.logits).clamp(min=free_nats).mean()
        dyn = kl(post.logits, prior.logits.detach()).clamp(min=free_nats).mean()
        return balance * rep + (1 - balance) * dyn


class WorldModel(nn.Module):
    """Encoder, RSSM and decoder over state observations (``observation`` + ``achieved_goal``, symlog-squashed).

    :param obs_dim: size of the flat state vector (observation followed by achieved goal).
    :param goal_dim: size of the goal (the last ``goal_dim`` values of the state vector).
    :param action_dim: action size.
    :param hidden: hidden units of encoder/decoder.
    :param layers: hidden layers of encoder/decoder.
    :param embed_dim: embedding size.
    :param deter: GRU state size.
    :param stoch: categorical variables.
    :param classes: classes per variable.
    :param kl_balance: DreamerV2's KL balancing weight (0.8).
    :param free_nats: DreamerV2's free nats (1.0).
    :param kl_scale: weight of the KL term.
    """

    def __init__(
        self,
        obs_dim: int,
        goal_dim: int,
        action_dim: int,
        hidden: int = 128,
        layers: int = 2,
        embed_dim: int = 128,
        deter: int = 128,
        stoch: int = 16,
        classes: int = 16,
        kl_balance: float = 0.8,
        free_nats: float = 1.0,
        kl_scale: float = 1.0,
    ) -> None:
        super().__init__()
        self.obs_dim, self.goal_dim = obs_dim, goal_dim
        self.kl_balance, self.free_nats, self.kl_scale = kl_balance, free_nats, kl_scale
        self.encoder = mlp(obs_dim, embed_dim, hidden, layers)
        self.rssm = RSSM(action_dim, embed_dim, deter, stoch, classes, hidden)
        self.decoder = mlp(self.rssm.feat_dim, obs_dim, hidden, layers)

    @property
    def feat_dim(self) -> int:
        return self.rssm.feat_dim

    def embed(self, states: th.Tensor) -> th.Tensor:
        """Embedding of raw state vectors (symlog applied here)."""
        return self.encoder(symlog(states))

    def decode_goal(self, feat: th.Tensor) -> th.Tensor:
        """The achieved goal of a latent state, in symlog space (what goals are compared in)."""
        return self.decoder(feat)[..., self.obs_dim - self.goal_dim :]

    def loss(
        self, states: th.Tensor, actions: th.Tensor, is_first: th.Tensor
    ) -> tuple[th.Tensor, LatentState, th.Tensor, dict[str, float]]:
        """World-model loss on time-major sequences; returns (loss, posteriors, embeddings, metrics)."""
        embed = self.embed(states)
        post, prior = self.rssm.observe(embed, actions, is_first)
        recon = self.decoder(post.feat)
        recon_loss = (recon - symlog(states)).pow(2).sum(-1).mean()
        kl = self.rssm.kl_loss(post, prior, self.kl_balance, self.free_nats)
        loss = recon_loss + self.kl_scale * kl
        return loss, post, embed, {"recon_loss": recon_loss.item(), "kl": kl.item()}


class Actor(nn.Module):
    """Gaussian policy with a tanh-bounded mean, samples clipped to [-1, 1] (DreamerV2's truncated normal).

    The clip passes gradients straight through, so a saturated mean still gets gradients (a tanh-squashed sample
    would not); the entropy bonus is the Gaussian's.

    :param feat_dim: latent feature size.
    :param goal_dim: goal size (0 for pi_E).
    :param action_dim: action size.
    :param hidden: hidden units.
    :param layers: hidden layers.
    :param min_std: lower bound of the Gaussian's std (DreamerV2: 0.1).
    """

    def __init__(
        self, feat_dim: int, goal_dim: int, action_dim: int, hidden: int, layers: int, min_std: float = 0.1
    ) -> None:
        super().__init__()
        self.net = mlp(feat_dim + goal_dim, 2 * action_dim, hidden, layers)
        self.min_std = min_std

    def forward(self, feat: th.Tensor, goal: th.Tensor | None = None) -> Normal:
        x = feat if goal is None else th.cat([feat, goal], -1)
        mean, std = self.net(x).chunk(2, -1)
        std = 2 * th.sigmoid(std / 2) + self.min_std
        return Normal(th.tanh(mean), std)

    def act(
        self, feat: th.Tensor, goal: th.Tensor | None = None, deterministic: bool = False
    ) -> tuple[th.Tensor, th.Tensor]:
        """Action in [-1, 1] (reparameterised, straight-through clip) and the Gaussian's entropy."""
        dist = self(feat, goal)
        if deterministic:
            return dist.mean, dist.entropy().sum(-1)
        raw = dist.rsample()
        action = raw + (raw.clamp(-1.0, 1.0) - raw).detach()
        return action, dist.entropy().sum(-1)


class Critic(nn.Module):
    """Scalar value of latent features (and a goal for V_G)."""

    def __init__(self, feat_dim: int, goal_dim: int, hidden: int, layers: int) -> None:
        super().__init__()
        self.net = mlp(feat_dim + goal_dim, 1, hidden, layers)

    def forward(self, feat: th.Tensor, goal: th.Tensor | None = None) -> th.Tensor:
        x = feat if goal is None else th.cat([feat, goal], -1)
        return self.net(x).squeeze(-1)


class DynamicalDistance(nn.Module):
    """Predicted steps between a latent state and a goal, divided by the horizon (LEXA's temporal distance).

    The output is squashed to [0, 1], the range of the targets, so that pi_G cannot exploit extrapolated negative
    distances far from the trained pairs.

    :param feat_dim: latent feature size.
    :param goal_dim: goal size.
    :param hidden: hidden units.
    :param layers: hidden layers.
    """

    def __init__(self, feat_dim: int, goal_dim: int, hidden: int, layers: int) -> None:
        super().__init__()
        self.net = mlp(feat_dim + goal_dim, 1, hidden, layers)

    def forward(self, feat: th.Tensor, goal: th.Tensor) -> th.Tensor:
        return th.sigmoid(self.net(th.cat([feat, goal], -1)).squeeze(-1))

    def loss(
        self,
        feats: th.Tensor,
        goals: th.Tensor,
        n_pairs: int,
        neg_fraction: float,
        generator: th.Generator | None,
        horizon: int | None = None,
        is_first: th.Tensor | None = None,
    ) -> th.Tensor:
        """Regression on state pairs of trajectories ``feats (T, N, F)`` with achieved goals ``goals (T, N, G)``.

        A pair (i, j), i <= j, of one trajectory has the target ``min((j - i) / horizon, 1)``; a fraction
        ``neg_fraction`` of the pairs takes the goal from another trajectory, with the largest target 1 (LEXA's
        negatives). Pairs whose goal lies after a physical reset of the state's trajectory (``is_first`` at some
        step in ``(i, j]``) are not used: no number of steps links them.

        :param feats: latent features along the trajectories (detached by the caller).
        :param goals: achieved goals along the same trajectories (detached).
        :param n_pairs: pairs sampled.
        :param neg_fraction: share of negative pairs.
        :param generator: torch generator for the pair indices.
        :param horizon: steps that make distance 1 (``None``: ``T - 1``); one horizon for every source of pairs
            keeps the distance in one unit.
        :param is_first: ``(T, N)`` stream starts of replayed sequences (``None``: none, e.g. imagined ones).
        :return: mean squared error over the usable pairs.
        """
        steps, n_traj = feats.shape[:2]
        device = feats.device
        horizon = max(steps - 1, 1) if horizon is None else horizon
        i = th.randint(0, steps, (n_pairs,), device=device, generator=generator)
        offset = th.rand(n_pairs, device=device, generator=generator)
        j = i + (offset * (steps - i).to(offset.dtype)).long().clamp(max=steps - 1 - i)
        traj = th.randint(0, n_traj, (n_pairs,), device=device, generator=generator)
        goal_traj = traj.clone()
        target = ((j - i).to(feats.dtype) / horizon).clamp(max=1.0)
        weight = th.ones_like(target)
        if is_first is not None:
            # starts[t, n]: stream starts in steps 0..t; a start in (i, j] separates the two states
            starts = is_first.to(th.long).cumsum(0)
            weight = (starts[j, traj] == starts[i, traj]).to(feats.dtype)
        n_neg = int(round(neg_fraction * n_pairs))
        if n_neg > 0 and n_traj > 1:
            shift = th.randint(1, n_traj, (n_neg,), device=device, generator=generator)
            goal_traj[:n_neg] = (traj[:n_neg] + shift) % n_traj
            target[:n_neg] = 1.0
            weight[:n_neg] = 1.0
        prediction = self(feats[i, traj], goals[j, goal_traj])
        return (weight * (prediction - target).pow(2)).sum() / weight.sum().clamp(min=1.0)


class DisagreementEnsemble(nn.Module):
    """Plan2Explore: ``size`` MLPs predict the next observation embedding from (features, action).

    :param feat_dim: latent feature size.
    :param action_dim: action size.
    :param target_dim: size of the predicted embedding.
    :param size: members.
    :param hidden: hidden units.
    :param layers: hidden layers.
    """

    def __init__(self, feat_dim: int, action_dim: int, target_dim: int, size: int, hidden: int, layers: int) -> None:
        super().__init__()
        self.members = nn.ModuleList(mlp(feat_dim + action_dim, target_dim, hidden, layers) for _ in range(size))

    def forward(self, feat: th.Tensor, action: th.Tensor) -> th.Tensor:
        x = th.cat([feat, action], -1)
        return th.stack([m(x) for m in self.members])

    def loss(self, feat: th.Tensor, action: th.Tensor, target: th.Tensor) -> th.Tensor:
        """Mean squared error of every member (inputs and target detached by the caller)."""
        return (self(feat, action) - target.unsqueeze(0)).pow(2).sum(-1).mean()

    def disagreement(self, feat: th.Tensor, action: th.Tensor) -> th.Tensor:
        """Intrinsic reward: variance across members, averaged over the embedding dimensions."""
        predictions = self(feat, action)
        return (predictions - predictions.mean(0)).pow(2).sum(0).mean(-1) / max(len(self.members) - 1, 1)


def lambda_returns(rewards: th.Tensor, values: th.Tensor, gamma: float, lam: float) -> th.Tensor:
    """TD(lambda) returns of imagined trajectories (DreamerV2 Eq. 4), no terminals (reset-free tasks).

    :param rewards: ``(H, N)``, reward of step t (for the transition out of state t).
    :param values: ``(H + 1, N)``, values of states 0..H (the last one bootstraps).
    :param gamma: discount.
    :param lam: lambda.
    :return: ``(H, N)`` returns.
    """
    out = []
    last = values[-1]
    for t in reversed(range(rewards.shape[0])):
        last = rewards[t] + gamma * ((1 - lam) * values[t + 1] + lam * last)
        out.append(last)
    return th.stack(out[::-1])
