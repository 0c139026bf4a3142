"""Speed of the model-based MoReFree agent's training step: bfloat16 autocast and ``torch.compile``.

Neither changes what a step computes beyond precision: :func:`autocast` runs matrix products in bfloat16 (PEG's
``precision: 16``) only where the device computes bfloat16 natively (:func:`native_bfloat16_or_warn`), and
:func:`compile_functions` compiles the step's loss computations with PyTorch's own random numbers, which the
compiled step reproduces on fixed seeds.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from typing import Any

import torch as th

from sb3_gcrl.common.hardware import describe_cpu, native_bfloat16

#: how long compiling the training step takes (here and in ``sb3-gcrl compare``'s notice before such runs)
COMPILE_TIME = (
    "minutes on a CPU (about 2-3 for the CPU presets, up to 20 on one core at the thesis sizes; torch's cache "
    "shortens later compiles of the same sizes)"
)
#: the line printed (with ``verbose >= 1``) before the first compiled training step
COMPILE_NOTICE = (
    "MoReFree: compiling the training step with torch.compile (compile_train_step=True). The first training step "
    f"waits for it, once per model in this process: {COMPILE_TIME}, then a step takes about half the time; "
    "compile_train_step=False skips it"
)


def autocast(bfloat16: bool, device: th.device, world_model: bool = False) -> AbstractContextManager[Any]:
    """bfloat16 matrix products (``torch.autocast``) where ``bfloat16``, as PEG's ``precision: 16``; the
    distributions, losses and the GRU's normalisation stay in float32.

    :param bfloat16: whether the agent trains in bfloat16 (:func:`native_bfloat16_or_warn`).
    :param device: the agent's device.
    :param world_model: for the world model's step (filtering the replayed sequences), which stays in float32 on
        a CPU: its products are small (one per sequence step), and bfloat16's casts cost more there than they
        save (``scripts/bench_morefree.py --profile``).
    """
    if not bfloat16 or (world_model and device.type == "cpu"):
        return nullcontext()
    return th.autocast(device.type, dtype=th.bfloat16)


def native_bfloat16_or_warn(mixed_precision: bool, device: th.device) -> bool:
    """Whether to train in bfloat16: ``mixed_precision`` where the device computes bfloat16 natively, with one
    warning where ``mixed_precision`` asks for bfloat16 on a device that would emulate it (slower than float32).

    :param mixed_precision: the agent's setting.
    :param device: the agent's device.
    """
    native = mixed_precision and native_bfloat16(device)
    if mixed_precision and not native:
        where = describe_cpu() if device.type == "cpu" else str(device)
        warnings.warn(
            f"MoReFree: mixed_precision=True, but {where} has no native bfloat16 (a CPU needs AVX512-BF16 or "
            "AMX): training in float32, which is faster there; set mixed_precision=False to silence this",
            stacklevel=3,
        )
    return native


def compile_functions(functions: dict[str, Callable[..., Any]], verbose: int = 0) -> dict[str, Callable[..., Any]]:
    """The functions compiled with ``torch.compile`` (compiled on their first call: minutes on a CPU).

    :param functions: the functions by name.
    :param verbose: print :data:`COMPILE_NOTICE` when >= 1.
    """
    if verbose >= 1:
        print(COMPILE_NOTICE)
    # fallback_random: random numbers come from PyTorch's own generator (as in the plain step) instead of inductor's
    # in-kernel ones, which cost about 60 ns a sample on a CPU core
    options = {"fallback_random": True}
    return {name: th.compile(function, options=options) for name, function in functions.items()}
