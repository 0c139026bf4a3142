"""IBC (Implicit and Bidirectional Curriculum, J. Kim et al., ICML 2023): the reset-free baseline of thesis Ch. 3.

:class:`IBC` holds the forward and backward SAC agents; :func:`ibc_go_explore` is the ``env_wrapper`` entry that puts
IBC's phases and curriculum (:class:`IBCCurriculumScheduler`) on the package's reset-free Go/Explore wrapper.
"""

from sb3_gcrl.ibc.curriculum import IBCCurriculumScheduler, find_ibc_scheduler, ibc_go_explore
from sb3_gcrl.ibc.ibc import IBC

__all__ = ["IBC", "IBCCurriculumScheduler", "find_ibc_scheduler", "ibc_go_explore"]
