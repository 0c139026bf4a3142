"""The package's argument checks (sb3_gcrl.common.validation): one module, messages that name the parameter and fix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.env_util import make_vec_env
from test_wrappers import LineGoalEnv

from sb3_gcrl.common.validation import (
    check_bool,
    check_choice,
    check_finite_returns,
    check_finite_rewards,
    check_float,
    check_int,
    check_n_sampled_goal,
    check_optional_int,
    check_saved_rows,
    check_unit_interval,
)
from sb3_gcrl.her import ExecutedActionHerReplayBuffer, TaskRelevantHerReplayBuffer


@pytest.mark.parametrize(
    "value, error, message",
    [
        (1.7, ValueError, r"capacity must be an integer, got 1.7 \(not truncated\); pass e.g. capacity=2"),
        (0, ValueError, r"capacity must be >= 1, got 0"),
        (float("inf"), ValueError, r"capacity must be a finite integer, got inf"),
        (True, TypeError, r"capacity must be an integer, got True of type bool"),
        ("10", TypeError, r"capacity must be an integer, got '10' of type str"),
    ],
)
def test_check_int_names_the_parameter_and_the_fix(value: object, error: type, message: str) -> None:
    with pytest.raises(error, match=f"^{message}$"):
        check_int("capacity", value)


def test_check_int_accepts_integral_floats_and_none_where_optional() -> None:
    assert check_int("capacity", 1e6) == 1_000_000 and isinstance(check_int("capacity", np.int64(3)), int)
    assert check_optional_int("projection_dim", None) is None
    assert check_int("learning_starts", 0, minimum=0) == 0


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"value": float("nan")}, r"tau must be a finite number, got nan"),
        ({"value": 0.0, "minimum": 0.0, "exclusive_minimum": True}, r"tau must be > 0.0, got 0.0"),
        ({"value": -1.0, "minimum": 0.0}, r"tau must be >= 0.0, got -1.0"),
        ({"value": 2.0, "maximum": 1.0}, r"tau must be <= 1.0, got 2.0"),
    ],
)
def test_check_float_messages(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=f"^{message}$"):
        check_float("tau", **kwargs)


@pytest.mark.parametrize("value", [1.5, -0.1, float("nan"), "0.5", True, None])
def test_check_unit_interval_is_a_value_error_naming_the_interval(value: object) -> None:
    with pytest.raises(ValueError, match=rf"^gamma must be a number in \[0, 1\], got {value!r}$"):
        check_unit_interval("gamma", value)


def test_check_unit_interval_can_exclude_zero() -> None:
    assert check_unit_interval("gamma", np.float32(0.5)) == 0.5 and check_unit_interval("gamma", 0) == 0.0
    with pytest.raises(ValueError, match=r"^learning_rate must be a number in \(0, 1\], got 0$"):
        check_unit_interval("learning_rate", 0, exclude_zero=True)


def test_check_bool_refuses_strings_and_numbers() -> None:
    assert check_bool("memory_update_truncated", np.bool_(False)) is False
    for value in ("false", 0, None):
        with pytest.raises(ValueError, match=rf"^post_exploration must be True or False, got {value!r}$"):
            check_bool("post_exploration", value)


def test_check_choice_lists_the_choices() -> None:
    assert check_choice("knn_backend", "flat", ("auto", "kdtree", "flat")) == "flat"
    with pytest.raises(ValueError, match=r"^knn_backend must be 'auto', 'kdtree' or 'flat', got 'annoy'$"):
        check_choice("knn_backend", "annoy", ("auto", "kdtree", "flat"))
    with pytest.raises(ValueError, match=r"^render_mode must be None or 'rgb_array', got 'human'$"):
        check_choice("render_mode", "human", (None, "rgb_array"))


@pytest.mark.parametrize("value", [-1, -3, 2.5, "4", float("nan"), None])
def test_check_n_sampled_goal_names_the_range(value: object) -> None:
    message = rf"^n_sampled_goal must be an integer >= 0 \(relabeled goals .* got {value!r}$"
    with pytest.raises(ValueError, match=message):
        check_n_sampled_goal(value)
    with pytest.raises(ValueError, match=r"integer >= 1 .* got 0; alpha needs relabeled goals$"):
        check_n_sampled_goal(0, minimum=1, why="; alpha needs relabeled goals")
    assert check_n_sampled_goal(4.0) == 4


@pytest.mark.parametrize("buffer_class", [ExecutedActionHerReplayBuffer, TaskRelevantHerReplayBuffer])
def test_n_sampled_goal_minus_one_is_a_value_error_at_construction(buffer_class: type) -> None:
    """SB3's HerReplayBuffer computes 1 / (n_sampled_goal + 1): -1 must fail before, with the valid range."""
    env = make_vec_env(LineGoalEnv, n_envs=1, seed=0)
    kwargs: dict = {"n_sampled_goal": -1}
    if buffer_class is TaskRelevantHerReplayBuffer:
        kwargs["task_goal_ratio"] = 0.0
    with pytest.raises(ValueError, match=r"^n_sampled_goal must be an integer >= 0 .*got -1$"):
        SAC("MultiInputPolicy", env, replay_buffer_class=buffer_class, replay_buffer_kwargs=kwargs)


def test_finite_checks_name_the_source_and_vec_check_nan() -> None:
    check_finite_rewards(np.array([0.0, 1.0]), "at timestep 3", "it would spread")
    with pytest.raises(ValueError, match=r"^Env 1 returned the reward nan at timestep 3: it would spread; .*VecCheck"):
        check_finite_rewards(np.array([0.0, np.nan]), "at timestep 3", "it would spread")
    with pytest.raises(ValueError, match=r"Episode returns contain inf \(1 non-finite of 2\).*VecCheckNan"):
        check_finite_returns(np.array([0.0, np.inf]))


def test_check_saved_rows_says_what_is_wrong() -> None:
    state = {"keys": np.zeros((2, 3)), "values": np.zeros(2), "last_update": np.zeros(2), "clock": 1}
    assert check_saved_rows(state, "CECMemory", 3, 10, ["values"]).shape == (2, 3)
    with pytest.raises(ValueError, match=r"Saved CECMemory keys have shape \(2, 3\), this memory expects \(n, 4\)"):
        check_saved_rows(state, "CECMemory", 4, 10, ["values"])
    with pytest.raises(ValueError, match=r"Saved CECMemory has 2 rows, more than capacity=1; raise the capacity"):
        check_saved_rows(state, "CECMemory", 3, 1, ["values"])
    with pytest.raises(ValueError, match=r"Saved CECMemory state lacks \['actions'\]"):
        check_saved_rows(state, "CECMemory", 3, 10, ["values", "actions"])


def test_an_output_folder_is_checked_without_creating_it(tmp_path: Path) -> None:
    from sb3_gcrl.common.validation import check_writable_folder

    folder = tmp_path / "a" / "b"
    assert check_writable_folder("the output folder", folder) == folder
    assert list(tmp_path.iterdir()) == []  # probed in the nearest existing parent, nothing left
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match=r"file is a file, not a folder; pass another output folder"):
        check_writable_folder("the output folder", tmp_path / "file" / "out")
