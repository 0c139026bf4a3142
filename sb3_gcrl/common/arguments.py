"""Settings that an algorithm takes as constructor arguments and hands on to its policy, their defaults stated once.

The policy states the settings and their defaults (stock SB3 algorithms, and SB3's ``load``, build it alone); the
algorithm restates the names in its own signature, so that they are documented, checked by the configs and given
by keyword, but reads their defaults from the policy (:func:`constructor_defaults`) and hands the values on by name,
as sb3-contrib's algorithms do (an attribute each, or an explicit keyword dict).
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any


def constructor_defaults(cls: type) -> Mapping[str, Any]:
    """The default of every constructor argument of ``cls`` that has one, by name.

    :param cls: the class (a policy).
    :return: a read-only mapping from argument name to default.
    """
    parameters = inspect.signature(cls.__init__).parameters.values()
    return MappingProxyType({p.name: p.default for p in parameters if p.default is not inspect.Parameter.empty})
