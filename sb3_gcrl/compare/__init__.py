"""``sb3-gcrl compare``: methods x envs x seeds through RL-Zoo's machinery, in parallel, resumable, analysed.

Python use::

    from sb3_gcrl.compare import compare

    result = compare(["sac", "td3"], ["Pendulum-v1"], seeds=[0, 1, 2], n_timesteps=20_000, output="results/pendulum")
    print(result.summary.table)
"""

from sb3_gcrl.compare.backends import LocalProcessBackend, RayBackend
from sb3_gcrl.compare.comparison import ComparisonResult, compare
from sb3_gcrl.compare.evaluation import EvaluationRecorder
from sb3_gcrl.compare.methods import Method, parse_method
from sb3_gcrl.compare.presets import PRESETS, Preset
from sb3_gcrl.compare.run import RunResult, RunSpec, execute_run

__all__ = [
    "PRESETS",
    "ComparisonResult",
    "EvaluationRecorder",
    "LocalProcessBackend",
    "Method",
    "Preset",
    "RayBackend",
    "RunResult",
    "RunSpec",
    "compare",
    "execute_run",
    "parse_method",
]
