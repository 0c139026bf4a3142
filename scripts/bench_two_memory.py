"""Training speed of TwoMemoryDQN vs SB3 DQN on MinAtar (same network, same training schedule).

Both agents are built by RL-Zoo from the shipped zoo configs, exactly as ``sb3-gcrl train`` builds them:
``zoo_configs/dqn.yml`` (DQN with the authors' MinAtar network) and ``zoo_configs/two_memory_dqn.yml``
(2M; also run with ``p_ec_schedule = 1``, i.e. every episode acted by MFEC). Runs are interleaved in one process
(``--repeats`` rounds of: DQN, 2M, 2M with p_ec = 1) and each is timed over ``--steps`` training env steps after
its own warm-up; medians and the 2M/DQN ratio are printed. ``torch.set_num_threads(1)``.

  nice -n 10 python scripts/bench_two_memory.py --steps 20000 --repeats 3
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from sb3_gcrl.cli import ZOO_CONFIGS_DIR
from sb3_gcrl.compare.run import prepare_process

#: kind -> (algorithm, zoo config, hyperparameter overrides of the benchmark variant)
KINDS: dict[str, tuple[str, str, dict[str, Any]]] = {
    "dqn": ("dqn", "dqn.yml", {}),
    "2m": ("two_memory_dqn", "two_memory_dqn.yml", {}),
    "2m_pec1": ("two_memory_dqn", "two_memory_dqn.yml", {"p_ec_schedule": 1.0}),  # MFEC acts in every episode
}


def make(kind: str, seed: int, game: str, log_folder: Path) -> Any:
    """The model ``sb3-gcrl train --algo ALGO --env MinAtar/GAME-v1 -conf CONFIG --seed SEED`` would train.

    :param kind: key of :data:`KINDS`.
    :param seed: model and env seed.
    :param game: MinAtar game name (``Breakout``...).
    :param log_folder: RL-Zoo's log folder (it writes the run's config there).
    :return: the model.
    """
    from rl_zoo3.exp_manager import ExperimentManager

    prepare_process(single_thread=False)  # our algorithms registered with RL-Zoo (the caller sets the threads)
    algo, config, overrides = KINDS[kind]
    env_id = f"MinAtar/{game}-v1"
    manager = ExperimentManager(
        argparse.Namespace(algo=algo, env=env_id, conf_file=str(ZOO_CONFIGS_DIR / config), seed=seed),
        algo,
        env_id,
        str(log_folder),
        hyperparams=dict(overrides),
        seed=seed,
        verbose=0,
        log_interval=-1,
        config=str(ZOO_CONFIGS_DIR / config),
        device="cpu",
    )
    with contextlib.redirect_stdout(io.StringIO()):  # RL-Zoo prints the hyperparameters and paths
        setup = manager.setup_experiment()
    assert setup is not None  # None only in hyperparameter-optimisation mode
    return setup[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--game", default="Breakout")
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--warmup", type=int, default=2_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    prepare_process()  # one torch thread, our algorithms registered with RL-Zoo
    th.set_num_threads(1)
    rates: dict[str, list[float]] = {kind: [] for kind in KINDS}
    with tempfile.TemporaryDirectory(prefix="bench_two_memory_") as log_folder:
        for repeat in range(args.repeats):
            for kind in KINDS:
                model = make(kind, seed=repeat, game=args.game, log_folder=Path(log_folder))
                model.learn(args.warmup)
                start = time.perf_counter()
                model.learn(args.steps, reset_num_timesteps=False)
                rate = args.steps / (time.perf_counter() - start)
                rates[kind].append(rate)
                extra = ""
                if kind != "dqn":
                    extra = f", MFEC rows {len(model.policy.mfec)}, EC episodes {model.policy.episode_counts[0]}"
                    extra += f" of {model.policy.episode_counts.sum()}"
                print(f"repeat {repeat} {kind:8s} {rate:7.0f} env steps/s{extra}", flush=True)
    medians = {kind: float(np.median(values)) for kind, values in rates.items()}
    print(f"\n{args.game}, {args.steps} training steps after {args.warmup} warm-up, {args.repeats} repeats (median):")
    for kind in KINDS:
        print(f"  {kind:8s} {medians[kind]:7.0f} env steps/s   ratio to DQN {medians[kind] / medians['dqn']:.2f}")


if __name__ == "__main__":
    main()
