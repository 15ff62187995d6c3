"""No command writes into the source tree unless asked: each console script of pyproject.toml and each
``python -m`` entry the README and docs/ show runs its default (its cheapest meaningful form: one plant,
--quick, the output folder in tmp where a run needs one) from the repository root, and afterwards the
tree's `git status` (ignored files included) is the same and no tracked file was rewritten, even with
the same bytes (its modification time)."""

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Generated caches that any Python or tool run may leave; not the commands' output.
CACHES = ("__pycache__", ".pytest_cache", ".mypy_cache", ".ruff_cache")

#: (id, arguments of ``python -m``, environment additions, slow?, a file the run must have written
#: outside the tree or a text its stdout must hold). "{tmp}" is the test's tmp_path.
COMMANDS = [
    ("studies --list", ["studies", "--list"], {}, False, ("stdout", "")),
    ("studies.errata", ["studies.errata"], {}, False, ("stdout", "# Errata in the case studies")),
    ("studies.designer --help", ["studies.designer", "--help"], {}, False, ("stdout", "usage:")),
    (
        "studies arm --quick",
        ["studies", "arm", "--quick", "--out", "{tmp}/out"],
        {},
        True,
        ("file", "out/arm/table.md"),
    ),
    (
        "studies.tuner arm",
        ["studies.tuner", "arm", "--max-iter", "1", "--widths", "0.01", "--no-jit", "--force"],
        {"CODESIGN_CONTROL_CACHE": "{tmp}/cache"},
        True,
        ("file", "cache/tuned/arm_tuned_gains.json"),
    ),
    (
        "studies.codesign_open_loop",
        ["studies.codesign_open_loop", "--quick", "--only", "spring_mass", "--samples", "0"],
        {},
        True,
        ("stdout", "# Open-loop co-design"),
    ),
    (
        "studies.codesign_report",
        ["studies.codesign_report", "--only", "arm", "--methods", "sequential"],
        {},
        True,
        ("stdout", "# Co-design"),
    ),
]


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=True).stdout


def tree_state() -> tuple[list[str], dict[str, int]]:
    """The tree's status lines (untracked and ignored entries too, the caches left out) and the modification
    time of every tracked file, ns."""
    status = _git("status", "--porcelain", "--ignored=matching", "--untracked-files=normal")
    lines = sorted(line for line in status.splitlines() if not any(cache in line for cache in CACHES))
    times = {}
    for name in _git("ls-files", "-z").split("\0"):
        path = ROOT / name
        if name and path.is_file() and not path.is_symlink():
            times[name] = path.stat().st_mtime_ns
    return lines, times


@pytest.fixture(scope="module")
def checkout():
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    try:
        _git("rev-parse", "HEAD")
    except (OSError, subprocess.CalledProcessError) as error:
        pytest.skip(f"git does not answer here: {error}")
    return ROOT


def test_every_console_script_is_one_of_the_commands():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["scripts"]
    modules = {target.split(":")[0] for target in scripts.values()}
    covered = {"studies.cli" if args[0] == "studies" else args[0] for _, args, *_ in COMMANDS}
    assert modules <= covered, modules - covered


@pytest.mark.parametrize(
    "args,env,expect",
    [
        pytest.param(args, env, expect, id=name, marks=[pytest.mark.slow] if slow else [])
        for name, args, env, slow, expect in COMMANDS
    ],
)
def test_the_default_run_leaves_the_source_tree_as_it_was(checkout, tmp_path, args, env, expect):
    before = tree_state()
    environment = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", MPLBACKEND="Agg")
    environment["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    environment.update({k: v.format(tmp=tmp_path) for k, v in env.items()})
    done = subprocess.run(
        [sys.executable, "-m", *(a.format(tmp=tmp_path) for a in args)],
        cwd=ROOT,
        env=environment,
        capture_output=True,
        text=True,
        timeout=600,
    )
    # The co-design report exits 1 when a method does not converge; the document is written all the same.
    assert done.returncode in (0, 1) and "Traceback" not in done.stderr, done.stderr[-3000:]
    after = tree_state()
    assert after[0] == before[0], f"the tree's status changed: {set(after[0]) ^ set(before[0])}"
    rewritten = sorted(name for name, t in after[1].items() if before[1].get(name) != t)
    assert not rewritten, f"rewrote {rewritten}"
    kind, what = expect
    if kind == "file":
        assert (tmp_path / what).is_file(), (what, done.stdout[-2000:], done.stderr[-2000:])
    else:
        assert what in done.stdout, done.stdout[:500]
