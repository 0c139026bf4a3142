"""What the machine can do: the CPU's model and instruction sets, and whether bfloat16 arithmetic is native on a device.

bfloat16 pays only where the hardware computes in it: on a CPU with AVX512-BF16 or AMX, or a CUDA GPU that supports it
(compute capability 8.0+). Elsewhere torch emulates it through float32 conversions, and a bfloat16 step is slower than
the float32 one (docs/morefree.md, "Speed": 7x slower on an AVX2-only EPYC).
"""

from __future__ import annotations

import platform
from pathlib import Path

import torch as th

#: instruction sets the speed figures depend on -> torch's probe of each (``torch.cpu``)
CPU_FEATURES = {
    "avx2": "_is_avx2_supported",
    "avx512": "_is_avx512_supported",
    "avx512_bf16": "_is_avx512_bf16_supported",
    "amx": "_is_amx_tile_supported",
}


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else :func:`platform.processor`)."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text(errors="replace").splitlines():
            if line.lower().startswith(("model name", "hardware")) and ":" in line:
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine() or "unknown CPU"


def cpu_features() -> dict[str, bool]:
    """Which of :data:`CPU_FEATURES` this CPU has, as torch's CPU kernels see them (False where torch cannot tell)."""
    probes = th.cpu
    return {name: bool(getattr(probes, probe, lambda: False)()) for name, probe in CPU_FEATURES.items()}


def describe_cpu() -> str:
    """One line for benchmark tables: the model and the instruction sets it has, e.g. ``AMD EPYC 9R14 (avx2,
    avx512, avx512_bf16)``."""
    features = [name for name, present in cpu_features().items() if present]
    return f"{cpu_model()} ({', '.join(features) if features else 'none of ' + ', '.join(CPU_FEATURES)})"


def native_bfloat16(device: th.device | str) -> bool:
    """Whether ``device`` computes in bfloat16 natively: a CPU with AVX512-BF16 or AMX, a CUDA GPU that supports
    bfloat16; False elsewhere (MPS and other backends included).

    :param device: the torch device.
    """
    device = th.device(device)
    if device.type == "cuda":
        return bool(th.cuda.is_available() and th.cuda.is_bf16_supported())
    if device.type == "cpu":
        features = cpu_features()
        return features["avx512_bf16"] or features["amx"]
    return False
