"""The package's own random draws come from ``numpy.random.Generator`` objects seeded from SB3's seed, never from
numpy's (or Python's) global generator, which SB3 keeps for its own draws (replay sampling, ``DQN``'s epsilon coin).

* :func:`seeded_generator`: a generator for one use of a run's seed (``stream``), independent of the generators of
  the other uses of that seed;
* :func:`draw_seed`: a seed for a component that SB3 builds (a policy, a replay buffer), drawn from the generator of
  its action space, which SB3's ``set_random_seed`` seeds with the model's seed right before it builds them;
* :func:`generator_state` / :func:`restore_generator`: a generator's state as a tensor, for a policy's
  ``state_dict`` (``get_extra_state``), so that ``save`` / ``load`` continue its draws;
* :class:`SeededGeneratorMixin`: an algorithm's own generator ``_rng``, seeded with SB3's generators, saved with the
  model and continued by ``load``.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces


def seeded_generator(seed: int | None, stream: str | None = None) -> np.random.Generator:
    """A generator for one use (``stream``) of ``seed``.

    Generators of the same seed and different streams draw independent numbers (two users of one seed would otherwise
    draw the same numbers); without ``stream``, ``numpy.random.default_rng(seed)``.

    :param seed: the run's seed; ``None``: fresh entropy.
    :param stream: name of the use (e.g. ``"two_memory dispatch"``).
    :return: the generator.
    """
    if seed is None:
        return np.random.default_rng()
    if stream is None:
        return np.random.default_rng(seed)
    return np.random.default_rng([int(seed), zlib.crc32(stream.encode())])


def draw_seed(space: spaces.Space) -> int:
    """A seed drawn from ``space``'s generator.

    SB3's ``set_random_seed`` seeds the action space with the model's seed before it builds the replay buffer and
    the policy from it, so a component that draws its seed here follows the model's seed (stock SB3 algorithms
    included, which pass no seed to a policy); a space nobody seeded draws from fresh entropy.

    :param space: the space the component is built with (its action space).
    :return: a seed in ``[0, 2**31 - 1)``.
    """
    return int(space.np_random.integers(2**31 - 1))


def generator_state(rng: np.random.Generator) -> th.Tensor:
    """The state of ``rng`` as a ``uint8`` tensor (the JSON of its bit generator's state), for a ``state_dict``.

    :param rng: the generator.
    :return: the tensor that :func:`restore_generator` reads.
    """
    return th.tensor(list(json.dumps(rng.bit_generator.state).encode()), dtype=th.uint8)


def restore_generator(state: th.Tensor) -> np.random.Generator:
    """The generator whose state :func:`generator_state` saved: it continues where the saved one stopped.

    :param state: the tensor of :func:`generator_state`.
    :return: the generator.
    :raises ValueError: if ``state`` is not such a tensor.
    """
    try:
        saved: dict[str, Any] = json.loads(bytes(state.cpu().numpy().astype(np.uint8)).decode())
        bit_generator = getattr(np.random, saved["bit_generator"])()
        bit_generator.state = saved
    except (ValueError, TypeError, KeyError, AttributeError) as error:
        raise ValueError(f"the saved random generator state cannot be restored: {error}") from error
    return np.random.Generator(bit_generator)


class SeededGeneratorMixin:
    """Mix in before an SB3 algorithm whose ``_setup_model`` calls ``super()._setup_model()``: the algorithm draws
    its own random numbers (exploration coins, sampling) from the generator ``_rng``.

    * ``set_random_seed(seed)`` seeds ``_rng`` with SB3's generators and reseeds the policy's own generators
      (``policy.set_seed``); a model built without a seed starts ``_rng`` from fresh entropy;
    * ``_rng`` is saved with the model (it is part of the model's data), and ``load`` continues it where the saved
      model stopped: SB3's ``load`` sets the model up again with its saved seed, which would restart it.

    Subclasses with more generators of their own extend :meth:`_seed_generators` and :meth:`_setup_model`.
    """

    #: the algorithm's own generator
    _rng: np.random.Generator

    def set_random_seed(self, seed: int | None = None) -> None:
        """SB3's seeding (Python, numpy, torch, the action space, the envs), the algorithm's own generators and the
        policy's (``policy.set_seed``).

        :param seed: the seed; ``None`` changes nothing, as in SB3.
        """
        super().set_random_seed(seed)  # type: ignore[misc]
        if seed is None:
            return
        self._seed_generators(seed)
        set_seed = getattr(getattr(self, "policy", None), "set_seed", None)
        if set_seed is not None:
            set_seed(seed)

    def _seed_generators(self, seed: int | None) -> None:
        """(Re)make the algorithm's own generators from ``seed``.

        :param seed: the seed; ``None``: fresh entropy.
        """
        self._rng = seeded_generator(seed)

    @contextmanager
    def _continuing_saved_generator(self) -> Iterator[None]:
        """Around an algorithm's set-up: a generator that ``load`` restored before the set-up (the saved model's) is
        kept over the one the set-up seeds; without a seed, fresh entropy. An algorithm whose ``_setup_model`` does
        not call ``super()._setup_model()`` runs its set-up inside this context itself."""
        restored = self.__dict__.pop("_rng", None)  # only ``load`` sets it before the set-up: continue it
        yield
        if restored is not None:
            self._rng = restored
        elif "_rng" not in self.__dict__:
            self._seed_generators(None)

    def _setup_model(self) -> None:
        with self._continuing_saved_generator():
            super()._setup_model()  # type: ignore[misc]  (seeds ``_rng`` when the model has a seed)
