"""Settings that an algorithm takes as constructor arguments and hands on to its policy, stated once.

The policy states the settings and their defaults (stock SB3 algorithms, and SB3's ``load``, build it alone); the
algorithm restates the names in its own signature, so that they are documented, checked by the configs and given
by keyword, but reads their defaults from the policy (:func:`constructor_defaults`) and picks the values to hand on
from its arguments by name (:func:`settings_among`).
"""

from __future__ import annotations

import inspect
from collections.abc import Collection, Mapping
from types import MappingProxyType
from typing import Any


def constructor_defaults(cls: type) -> Mapping[str, Any]:
    """The default of every constructor argument of ``cls`` that has one, by name.

    :param cls: the class (a policy).
    :return: a read-only mapping from argument name to default.
    """
    parameters = inspect.signature(cls.__init__).parameters.values()
    return MappingProxyType({p.name: p.default for p in parameters if p.default is not inspect.Parameter.empty})


def settings_among(arguments: Mapping[str, Any], names: Collection[str]) -> dict[str, Any]:
    """The arguments named in ``names`` among a constructor's arguments (its ``locals()``).

    :param arguments: the constructor's arguments by name.
    :param names: the names of the settings to hand on.
    :return: those settings by name.
    """
    return {name: value for name, value in arguments.items() if name in names}
