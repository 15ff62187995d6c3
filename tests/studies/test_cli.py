"""python -m studies as a user runs it: documented errors on bad arguments, a small run's files."""

import subprocess
import sys

import pytest

from conftest import REPO, subprocess_env


def run_cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "studies", *args], cwd=REPO, env=subprocess_env(),
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("args,message", [
    (["foo"], "unknown plant 'foo'; valid plants: arm, pendulum, satellite, uuv, ballbeam, crane"),
    (["arm", "--mc", "-5"], "argument --mc: the number of samples must be >= 0, got -5"),
    (["arm", "--mc", "many"], "argument --mc: expected a whole number of samples, got 'many'"),
    (["arm", "--scenario", "step,ramp"], "unknown scenario 'ramp'; valid scenarios: step, steps, disturbance"),
    (["arm", "--provider", "nocolon"], "--provider needs MODULE:FUNCTION"),
    (["arm", "--jobs", "0"], "--jobs must be >= 1"),
])
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


def test_list_names_plants_scenarios_and_what_is_provided():
    done = run_cli("--list", "uuv", "--provider", "example_providers:controllers")
    assert done.returncode == 0
    assert "plants: arm, pendulum, satellite, uuv, ballbeam, crane" in done.stdout
    listed = next(line for line in done.stdout.splitlines() if line.strip().startswith("controllers:"))
    assert listed.strip().startswith("controllers: PD,") and listed.endswith("LQR fast, LQR slow")
    assert "controller 'LQR' already provided; the first one is kept" in done.stdout


def test_a_small_run_prints_answers_and_writes_the_files(tmp_path):
    out = tmp_path / "out"
    done = run_cli("uuv", "--scenario", "step", "--mc", "0", "--out", str(out), "--quick",
                   "--provider", "example_providers:controllers")
    assert done.returncode == 0, done.stderr
    assert "IV.5" in done.stdout and "IV.6" in done.stdout and "Errata found" in done.stdout
    for name in ("uuv/table.csv", "uuv/table.md", "uuv/answers.json", "uuv/step.png", "uuv/animation.gif",
                 "uuv/animation.html", "summary.md", "index.html"):
        assert (out / name).exists(), name
    assert "wrote" in done.stderr
