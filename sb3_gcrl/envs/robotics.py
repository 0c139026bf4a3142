"""Import gymnasium-robotics once, without its notice about the Adroit envs' v1 rewards (we use none of them).

gymnasium-robotics 1.4.0-1.4.2 prints that notice to stderr on every import, i.e. on every ``import sb3_gcrl`` and in
every worker process. Importing this module first (``sb3_gcrl.envs`` does) drops those lines; anything else the
import prints passes through.
"""

from __future__ import annotations

import contextlib
import io
import sys

if "gymnasium_robotics" not in sys.modules:
    _captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(_captured):
            import gymnasium_robotics  # noqa: F401
    finally:
        sys.stderr.write("".join(line for line in _captured.getvalue().splitlines(True) if "AdroitHand" not in line))
