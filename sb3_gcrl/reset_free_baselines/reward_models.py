"""Rewards of the backward policies: MEDAL's discriminator and R3L's Random Network Distillation novelty.

Both are small ``nn.Module`` s with their own Adam optimizer (``.optimizer``), trained on states the backward policy
visited, and saved/loaded with the model (their state dicts, running statistics included, are listed in
:meth:`~sb3_gcrl.reset_free_baselines.BackwardRewardSAC._get_torch_save_params`).
"""

from __future__ import annotations

import numpy as np
import torch as th
import torch.nn.functional as F
from torch import nn


def mlp(in_dim: int, hidden: list[int], out_dim: int) -> nn.Sequential:
    """A ReLU MLP ``in_dim -> hidden... -> out_dim`` (linear output).

    :param in_dim: input size.
    :param hidden: hidden layer sizes.
    :param out_dim: output size.
    :return: the network.
    """
    layers: list[nn.Module] = []
    last = in_dim
    for size in hidden:
        layers += [nn.Linear(last, size), nn.ReLU()]
        last = size
    layers.append(nn.Linear(last, out_dim))
    return nn.Sequential(*layers)


class Discriminator(nn.Module):
    """MEDAL's state discriminator D(s): demonstration states (label 1) against backward-visited states (label 0).

    Official MEDAL defaults: one hidden layer of 128 ReLU units, Adam (lr 3e-4), binary cross-entropy on balanced
    batches (800 = 400 + 400) with mixup (Beta(1, 1)); the backward reward is ``-log(1 - sigmoid(D(s')) + 1e-10)``
    of the next state, which grows as s' looks like a demonstration state.

    :param state_dim: size of the state vector.
    :param hidden: hidden layer sizes.
    :param learning_rate: Adam learning rate.
    :param mixup: train on mixup interpolations of the batch (as the official code does by default).
    :param eps: the constant inside the log of the reward.
    """

    def __init__(
        self,
        state_dim: int,
        hidden: list[int] | None = None,
        learning_rate: float = 3e-4,
        mixup: bool = True,
        eps: float = 1e-10,
    ) -> None:
        super().__init__()
        self.net = mlp(state_dim, [128] if hidden is None else list(hidden), 1)
        self.mixup = mixup
        self.eps = eps
        self.optimizer = th.optim.Adam(self.net.parameters(), lr=learning_rate)

    def forward(self, states: th.Tensor) -> th.Tensor:
        """Logits of "is a demonstration state", shape ``(batch, 1)``."""
        return self.net(states)

    def reward(self, states: th.Tensor) -> th.Tensor:
        """MEDAL's backward reward ``-log(1 - D(s) + eps)``, shape ``(batch, 1)``.

        :param states: next states, shape ``(batch, state_dim)``.
        """
        with th.no_grad():
            return -th.log(1.0 - th.sigmoid(self(states)) + self.eps)

    def train_step(self, positives: th.Tensor, negatives: th.Tensor) -> float:
        """One gradient step of binary cross-entropy (with mixup when enabled).

        :param positives: demonstration states, ``(n_pos, state_dim)``.
        :param negatives: backward-visited states, ``(n_neg, state_dim)``.
        :return: the loss.
        """
        inputs = th.cat([positives, negatives])
        labels = th.cat([th.ones(len(positives), 1), th.zeros(len(negatives), 1)]).to(inputs.device)
        if self.mixup:
            coef = th.distributions.Beta(1.0, 1.0).sample((len(inputs), 1)).to(inputs.device)
            perm = th.randperm(len(inputs), device=inputs.device)
            inputs = coef * inputs + (1 - coef) * inputs[perm]
            labels = coef * labels + (1 - coef) * labels[perm]
        loss = F.binary_cross_entropy_with_logits(self(inputs), labels)
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        return float(loss.item())


class RunningMeanStd(nn.Module):
    """Running mean and variance of vectors (parallel-variance update), kept as module buffers (saved with it).

    :param shape: shape of one vector.
    :param epsilon: initial count (as the RND implementations use, 1e-4).
    """

    def __init__(self, shape: tuple[int, ...], epsilon: float = 1e-4) -> None:
        super().__init__()
        self.register_buffer("mean", th.zeros(shape, dtype=th.float64))
        self.register_buffer("var", th.ones(shape, dtype=th.float64))
        self.register_buffer("count", th.tensor(epsilon, dtype=th.float64))

    def update(self, batch: th.Tensor) -> None:
        """Add a batch ``(n, *shape)``."""
        batch = batch.detach().to(th.float64)
        mean, var, n = batch.mean(0), batch.var(0, unbiased=False), batch.shape[0]
        delta, total = mean - self.mean, self.count + n
        self.mean += delta * n / total
        self.var.copy_((self.var * self.count + var * n + delta**2 * self.count * n / total) / total)
        self.count.fill_(float(total))

    @property
    def std(self) -> th.Tensor:
        return th.sqrt(self.var + 1e-8)


class RND(nn.Module):
    """Random Network Distillation (Burda et al. 2018) novelty of states, as R3L's perturbation reward.

    A fixed, randomly initialised target network and a predictor trained (MSE) to match it on the backward policy's
    states; the novelty of a state is the predictor's error there, which falls as the state is visited again.
    Defaults follow DI-engine's ``RndRewardModel`` (the implementation the thesis used for R3L): MLP 64-64-128,
    Adam lr 1e-3, batch 64, states normalised by their running mean/std and clipped to [-1, 1], and the reward
    of a batch min-max normalised to [0, 1] (its ``assign`` mode: the backward reward *is* the novelty).

    :param state_dim: size of the state vector.
    :param hidden: hidden sizes and, last, the output feature size.
    :param learning_rate: Adam learning rate of the predictor.
    :param obs_clip: normalised states are clipped to ``[-obs_clip, obs_clip]``.
    """

    def __init__(
        self, state_dim: int, hidden: list[int] | None = None, learning_rate: float = 1e-3, obs_clip: float = 1.0
    ) -> None:
        super().__init__()
        sizes = [64, 64, 128] if hidden is None else list(hidden)
        if len(sizes) < 1:
            raise ValueError("RND needs at least the output feature size in hidden")
        self.target = mlp(state_dim, sizes[:-1], sizes[-1])
        self.predictor = mlp(state_dim, sizes[:-1], sizes[-1])
        for param in self.target.parameters():
            param.requires_grad_(False)
        self.obs_rms = RunningMeanStd((state_dim,))
        self.obs_clip = obs_clip
        self.optimizer = th.optim.Adam(self.predictor.parameters(), lr=learning_rate)

    def _normalise(self, states: th.Tensor) -> th.Tensor:
        mean, std = self.obs_rms.mean.float(), self.obs_rms.std.float()
        return th.clamp((states - mean) / std, -self.obs_clip, self.obs_clip)

    def novelty(self, states: th.Tensor) -> th.Tensor:
        """Prediction error per state (not normalised), shape ``(batch,)``."""
        with th.no_grad():
            x = self._normalise(states)
            return (self.predictor(x) - self.target(x)).pow(2).mean(dim=1)

    def reward(self, states: th.Tensor) -> th.Tensor:
        """The backward reward: novelty min-max normalised over the batch to [0, 1], shape ``(batch, 1)``."""
        error = self.novelty(states)
        return ((error - error.min()) / (error.max() - error.min() + 1e-11)).unsqueeze(1)

    def train_step(self, states: th.Tensor) -> float:
        """Update the state statistics with the batch, then one predictor step.

        :param states: backward-visited states, ``(batch, state_dim)``.
        :return: the prediction loss.
        """
        self.obs_rms.update(states)
        x = self._normalise(states)
        loss = F.mse_loss(self.predictor(x), self.target(x))
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        return float(loss.item())


def as_tensor(states: np.ndarray, device: th.device) -> th.Tensor:
    """float32 tensor of a state batch on ``device``."""
    return th.as_tensor(np.asarray(states, dtype=np.float32), device=device)
