"""Deprecated alias of :mod:`sb3_gcrl.reset_free_baselines.ibc_curriculum` (runs pickled before the move name it)."""

from sb3_gcrl.reset_free_baselines.ibc_curriculum import (
    AUXILIARY,
    BACK,
    FORWARD,
    FORWARD_KINDS,
    CurriculumValueSource,
    IBCCurriculumScheduler,
    _SuccessTest,
    find_ibc_scheduler,
    ibc_go_explore,
)

__all__ = [
    "AUXILIARY",
    "BACK",
    "FORWARD",
    "FORWARD_KINDS",
    "CurriculumValueSource",
    "IBCCurriculumScheduler",
    "_SuccessTest",
    "find_ibc_scheduler",
    "ibc_go_explore",
]
