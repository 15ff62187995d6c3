"""README.md stays short and starts with its two commands; every Python block of README.md and of
docs/guide.md (where the README's long examples live) runs on its own, in a fresh interpreter and an empty folder."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
README = (REPO / "README.md").read_text(encoding="utf-8")
#: The most characters README.md may hold: the rest goes to docs/.
README_LIMIT = 6000
BLOCKS = [
    block
    for page in ("README.md", "docs/guide.md")
    for block in re.findall(r"```python\n(.*?)```", (REPO / page).read_text(encoding="utf-8"), re.S)
]
#: Blocks that run studies, Dask or tuning take a minute or more: they run with the slow tests.
LONG = ("studies.run(", "tune(", "LocalCluster(")


def test_the_readme_is_short_and_starts_with_its_two_commands():
    assert len(README) <= README_LIMIT, len(README)
    first, second = [line for line in README.splitlines() if line.strip()][:2]
    assert first.startswith("Run the studies: `") and "pip install -e ." in first and "-m studies`" in first
    assert second.startswith("Run the tests: `") and "-m pytest`" in second


def test_the_readme_links_resolve():
    for target in re.findall(r"\]\(([^)#]+)\)", README):
        if not target.startswith(("http://", "https://")):
            assert (REPO / target).exists(), target


def test_the_readme_has_python_blocks():
    assert len(BLOCKS) >= 5


@pytest.mark.parametrize(
    "index",
    [
        pytest.param(i, marks=[pytest.mark.slow] if any(k in b for k in LONG) else [], id=f"block{i}")
        for i, b in enumerate(BLOCKS)
    ],
)
def test_each_readme_block_runs_on_its_own(index, tmp_path):
    env = dict(
        os.environ,
        MPLBACKEND="Agg",
        PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
    )
    done = subprocess.run(
        [sys.executable, "-c", BLOCKS[index]], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1800
    )
    assert done.returncode == 0, f"README block {index}:\n{BLOCKS[index]}\n{done.stderr[-3000:]}"
