"""The output folder owns only what it made (issue 31, class 3): a plant folder holding files no run of
ours wrote is refused, never deleted; a symlinked plant folder is replaced where it points, with no
hidden leftover; a staging folder left by a dead run is removed by the next one, and one it cannot
judge is named."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import pytest
from conftest import subprocess_env

import studies
from studies import runner, writers

STEP_ONLY = runner.Options(scenarios=("step",), mc=0)
THESIS = "\\documentclass{article} my thesis, three years of work\n"


@pytest.fixture(scope="module")
def arm_result():
    """A step-only study of the arm with one LQR (a few seconds)."""
    return runner.run_study(
        dataclasses.replace(studies.get("arm"), providers=("example_providers:lqr_only",)), STEP_ONLY
    )


def hidden(folder: Path) -> list[str]:
    """Names of the hidden entries of `folder`."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def staged_plant(tmp_path: Path, name: str = "uuv", text: str = "# the new run\n") -> Path:
    """A staging folder holding one plant folder of a run: a table.md and the run.json listing it (they
    stand for a study's files)."""
    staging = tmp_path / "out" / ".run-new.partial"
    (staging / name).mkdir(parents=True)
    (staging / name / "table.md").write_text(text)
    record = {"run_id": "new", "sha256": {"table.md": writers.file_digest(staging / name / "table.md")}}
    (staging / name / "run.json").write_text(json.dumps(record))
    return staging


# ---------------------------------------------------------------------------- a user's files
def test_publish_refuses_a_plant_folder_without_our_run_json_and_deletes_nothing(tmp_path):
    staging = staged_plant(tmp_path)
    out = tmp_path / "out"
    (out / "uuv").mkdir()
    (out / "uuv" / "my_thesis.tex").write_text(THESIS)
    with pytest.raises(writers.ForeignFolderError) as refused:
        writers.publish(staging, out, ["uuv"], "new")
    message = str(refused.value)
    assert str(out / "uuv") in message and "my_thesis.tex" in message and "run.json" in message
    assert refused.value.folders == {out / "uuv": ["my_thesis.tex"]}
    assert (out / "uuv" / "my_thesis.tex").read_text() == THESIS
    assert sorted(p.name for p in (out / "uuv").iterdir()) == ["my_thesis.tex"]
    assert not (out / "summary.md").exists() and (staging / "uuv" / "table.md").exists()  # nothing published


def test_publish_replaces_nothing_when_one_of_the_plants_is_refused(tmp_path, arm_result):
    """All or nothing: the arm's folder (ours) is not replaced either when the uuv's is refused."""
    out = tmp_path / "out"
    writers.write_study(arm_result, out, run_id="earlier")
    before = (out / "arm" / "run.json").read_text()
    staging = staged_plant(tmp_path)
    writers.write_study(arm_result, staging, run_id="new")
    (out / "uuv").mkdir()
    (out / "uuv" / "notes.txt").write_text("mine")
    with pytest.raises(writers.ForeignFolderError, match="notes.txt"):
        writers.publish(staging, out, ["arm", "uuv"], "new")
    assert (out / "arm" / "run.json").read_text() == before
    assert (out / "uuv" / "notes.txt").read_text() == "mine"


def test_write_study_refuses_a_users_folder_before_writing_anything(tmp_path, arm_result):
    out = tmp_path / "out"
    (out / "arm").mkdir(parents=True)
    (out / "arm" / "my_thesis.tex").write_text(THESIS)
    with pytest.raises(writers.ForeignFolderError, match=r"my_thesis\.tex"):
        writers.write_study(arm_result, out, run_id="new")
    assert sorted(p.name for p in (out / "arm").iterdir()) == ["my_thesis.tex"]
    assert (out / "arm" / "my_thesis.tex").read_text() == THESIS
    assert sorted(p.name for p in out.iterdir()) == ["arm"]  # no staging folder left


def test_a_file_added_to_our_folder_is_not_ours_either(tmp_path, arm_result):
    """Our run.json owns the files of its manifest (changed or not); a file it does not list is refused."""
    out = tmp_path / "out"
    writers.write_study(arm_result, out, run_id="first")
    (out / "arm" / "table.md").write_text("edited by hand")  # ours, though changed: replaced
    writers.write_study(arm_result, out, run_id="second")
    assert json.loads((out / "arm" / "run.json").read_text())["run_id"] == "second"
    (out / "arm" / "my_notes.md").write_text("mine")
    with pytest.raises(writers.ForeignFolderError, match=r"my_notes\.md"):
        writers.write_study(arm_result, out, run_id="third")
    assert (out / "arm" / "my_notes.md").read_text() == "mine"
    assert json.loads((out / "arm" / "run.json").read_text())["run_id"] == "second"


def test_an_empty_folder_and_a_sweeps_folder_are_ours_to_replace(tmp_path, arm_result):
    out = tmp_path / "out"
    (out / "arm").mkdir(parents=True)
    writers.write_study(arm_result, out, run_id="into-empty")
    for name in ("sweep.csv", "sweep.png", "sweep.md"):
        (out / "arm" / name).write_text("a sweep of ours")
    (out / "arm" / "run.json").unlink()  # a folder a sweep made: no run.json, only its files
    for name in (p.name for p in (out / "arm").iterdir() if not p.name.startswith("sweep.")):
        (out / "arm" / name).unlink()
    writers.write_study(arm_result, out, run_id="over-a-sweep")
    assert json.loads((out / "arm" / "run.json").read_text())["run_id"] == "over-a-sweep"


def test_check_output_folder_names_every_refused_plant_before_a_run(tmp_path):
    out = tmp_path / "out"
    for name in ("uuv", "arm"):
        (out / name).mkdir(parents=True)
        (out / name / f"{name}.tex").write_text(THESIS)
    (out / "crane").mkdir()
    with pytest.raises(writers.ForeignFolderError) as refused:
        writers.check_output_folder(out, ["arm", "crane", "uuv", "pendulum"])
    assert refused.value.folders == {out / "arm": ["arm.tex"], out / "uuv": ["uuv.tex"]}
    writers.check_output_folder(out, ["crane", "pendulum"])  # empty or absent: nothing to refuse


def test_the_command_refuses_a_users_plant_folder_and_leaves_it(tmp_path):
    """``python -m studies uuv --out OUT`` with OUT/uuv/my_thesis.tex: not exit 0, the folder named, the
    file intact (before: exit 0, and the file was gone)."""
    out = tmp_path / "out"
    (out / "uuv").mkdir(parents=True)
    (out / "uuv" / "my_thesis.tex").write_text(THESIS)
    done = subprocess.run(
        [sys.executable, "-m", "studies", "uuv", "--quick", "--scenario", "step", "--out", "out"],
        cwd=tmp_path,
        env=subprocess_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 2, done.stdout[-2000:]
    assert "ForeignFolderError" in done.stderr and "my_thesis.tex" in done.stderr, done.stderr[-2000:]
    assert (out / "uuv" / "my_thesis.tex").read_text() == THESIS
    assert sorted(p.name for p in (out / "uuv").iterdir()) == ["my_thesis.tex"]
    assert hidden(out) == []


# ---------------------------------------------------------------------------- symbolic links
@pytest.mark.parametrize("where", ["same filesystem", "another filesystem"])
def test_a_symlinked_plant_folder_is_replaced_where_it_points_and_leaves_nothing_hidden(tmp_path, where):
    if where == "same filesystem":
        elsewhere = tmp_path / "elsewhere"
        elsewhere.mkdir()
    else:
        if not os.access("/dev/shm", os.W_OK) or os.stat("/dev/shm").st_dev == os.stat(tmp_path).st_dev:
            pytest.skip("no writable /dev/shm on another filesystem")
        elsewhere = Path(tempfile.mkdtemp(prefix="out-elsewhere-", dir="/dev/shm"))
    try:
        real = elsewhere / "uuv_results"
        out = tmp_path / "out"
        out.mkdir()
        writers.publish(staged_plant(tmp_path / "first"), out, ["uuv"], "first")  # an earlier run of ours
        shutil.copytree(out / "uuv", real)
        shutil.rmtree(out / "uuv")
        (out / "uuv").symlink_to(real, target_is_directory=True)
        staging = staged_plant(tmp_path / "second", text="# the second run\n")
        writers.publish(staging, out, ["uuv"], "second")
        assert hidden(out) == [] and hidden(elsewhere) == []
        assert (out / "uuv").is_symlink() and os.path.realpath(out / "uuv") == str(real)
        assert (real / "table.md").read_text() == "# the second run\n"
    finally:
        shutil.rmtree(elsewhere, ignore_errors=True)


# ---------------------------------------------------------------------------- staging left by a dead run
def dead_pid() -> int:
    """The PID of a process that has ended (and been reaped)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def left_staging(out: Path, name: str, owner: dict | None) -> Path:
    """A staging folder as a killed run leaves it: a plant folder with a file, and its owner record."""
    folder = out / f".run-{name}.partial"
    (folder / "uuv").mkdir(parents=True)
    (folder / "uuv" / "table.csv").write_text("controller\nPD\n")
    if owner is not None:
        (folder / writers.STAGING_OWNER).write_text(json.dumps(owner))
    return folder


def test_a_staging_folder_of_a_dead_run_is_removed_and_one_that_cannot_be_judged_is_named(tmp_path):
    out = tmp_path / "out"
    host = socket.gethostname()
    dead = left_staging(out, "dead", {"run_id": "dead", "pid": dead_pid(), "host": host})
    alive = left_staging(out, "alive", {"run_id": "alive", "pid": os.getpid(), "host": host})
    remote = left_staging(out, "remote", {"run_id": "remote", "pid": 1, "host": host + "-elsewhere"})
    unowned = left_staging(out, "unowned", None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        staging = writers.new_staging(out, "next")
    assert not dead.exists()
    assert alive.exists() and remote.exists() and unowned.exists()  # never removed without proof
    named = [str(w.message) for w in caught if issubclass(w.category, writers.StagingLeftOver)]
    assert len(named) == 2, named
    assert any(str(remote) in m and "elsewhere" in m for m in named)
    assert any(str(unowned) in m and "no owner record" in m for m in named)
    assert not any(str(alive) in m for m in named)  # a run going on now is nobody's leftover
    owner = json.loads((staging / writers.STAGING_OWNER).read_text())
    assert owner["pid"] == os.getpid() and owner["host"] == host and owner["run_id"] == "next"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="process start times are read from /proc")
def test_a_reused_pid_does_not_keep_a_dead_runs_staging(tmp_path):
    """The record holds the owner's start time: a PID now used by another process is not the owner."""
    out = tmp_path / "out"
    me = {"run_id": "old", "pid": os.getpid(), "host": socket.gethostname(), "started": -1}
    stale = left_staging(out, "old", me)
    writers.new_staging(out, "next")
    assert not stale.exists()
