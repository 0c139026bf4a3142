"""Speed of the episodic memories : query latency, update cost, end-to-end training steps/s.

Prints three tables (single thread: torch, faiss and BLAS pinned to one thread). Latencies are CPU
time of the measuring thread (``time.thread_time_ns``), throughputs are given per wall second and per
CPU second: on a machine shared with other jobs the CPU figures are the ones that do not depend on the
load; on an idle machine both agree.

1. CEC memory vs size (1e3 .. 1e6 rows) and key dimension (3, 8, 64): median latency of one
   action-selection query (``select_actions``, k=5) and the cost of one 1000-step episode update
   (``update_episode``), with Gaussian keys (the hardest case for a KD-tree) and 10% of the episode
   far enough from the table to be added.
2. MFEC action selection on MinAtar (Breakout: 3 actions, Seaquest: 6) with ``rows_per_action``
   rows per action and 8-dim projected keys: median microseconds per env step for ``policy.act``,
   for states seen before (exact hash hits, the common case in MinAtar) and unseen ones (kNN search
   in every action table).
   The tables are filled with the projected keys of real observations from random play plus
   copies of them jittered by 1% of the key scale (random play visits only a few thousand
   distinct states, far fewer than 1e5).
3. End-to-end training throughput: CEC on ``GCRL/PointUMaze-v0`` starting from a memory pre-filled
   with ``rows`` rows (real states of random play, jittered), and MFEC on ``MinAtar/Breakout-v1``,
   next to the raw env's random-action steps/s measured in the same run.

Usage: ``python scripts/bench_memory.py [--quick] [--tables cec mfec e2e]`` (``--quick``: smaller sizes).
"""

from __future__ import annotations

import argparse
import os
import time
from functools import partial

os.environ.setdefault("OMP_NUM_THREADS", "1")

import faiss  # noqa: E402
import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

import sb3_gcrl  # noqa: E402, F401
from sb3_gcrl import CEC, MFEC  # noqa: E402
from sb3_gcrl.memory import CECMemory  # noqa: E402

torch.set_num_threads(1)
faiss.omp_set_num_threads(1)


def median_us(fn, queries: np.ndarray) -> float:
    """Median CPU microseconds of ``fn(one_query)`` over the rows of ``queries``."""
    times = np.empty(len(queries))
    for i in range(len(queries)):
        query = queries[i : i + 1]
        start = time.thread_time_ns()
        fn(query)
        times[i] = time.thread_time_ns() - start
    return float(np.median(times) / 1e3)


class Timer:
    """Wall-clock and CPU seconds of a block (on a shared machine CPU time is the steadier figure)."""

    def __enter__(self) -> Timer:
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall, self.cpu = time.perf_counter() - self.wall, time.process_time() - self.cpu


def fill_cec(memory: CECMemory, keys: np.ndarray, rng: np.random.Generator) -> None:
    n = len(keys)
    memory.load_state_dict(
        {
            "keys": keys,
            "actions": rng.uniform(-1, 1, (n, memory.action_dim)).astype(np.float32),
            "values": rng.random(n),
            "last_update": np.arange(1, n + 1),
            "clock": n,
        }
    )


def table_cec_memory(sizes: list[int], dims: list[int], queries: int) -> None:
    print("\n## CEC memory: action selection (median CPU us / query, k=5), update (CPU ms / 1000-step episode)")
    print(f"{'rows':>9} {'dim':>4} {'backend':>8} {'select us':>10} {'update ms':>10} {'build s':>8}")
    rng = np.random.default_rng(0)
    for dim in dims:
        for size in sizes:
            memory = CECMemory(dim, 2, capacity=size + 2000, distance_threshold=0.5, n_neighbors=5)
            keys = rng.standard_normal((size, dim)).astype(np.float32)
            fill_cec(memory, keys, rng)
            n_queries = queries if size * dim <= 10_000_000 else queries // 10  # brute force at 1e6 x 64 is slow
            q = rng.standard_normal((n_queries, dim)).astype(np.float32)
            with Timer() as build:
                memory.select_actions(q[:1], rng)  # first query builds the KD-tree (if any)
            select = median_us(partial(memory.select_actions, rng=rng), q)
            # an episode of states near stored rows, 10% of them far away (-> added)
            episode = keys[rng.integers(size, size=1000)] + 0.05 * rng.standard_normal((1000, dim)).astype(np.float32)
            episode[::10] += 10.0
            with Timer() as update:
                memory.update_episode(episode, rng.uniform(-1, 1, (1000, 2)), rng.random(1000))
            backend = memory.index.backend
            print(f"{size:>9} {dim:>4} {backend:>8} {select:>10.1f} {update.cpu * 1e3:>10.1f} {build.cpu:>8.2f}")
            del memory


def collect_keys(env_id: str, embed, n_steps: int, seed: int = 0) -> np.ndarray:
    env = gym.make(env_id)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    observations = []
    for _ in range(n_steps):
        observations.append(obs)
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            obs, _ = env.reset(seed=int(rng.integers(1 << 30)))
    env.close()
    return embed(np.asarray(observations))


def jittered(keys: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    unique = np.unique(keys, axis=0)
    scale = 0.01 * keys.std(axis=0, keepdims=True)
    picks = unique[rng.integers(len(unique), size=n)]
    out = picks + scale * rng.standard_normal(picks.shape).astype(np.float32)
    out[: len(unique)] = unique[:n]
    return out.astype(np.float32)


def table_mfec_selection(rows_per_action: int, steps: int) -> None:
    print(f"\n## MFEC action selection, {rows_per_action} rows per action, 8-dim keys (median us / env step)")
    print("(real: queries are states of random play, stored exactly -> hash hits; unseen: the same states")
    print(" jittered, so every action table runs the exact kNN search)")
    print(f"{'env':>22} {'actions':>7} {'distinct real states':>20} {'real us':>8} {'unseen us':>10}")
    rng = np.random.default_rng(0)
    for env_id in ("MinAtar/Breakout-v1", "MinAtar/Seaquest-v1"):
        model = MFEC("MFECPolicy", gym.make(env_id), capacity_per_action=rows_per_action, seed=0)
        policy = model.policy
        real = collect_keys(env_id, policy.embedding, 50_000)
        for table in policy.memory.tables:
            keys = jittered(real, rows_per_action, rng)
            table.load_state_dict(
                {
                    "keys": keys,
                    "values": rng.random(len(keys)),
                    "last_update": np.arange(1, len(keys) + 1),
                    "clock": len(keys),
                }
            )
        queries = real[rng.integers(len(real), size=steps)]
        policy.act(queries[:1])
        act = median_us(policy.act, queries)
        unseen = queries + 0.01 * real.std(axis=0) * rng.standard_normal(queries.shape).astype(np.float32)
        act_unseen = median_us(policy.act, unseen)
        n_actions = policy.action_space.n
        print(f"{env_id:>22} {n_actions:>7} {len(np.unique(real, axis=0)):>20} {act:>8.1f} {act_unseen:>10.1f}")


def raw_steps_per_second(env_id: str, n_steps: int) -> tuple[float, float]:
    """Random-action steps per wall second and per CPU second of the bare env."""
    env = gym.make(env_id)
    env.reset(seed=0)
    with Timer() as timer:
        for _ in range(n_steps):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()
    return n_steps / timer.wall, n_steps / timer.cpu


def table_end_to_end(rows: int, steps: int) -> None:
    print(f"\n## End-to-end training (1 env), CEC memory pre-filled with {rows} rows; steps/s per wall | CPU second")
    print(f"{'algo':>5} {'env':>20} {'memory rows':>12} {'train steps/s':>16} {'raw env steps/s':>16}")
    rng = np.random.default_rng(0)
    env_id = "GCRL/PointUMaze-v0"
    model = CEC("CECPolicy", gym.make(env_id), capacity=1_000_000, seed=0)
    fill_cec(model.policy.memory, jittered(collect_keys(env_id, model.policy.embedding, 20_000), rows, rng), rng)
    raw_wall, raw_cpu = raw_steps_per_second(env_id, steps)
    with Timer() as timer:
        model.learn(steps, log_interval=None)
    train, raw = f"{steps / timer.wall:.0f} | {steps / timer.cpu:.0f}", f"{raw_wall:.0f} | {raw_cpu:.0f}"
    print(f"{'CEC':>5} {env_id:>20} {len(model.policy.memory):>12} {train:>16} {raw:>16}")
    env_id = "MinAtar/Breakout-v1"
    model = MFEC("MFECPolicy", gym.make(env_id), capacity_per_action=100_000, seed=0)
    raw_wall, raw_cpu = raw_steps_per_second(env_id, steps)
    with Timer() as timer:
        model.learn(steps, log_interval=None)
    train, raw = f"{steps / timer.wall:.0f} | {steps / timer.cpu:.0f}", f"{raw_wall:.0f} | {raw_cpu:.0f}"
    print(f"{'MFEC':>5} {env_id:>20} {len(model.policy.memory):>12} {train:>16} {raw:>16}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    parser.add_argument("--tables", nargs="+", default=["cec", "mfec", "e2e"], choices=["cec", "mfec", "e2e"])
    args = parser.parse_args()
    if "cec" in args.tables:
        if args.quick:
            table_cec_memory([1_000, 10_000], [3, 8], queries=200)
        else:
            table_cec_memory([1_000, 10_000, 100_000, 1_000_000], [3, 8, 64], queries=500)
    if "mfec" in args.tables:
        table_mfec_selection(10_000 if args.quick else 100_000, steps=300 if args.quick else 2_000)
    if "e2e" in args.tables:
        table_end_to_end(10_000 if args.quick else 100_000, steps=2_000 if args.quick else 20_000)


if __name__ == "__main__":
    main()
