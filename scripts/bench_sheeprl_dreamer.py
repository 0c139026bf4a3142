"""Speed reference: the train step of sheeprl's DreamerV3 (sheeprl 0.8.4) on one CPU thread, vector observations.

What it measures
----------------
The gradient steps per second of ``sheeprl.algos.dreamer_v3.dreamer_v3.train``, sheeprl's own DreamerV3 training step,
called exactly as sheeprl's ``main`` calls it, on random data of the right shapes (the content does not matter for
timing). The modules, the optimizers and the return normaliser (``Moments``) are built by sheeprl's own code
(``build_agent``, the optimizers instantiated from its hydra config, ``Moments``), from sheeprl's own hydra config
(``exp=dreamer_v3``, i.e. the ``dreamer_v3_S`` preset) with the sizes given on the command line as overrides:

* ``--deter``: ``algo.world_model.recurrent_model.recurrent_state_size`` (the GRU state);
* ``--stoch``/``--classes``: ``algo.world_model.stochastic_size``/``discrete_size`` (stoch x classes one-hots);
* ``--hidden``: ``algo.dense_units`` (encoder, decoder, reward, continue, actor, critic and the GRU's input layer) and
  the hidden sizes of the RSSM's prior and posterior MLPs;
* ``--layers``: ``algo.mlp_layers`` (encoder, decoder, reward, continue, actor and critic);
* ``--batch``/``--length``: ``algo.per_rank_batch_size``/``per_rank_sequence_length``;
* ``--horizon``: ``algo.horizon``.

One observation key (``state``, ``--obs-dim`` floats) is encoded and decoded by MLPs (no images), the actions are
continuous (``--action-dim``). As in sheeprl (and DreamerV3), every posterior state of the batch (batch x length of
them) starts an imagined trajectory of ``--horizon`` steps.

One timed step is what sheeprl's main loop does per gradient step: the EMA update of the target critic
(``per_rank_target_network_update_freq=1``, ``tau=0.02``, the same three lines as sheeprl's ``main``) and ``train``,
which does one world-model update (encoder, RSSM unroll over the sequence, decoder, reward and continue heads, KL
balancing, one Adam step with gradient clipping), then one imagination of ``horizon`` steps from all the posteriors
(with gradients, for the dynamics backpropagation of continuous actions), the lambda-returns, the return normalisation
by percentiles (``Moments``, 5%-95%, EMA 0.99), one actor update and one critic update (two-hot symlog critic,
regularised towards the target critic): three Adam steps per train step. The sampling from the replay buffer is not
timed (the batches are made beforehand). The metrics aggregation of a logged sheeprl run (``metric.log_level=1``) is
off by default (``MetricAggregator.disabled``, which also skips the posterior/prior entropy metrics); ``--with-metrics``
turns it on.

Settings: ``torch.set_num_threads(1)`` (as sheeprl's ``num_threads: 1``) and one inter-op thread,
``float32_matmul_precision("high")`` and distributions without argument validation, as sheeprl's command line sets
them. The two settings a sheeprl user can turn on for speed are options here:

* ``--precision``: ``fabric.precision``, ``32-true`` (sheeprl's default) or ``bf16-mixed`` (Lightning's bfloat16
  autocast);
* ``--compile``: ``algo.compile.enabled=True``, sheeprl's ``torch.compile`` of its losses (the world-model loss, the
  imagination, the actor and critic losses; ``sheeprl.utils.compile.compiled``) in its configured mode
  (``algo.compile.mode=reduce-overhead``: CUDA graphs, which on a CPU compile as the default mode). Off by default,
  as in sheeprl: the step then runs eagerly. The first warm-up step compiles.

Adam keeps sheeprl's ``fused: True`` (supported on CPU by recent PyTorch).

Venv (separate from the project's: it must not import sb3_gcrl), the commands that worked::

    python -m venv /work/venv-sheeprl
    /work/venv-sheeprl/bin/pip install torch==2.13.0     # first: the CPU wheel (2.13.0+cpu)
    /work/venv-sheeprl/bin/pip install sheeprl==0.8.4    # its pin is torch>=2.6: torch is kept as is

Run::

    /work/venv-sheeprl/bin/python scripts/bench_sheeprl_dreamer.py --deter 64 --stoch 16 --classes 1 \\
        --hidden 128 --layers 2 --batch 16 --length 32

It prints ``SHEEPRL_TRAIN_STEPS_PER_S <median over the repeats>``, the figure of every repeat and the sizes used
(and, on stderr, the time of every warm-up step).

Caveat: at large sizes glibc's malloc hands the big activation buffers back to the kernel and faults them in again at
every step (the DreamerV3-S-like run, deter 200, 32x32 latents, hidden 400, 3 layers, batch 45 x 50, spent ~45% of its
time in the kernel); ``MALLOC_MMAP_MAX_=0 MALLOC_TRIM_THRESHOLD_=68719476736`` in the environment avoids it (there 1.7x
faster). Compare agents under the same allocator settings.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
import warnings

import gymnasium as gym
import hydra
import numpy as np
import sheeprl
import torch
from hydra import compose, initialize_config_module
from lightning import Fabric
from omegaconf import OmegaConf
from sheeprl.algos.dreamer_v3.agent import build_agent
from sheeprl.algos.dreamer_v3.dreamer_v3 import train
from sheeprl.algos.dreamer_v3.utils import Moments
from sheeprl.utils.metric import MetricAggregator
from sheeprl.utils.timer import timer
from sheeprl.utils.utils import dotdict
from torch.distributions import Distribution

OBS_KEY = "state"


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--obs-dim", type=int, default=6)
    parser.add_argument("--action-dim", type=int, default=2)
    parser.add_argument("--deter", type=int, default=512, help="recurrent state size")
    parser.add_argument("--stoch", type=int, default=32, help="number of categorical latents")
    parser.add_argument("--classes", type=int, default=32, help="classes of every categorical latent")
    parser.add_argument("--hidden", type=int, default=512, help="MLP units")
    parser.add_argument("--layers", type=int, default=2, help="MLP layers")
    parser.add_argument("--batch", type=int, default=16, help="sequences per batch")
    parser.add_argument("--length", type=int, default=64, help="steps per sequence")
    parser.add_argument("--horizon", type=int, default=15, help="imagination horizon")
    parser.add_argument("--steps", type=int, default=10, help="timed train steps per repeat")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--warmup", type=int, default=2, help="untimed train steps first")
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument(
        "--precision", default="32-true", choices=["32-true", "bf16-mixed"], help="fabric.precision (sheeprl's setting)"
    )
    parser.add_argument("--compile", action="store_true", help="algo.compile.enabled=True (sheeprl's torch.compile)")
    parser.add_argument(
        "--with-metrics", action="store_true", help="aggregate sheeprl's training metrics, as a logged run does"
    )
    return parser.parse_args()


def compose_config(args: argparse.Namespace) -> dotdict:
    """sheeprl's own hydra config of DreamerV3 (``exp=dreamer_v3``) with the sizes of ``args``, resolved as sheeprl's
    command line resolves it."""
    overrides = [
        "exp=dreamer_v3",
        "env=dummy",
        "env.num_envs=1",
        "algo.cnn_keys.encoder=[]",
        "algo.cnn_keys.decoder=[]",
        f"algo.mlp_keys.encoder=[{OBS_KEY}]",
        f"algo.mlp_keys.decoder=[{OBS_KEY}]",
        "algo.total_steps=1",
        f"algo.compile.enabled={args.compile}",
        f"algo.per_rank_batch_size={args.batch}",
        f"algo.per_rank_sequence_length={args.length}",
        f"algo.horizon={args.horizon}",
        f"algo.dense_units={args.hidden}",
        f"algo.mlp_layers={args.layers}",
        f"algo.world_model.recurrent_model.recurrent_state_size={args.deter}",
        f"algo.world_model.transition_model.hidden_size={args.hidden}",
        f"algo.world_model.representation_model.hidden_size={args.hidden}",
        f"algo.world_model.stochastic_size={args.stoch}",
        f"algo.world_model.discrete_size={args.classes}",
        "fabric.accelerator=cpu",
        "fabric.devices=1",
        "fabric.strategy=auto",
        f"fabric.precision={args.precision}",
        f"metric.log_level={1 if args.with_metrics else 0}",
        "model_manager.disabled=True",
        f"seed={args.seed}",
        "num_threads=1",
        f"log_root={tempfile.gettempdir()}/bench_sheeprl_dreamer",
    ]
    with initialize_config_module(config_module="sheeprl.configs", version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    return dotdict(OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True))


def random_batch(
    generator: torch.Generator, length: int, batch: int, obs_dim: int, action_dim: int
) -> dict[str, torch.Tensor]:
    """A batch as sheeprl's ``sample_batches`` gives it: float tensors of shape [length, batch, ...]."""
    shape = (length, batch, 1)
    return {
        OBS_KEY: torch.randn(length, batch, obs_dim, generator=generator),
        "actions": torch.rand(length, batch, action_dim, generator=generator) * 2 - 1,
        "rewards": torch.randn(shape, generator=generator),
        "terminated": (torch.rand(shape, generator=generator) < 0.01).float(),
        "truncated": torch.zeros(shape),
        "is_first": torch.zeros(shape),
    }


def main() -> None:
    args = parse_args()
    torch.set_num_threads(1)
    torch.set_num_interop_threads(1)
    warnings.filterwarnings("ignore")
    cfg = compose_config(args)

    # What sheeprl's `run_algorithm` sets before launching the algorithm
    torch.set_float32_matmul_precision(cfg.float32_matmul_precision)
    Distribution.set_default_validate_args(cfg.distribution.validate_args)
    timer.disabled = True
    MetricAggregator.disabled = cfg.metric.log_level == 0
    fabric = Fabric(accelerator="cpu", devices=1, precision=cfg.fabric.precision)
    fabric.seed_everything(cfg.seed, verbose=False)

    observation_space = gym.spaces.Dict({OBS_KEY: gym.spaces.Box(-np.inf, np.inf, (args.obs_dim,), np.float32)})
    actions_dim = (args.action_dim,)
    is_continuous = True
    world_model, actor, critic, target_critic, _player = build_agent(
        fabric, actions_dim, is_continuous, cfg, observation_space
    )
    # The optimizers and the return normaliser, as sheeprl's `main` builds them
    world_optimizer = hydra.utils.instantiate(
        cfg.algo.world_model.optimizer, params=world_model.parameters(), _convert_="all"
    )
    actor_optimizer = hydra.utils.instantiate(cfg.algo.actor.optimizer, params=actor.parameters(), _convert_="all")
    critic_optimizer = hydra.utils.instantiate(cfg.algo.critic.optimizer, params=critic.parameters(), _convert_="all")
    world_optimizer, actor_optimizer, critic_optimizer = fabric.setup_optimizers(
        world_optimizer, actor_optimizer, critic_optimizer
    )
    moments = Moments(
        cfg.algo.actor.moments.decay,
        cfg.algo.actor.moments.max,
        cfg.algo.actor.moments.percentile.low,
        cfg.algo.actor.moments.percentile.high,
    )
    aggregator = None
    if not MetricAggregator.disabled:
        aggregator = hydra.utils.instantiate(cfg.metric.aggregator, _convert_="all").to(fabric.device)

    generator = torch.Generator().manual_seed(args.seed)
    batches = [random_batch(generator, args.length, args.batch, args.obs_dim, args.action_dim) for _ in range(4)]
    gradient_steps = 0

    def step() -> None:
        nonlocal gradient_steps
        # The target critic's update of sheeprl's main loop, before every gradient step
        if gradient_steps % cfg.algo.critic.per_rank_target_network_update_freq == 0:
            tau = 1 if gradient_steps == 0 else cfg.algo.critic.tau
            for cp, tcp in zip(critic.module.parameters(), target_critic.parameters()):
                tcp.data.copy_(tau * cp.data + (1 - tau) * tcp.data)
        # `train` sets `is_first` of the first step in place: a fresh copy, as a freshly sampled batch
        data = {k: v.clone() for k, v in batches[gradient_steps % len(batches)].items()}
        train(
            fabric,
            world_model,
            actor,
            critic,
            target_critic,
            world_optimizer,
            actor_optimizer,
            critic_optimizer,
            data,
            aggregator,
            cfg,
            is_continuous,
            actions_dim,
            moments,
        )
        gradient_steps += 1

    for i in range(args.warmup):
        start = time.perf_counter()
        step()
        print(f"warmup step {i + 1}/{args.warmup}: {time.perf_counter() - start:.3f} s", file=sys.stderr, flush=True)
    rates = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        for _ in range(args.steps):
            step()
        rates.append(args.steps / (time.perf_counter() - start))
        print(f"repeat {len(rates)}/{args.repeats}: {rates[-1]:.4f} steps/s", file=sys.stderr, flush=True)

    n_params = {
        "world_model": sum(p.numel() for p in world_model.parameters()),
        "actor": sum(p.numel() for p in actor.parameters()),
        "critic": sum(p.numel() for p in critic.parameters()),
    }
    sizes = {
        "obs_dim": args.obs_dim,
        "action_dim": args.action_dim,
        "deter": args.deter,
        "stoch": args.stoch,
        "classes": args.classes,
        "hidden": args.hidden,
        "layers": args.layers,
        "batch": args.batch,
        "length": args.length,
        "horizon": args.horizon,
        "steps": args.steps,
        "repeats": args.repeats,
        "warmup": args.warmup,
        "with_metrics": args.with_metrics,
        "precision": args.precision,
        "compile": args.compile,
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "sheeprl": sheeprl.__version__,
    }
    print("sizes " + json.dumps(sizes))
    print("params " + json.dumps(n_params))
    print("per_repeat_steps_per_s " + " ".join(f"{r:.4f}" for r in rates))
    print(f"SHEEPRL_TRAIN_STEPS_PER_S {statistics.median(rates):.4f}")


if __name__ == "__main__":
    main()
