"""Hyperparameter defaults the RL-Zoo way: one file per algorithm, variants as sections, one lookup for train and
compare (:func:`sb3_gcrl.zoo_config.resolve_config`)."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import pytest
import torch
import yaml

from sb3_gcrl.algorithms import ALGORITHMS
from sb3_gcrl.envs.tasks import TASKS
from sb3_gcrl.zoo_config import (
    THESIS_SUFFIX,
    ZOO_CONFIGS_DIR,
    ConfigNotFoundError,
    config_sections,
    parse_override,
    read_zoo_config,
    resolve_config,
    split_section_key,
)

REPO = Path(__file__).resolve().parents[1]
#: the stock SB3 algorithms this package configures
STOCK = ("sac", "ddpg", "dqn")
FILES = sorted(ZOO_CONFIGS_DIR.glob("*.yml"))
#: (algorithm, env id) of every env section of an algorithm's default file, ours and the stock ones we configure
DEFAULTS = [
    (algo, env_id)
    for algo in sorted(ALGORITHMS) + list(STOCK)
    for env_id in config_sections(ZOO_CONFIGS_DIR / f"{algo}.yml")
]
#: (file, section key) of every section of every shipped file
SECTIONS = [(path.stem, key) for path in FILES for key in read_zoo_config(path)]


def test_one_file_per_algorithm_and_the_thesis_scale_beside_it() -> None:
    names = {path.stem for path in FILES}
    assert set(ALGORITHMS) | set(STOCK) == {name.removesuffix(THESIS_SUFFIX) for name in names}
    assert {name for name in names if name.endswith(THESIS_SUFFIX)} == {"morefree_thesis", "ibc_thesis"}
    for thesis in ("morefree", "ibc"):  # every section at the thesis's scale; CPU presets only where measured
        thesis_keys = read_zoo_config(ZOO_CONFIGS_DIR / f"{thesis}_thesis.yml").keys()
        cpu_keys = read_zoo_config(ZOO_CONFIGS_DIR / f"{thesis}.yml").keys()
        assert cpu_keys < thesis_keys
        assert {split_section_key(key)[0] for key in cpu_keys} == {"GCRL/PointUMazeGoal-v0", "GCRL/Tabletop-v0"}
        assert {split_section_key(key)[0] for key in thesis_keys} == {
            env_id for env_id, task in TASKS.items() if task.reset_free
        }


@pytest.mark.parametrize(("algo", "env_id"), DEFAULTS, ids=[f"{a}-{e}" for a, e in DEFAULTS])
def test_train_and_compare_find_the_default_section_without_a_config(algo: str, env_id: str) -> None:
    from sb3_gcrl.cli import resolve_train_config
    from sb3_gcrl.compare.methods import parse_method

    resolved = resolve_config(algo, env_id)
    assert resolved.path == ZOO_CONFIGS_DIR / f"{algo}.yml" and resolved.key == env_id and resolved.variant is None
    argv, trained = resolve_train_config(["--algo", algo, "--env", env_id])
    assert argv[-2:] == ["-conf", str(resolved.path)] and trained == resolved
    assert parse_method(algo).resolve(env_id) == resolved
    for variant in config_sections(resolved.path)[env_id]:
        assert resolve_config(algo, env_id, variant).key == f"{env_id}@{variant}"
        assert parse_method(f"{algo}@{variant}").resolve(env_id).hyperparams == resolved_variant(algo, env_id, variant)


def resolved_variant(algo: str, env_id: str, variant: str) -> dict:
    return read_zoo_config(ZOO_CONFIGS_DIR / f"{algo}.yml")[f"{env_id}@{variant}"]


def test_the_thesis_scale_is_a_named_file_and_the_next_default() -> None:
    cpu = resolve_config("morefree", "GCRL/PointUMazeGoal-v0", "peg")
    thesis = resolve_config("morefree", "GCRL/PointUMazeGoal-v0", "peg", "morefree_thesis")
    assert thesis.path.name == "morefree_thesis.yml" and thesis.key == cpu.key
    assert thesis.hyperparams["batch_size"] > cpu.hyperparams["batch_size"]
    assert thesis.hyperparams["env_wrapper"] == cpu.hyperparams["env_wrapper"]  # the same method, other sizes
    assert resolve_config("ibc", "GCRL/Tabletop-v0", config="ibc_thesis").hyperparams["batch_size"] == 512


def test_the_thesis_file_is_searched_after_the_default_then_rl_zoos_own(tmp_path: Path) -> None:
    (tmp_path / "algo_x.yml").write_text("A-v0: {n: 1}\n")
    (tmp_path / "algo_x_thesis.yml").write_text("A-v0: {n: 2}\nB-v0: {n: 3}\n")
    assert resolve_config("algo_x", "A-v0", config_dir=tmp_path).hyperparams == {"n": 1}
    with warnings.catch_warnings(record=True) as caught:  # the GPU-scale file on a machine without CUDA says so
        warnings.simplefilter("always")
        assert resolve_config("algo_x", "B-v0", config_dir=tmp_path).hyperparams == {"n": 3}
    assert [str(w.message) for w in caught if "no CPU preset" in str(w.message)] == (
        [] if torch.cuda.is_available() else [str(caught[-1].message)]
    )
    with warnings.catch_warnings():  # a file named by the user: no warning
        warnings.simplefilter("error")
        resolve_config("algo_x", "B-v0", config="algo_x_thesis", config_dir=tmp_path)
    sac = resolve_config("sac", "Pendulum-v1", config_dir=tmp_path)  # stock algorithm, stock env: RL-Zoo's file
    assert sac.path.parent.name == "hyperparams" and sac.key == "Pendulum-v1"
    assert resolve_config("sac", "Pendulum-v1").path.parent.name == "hyperparams"


def test_missing_env_and_missing_variant_name_the_files_envs_and_variants() -> None:
    with pytest.raises(ConfigNotFoundError) as error:
        resolve_config("morefree", "GCRL/PointUMaze-v0")
    message = str(error.value)
    assert "morefree.yml covers" in message and "morefree_thesis.yml covers" in message
    assert "GCRL/PointUMazeGoal-v0" in message and "Add a section 'GCRL/PointUMaze-v0'" in message
    with pytest.raises(ConfigNotFoundError, match=r"variants of GCRL/Tabletop-v0: \['peg'\] \(did you mean 'peg'"):
        resolve_config("morefree", "GCRL/Tabletop-v0", "pg")
    with pytest.raises(ConfigNotFoundError, match="variant 'wo_bf'.*variants of GCRL/Tabletop-v0: \\['peg'\\]"):
        resolve_config("morefree", "GCRL/Tabletop-v0", "wo_bf")
    from sb3_gcrl.cli import main

    with pytest.raises(SystemExit, match=r"sb3-gcrl train: .*variants of GCRL/PointUMazeGoal-v0: \['oracle', "):
        main(["train", "--algo", "sac", "--env", "GCRL/PointUMazeGoal-v0", "--variant", "no_such"])
    from sb3_gcrl.compare import compare

    with pytest.raises(ValueError, match="Method 'morefree_peg': .*sac|Method 'morefree_peg': .*covers"):
        compare(["morefree@peg"], ["GCRL/PointUMaze-v0"], seeds=[0], n_timesteps=10, output="unused")


@pytest.mark.parametrize(("file", "key"), SECTIONS, ids=[f"{f}-{k}" for f, k in SECTIONS])
def test_every_section_is_accepted_by_its_algorithm(file: str, key: str) -> None:
    from sb3_gcrl.zoo_checks import check_hyperparameters, check_mode_switching_callbacks

    section = read_zoo_config(ZOO_CONFIGS_DIR / f"{file}.yml")[key]
    check_hyperparameters(file.removesuffix(THESIS_SUFFIX), section, f"{file}.yml ({key})")
    check_mode_switching_callbacks(section, f"{file}.yml ({key})")


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_every_file_starts_with_what_it_holds_and_how_to_run_it(path: Path) -> None:
    text = path.read_text()
    header = text[: text.index("\n\n")]
    assert all(line.startswith("#") for line in header.splitlines())
    algo = path.stem.removesuffix(THESIS_SUFFIX)
    assert re.search(rf"Run: sb3-gcrl train --algo {algo} --env \S+", header)
    assert "thesis" in header.lower() or "not in the thesis" in header
    for env_id, variants in config_sections(path).items():
        assert env_id in header, f"{path.name}: env section {env_id} not named in the header"
        for variant in variants:
            assert variant in header, f"{path.name}: variant {variant} not named in the header"
    if any(config_sections(path).values()):
        assert "--variant" in header


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_a_variant_states_only_what_differs(path: Path) -> None:
    """Each variant section merges its env's section (or another section of the file) and restates few keys, unless
    it is itself the base that other sections merge (the episodic oracle of MoReFree-SAC, the post-exploration SAC)."""
    text = path.read_text()
    anchors = {anchor: key for key, anchor in re.findall(r"^(\S+): &(\w+)", text, re.M)}  # anchor -> its section
    for key in read_zoo_config(path):
        _, variant = split_section_key(key)
        if variant is None:
            continue
        block = re.search(rf"^{re.escape(key)}:(.*?)(?=^\S|\Z)", text, re.M | re.S)
        assert block is not None, key
        body = block.group(1)
        merged = re.findall(r"<<: \*(\w+)", body) + re.findall(r"^ \*(\w+)", body)
        if merged:
            same_env = [anchors.get(name, "").partition("@")[0] == key.partition("@")[0] for name in merged]
            if any(same_env):  # a variant of its env's settings (not the settings of another env, shared)
                assert len(body.strip().splitlines()) <= 8, f"{path.name} {key} restates too much"
        else:
            anchor = re.match(r" &(\w+)", body)
            assert anchor and f"<<: *{anchor.group(1)}" in text, f"{path.name} {key} merges nothing, nor is merged"


def test_variants_are_written_keyed_by_the_env_id_for_rl_zoo(tmp_path: Path) -> None:
    resolved = resolve_config("tabular_2m", "GCRL/WindyGrid-v0", "no_sharing")
    assert not resolved.rl_zoo_reads_it
    path = resolved.zoo_file(tmp_path)
    assert path.parent == tmp_path and resolved.digest in path.name
    assert yaml.safe_load(path.read_text()) == {"GCRL/WindyGrid-v0": resolved.hyperparams}
    assert resolved.zoo_file(tmp_path) == path  # named by content: written once
    default = resolve_config("tabular_2m", "GCRL/WindyGrid-v0")
    assert default.zoo_file(tmp_path) == default.path and default.digest != resolved.digest


def test_compare_specs_with_variants_and_their_labels() -> None:
    from sb3_gcrl.compare.methods import method_label, parse_method

    assert method_label("morefree@peg") == "morefree_peg"
    assert method_label("peg_world_model=morefree@peg") == "peg_world_model"
    assert method_label("morefree@peg:morefree_thesis") == "morefree_thesis_peg"
    method = parse_method("morefree@peg:morefree_thesis")
    assert method.variant == "peg" and method.config == ZOO_CONFIGS_DIR / "morefree_thesis.yml"


def test_the_run_digest_covers_the_resolved_section(tmp_path: Path) -> None:
    """A changed variant is never silently reused: each section has its own digest, stored with the run."""
    from sb3_gcrl.compare.comparison import plan_runs
    from sb3_gcrl.compare.methods import parse_method

    methods = [parse_method(spec) for spec in ("sac", "sac@naive", "sac@oracle")]
    specs = plan_runs(
        methods, ["GCRL/PointUMazeGoal-v0"], [0], 100, 50, 1, {}, (), ZOO_CONFIGS_DIR, config_folder=tmp_path
    )
    digests = {spec.method: spec.config_digest for spec in specs}
    assert len(set(digests.values())) == 3
    assert digests["sac"] == resolve_config("sac", "GCRL/PointUMazeGoal-v0").digest
    assert specs[0].config == str(ZOO_CONFIGS_DIR / "sac.yml")  # RL-Zoo reads the env's own section there
    naive = Path(specs[1].config)
    assert naive.parent == tmp_path  # a variant's section, keyed by the plain env id
    assert yaml.safe_load(naive.read_text())["GCRL/PointUMazeGoal-v0"]["replay_buffer_class"] == "HerReplayBuffer"
    # an edited section gets another digest, so a finished run with the old one is not taken for it
    config = tmp_path / "edited.yml"
    sections = read_zoo_config(ZOO_CONFIGS_DIR / "sac.yml")
    sections["GCRL/PointUMazeGoal-v0@naive"] = {**sections["GCRL/PointUMazeGoal-v0@naive"], "gamma": 0.9}
    config.write_text(yaml.safe_dump(json.loads(json.dumps(sections))))
    edited = plan_runs(
        [parse_method(f"sac@naive:{config}")], ["GCRL/PointUMazeGoal-v0"], [0], 100, 50, 1, {}, (), ZOO_CONFIGS_DIR,
        config_folder=tmp_path,
    )  # fmt: skip
    assert edited[0].config_digest != digests["sac_naive"]


def test_train_with_a_variant_writes_its_section_to_the_run(tmp_path: Path) -> None:
    """``sb3-gcrl train --variant``: the section, keyed by the plain env id, lives with the run (``--resume`` reads it
    back); without ``-conf``, from the algorithm's default file."""
    from sb3_gcrl.cli import main
    from sb3_gcrl.zoo_train import ARGUMENTS_FILE, CONFIG_FILE

    logs = tmp_path / "logs"
    argv = ["train", "--algo", "tabular_2m", "--env", "GCRL/WindyGrid-v0", "--variant", "no_sharing", "-n", "200"]
    assert main([*argv, "--eval-freq", "-1", "-f", str(logs), "--seed", "0"]) == 0
    params = logs / "tabular_2m" / "GCRL-WindyGrid-v0_1" / "GCRL-WindyGrid-v0"
    written = yaml.safe_load((params / CONFIG_FILE).read_text())
    assert written == {"GCRL/WindyGrid-v0": resolve_config("tabular_2m", "GCRL/WindyGrid-v0", "no_sharing").hyperparams}
    assert "- - data_sharing\n    - false" in (params / "config.yml").read_text()  # what RL-Zoo read and used
    arguments = json.loads((params / ARGUMENTS_FILE).read_text())
    assert "--variant" not in arguments and arguments[arguments.index("-conf") + 1] == str(params / CONFIG_FILE)


def test_train_a_variant_of_the_world_model_agent_at_a_tiny_size(tmp_path: Path) -> None:
    """``sb3-gcrl train --algo morefree --variant peg`` (reset-free PEG) without ``-conf``, tiny and uncompiled."""
    from sb3_gcrl.cli import main
    from sb3_gcrl.zoo_train import CONFIG_FILE

    tiny = [
        "learning_starts:300", "compile_train_step:False", "batch_size:4", "batch_length:8", "imagination_horizon:3",
        "imagination_starts:8", "peg_samples:10",
        "policy_kwargs:dict(deter=8, stoch=4, rssm_hidden=8, model_hidden=8, model_layers=1, head_hidden=8, "
        "head_layers=1, ensemble_size=2, ensemble_hidden=8)",
    ]  # fmt: skip
    argv = ["train", "--algo", "morefree", "--env", "GCRL/PointUMazeGoal-v0", "--variant", "peg", "-n", "400"]
    assert main([*argv, "--eval-freq", "-1", "-f", str(tmp_path), "--seed", "0", "-params", *tiny]) == 0
    run = tmp_path / "morefree" / "GCRL-PointUMazeGoal-v0_1"
    assert (run / "GCRL-PointUMazeGoal-v0.zip").is_file()
    (section,) = yaml.safe_load((run / "GCRL-PointUMazeGoal-v0" / CONFIG_FILE).read_text()).values()
    assert section["env_wrapper"][1]["sb3_gcrl.morefree.morefree_go_explore"]["alpha"] == 0.0


def test_plain_rl_zoo3_train_reads_the_env_section_of_an_algorithm_file(tmp_path: Path) -> None:
    """``rl_zoo3 train --algo sac --env GCRL/PointUMazeGoal-v0 -conf zoo_configs/sac.yml``: RL-Zoo picks the exact
    env-id key (MoReFree-SAC) and ignores the ``<env id>@<variant>`` keys."""
    import subprocess
    import sys

    cmd = [
        sys.executable, "-m", "rl_zoo3.train", "--algo", "sac", "--env", "GCRL/PointUMazeGoal-v0", "--gym-packages",
        "sb3_gcrl", "-conf", str(REPO / "zoo_configs" / "sac.yml"), "-n", "400", "--eval-freq", "-1", "--seed", "0",
        "-f", str(tmp_path), "-params", "learning_starts:350", "batch_size:8", "policy_kwargs:dict(net_arch=[8])",
    ]  # fmt: skip
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    saved = tmp_path / "sac" / "GCRL-PointUMazeGoal-v0_1" / "GCRL-PointUMazeGoal-v0" / "config.yml"
    assert "TaskRelevantHerReplayBuffer" in saved.read_text()  # MoReFree-SAC's own buffer: its default section


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("projection_dim:None", ("projection_dim", None)),  # RL-Zoo's -params spelling, not the string "None"
        ("n_timesteps:1e5", ("n_timesteps", 100_000.0)),  # YAML 1.1 would keep "1e5" a string
        ("goal:(1.0, 0.5)", ("goal", (1.0, 0.5))),
        ("net_arch:[64, 64]", ("net_arch", [64, 64])),
        ("policy:MlpPolicy", ("policy", "MlpPolicy")),  # a bare word: YAML
        ("projection_dim:null", ("projection_dim", None)),
        ("policy_kwargs:{net_arch: [64]}", ("policy_kwargs", {"net_arch": [64]})),
        ("policy_kwargs:dict(net_arch=[64])", ("policy_kwargs", "dict(net_arch=[64])")),  # RL-Zoo evaluates it
        ("url:http://host:80", ("url", "http://host:80")),
    ],
)
def test_an_override_reads_python_literals_then_yaml(text: str, expected: tuple) -> None:
    assert parse_override(text) == expected


@pytest.mark.parametrize("text", ["learning_rate", ":0.1"])
def test_an_override_without_key_or_colon_is_refused(text: str) -> None:
    with pytest.raises(ValueError, match="expected key:value"):
        parse_override(text)
