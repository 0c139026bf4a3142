"""Reading an option out of a command line that another parser (RL-Zoo's) parses later."""

from __future__ import annotations

from collections.abc import Sequence


def option_value(argv: Sequence[str], *flags: str) -> str | None:
    """Value of the first of ``flags`` in ``argv`` (``--flag value`` or ``--flag=value``), else None.

    :param argv: the command line's words.
    :param flags: the option's spellings (``-n``, ``--n-timesteps``).
    :return: the value, or None when the option is absent.
    """
    for i, arg in enumerate(argv):
        for flag in flags:
            if arg == flag and i + 1 < len(argv):
                return argv[i + 1]
            if arg.startswith(flag + "="):
                return arg.split("=", 1)[1]
    return None
