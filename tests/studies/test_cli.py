"""python -m studies as a user runs it: documented errors on bad arguments, a small run's files."""

import json
import subprocess
import sys

import pandas as pd
import pytest
from conftest import REPO, subprocess_env

import studies


def run_cli(*args, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "studies", *args],
        cwd=REPO,
        env=subprocess_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.parametrize(
    "args,message",
    [
        (["foo"], "unknown plant 'foo'; valid plants: arm, pendulum, satellite, uuv, ballbeam, crane"),
        (["arm", "--mc", "-5"], "argument --mc: the number of samples must be >= 0, got -5"),
        (["arm", "--mc", "many"], "argument --mc: expected a whole number of samples, got 'many'"),
        (["arm", "--scenario", "step,ramp"], "unknown scenario 'ramp'; valid scenarios: step, steps, disturbance"),
        (["arm", "--provider", "nocolon"], "--provider needs MODULE:FUNCTION"),
        (["arm", "--jobs", "0"], "--jobs must be >= 1"),
        (["arm", "--without", "PD", "--without", " "], "--without names an empty controller label: ['PD', ' ']"),
        (["arm", "--workers", "0"], "--workers must be >= 1"),
        (["arm", "--workers", "2", "--scheduler", "tcp://localhost:1"], "give --workers (a local Dask cluster) or"),
        (["arm", "pendulum", "--sweep", "m=1:2:3"], "--sweep runs one plant; name exactly one, got 2"),
        (["pendulum", "--sweep", "m2=2:1:3"], "a sweep needs finite LOW < HIGH and N >= 2 points"),
        (["pendulum", "--sweep", "m2"], "a sweep is PARAM=LOW:HIGH:N"),
        (["pendulum", "--sweep", "mass=1:2:3"], "pendulum has no parameter 'mass'; its parameters are m1, m2"),
    ],
)
def test_bad_arguments_exit_2_with_the_documented_message(args, message):
    done = run_cli(*args)
    assert done.returncode == 2
    assert message in done.stderr
    assert done.stderr.startswith("usage: python -m studies")


def test_an_unwritable_output_folder_is_refused_before_running(tmp_path):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    done = run_cli("arm", "--out", str(blocker / "results"))
    assert done.returncode == 2
    assert "cannot write to the output folder" in done.stderr and "not-a-folder" in done.stderr


def test_list_names_plants_scenarios_and_declared_controllers_without_designing():
    done = run_cli("--list", "uuv", "--provider", "example_providers:controllers")
    assert done.returncode == 0
    assert "plants: arm, pendulum, satellite, uuv, ballbeam, crane" in done.stdout
    listed = next(line for line in done.stdout.splitlines() if line.strip().startswith("controllers:"))
    assert listed.strip() == "controllers: " + ", ".join(studies.get("uuv").controllers)
    assert "+ the controllers of example_providers:controllers, named when they are designed" in done.stdout


def test_a_small_run_writes_the_files_and_ends_with_verdicts_and_paths(tmp_path):
    out = tmp_path / "out"
    done = run_cli(
        "uuv",
        "--scenario",
        "step",
        "--mc",
        "0",
        "--out",
        str(out),
        "--quick",
        "--provider",
        "example_providers:controllers",
        "--without",
        "tube MPC",
        "--without",
        "no such controller",
    )
    assert done.returncode == 0, done.stderr
    for name in (
        "uuv/table.csv",
        "uuv/table.md",
        "uuv/answers.json",
        "uuv/answers.md",
        "uuv/step.png",
        "uuv/animation.gif",
        "uuv/animation.html",
        "summary.md",
        "index.html",
    ):
        assert (out / name).exists(), name
    # Answers go to the files, not the console; the console names every row that misses its specs.
    assert "IV.5" not in done.stdout and "IV.5" in (out / "uuv" / "answers.md").read_text()
    table = pd.read_csv(out / "uuv" / "table.csv")
    lines = done.stdout.splitlines()
    counts = table.verdict.value_counts()
    assert lines[0].startswith(f"uuv: {table.controller.nunique()} controllers, {len(table)} rows: ")
    plural = {"meets specs": "meet specs", "violates": "violate"}
    assert all(f"{n} {plural.get(label, label) if n > 1 else label}" in lines[0] for label, n in counts.items())
    listed = " ".join(" ".join(lines[1:]).split())  # the console wraps long labels at its width
    for row in table[table.verdict != "meets specs"].itertuples():
        assert " ".join(row.controller.split()) in listed and f"{row.verdict}:" in listed
    assert lines[-3].startswith(f"open {out / 'index.html'}") and lines[-2].startswith("total ")
    assert len(lines) <= 40
    # --without: the label left out has no rows, the run's record says so, and a label that matched no
    # controller of any plant is the last line.
    assert "tube MPC" not in set(table.controller) and "LQR" in set(table.controller)
    record = json.loads((out / "uuv" / "run.json").read_text())
    assert record["settings"]["without"] == ["tube MPC", "no such controller"]
    assert "tube MPC: left out, as asked (without)" in record["notes"]
    assert lines[-1] == "python -m studies: --without 'no such controller' matched no controller of the plants run"


def test_answers_are_printed_when_asked(tmp_path):
    done = run_cli(
        "uuv",
        "--scenario",
        "step",
        "--mc",
        "0",
        "--out",
        str(tmp_path / "out"),
        "--quick",
        "--answers",
        "--provider",
        "example_providers:lqr_only",
    )
    assert done.returncode == 0, done.stderr
    assert "IV.5" in done.stdout and "IV.6" in done.stdout and "Errata found" in done.stdout


@pytest.mark.parametrize(
    "module", ["studies.tuner", "studies.errata", "studies.codesign_report", "studies.codesign_open_loop"]
)
def test_every_command_of_the_package_runs_its_module_once(module):
    """`import studies` imports none of the modules that also run as commands: runpy would warn that the
    module is imported already and run a second copy of it."""
    done = subprocess.run(
        [sys.executable, "-m", module, "--help"], cwd=REPO, env=subprocess_env(), capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"usage: python -m {module}") and "RuntimeWarning" not in done.stderr
