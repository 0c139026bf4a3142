"""Stateless tensor functions of the model-based MoReFree agent: the symlog transform, MLPs, frozen modules, the
Gaussian std of DreamerV2, PEG's grid of distance pairs and the lambda-returns of imagined trajectories.

The networks (:mod:`~sb3_gcrl.morefree.networks`) are built from them; the losses
(:mod:`~sb3_gcrl.morefree.losses`) and the PEG planner (:mod:`~sb3_gcrl.morefree.peg`) compute with them.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager

import torch as th
from torch import nn


def symlog(x: th.Tensor) -> th.Tensor:
    """sign(x) log(1 + |x|): squashes state vectors of any scale to a range an MLP handles (DreamerV3)."""
    return th.sign(x) * th.log1p(th.abs(x))


def symexp(x: th.Tensor) -> th.Tensor:
    """sign(x) (exp(|x|) - 1), the inverse of :func:`symlog`: decoded goals back in the env's units."""
    return th.sign(x) * th.expm1(th.abs(x))


def mlp(in_dim: int, out_dim: int, hidden: int, layers: int) -> nn.Sequential:
    """An ELU MLP with ``layers`` hidden layers of ``hidden`` units and a linear output (DreamerV2 / PEG, no norm).

    :param in_dim: input size.
    :param out_dim: output size.
    :param hidden: hidden units per layer.
    :param layers: number of hidden layers (0: one linear layer).
    :return: the network.
    """
    modules: list[nn.Module] = []
    size = in_dim
    for _ in range(layers):
        modules += [nn.Linear(size, hidden), nn.ELU()]
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


_LOG_SQRT_2PI_E = 0.5 * math.log(2 * math.pi * math.e)


def truncated_normal_entropy(scale: th.Tensor, z: th.Tensor, alpha: th.Tensor, beta: th.Tensor) -> th.Tensor:
    """Entropy of a normal of std ``scale`` truncated to the standardised bounds ``alpha``, ``beta`` (normaliser
    ``z``), per dimension: ``log(sqrt(2 pi e) scale z) + (alpha phi(alpha) - beta phi(beta)) / (2 z)``."""

    def phi_times(x: th.Tensor) -> th.Tensor:
        # x * phi(x), 0 at the infinite bounds
        return x * th.exp(-0.5 * x.pow(2)) / math.sqrt(2 * math.pi)

    return _LOG_SQRT_2PI_E + scale.log() + z.log() + (phi_times(alpha) - phi_times(beta)) / (2 * z)


def gaussian_std(raw: th.Tensor, min_std: float) -> th.Tensor:
    """DreamerV2's ``sigmoid2`` standard deviation: ``2 sigmoid(raw / 2) + min_std``."""
    return 2 * th.sigmoid(raw / 2) + min_std


def goal_embedding(goal_dim: int, width: int) -> nn.Module | None:
    """The layer through which a goal enters an actor or critic: ``ELU(Linear(goal, width))`` (None for no goal).

    PEG's goals enter as 400-dimensional encoder embeddings, beside latent features of 250; a goal-space vector of
    2-3 values concatenated to the latent would start with a few percent of the first layer's input.
    """
    return None if goal_dim == 0 else nn.Sequential(nn.Linear(goal_dim, width), nn.ELU())


def future_pairs(steps: int, device: th.device | str) -> tuple[th.Tensor, th.Tensor]:
    """Every pair ``(i, j)``, ``i <= j < steps``, of a trajectory's steps (PEG's grid of distance pairs)."""
    i, j = th.triu_indices(steps, steps, device=device)
    return i, j


def lambda_returns(rewards: th.Tensor, values: th.Tensor, gamma: float, lam: float) -> th.Tensor:
    """TD(lambda) returns of imagined trajectories (DreamerV2 Eq. 4), no terminals (reset-free tasks).

    :param rewards: ``(H, N)``, reward of step t (for the transition out of state t).
    :param values: ``(H + 1, N)``, values of states 0..H (the last one bootstraps).
    :param gamma: discount.
    :param lam: lambda.
    :return: ``(H, N)`` returns.
    """
    inputs = rewards + gamma * (1 - lam) * values[1:]
    out = []
    last = values[-1]
    for t in reversed(range(rewards.shape[0])):
        last = inputs[t] + gamma * lam * last
        out.append(last)
    return th.stack(out[::-1])
