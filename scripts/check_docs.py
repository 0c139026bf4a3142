"""Run every example of the README and docs as written, at tiny budgets, and report which ones fail.

Every fenced ``python`` block is run as a script and every command of a ``bash`` block through ``bash``, in the
order of the file, in a scratch folder holding links to this clone's ``zoo_configs/``, ``scripts/``, ``docs/`` and
``README.md`` (so relative paths resolve as in a clone and the outputs land outside it). ``pip install`` set-up is
skipped (the package is installed already), and so is the test command (CI runs it).

Only the budgets are cut: budgets stated in a training command or script (``-n``, ``--steps``, ``--budget``,
``n_timesteps=``; evaluations and checkpoints then every half budget) are set to ``--steps`` env steps, and a
``sitecustomize`` put on ``PYTHONPATH`` of every process (compare's workers included) caps what each ``learn`` call
trains at ``--steps``, through SB3's ``_setup_learn``, which every algorithm of SB3 and of this package calls; the
rest runs as written (construction, wrappers, configs, evaluation, saving, plots). No display: ``MPLBACKEND=Agg``
and no ``DISPLAY``.

Example::

    python scripts/check_docs.py                      # all files; about 15-25 min on 2 cores
    python scripts/check_docs.py README.md docs/morefree.md --steps 200
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: what the scratch folder links to
LINKED = ("zoo_configs", "scripts", "docs", "README.md", "sb3_gcrl")

SITECUSTOMIZE = """
import os

def _cap_learn_budgets():
    from stable_baselines3.common.base_class import BaseAlgorithm

    cap = int(os.environ["SB3_GCRL_DOCS_STEPS"])
    setup = BaseAlgorithm._setup_learn

    def _setup_learn(self, total_timesteps, *args, **kwargs):
        total, callback = setup(self, min(int(total_timesteps), cap), *args, **kwargs)
        return total, callback

    BaseAlgorithm._setup_learn = _setup_learn

try:
    _cap_learn_budgets()
except ImportError:
    pass
"""

FENCE = re.compile(r"^```(\w+)\s*$")


def blocks(path: Path) -> list[tuple[str, int, str]]:
    """The ``python`` and ``bash`` blocks of a Markdown file: ``(language, first line number, text)``."""
    out, language, start, lines = [], None, 0, []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if language is None:
            match = FENCE.match(line)
            if match and match.group(1) in ("python", "bash"):
                language, start, lines = match.group(1), number + 1, []
        elif line.startswith("```"):
            out.append((language, start, "\n".join(lines) + "\n"))
            language = None
        else:
            lines.append(line)
    return out


def commands(text: str) -> list[str]:
    """The commands of a bash block: continuation lines joined, comments and ``pip install`` set-up left out."""
    joined = re.sub(r"\\\n\s*", " ", text)
    out = []
    for line in joined.splitlines():
        line = line.split("  #")[0].split(" # ")[0].strip()
        if not line or line.startswith("#"):
            continue
        # "pip install ... && command": keep what follows the set-up
        parts = [part.strip() for part in line.split("&&") if not part.strip().startswith("pip install")]
        parts = [part for part in parts if not part.startswith(("python -m venv", ". .venv", "source "))]
        parts = [part for part in parts if "pytest" not in part]  # the test suite: CI runs it
        if parts:
            out.append(" && ".join(parts))
    return out


BUDGET_FLAG = re.compile(r"(?<=\s)(-n|--n-timesteps|--steps|--budget)\s+[\d_.e]+")
EVAL_FLAG = re.compile(r"(?<=\s)--eval-freq\s+[\d_.e]+")
#: commands whose budget flags are rewritten (``-n`` means something else to other tools, e.g. pytest's workers)
TRAINING_COMMANDS = ("sb3-gcrl ", "rl_zoo3 ", "python scripts/")
SAVE_FLAG = re.compile(r"(?<=\s)--save-freq\s+[\d_.e]+")


def shrink_budgets(example: str, language: str, steps: int) -> str:
    """``example`` with its stated budgets set to ``steps`` (evaluations and checkpoints every ``steps // 2``), so
    that tools that check a run reached its budget (``sb3-gcrl compare``) see it reached."""
    every = max(steps // 2, 1)
    if language == "python":
        example = re.sub(r"\bn_timesteps=[\d_.e]+", f"n_timesteps={steps}", example)
        return re.sub(r"\beval_freq=[\d_.e]+", f"eval_freq={every}", example)
    if not example.startswith(TRAINING_COMMANDS):
        return example
    stated = BUDGET_FLAG.search(example) is not None
    example = BUDGET_FLAG.sub(lambda m: f"{m.group(1)} {steps}", example)
    example = SAVE_FLAG.sub(f"--save-freq {every}", EVAL_FLAG.sub(f"--eval-freq {every}", example))
    if "sb3-gcrl compare" in example:
        example += "" if stated else f" -n {steps}"
        example += "" if EVAL_FLAG.search(example) else f" --eval-freq {every}"
    elif "reproduce_ch3.py" in example and "--analyse-only" not in example:
        example += "" if stated else f" --steps {steps}"
        example += "" if EVAL_FLAG.search(example) else f" --eval-freq {every}"
    return example


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("files", nargs="*", type=Path, help="Markdown files (default: README.md and docs/*.md)")
    parser.add_argument("--steps", type=int, default=1000, help="env steps each learn() call trains at most")
    parser.add_argument("--timeout", type=int, default=900, help="seconds per example")
    args = parser.parse_args()
    files = args.files or [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    results = []
    with tempfile.TemporaryDirectory() as temp:
        site = Path(temp) / "site"
        site.mkdir()
        (site / "sitecustomize.py").write_text(SITECUSTOMIZE)
        env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
        env.update(
            PYTHONPATH=os.pathsep.join([str(site), env.get("PYTHONPATH", "")]),
            SB3_GCRL_DOCS_STEPS=str(args.steps),
            MPLBACKEND="Agg",
        )
        for path in files:
            work = Path(temp) / path.stem
            work.mkdir()
            for name in LINKED:
                (work / name).symlink_to(ROOT / name)
            for language, line, text in blocks(path):
                examples = [(line, text)] if language == "python" else [(line, c) for c in commands(text)]
                for number, example in examples:
                    example = shrink_budgets(example, language, args.steps)
                    if language == "python":
                        script = work / f"example_{number}.py"
                        script.write_text(example)
                        command = [sys.executable, str(script)]
                    else:
                        command = ["bash", "-euo", "pipefail", "-c", example]
                    started = time.perf_counter()
                    try:
                        done = subprocess.run(
                            command, cwd=work, env=env, capture_output=True, text=True, timeout=args.timeout
                        )
                        ok, tail = done.returncode == 0, (done.stdout + done.stderr)[-1500:]
                    except subprocess.TimeoutExpired:
                        ok, tail = False, f"timed out after {args.timeout} s"
                    seconds = time.perf_counter() - started
                    first = "".join(c for c in example.strip().splitlines()[0][:70] if c.isprintable())
                    name = f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{number}"
                    results.append((name, language, first, ok, seconds, tail))
                    print(f"{'ok  ' if ok else 'FAIL'} {seconds:6.1f}s {name:28s} {first}", flush=True)
    failed = [r for r in results if not r[3]]
    print(f"\n{len(results) - len(failed)} of {len(results)} examples ran as written (budgets capped at {args.steps})")
    for name, _, first, _, _, tail in failed:
        print(f"\n--- FAIL {name}: {first}\n{tail}")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
