"""Deprecated alias of IBC's old home: import from :mod:`sb3_gcrl.reset_free_baselines` (or ``sb3_gcrl.IBC``).

Re-exports the same objects, so that ``sb3_gcrl.ibc.ibc_go_explore`` in an RL-Zoo ``env_wrapper`` and runs saved
before the move (pickles naming ``sb3_gcrl.ibc.curriculum`` / ``sb3_gcrl.ibc.ibc``) keep working.
"""

import warnings

from sb3_gcrl.reset_free_baselines.ibc import IBC
from sb3_gcrl.reset_free_baselines.ibc_curriculum import IBCCurriculumScheduler, find_ibc_scheduler, ibc_go_explore

warnings.warn(
    "sb3_gcrl.ibc is deprecated: import IBC, IBCCurriculumScheduler, ibc_go_explore and find_ibc_scheduler from "
    "sb3_gcrl.reset_free_baselines (RL-Zoo env_wrapper: sb3_gcrl.reset_free_baselines.ibc_go_explore)",
    DeprecationWarning,
    stacklevel=2,
)

__all__ = ["IBC", "IBCCurriculumScheduler", "find_ibc_scheduler", "ibc_go_explore"]
