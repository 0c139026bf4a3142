"""Model files of this package's algorithms: atomic writes, a check of the file before SB3 reads it, and the
class that saved it.

* :func:`atomic_file`, :func:`atomic_write_bytes`, :func:`atomic_write_text`: write through a temporary file beside
  the destination and a rename, so that a crash or a kill during a save leaves the previous file intact.
* :func:`atomic_save_to_pkl`: SB3's ``save_to_pkl`` through :func:`atomic_file` (replay buffers).
* :class:`ModelFileMixin`: mixed in before the SB3 base of every algorithm of :data:`sb3_gcrl.algorithms.ALGORITHMS`.
  ``save`` is atomic and records the class in the archive (entry :data:`SAVED_BY_ENTRY`); ``load`` first checks the
  archive (:func:`check_model_file`), so that a truncated or damaged file, a zip that is no model, or a file
  saved by another of our algorithms is refused with a :class:`ModelFileError` that names the fix, instead of an
  error from deep inside SB3. A file without the entry (written by SB3's own ``save``) is loaded as SB3 loads it.
* :func:`refuse_learning_rate_schedule`: for policy constructors whose third argument is not SB3's learning-rate
  schedule, so that SB3's own ``load`` of one of our files (``SAC.load`` of a CEC model) names the right class.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import pathlib
import stat
import tempfile
import warnings
import zipfile
import zlib
from collections.abc import Iterable, Iterator
from typing import Any, TypeVar

import torch as th
from stable_baselines3.common.save_util import open_path, save_to_pkl
from stable_baselines3.common.type_aliases import GymEnv

#: archive entry holding the name of the class that saved the model (SB3's ``load`` ignores unknown entries)
SAVED_BY_ENTRY = "sb3_gcrl_class"

SelfModelFileMixin = TypeVar("SelfModelFileMixin", bound="ModelFileMixin")


class ModelFileError(ValueError):
    """A model file that cannot be loaded, with what it is (or is not) and what to do."""


def _current_umask() -> int:
    """The process's umask (read by setting it and putting it back: Python has no getter)."""
    mask = os.umask(0o022)  # not 0 meanwhile: a file another thread creates in between is not world-writable
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_file(path: str | pathlib.Path) -> Iterator[pathlib.Path]:
    """Yield a temporary path beside ``path``; when the block ends without an error, rename it to ``path``.

    A reader never sees half a file, and an error or a kill during the write leaves the previous ``path`` as it
    was (the temporary file is removed on an error). The file gets the mode ``open(path, "wb")`` would give it: an
    existing file's mode, else ``0o666`` less the umask, not the ``0o600`` of the temporary file.

    :param path: destination (its folder is created if needed).
    :return: the temporary path to write to (it ends in ``.tmp``, so SB3 adds no suffix to it).
    """
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
    except FileNotFoundError:
        mode = 0o666 & ~_current_umask()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, mode)
        os.close(fd)
        yield pathlib.Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path: str | pathlib.Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (:func:`atomic_file`).

    :param path: destination.
    :param data: content.
    """
    with atomic_file(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | pathlib.Path, text: str) -> None:
    """:func:`atomic_write_bytes` for text (UTF-8).

    :param path: destination.
    :param text: content.
    """
    atomic_write_bytes(path, text.encode())


def with_suffix_if_none(path: str | pathlib.Path, suffix: str) -> pathlib.Path:
    """The file SB3 writes for ``path``: ``path.<suffix>`` when ``path`` has no suffix (``model`` ->
    ``model.zip``), and ``path_2`` when ``path`` is a folder (with SB3's warning).

    :param path: the path given to ``save``.
    :param suffix: SB3's preferred suffix, without the dot (``"zip"``, ``"pkl"``).
    """
    path = pathlib.Path(path)
    if path.suffix == "":
        path = pathlib.Path(f"{path}.{suffix}")
    if path.is_dir():
        warnings.warn(f"Path '{path}' is a folder. Will save instead to {path}_2", stacklevel=3)
        path = pathlib.Path(f"{path}_2")
    return path


def atomic_save_to_pkl(path: str | pathlib.Path | io.BufferedIOBase, obj: Any, verbose: int = 0) -> None:
    """SB3's ``save_to_pkl`` (``.pkl`` added to a path without suffix), written atomically to a path
    (:func:`atomic_file`); a file object is written directly.

    :param path: file path or writable file object.
    :param obj: what to pickle.
    :param verbose: SB3's verbosity.
    """
    if not isinstance(path, (str, pathlib.Path)):
        save_to_pkl(path, obj, verbose)
        return
    with atomic_file(with_suffix_if_none(path, "pkl")) as tmp:
        save_to_pkl(tmp, obj, verbose)


def _describe(path: str | pathlib.Path | io.BufferedIOBase) -> str:
    return str(path) if isinstance(path, (str, pathlib.Path)) else f"the file object {path!r}"


def saved_by(archive: zipfile.ZipFile) -> str | None:
    """Name of the class that saved the model in ``archive``, or None for a file without the entry.

    :param archive: an open model archive.
    """
    if SAVED_BY_ENTRY not in archive.namelist():
        return None
    return archive.read(SAVED_BY_ENTRY).decode()


def check_model_file(path: str | pathlib.Path | io.BufferedIOBase, cls: type) -> None:
    """Check that ``path`` is a model file that ``cls.load`` can read, before SB3 reads it.

    A file object is read from its current position and put back there.

    :param path: what was given to ``load`` (a path with or without ``.zip``, or a file object).
    :param cls: the class whose ``load`` was called.
    :raises FileNotFoundError: as SB3, for a missing file.
    :raises ModelFileError: for a file that is not a zip archive or is truncated, a damaged entry, an archive without
        SB3's ``data`` entry (not a model file), a damaged ``data`` section, or a model saved by a class that is not
        ``cls`` nor one of its bases.
    """
    name = _describe(path)
    file = open_path(path, "r", suffix="zip")
    start = file.tell()
    try:
        truncated = (
            f"{name} is not a zip archive, or a truncated one (a model file is a zip archive written by save(); an "
            "interrupted save, copy or download cuts off its end): re-save the model, or restore the file from a "
            "backup or the original"
        )
        try:
            archive = zipfile.ZipFile(file)
        except (zipfile.BadZipFile, EOFError) as error:
            raise ModelFileError(f"{truncated} ({error})") from error
        with archive:
            if min((entry.header_offset for entry in archive.infolist()), default=0) > start:
                # the zip found is not at the start: the end of a zip inside the file (a parameters entry, itself a
                # zip written by torch.save) became the end of a truncated file
                raise ModelFileError(truncated)
            if "data" not in archive.namelist():
                raise ModelFileError(
                    f"{name} is a zip archive without a 'data' entry, so it is not a Stable-Baselines3 model file "
                    f"(save() writes one); it holds {archive.namelist()[:10]}. Load a file written by {cls.__name__}"
                    ".save(path)"
                )
            try:
                damaged = archive.testzip()  # the first entry whose checksum fails, or None
            except (zipfile.BadZipFile, EOFError, OSError, zlib.error) as error:
                raise ModelFileError(
                    f"{name} is damaged ({error}): re-save the model, or restore the file from a backup"
                ) from error
            if damaged == "data":
                raise ModelFileError(
                    f"{name} has a damaged data section (the 'data' entry, the model's saved arguments, fails the "
                    "zip checksum: the file was altered after save()): re-save the model, or restore the file from a "
                    "backup"
                )
            if damaged is not None:
                raise ModelFileError(
                    f"{name} is damaged: its entry {damaged!r} fails the zip checksum (the file was altered after "
                    "save()): re-save the model, or restore the file from a backup"
                )
            try:
                json.loads(archive.read("data").decode())
            except (UnicodeDecodeError, json.JSONDecodeError) as error:
                raise ModelFileError(
                    f"{name} has a damaged data section (the 'data' entry, the model's saved arguments, is not the "
                    f"JSON that save() writes: {error}): re-save the model, or restore the file from a backup"
                ) from error
            saver = saved_by(archive)
    finally:
        if isinstance(path, (str, pathlib.Path)):
            file.close()
        else:
            file.seek(start)
    if saver is not None and saver not in {base.__name__ for base in cls.__mro__}:
        raise ModelFileError(
            f"{name} is a model of {saver}, not of {cls.__name__} (it was saved by {saver}): load it with "
            f"{saver}.load(path)"
        )


def refuse_learning_rate_schedule(policy: str, parameter: str, value: Any, algorithm: str) -> None:
    """Refuse a callable where a policy expects ``parameter``: SB3's algorithms pass their learning-rate schedule
    third, so a callable there means that SB3's own ``load`` (``SAC.load``) read a model of ``algorithm``.

    :param policy: the policy class's name.
    :param parameter: the policy's third parameter (``"capacity"``).
    :param value: what it got.
    :param algorithm: the algorithm whose models use this policy (``"CEC"``).
    :raises TypeError: naming ``algorithm.load``, when ``value`` is callable.
    """
    if callable(value):
        raise TypeError(
            f"{policy} got a learning-rate schedule ({value!r}) where its {parameter} goes: a Stable-Baselines3 "
            f"algorithm built it, as SAC.load, DQN.load, ... do for the policy in a file. {policy} is the policy of "
            f"{algorithm}: load {algorithm} models with {algorithm}.load(path)"
        )


class ModelFileMixin:
    """Mix in before an SB3 algorithm: atomic ``save`` that records the class, ``load`` that checks the file
    first (:func:`check_model_file`)."""

    def save(
        self,
        path: str | pathlib.Path | io.BufferedIOBase,
        exclude: Iterable[str] | None = None,
        include: Iterable[str] | None = None,
    ) -> None:
        """SB3's ``save``, written atomically (a crash or kill during the save leaves the previous file intact), with
        the class name in the archive, so that another class's ``load`` of the file says which class to use.

        :param path: file path (``.zip`` added when it has no suffix) or a writable file object.
        :param exclude: names of attributes not to save, besides the default ones.
        :param include: names of attributes to save even though excluded by default.
        """
        if isinstance(path, (str, pathlib.Path)):
            with atomic_file(with_suffix_if_none(path, "zip")) as tmp:
                super().save(tmp, exclude=exclude, include=include)  # type: ignore[misc]
                with zipfile.ZipFile(tmp, mode="a") as archive:
                    archive.writestr(SAVED_BY_ENTRY, type(self).__name__)
            return
        buffer = io.BytesIO()
        super().save(buffer, exclude=exclude, include=include)  # type: ignore[misc]
        with zipfile.ZipFile(buffer, mode="a") as archive:
            archive.writestr(SAVED_BY_ENTRY, type(self).__name__)
        path.write(buffer.getvalue())

    @classmethod
    def load(
        cls: type[SelfModelFileMixin],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfModelFileMixin:
        """SB3's ``load``, after a check of the file that names what is wrong with it (:func:`check_model_file`).

        :param path: file path (with or without ``.zip``) or a file object.
        :param env: the env to run the loaded model on (``None``: predict only, or the saved env).
        :param device: device of the model.
        :param custom_objects: saved attributes to replace instead of deserializing them.
        :param print_system_info: print the system info of the saved model and of this machine.
        :param force_reset: reset the env before the next ``learn``.
        :param kwargs: attributes to change on the loaded model.
        :return: the loaded model.
        :raises ModelFileError: for a file that is not a model of this class (see :func:`check_model_file`).
        """
        check_model_file(path, cls)
        return super().load(  # type: ignore[misc]
            path,
            env=env,
            device=device,
            custom_objects=custom_objects,
            print_system_info=print_system_info,
            force_reset=force_reset,
            **kwargs,
        )
