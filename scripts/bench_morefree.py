"""Speed of the world-model MoReFree agent's training step, beside sheeprl's DreamerV3 step at equal sizes.

Prints one table row per setting, each timed on one thread after every warm-up (compilation included in the
warm-up, reported apart):

* ``cpu``: the CPU preset as shipped (``CPU_NETWORK``, batch 16 x 32, 128 imagination starts, train ratio 2);
* ``cpu-full``: the CPU preset with every posterior state an imagination start (512, as PEG / DreamerV3);
* ``thesis``: the thesis preset (``THESIS_NETWORK``, PEG's batch 45 x 50, 2250 starts), a few steps;
* ``before``: the sizes of the CPU preset the agent had before it was rebuilt on PEG's (commit ``ec97e36``: GRU 64,
  64 latent units, 64-wide layers, 3 ensemble members), every posterior state a start. With ``--before`` (a checkout
  of that commit) that agent's step is timed in the same run, alternating with ours.

For each, the train steps/s (median over ``--repeats``, wall and process CPU time) of the plain step (``eager``),
the compiled one (``compiled``: ``compile_train_step``) and the compiled bfloat16 one (``compiled-bf16``: also
``mixed_precision``). Where both imagine from every posterior state (``cpu-full``, ``thesis``), sheeprl's DreamerV3
train step at the same sizes (``scripts/bench_sheeprl_dreamer.py``, run with ``--sheeprl-python``, the interpreter
of a venv holding sheeprl; skipped without it) is timed in the same run, alternating with ours, at each of its own
speed settings (``--sheeprl-variants``: ``eager`` float32, sheeprl's default; ``compiled``, its
``algo.compile.enabled``; ``bf16``, its ``fabric.precision=bf16-mixed``; ``compiled-bf16``, both), and the table
gives our fastest step against each (the best of sheeprl's marked). sheeprl's latent is
``stoch`` categoricals of one class (as wide as our Gaussian latent, so the matrix products match; it carries no
information, which does not change the time), its MLPs all ``head_hidden`` wide with ``head_layers`` layers. Our
step does more than sheeprl's: two actor-critics (pi_G and pi_E), the distance and the Plan2Explore ensemble
besides the world model::

    python scripts/bench_morefree.py --sheeprl-python /work/venv-sheeprl/bin/python
    python scripts/bench_morefree.py --settings cpu --variants compiled-bf16 --collect   # + env steps/s
    git worktree add /tmp/sb3_gcrl_before ec97e36
    python scripts/bench_morefree.py --settings before --before /tmp/sb3_gcrl_before      # vs the agent before

``--collect`` also times data collection (filtering, pi_G / pi_E actions, Back-and-Forth Go-Explore with PEG goals)
of the CPU preset and prints what a 100k-step reset-free PointUMaze run costs at train ratio 2.

``--profile N`` then profiles N more steps of each setting and step (``torch.profiler``, one thread) and prints where
a step's CPU time goes: the parts of the step (world model; imagination of pi_G and pi_E; critics and distance; the
backward passes with the optimizer steps), and by kind of work, matrix products against the compiled graphs' own
fused kernels (elementwise work, reductions) and the rest::

    python scripts/bench_morefree.py --settings cpu-full --variants eager compiled-bf16 --repeats 3 --profile 5
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.env_util import make_vec_env

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl.callbacks import ResetFreeCallback
from sb3_gcrl.common.hardware import describe_cpu
from sb3_gcrl.morefree import CPU_NETWORK, THESIS_NETWORK, MoReFree, morefree_go_explore
from sb3_gcrl.wrappers import ResetFreeWrapper

#: (network, algorithm settings, timed steps per repeat) of each setting
SETTINGS: dict[str, tuple[dict[str, Any], dict[str, Any], int]] = {
    "cpu": (CPU_NETWORK, {"batch_size": 16, "batch_length": 32, "imagination_starts": 128}, 20),
    "cpu-full": (CPU_NETWORK, {"batch_size": 16, "batch_length": 32, "imagination_starts": None}, 10),
    "thesis": (THESIS_NETWORK, {"batch_size": 45, "batch_length": 50, "imagination_starts": None}, 2),
    "before": (
        dict(
            deter=64,
            stoch=64,
            rssm_hidden=64,
            model_hidden=64,
            model_layers=2,
            head_hidden=64,
            head_layers=2,
            ensemble_size=3,
            ensemble_hidden=64,
        ),
        {"batch_size": 16, "batch_length": 32, "imagination_starts": None},
        10,
    ),
}
#: the same sizes in the arguments of the agent before the rebuild (commit ec97e36: 8 categoricals of 8 classes)
BEFORE_NETWORK = dict(
    deter=64,
    stoch=8,
    classes=8,
    hidden=64,
    embed_dim=64,
    model_layers=2,
    actor_hidden=64,
    actor_layers=2,
    ensemble_size=3,
)
BEFORE_SCRIPT = """
import json, sys, time
import torch as th
sys.path.insert(0, {source!r})
th.set_num_threads(1)
from stable_baselines3.common.env_util import make_vec_env
import sb3_gcrl
from sb3_gcrl.morefree import MoReFree
assert sb3_gcrl.__file__.startswith({source!r}), sb3_gcrl.__file__
env = make_vec_env("GCRL/PointUMazeGoal-v0", n_envs=1, seed=0)
model = MoReFree("MultiInputPolicy", env, learning_starts=500, train_ratio=10**9, policy_kwargs={network!r},
                 seed=0, batch_size=16, batch_length=32, imagination_starts=None)
model.learn(600)
for _ in range(3):
    model.train()
wall, cpu = time.perf_counter(), time.process_time()
for _ in range({steps}):
    model.train()
print("BEFORE", json.dumps([({steps}) / (time.perf_counter() - wall), (time.process_time() - cpu) / {steps}]))
"""
VARIANTS = {
    "eager": {"compile_train_step": False, "mixed_precision": False},
    "compiled": {"compile_train_step": True, "mixed_precision": False},
    "compiled-bf16": {"compile_train_step": True, "mixed_precision": True},
}
SHEEPRL_SCRIPT = Path(__file__).resolve().parent / "bench_sheeprl_dreamer.py"
# sheeprl's own speed settings, as a sheeprl user turns them on: fabric.precision and algo.compile.enabled
SHEEPRL_VARIANTS = {
    "eager": ["--precision=32-true"],
    "compiled": ["--precision=32-true", "--compile"],
    "bf16": ["--precision=bf16-mixed"],
    "compiled-bf16": ["--precision=bf16-mixed", "--compile"],
}


def make_env(env: gym.Env) -> gym.Env:
    env = ResetFreeWrapper(env, hard_reset_every=200_000, eval_horizon=300)
    return morefree_go_explore(
        env, alpha=0.2, scheduler_kwargs={"goal_low": [-1.5, -1.5], "goal_high": [1.5, 1.5], "n_bins": 12}
    )


def build(setting: str, variant: str, device: str) -> MoReFree:
    """An agent of ``setting`` on reset-free PointUMaze whose replay holds 600 steps and that has trained (and
    compiled) already: what follows are steady-state steps."""
    network, algo, _ = SETTINGS[setting]
    env = make_vec_env("GCRL/PointUMazeGoal-v0", n_envs=1, seed=0, wrapper_class=make_env)
    model = MoReFree(
        "MultiInputPolicy",
        env,
        learning_starts=500,
        train_ratio=10**9,  # no training inside learn: the steps are timed one by one below
        policy_kwargs=dict(network),
        device=device,
        seed=0,
        peg_samples=100,
        peg_iterations=3,
        **algo,
        **VARIANTS[variant],
    )
    model.learn(600, callback=ResetFreeCallback())
    return model


def time_steps(model: MoReFree, steps: int) -> tuple[float, float]:
    """(wall, CPU) seconds per training step over ``steps`` steps."""
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(steps):
        model.train()
    if model.device.type == "cuda":
        th.cuda.synchronize()
    return (time.perf_counter() - wall) / steps, (time.process_time() - cpu) / steps


#: the labelled parts of ``MoReFree.train`` (``torch.profiler.record_function``)
PARTS = (
    "morefree.world_model",
    "morefree.world_model_backward",
    "morefree.imagination",
    "morefree.learners",
    "morefree.imagination_backward",
)
#: matrix products (dense layers, the batched ensemble)
MATRIX_PRODUCTS = ("aten::mm", "aten::addmm", "aten::bmm", "aten::baddbmm")


def profile_steps(model: MoReFree, steps: int) -> dict[str, float]:
    """CPU milliseconds per training step: each labelled part of the step, matrix products, the compiled graphs' own
    kernels (``## Call CompiledFxGraph``, self time) and everything else, over ``steps`` profiled steps."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(steps):
            model.train()
    events = prof.key_averages()
    total = sum(event.self_cpu_time_total for event in events)
    per_step = {name: 0.0 for name in (*PARTS, "matrix products", "compiled kernels", "other", "total")}
    for event in events:
        if event.key in PARTS:
            per_step[event.key] += event.cpu_time_total
        if event.key in MATRIX_PRODUCTS:
            per_step["matrix products"] += event.self_cpu_time_total
        elif event.key.startswith("## Call CompiledFxGraph"):
            per_step["compiled kernels"] += event.self_cpu_time_total
    per_step["other"] = total - per_step["matrix products"] - per_step["compiled kernels"]
    per_step["total"] = total
    return {name: value / 1000 / steps for name, value in per_step.items()}


def sheeprl_step(python: str, setting: str, steps: int, variant: str) -> float | None:
    """sheeprl's DreamerV3 train steps/s at the sizes of ``setting`` with its settings ``variant`` (one repeat, in a
    fresh process: a compiled variant compiles in its warm-up steps), or None if it failed."""
    network, algo, _ = SETTINGS[setting]
    batch = algo["batch_size"]
    # every posterior state starts an imagination in sheeprl: its full volume is batch x length starts
    command = [
        python,
        str(SHEEPRL_SCRIPT),
        f"--deter={network['deter']}",
        f"--stoch={network['stoch']}",
        "--classes=1",
        f"--hidden={network['head_hidden']}",
        f"--layers={network['head_layers']}",
        f"--batch={batch}",
        f"--length={algo['batch_length']}",
        f"--steps={steps}",
        "--repeats=1",
        "--warmup=3",
        *SHEEPRL_VARIANTS[variant],
    ]
    result = subprocess.run(command, capture_output=True, text=True, env=dict(os.environ), check=False)
    match = re.search(r"SHEEPRL_TRAIN_STEPS_PER_S\s+([0-9.eE+-]+)", result.stdout)
    if match is None:
        print(f"sheeprl ({variant}) failed for {setting}: {result.stderr[-500:]}", file=sys.stderr)
        return None
    return float(match.group(1))


def before_step(source: str, steps: int) -> tuple[float, float] | None:
    """(train steps/s, CPU s per step) of the agent before the rebuild, checked out at ``source``, or None."""
    code = BEFORE_SCRIPT.format(source=str(Path(source).resolve()), network=BEFORE_NETWORK, steps=steps)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/", check=False)
    match = re.search(r"^BEFORE (.*)$", result.stdout, re.MULTILINE)
    if match is None:
        print(f"the agent at {source} failed: {result.stderr[-500:]}", file=sys.stderr)
        return None
    rate, cpu = json.loads(match.group(1))
    return float(rate), float(cpu)


def collection(steps: int, variant: str) -> float:
    """Env steps/s of data collection with the CPU preset's trained-for-a-moment agent (no training)."""
    model = build("cpu", variant, "cpu")
    start = time.perf_counter()
    model.learn(steps, callback=ResetFreeCallback(), reset_num_timesteps=False)
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--settings", nargs="*", default=["cpu", "cpu-full", "thesis"], choices=list(SETTINGS))
    parser.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--repeats", type=int, default=3, help="repeats; medians are reported")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--sheeprl-python", help="python of a venv with sheeprl 0.8.4 (the DreamerV3 reference)")
    parser.add_argument(
        "--sheeprl-variants",
        nargs="*",
        default=list(SHEEPRL_VARIANTS),
        choices=list(SHEEPRL_VARIANTS),
        help="sheeprl's settings to time: float32 or bf16-mixed (fabric.precision), eager or compiled "
        "(algo.compile.enabled)",
    )
    parser.add_argument("--collect", action="store_true", help="also time data collection (CPU preset)")
    parser.add_argument("--before", help="a checkout of commit ec97e36, timed beside the 'before' setting")
    parser.add_argument("--profile", type=int, default=0, help="then profile this many steps of each (0: none)")
    args = parser.parse_args()
    th.set_num_threads(1)

    print(f"CPU: {describe_cpu()}; one thread, device {args.device}, load before: {os.getloadavg()[0]:.1f}")
    print("| setting | step | train steps/s (median) | CPU s per step | set-up + compile s | runs (steps/s) |")
    print("|---|---|---|---|---|---|")
    for setting in args.settings:
        steps = SETTINGS[setting][2]
        models: dict[str, MoReFree] = {}
        setup: dict[str, float] = {}
        for variant in args.variants:
            start = time.perf_counter()
            models[variant] = build(setting, variant, args.device)
            models[variant].train()  # the first step compiles
            setup[variant] = time.perf_counter() - start
        sheeprl_names = [f"sheeprl {variant}" for variant in args.sheeprl_variants]
        rates: dict[str, list[float]] = {name: [] for name in [*args.variants, *sheeprl_names, "before"]}
        cpu_per_step: dict[str, list[float]] = {name: [] for name in [*args.variants, "before"]}
        for _ in range(args.repeats):  # alternate: every repeat times every step once
            for variant, model in models.items():
                wall, cpu = time_steps(model, steps)
                rates[variant].append(1 / wall)
                cpu_per_step[variant].append(cpu)
            if args.sheeprl_python and SETTINGS[setting][1]["imagination_starts"] is None:  # equal volume only
                for variant in args.sheeprl_variants:
                    rate = sheeprl_step(args.sheeprl_python, setting, steps, variant)
                    if rate is not None:
                        rates[f"sheeprl {variant}"].append(rate)
            if args.before and setting == "before":
                timing = before_step(args.before, steps)
                if timing is not None:
                    rates["before"].append(timing[0])
                    cpu_per_step["before"].append(timing[1])
        for name, runs in rates.items():
            if not runs:
                continue
            cpu = f"{np.median(cpu_per_step[name]):.3f}" if name in cpu_per_step else "(sheeprl's own timing)"
            built = f"{setup[name]:.0f}" if name in setup else "-"
            label = {"before": "before the rebuild (ec97e36)"}.get(name, name.replace("sheeprl", "sheeprl DreamerV3"))
            print(
                f"| {setting} | {label} | {np.median(runs):.3g} | {cpu} | {built} | "
                f"{', '.join(f'{r:.3g}' for r in runs)} |",
                flush=True,
            )
        timed_sheeprl = [name for name in sheeprl_names if rates[name]]
        if timed_sheeprl:
            best = max(args.variants, key=lambda v: float(np.median(rates[v])))
            sheeprl_best = max(timed_sheeprl, key=lambda v: float(np.median(rates[v])))
            for name in timed_sheeprl:
                ratio = float(np.median(rates[best])) / float(np.median(rates[name]))
                mark = " (sheeprl's best)" if name == sheeprl_best else ""
                print(f"| {setting} | ratio ours {best} / {name}{mark} | {ratio:.2f}x | | | |")
        if rates["before"]:
            before = float(np.median(rates["before"]))
            best = max(args.variants, key=lambda v: float(np.median(rates[v])))
            print(f"| {setting} | ratio {best} / before | {float(np.median(rates[best])) / before:.2f}x | | | |")
        if args.profile:
            profiles = {variant: profile_steps(model, args.profile) for variant, model in models.items()}
            cpu = describe_cpu()
            print(f"\n{setting}: CPU ms per training step ({args.profile} profiled steps, torch.profiler; {cpu})\n")
            print("| part of the step | " + " | ".join(profiles) + " |")
            print("|---|" + "---|" * len(profiles))
            for name in next(iter(profiles.values())):
                label = name.removeprefix("morefree.").replace("_", " ")
                print(f"| {label} | " + " | ".join(f"{p[name]:.1f}" for p in profiles.values()) + " |")
            print("", flush=True)
    if args.collect:
        variant = args.variants[-1]
        env_rate = collection(3000, variant)
        models = {variant: build("cpu", variant, "cpu")}
        models[variant].train()
        train_rate = 1 / float(np.median([time_steps(models[variant], 20)[0] for _ in range(args.repeats)]))
        hours = (100_000 / env_rate + 50_000 / train_rate) / 3600
        print(f"collection: {env_rate:.0f} env steps/s; CPU preset {variant}: {train_rate:.1f} train steps/s")
        print(f"100k reset-free PointUMaze steps at train ratio 2 (50k training steps): {hours:.2f} h of one core")
    print(f"load after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
