"""Faults injected into the studies and their command line; each test asserts the exact behaviour.

Five classes: Ctrl-C always stops the run and leaves no partial or mixed files; an output
folder always holds one run; a row's status tells the truth (ok, degraded, diverged, failed,
skipped) and --strict makes any other than ok an exit 1; resources are checked before the work; bad
input gets a one-line error naming the argument; the same seed gives the same bytes, and labels
are shown literally in Markdown and HTML. Commands run in a folder whose path holds a space and a
semicolon, and once from a read-only folder as a user other than root.
"""

from __future__ import annotations

import dataclasses
import hashlib
import html
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import example_providers
import fault_providers
import numpy as np
import pandas as pd
import pytest
from conftest import subprocess_env
from fault_providers import HOSTILE_LABELS

import models
import models.checks
import models.closed_loop
import studies
from models import files, metrics
from studies import plain_markdown, runner, writers

EXAMPLE = "example_providers:controllers"
STEP_ONLY = runner.Options(scenarios=("step",), mc=0)


def arm_study(*providers):
    """The arm case with only `providers` (callables ``provider(case, known)``)."""
    return dataclasses.replace(studies.get("arm"), providers=tuple(providers))


@pytest.fixture
def workdir(tmp_path) -> Path:
    """A working folder whose path contains a space and a semicolon (a shell would split it)."""
    folder = tmp_path / "study run; touch INJECTED"
    folder.mkdir()
    return folder


def cli(*args, cwd, timeout=600) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "studies", *args],
        cwd=cwd,
        env=subprocess_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def snapshot(folder: Path) -> dict:
    """Every file under `folder`, hidden ones included: relative path -> SHA-256."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def previous_run(out: Path) -> dict:
    """An output folder as an earlier run left it (its run.json lists its file); returns its snapshot."""
    (out / "arm").mkdir(parents=True)
    (out / "arm" / "table.csv").write_text("controller,scenario,status\nPD,step,ok\n")
    digest = hashlib.sha256((out / "arm" / "table.csv").read_bytes()).hexdigest()
    (out / "arm" / "run.json").write_text(json.dumps({"run_id": "earlier", "sha256": {"table.csv": digest}}) + "\n")
    (out / "summary.md").write_text("# Summary of the earlier run\n")
    (out / "index.html").write_text("<!DOCTYPE html><title>earlier</title>\n")
    return snapshot(out)


# =========================================================================== class 2: Ctrl-C
def descendants(pid: int) -> set:
    """Every process started by `pid`, directly or not, from /proc."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            parents[int(entry.name)] = int(stat[stat.rindex(")") + 2 :].split()[1])
    found, grew = set(), {pid}
    while grew:
        grew = {child for child, parent in parents.items() if parent in grew} - found
        found |= grew
    return found


def alive(pids: set) -> set:
    running = set()
    for pid in pids:
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
        except OSError:
            continue
        if stat[stat.rindex(")") + 2] != "Z":
            running.add(pid)
    return running


def interrupted_run(
    workdir: Path, offset: float, jobs: int, tag: str, sent_signal=signal.SIGINT, grace: float = 10.0
) -> tuple:
    """Start `python -m studies` on the arm and the UUV, wait until a nonlinear MPC run started, send
    `sent_signal` (SIGINT) `offset` seconds later. Returns (exit code, seconds to stop, stderr,
    processes it started that are still running `grace` seconds after the signal). The UUV follows
    the arm even with one job, so the run is still going at the largest offset on a quiet machine
    (the arm alone finished 1.45 s after its MPC started)."""
    plants = ["arm", "uuv"]
    log = workdir / f"stderr-{tag}.txt"
    with open(log, "w") as stream:
        process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "studies",
                *plants,
                "--scenario",
                "step",
                "--mc",
                "0",
                "--quick",
                "--quiet",
                "--jobs",
                str(jobs),
                "--out",
                "out",
                "--provider",
                "fault_providers:announce_nonlinear_mpc",
            ],
            cwd=workdir,
            env=subprocess_env(),
            stdout=subprocess.DEVNULL,
            stderr=stream,
            # SIGHUP as a terminal delivers it, even when the tests run under nohup (which ignores it,
            # and the command keeps an ignored SIGHUP ignored)
            preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_DFL),
        )
    try:
        deadline = time.monotonic() + 300
        while "NMPC RUN STARTED" not in log.read_text():
            assert process.poll() is None, f"ended before its MPC ran: {log.read_text()[-2000:]}"
            assert time.monotonic() < deadline, "no nonlinear MPC run started"
            time.sleep(0.05)
        time.sleep(offset)
        children = descendants(process.pid)
        assert len(children) >= jobs - 1, f"expected the pool's workers among {children}"
        process.send_signal(sent_signal)
        sent = time.monotonic()
        code = process.wait(timeout=120)
        delay = time.monotonic() - sent
        while alive(children) and time.monotonic() < sent + grace:
            time.sleep(0.1)
        return code, delay, log.read_text(), alive(children)
    finally:
        process.kill()
        process.wait()
        log.unlink()


def assert_interrupted_cleanly(workdir: Path, before: dict, outcome: tuple, what: str, status: int = 130) -> None:
    code, delay, err, left = outcome
    assert code == status, f"{what}: exit {code}\n{err[-3000:]}"
    assert "python -m studies: interrupted; nothing of this run was written to out" in err, err[-3000:]
    assert delay < 30.0, f"{what}: stopped {delay:.1f} s after the signal"
    assert not left, f"{what}: processes of the run still running: {left}"
    assert snapshot(workdir / "out") == before, f"{what}: the output folder changed"


def test_ctrl_c_during_a_nonlinear_mpc_row_stops_the_run_and_writes_nothing(workdir):
    """SIGINT while the arm's nonlinear MPC solves: exit 130 within seconds, and the output folder
    holds exactly the earlier run's files (no partial file, no staging folder, nothing mixed)."""
    before = previous_run(workdir / "out")
    outcome = interrupted_run(workdir, 0.4, 1, "one")
    assert_interrupted_cleanly(workdir, before, outcome, "offset 0.4 s, one job")


def test_a_sigint_after_the_status_is_decided_does_not_change_it(tmp_path):
    """The command's exit status, once decided, is the process's: a SIGINT during shutdown (here from an
    exit handler, which runs after the status is chosen) neither kills the process nor raises."""
    script = (
        "import atexit, os, signal\n"
        "from studies.__main__ import _exit_with\n"
        "atexit.register(lambda: os.kill(os.getpid(), signal.SIGINT))\n"
        "_exit_with(130)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, env=subprocess_env(), capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 130, done.stderr
    assert "KeyboardInterrupt" not in done.stderr, done.stderr


def test_an_interrupt_caught_inside_exec_does_not_end_the_command_by_sigint(tmp_path):
    """A Ctrl-C that landed in code run from a string (an `exec` in an import, caught by the command)
    leaves CPython's flag that ends a ``python -m`` program by SIGINT (-2); the status decided is the
    process's all the same."""
    (tmp_path / "interrupted_in_exec.py").write_text(
        "from studies.__main__ import _exit_with\n"
        "try:\n"
        "    exec('raise KeyboardInterrupt', {})\n"
        "except KeyboardInterrupt:\n"
        "    pass\n"
        "_exit_with(130)\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "interrupted_in_exec"],
        cwd=tmp_path,
        env=subprocess_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 130, done.stderr


@pytest.mark.slow
def test_sigterm_with_two_jobs_ends_the_workers_and_writes_nothing(workdir):
    """SIGTERM (kill, a job scheduler) to the command while two worker processes run plants: it ends
    them as on Ctrl-C, leaves the earlier files, and exits 143 (128 + SIGTERM)."""
    before = previous_run(workdir / "out")
    outcome = interrupted_run(workdir, 0.4, 2, "term", signal.SIGTERM)
    assert_interrupted_cleanly(workdir, before, outcome, "SIGTERM, two jobs", status=143)


@pytest.mark.slow
def test_sighup_with_two_jobs_is_handled_as_sigterm_and_exits_129(workdir):
    """SIGHUP (the terminal closed) while two workers run plants: the same exit path as SIGTERM (the
    workers ended, nothing written, the earlier files kept), exit 129 (128 + SIGHUP), and no process
    of the run left 5 s after the signal."""
    before = previous_run(workdir / "out")
    outcome = interrupted_run(workdir, 0.4, 2, "hup", signal.SIGHUP, grace=5.0)
    assert_interrupted_cleanly(workdir, before, outcome, "SIGHUP, two jobs", status=129)


@pytest.mark.slow
def test_sigkill_with_two_jobs_takes_the_workers_along_and_the_next_run_removes_the_staging(workdir):
    """SIGKILL to the command while two workers run plants: the parent cannot clean up, yet 5 s later
    no process it started is running (each worker gets SIGTERM when its parent dies, and the resource
    tracker sees its pipe close); the staging folder it left is removed by the next run's
    `new_staging`, and the earlier run's files are as they were."""
    before = previous_run(workdir / "out")
    code, _, err, left = interrupted_run(workdir, 0.4, 2, "kill", signal.SIGKILL, grace=5.0)
    assert code == -signal.SIGKILL, err[-3000:]
    assert not left, f"processes of the killed run still running 5 s later: {left}"
    out = workdir / "out"
    assert list(out.glob(".run-*.partial")), "the killed run left no staging folder (nothing to check)"
    fresh = writers.new_staging(out, "next")
    assert [p.name for p in out.glob(".run-*.partial")] == [fresh.name]
    shutil.rmtree(fresh)
    assert snapshot(out) == before


@pytest.mark.slow
def test_ctrl_c_at_twelve_offsets_with_one_and_two_jobs_never_leaves_partial_files(workdir):
    """Twelve runs, each interrupted once during a nonlinear MPC run at its own offset (0.05-1.6 s
    after the run started), alternately in this process and in two worker processes (SIGINT to the
    command only: it must end its workers). Every run exits 130 and leaves the earlier files."""
    before = previous_run(workdir / "out")
    offsets = [0.05 + 0.14 * k for k in range(12)]
    for k, offset in enumerate(offsets):
        jobs = 1 + k % 2
        outcome = interrupted_run(workdir, offset, jobs, f"{k}")
        assert_interrupted_cleanly(workdir, before, outcome, f"offset {offset:.2f} s, {jobs} jobs")


def test_an_interrupt_casadi_reports_as_an_error_stops_the_study():
    """CasADi turns Ctrl-C inside a solver into RuntimeError('... KeyboardInterrupt'): the study stops
    with KeyboardInterrupt instead of noting a failed row and going on."""
    with pytest.raises(KeyboardInterrupt):
        runner.run_study(arm_study(fault_providers.interrupt_in_disguise), STEP_ONLY)


def test_the_command_reads_an_interrupt_reported_as_an_error_as_an_interrupt(workdir, monkeypatch, capsys):
    """A worker's CasADi call turned Ctrl-C into SystemError('... KeyboardInterrupt'): exit 130 and
    nothing written, not 'failed' and exit 1."""
    from studies import cli as command

    def interrupted(*args, **kwargs):
        raise SystemError(
            "<built-in function Function_call> returned a result with an exception set: KeyboardInterrupt"
        )

    from studies import batch

    monkeypatch.setattr(batch, "run_plants", interrupted)
    monkeypatch.chdir(workdir)
    before = previous_run(workdir / "out")
    assert command.main(["arm", "--quick", "--out", "out"]) == 130
    assert "python -m studies: interrupted; nothing of this run was written to out" in capsys.readouterr().err
    assert snapshot(workdir / "out") == before


def test_an_interrupted_write_leaves_the_previous_folder(tmp_path, monkeypatch):
    """Ctrl-C while a study's files are written (in the middle of its plots): out/arm is the earlier
    folder, file for file, and no staging folder is left."""
    result = runner.run_study(arm_study(example_providers.lqr_only), STEP_ONLY)
    out = tmp_path / "out"
    before = previous_run(out)
    from studies import plots

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(plots, "pole_map", interrupt)
    with pytest.raises(KeyboardInterrupt):
        writers.write_study(result, out)
    assert snapshot(out) == before


# =========================================================================== class 3: one run per folder
def test_a_study_folder_is_replaced_whole_and_records_its_run(tmp_path):
    """A stale file of an earlier run does not survive a rewrite; run.json names the run, its settings
    and the SHA-256 of every file, which check_study_folder verifies."""
    result = runner.run_study(arm_study(example_providers.lqr_only), runner.Options(scenarios=("step",), mc=0, seed=7))
    out = tmp_path / "out"
    (out / "arm").mkdir(parents=True)
    (out / "arm" / "stale.png").write_bytes(b"from an earlier run")
    earlier = {"run_id": "run-one", "sha256": {"stale.png": hashlib.sha256(b"from an earlier run").hexdigest()}}
    (out / "arm" / "run.json").write_text(json.dumps(earlier))
    written = writers.write_study(result, out, run_id="run-two")
    folder = out / "arm"
    assert not (folder / "stale.png").exists()
    assert sorted(p.name for p in out.iterdir()) == ["arm"]  # no staging folder left
    info = json.loads((folder / "run.json").read_text())
    assert info["run_id"] == "run-two" and info["settings"]["seed"] == 7
    assert info["settings"]["providers"] == ["example_providers:lqr_only"]
    assert set(info["sha256"]) == set(written.values()) == {p.name for p in folder.iterdir()} - {"run.json"}
    for name, digest in info["sha256"].items():
        assert hashlib.sha256((folder / name).read_bytes()).hexdigest() == digest
    assert writers.check_study_folder(folder) == []


def test_a_mixed_folder_is_detected_and_reported_in_the_summary_and_index(tmp_path):
    """A table.csv of another run copied into a plant folder, and a file it never wrote, are named by
    check_study_folder, and summary.md and index.html say the folder is not as its run wrote it; a
    plant written by an earlier run is marked as such."""
    result = runner.run_study(arm_study(example_providers.lqr_only), STEP_ONLY)
    uuv = runner.run_study(dataclasses.replace(studies.get("uuv"), providers=(example_providers.lqr_only,)), STEP_ONLY)
    out = tmp_path / "out"
    writers.write_study(uuv, out, run_id="earlier")
    writers.write_study(result, out, run_id="now")
    table = out / "arm" / "table.csv"
    table.write_text(table.read_text() + "\n")  # the same rows, not the same bytes
    (out / "arm" / "notes.txt").write_text("left by hand")
    problems = writers.check_study_folder(out / "arm")
    assert problems == ["table.csv is not the file run now wrote", "notes.txt is not from run now"]
    writers.write_summary(out, studies.names(), "now")
    writers.write_index(out, studies.names(), "now")
    summary, index = (out / "summary.md").read_text(), (out / "index.html").read_text()
    assert "run now; folder not as its run wrote it: table.csv is not the file run now wrote" in summary
    assert "run earlier (an earlier run, not now)" in summary
    assert html.escape("run earlier (an earlier run, not now)") in index
    assert "folder not as its run wrote it" in index


def test_a_failed_run_leaves_the_output_folder_as_it_was(workdir):
    """--strict with a provider that raises: exit 1, and OUT holds the earlier run's files only."""
    before = previous_run(workdir / "out")
    done = cli(
        "arm",
        "--scenario",
        "step",
        "--mc",
        "0",
        "--quick",
        "--quiet",
        "--strict",
        "--out",
        "out",
        "--provider",
        "example_providers:failing",
        cwd=workdir,
    )
    assert done.returncode == 1, done.stderr[-3000:]
    assert (
        "python -m studies: failed: RuntimeError: no design for arm; nothing of this run was written to out"
        in done.stderr
    )
    assert snapshot(workdir / "out") == before


# =========================================================================== class 6: status
def test_status_kinds():
    assert [
        runner.status_kind(s)
        for s in (
            "ok",
            "degraded: solver failed on 3 of 500 steps",
            "diverged at t = 1 s",
            "diverged: 2 of 9 samples, first at t = 1 s",
            "failed: ValueError: x",
            "skipped: no such scenario",
            math.nan,
            "",
        )
    ] == ["ok", "degraded", "diverged", "diverged", "failed", "skipped", "failed", "failed"]


def test_an_mpc_whose_solver_fails_on_every_step_is_degraded_not_ok():
    """500 failed solves (each falling back on the previous plan) in the step, and in every step of
    the Monte Carlo samples: 'degraded' with the counts, never 'ok', and not the best row."""
    result = runner.run_study(
        arm_study(fault_providers.solver_always_fails, example_providers.lqr_only),
        runner.Options(scenarios=("step", "mc"), mc=2),
    )
    table = result.table.set_index(["controller", "scenario"]).status
    assert table[("failing MPC", "step")] == "degraded: solver failed on 500 of 500 steps, fallback on 500"
    assert (
        table[("failing MPC", "mc")] == "degraded: solver failed on 1000 of 1000 steps of 2 samples, fallback on 1000"
    )
    assert table[("LQR", "step")] == table[("LQR", "mc")] == "ok"
    assert result.best(meeting=False) == "LQR" and result.best() != "failing MPC"


def test_counts_of_solver_records():
    records = [
        {"success": True},
        {"success": False, "fallback": True},
        {"status": "Solve_Succeeded"},
        {"status": "Maximum_Iterations_Exceeded"},
        {"status": "optimal"},
        "not a record",
    ]
    assert runner.solver_counts(records) == (5, 2, 1)
    assert runner.degraded_status(5, 2, 1) == "degraded: solver failed on 2 of 5 steps, fallback on 1"
    assert runner.degraded_status(5, 0, 1) == "degraded: fallback on 1 of 5 steps"
    assert runner.degraded_status(5, 0, 0) is None


def test_a_diverging_and_a_failing_controller_have_their_own_status_and_the_others_run():
    result = runner.run_study(arm_study(example_providers.diverging, fault_providers.raises_mid_run), STEP_ONLY)
    status = result.table.set_index("controller").status
    assert status["broken"] == "diverged at t = 1 s"
    assert status["broken MPC"] == "failed: FloatingPointError: the solver's factorization broke down"
    assert status["LQR"] == "ok"
    with pytest.raises(FloatingPointError, match="factorization broke down"):
        runner.run_study(
            arm_study(fault_providers.raises_mid_run), runner.Options(scenarios=("step",), mc=0, strict=True)
        )


def test_a_provider_that_returns_no_dict_is_noted():
    result = runner.run_study(arm_study(fault_providers.not_a_dict, example_providers.lqr_only), STEP_ONLY)
    assert "fault_providers:not_a_dict: returned list, not a dict of controllers; skipped" in result.notes


def test_non_ok_rows_are_visible_in_the_console_summary_and_index_and_strict_exits_1(workdir):
    """A run with an MPC whose solver always fails and a controller that diverges, with --strict:
    every file is written (they are the truth), each non-ok row is named on the console, in
    table.md, summary.md and index.html, and the exit status is 1. The arm's tube MPC, refused at
    construction, is a failed row that --strict counts, not an error that stops the run."""
    done = cli(
        "arm",
        "--scenario",
        "step",
        "--mc",
        "0",
        "--quick",
        "--quiet",
        "--strict",
        "--out",
        "out",
        "--provider",
        "fault_providers:solver_always_fails",
        "--provider",
        "example_providers:diverging",
        cwd=workdir,
    )
    assert done.returncode == 1, done.stderr[-3000:]
    degraded = "degraded: solver failed on 500 of 500 steps, fallback on 500"
    console = done.stdout.splitlines()
    # One scenario ran, so each row is listed as "[all]" of its controller's scenarios.
    assert any(
        line.strip().startswith(("degraded: ", "violates (degraded): ")) and "failing MPC [all]" in line
        for line in console
    ), done.stdout
    assert "  diverged: broken [all]" in console, done.stdout
    assert "  failed: tube MPC [all]" in console, done.stdout
    assert "python -m studies: --strict: 3 row(s) not ok (listed above)" in console
    out = workdir / "out"
    assert f"- **failing MPC / step**: {degraded}" in (out / "arm" / "table.md").read_text()
    assert re.search(rf"\| failing MPC \| step \| [^|]+ \| {degraded} \|", (out / "arm" / "table.md").read_text())
    summary = (out / "summary.md").read_text()
    assert f"- **failing MPC / step**: {degraded}" in summary and "- **broken / step**: diverged at t = 1 s" in summary
    index = (out / "index.html").read_text()
    assert f"<li><b>failing MPC / step</b>: {degraded}</li>" in index
    assert "<li><b>broken / step</b>: diverged at t = 1 s</li>" in index
    info = json.loads((out / "arm" / "run.json").read_text())
    assert info["status"]["degraded"] == 1 and info["status"]["diverged"] == 1
    assert sorted(p.name for p in workdir.iterdir()) == ["out"]  # the working folder holds only --out
    assert sorted(p.name for p in out.iterdir()) == ["arm", "index.html", "summary.md"]
    assert writers.check_study_folder(out / "arm") == []


@pytest.mark.parametrize(
    "spec,culprit",
    [
        ("mpc_typo:controllers", "--provider mpc_typo:controllers: no module named 'mpc_typo'"),
        (
            "example_providers:controlers",
            "--provider example_providers:controlers: module example_providers has no function controlers()",
        ),
        (
            "studies.no_such_module:controllers",
            "--provider studies.no_such_module:controllers: no module named 'studies.no_such_module'",
        ),
    ],
)
def test_a_misspelled_provider_is_named_and_with_strict_nothing_runs(workdir, monkeypatch, capsys, spec, culprit):
    from studies import cli as command

    monkeypatch.chdir(workdir)
    assert command.main(["arm", "--strict", "--quick", "--out", "out", "--provider", spec]) == 1
    err = capsys.readouterr().err
    assert f"python -m studies: {culprit}\n" in err
    assert "--strict: not running with a missing provider" in err
    assert list(workdir.iterdir()) == []


@pytest.mark.slow
def test_a_misspelled_provider_without_strict_is_named_before_and_after_the_run(workdir):
    done = cli(
        "uuv",
        "--scenario",
        "step",
        "--mc",
        "0",
        "--quick",
        "--quiet",
        "--out",
        "out",
        "--provider",
        "mpc_typo:controllers",
        cwd=workdir,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert (
        "python -m studies: --provider mpc_typo:controllers: no module named 'mpc_typo'; running without it"
        in done.stderr
    )
    # the closing lines (stdout) name it again after the run
    assert "ran without 1 missing provider(s): --provider mpc_typo:controllers" in done.stdout
    note = "mpc_typo:controllers: skipped, no module named 'mpc_typo'"
    assert f"- {plain_markdown.markdown_text(note)}" in (workdir / "out/uuv/table.md").read_text()


# =========================================================================== class 7: resources
def test_two_million_monte_carlo_samples_are_refused_before_any_work(workdir):
    started = time.monotonic()
    done = cli("arm", "--mc", "2000000", "--out", "out", cwd=workdir)
    assert done.returncode == 2
    line = done.stderr.strip().splitlines()[-1]
    assert re.fullmatch(
        r"python -m studies: error: --mc 2000000: a Monte Carlo of 2000000 samples on arm needs "
        r"about [0-9.]+ GiB, above the limit of 1 GiB \(models.checks.MEMORY_LIMIT_BYTES\); give "
        r"fewer samples \(mc\)",
        line,
    ), line
    assert time.monotonic() - started < 120 and list(workdir.iterdir()) == []


def test_the_api_refuses_the_same_before_designing_anything(monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("designed controllers")

    monkeypatch.setattr(runner, "design_controllers", never)
    with pytest.raises(models.checks.ResourceLimitError, match="a Monte Carlo of 2000000 samples on arm needs"):
        studies.run_study("arm", mc=2_000_000)


def test_the_estimate_is_the_kept_tracked_coordinate_and_input_of_every_sample():
    """Hand count for the arm: its Monte Carlo is the 5 s step at 10 ms, 500 steps; per sample two
    arrays of 501 doubles kept and copied once, plus a row of 4 parameters, 15 metrics and 4 more."""
    study = studies.get("arm")
    scenario = next(s for s in study.scenarios if s.monte_carlo)
    assert scenario.duration(study) == 5.0 and study.sample_period == 0.01
    bytes_ = runner.monte_carlo_bytes(study, runner.Options(mc=1000), n_params=4)
    assert bytes_ == 1000 * 8 * (4 * 501 + 4 + 15 + 4) and len(metrics.METRIC_COLUMNS) == 15


def test_the_streamed_monte_carlo_equals_the_one_batch_of_models_monte_carlo(monkeypatch):
    """The runner consumes the samples a chunk at a time; forced into chunks of 3 samples, every
    per-sample metric equals those computed from models.monte_carlo's single batch (a second path)."""
    import models.monte_carlo_batch

    monkeypatch.setattr(models.monte_carlo_batch, "MONTE_CARLO_CHUNK_BYTES", 1)  # one sample per chunk
    study = arm_study(example_providers.lqr_only)
    options = runner.Options(scenarios=("mc",), mc=7, seed=2, jit=False)
    result = runner.run_study(study, options)
    plant = result.plant
    lqr = result.controllers["LQR"]
    scenario = next(s for s in study.scenarios if s.monte_carlo)
    _, base = runner.tracked_equilibrium(plant, study)
    params = models.sample_params(plant, 7, rel=scenario.rel, seed=2)
    monkeypatch.setattr(models.monte_carlo_batch, "MONTE_CARLO_CHUNK_BYTES", 64 * 2**20)
    batch = models.monte_carlo(
        plant, lqr, scenario.reference(study, base), scenario.duration(study), params, seed=2, substeps=study.substeps
    )
    expected = pd.DataFrame([metrics.run_metrics(run, study.tracked) for run in batch])
    got = result.samples[result.samples.controller == "LQR"].reset_index(drop=True)
    for column in ("iae", "itae", "peak_u", "overshoot_pct", "settling_time_s"):
        np.testing.assert_array_equal(got[column].to_numpy(), expected[column].to_numpy(), column)
    envelope = result.envelopes["LQR"]
    theta = batch.x[:, :, plant.state_names.index(study.tracked)]
    np.testing.assert_array_equal(envelope.tracked, np.quantile(theta, envelope.quantiles, axis=0))


def test_a_controllers_compiled_closed_loops_are_freed_after_each_row():
    """The work memory of a closed loop (hundreds of MB at 1 ms over a minute) is not kept once its row
    is done: after the study no cached closed-loop Function of the controller is left on the plant."""
    result = runner.run_study(arm_study(example_providers.lqr_only), runner.Options(scenarios=("step", "mc"), mc=3))
    lqr = result.controllers["LQR"]

    def cached():
        return [
            key
            for key, value in result.plant.function_cache.items()
            if isinstance(value, tuple) and value[0] is lqr.casadi_step
        ]

    assert cached() == []
    models.simulate_closed_loop(result.plant, lqr, 0.1, 1.0)
    assert len(cached()) == 1
    assert models.closed_loop.release(result.plant, lqr) == 1 and cached() == []


# =========================================================================== class 8: bad input
@pytest.mark.parametrize(
    "args,message",
    [
        (["--seed", "-1"], "argument --seed: the seed must be a whole number >= 0, got -1"),
        (["--seed", "1.5"], "argument --seed: expected a whole number >= 0, got '1.5'"),
        (["--out", ""], "argument --out: expected a folder name, got '' (use . for this folder)"),
        (["--out", "  "], "argument --out: expected a folder name, got '  ' (use . for this folder)"),
        (["--scenario", ""], "--scenario names no scenario; valid scenarios: step, steps, disturbance, noise, mc"),
        (["--scenario", " , "], "--scenario names no scenario"),
        (["--jobs", "two"], "argument --jobs: invalid int value: 'two'"),
        (["--provider", "a:b:c"], "--provider needs MODULE:FUNCTION, got 'a:b:c'"),
        (["--provider", " :controllers"], "--provider needs MODULE:FUNCTION, got ' :controllers'"),
        (["--provider", "example_providers:"], "--provider needs MODULE:FUNCTION, got 'example_providers:'"),
    ],
)
def test_bad_command_line_arguments_exit_2_naming_the_argument(workdir, monkeypatch, capsys, args, message):
    """The command's main() in this process (the interpreter's start-up would dominate), run from the
    working folder with a space and a semicolon."""
    from studies import cli as command

    monkeypatch.chdir(workdir)
    with pytest.raises(SystemExit) as exited:
        command.main(["arm", *args])
    err = capsys.readouterr().err
    assert exited.value.code == 2, err
    assert err.startswith("usage: python -m studies")
    assert message in err.splitlines()[-1]
    assert list(workdir.iterdir()) == []  # nothing written, not even into the working folder


@pytest.mark.parametrize(
    "kwargs,error,message",
    [
        (
            {"scenarios": "step"},
            TypeError,
            "scenarios must be a list of scenario names such as ['step'], got str 'step'",
        ),
        ({"scenarios": []}, ValueError, "scenarios is empty; give None for every scenario"),
        ({"scenarios": ["step", "ramp"]}, ValueError, "unknown scenario 'ramp' in scenarios"),
        ({"mc": True}, TypeError, "mc (Monte Carlo samples) must be an integer, got bool True"),
        ({"mc": "5"}, TypeError, "mc (Monte Carlo samples) must be an integer, got str '5'"),
        ({"mc": 2.5}, ValueError, "mc (Monte Carlo samples) must be an integer, got 2.5"),
        ({"mc": -1}, ValueError, "mc (Monte Carlo samples) must be an integer >= 0, got -1"),
        ({"seed": -1}, ValueError, "seed must be an integer >= 0, got -1"),
        ({"seed": "0"}, TypeError, "seed must be an integer, got str '0'"),
        ({"threads": 0}, ValueError, "threads must be an integer >= 1, got 0"),
        ({"quick": "no"}, TypeError, "quick must be True or False, got str 'no'"),
        ({"strict": 1}, TypeError, "strict must be True or False, got int 1"),
        ({"jit": "yes"}, ValueError, "jit must be True, False or 'auto', got 'yes'"),
        ({"jit": 1}, ValueError, "jit must be True, False or 'auto', got 1"),
        ({"out": ""}, ValueError, "out must name a folder (or be None to write nothing), got ''"),
        ({"out": 5}, ValueError, "out must name a folder (or be None to write nothing), got 5"),
        (
            {"providers": EXAMPLE},
            TypeError,
            "providers must be a list of providers (functions, or 'module:function' strings), got str",
        ),
        (
            {"providers": ["nocolon"]},
            ValueError,
            "providers: each provider is a function or 'module:function', got 'nocolon'",
        ),
        ({"controllers": ["PD"]}, TypeError, "controllers must be a dict {label: controller}, got list"),
        ({"progress": 5}, TypeError, "progress must be a function progress(done, total, text), got 5"),
        ({"mc": 2_000_000}, models.checks.ResourceLimitError, "a Monte Carlo of 2000000 samples on arm needs about"),
    ],
)
def test_bad_arguments_of_run_study_are_named_before_any_work(monkeypatch, kwargs, error, message):
    monkeypatch.setattr(runner, "design_controllers", lambda *a, **k: pytest.fail("ran"))
    with pytest.raises(error) as raised:
        studies.run_study("arm", **kwargs)
    assert message in str(raised.value) and "\n" not in str(raised.value)


def test_a_name_that_is_not_a_plant_is_named():
    with pytest.raises(TypeError, match="name must be a plant name or a CaseStudy, got int 5"):
        studies.run_study(5)
    with pytest.raises(ValueError, match="unknown plant 'arms'; valid plants: arm, pendulum"):
        studies.run_study("arms")
    with pytest.raises(TypeError, match="options must be a studies.Options, got dict"):
        runner.run_study(studies.get("arm"), {"mc": 0})


def test_an_output_folder_that_is_a_file_is_refused_before_running(workdir, monkeypatch, capsys):
    from studies import cli as command

    monkeypatch.chdir(workdir)
    (workdir / "results").write_text("a file")
    with pytest.raises(SystemExit) as exited:
        command.main(["arm", "--out", "results"])
    assert exited.value.code == 2
    assert "cannot write to the output folder 'results'" in capsys.readouterr().err


# =========================================================================== class 9: reproducible files
def test_the_same_seed_gives_the_same_bytes_and_the_timings_are_apart(tmp_path):
    """Two runs of the arm with a Block and a controller timed step by step (example linear MPC),
    Monte Carlo included: table.csv and monte_carlo.csv are byte-identical; compute times are only in
    timings.csv (and they differ); another seed changes the Monte Carlo."""
    study = arm_study(example_providers.controllers)
    options = runner.Options(scenarios=("step", "mc"), mc=3, seed=11)
    outs = []
    for k, seed in enumerate((11, 11, 12)):
        result = runner.run_study(study, dataclasses.replace(options, seed=seed))
        writers.write_study(result, tmp_path / f"run{k}")
        outs.append(tmp_path / f"run{k}" / "arm")
    for name in ("table.csv", "monte_carlo.csv"):
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name
        assert not set(writers.TIMING_COLUMNS) & set(pd.read_csv(outs[0] / name).columns), name
    assert (outs[0] / "monte_carlo.csv").read_bytes() != (outs[2] / "monte_carlo.csv").read_bytes()
    timings = [pd.read_csv(o / "timings.csv") for o in outs[:2]]
    mpc = [
        t[(t.controller == "linear MPC") & (t.scenario == "step") & t["sample"].isna()].step_ms.iloc[0] for t in timings
    ]
    assert all(v > 0 for v in mpc)
    per_sample = timings[0][timings[0]["sample"].notna()]
    assert set(per_sample.controller) == {"linear MPC"} and len(per_sample) == 3


@pytest.mark.slow
def test_two_runs_of_the_command_write_the_same_tables(workdir):
    """The command twice with the same seed (MPC rows included, on the same samples): table.csv and
    monte_carlo.csv of every plant are byte-identical; run ids differ."""
    outs = []
    for k in range(2):
        done = cli(
            "arm",
            "uuv",
            "--scenario",
            "step,mc",
            "--mc",
            "3",
            "--quiet",
            "--seed",
            "3",
            "--out",
            f"out{k}",
            cwd=workdir,
        )
        assert done.returncode == 0, done.stderr[-3000:]
        outs.append(workdir / f"out{k}")
    for plant in ("arm", "uuv"):
        for name in ("table.csv", "monte_carlo.csv"):
            assert (outs[0] / plant / name).read_bytes() == (outs[1] / plant / name).read_bytes(), (plant, name)
        ids = [json.loads((o / plant / "run.json").read_text())["run_id"] for o in outs]
        assert ids[0] != ids[1]


def unescape_markdown(text: str) -> str:
    """CommonMark's rule: a backslash before an ASCII punctuation character is that character."""
    return re.sub(r"\\([!-/:-@\[-`{-~])", r"\1", text)


@pytest.mark.parametrize("label", [*HOSTILE_LABELS, "1. first", "+ plus", "a\\b", "x & y &amp;", "~~gone~~ #1"])
def test_markdown_escaping_shows_the_text_and_starts_no_syntax(label):
    escaped = files.escape_markdown(label)
    assert unescape_markdown(escaped) == label
    # Every character that starts inline syntax is escaped, and no line starts a list or quote.
    assert not re.search(r"(?<!\\)[`*_\[\]<>|~&#]", escaped.replace("\\\\", "")), escaped
    assert not re.match(r"\s*([-+>]|\d+[.)])(\s|$)", escaped)


def test_labels_are_shown_literally_in_every_file(tmp_path):
    """Labels with HTML, Markdown and the animation page's placeholders: escaped in table.md, summary.md
    and index.html, and the animation page's title is the label (its data appears once, in the script)."""
    result = runner.run_study(arm_study(fault_providers.hostile_labels), STEP_ONLY)
    out = tmp_path / "out"
    writers.write_study(result, out, run_id="labels")
    writers.write_summary(out, ["arm"], "labels")
    writers.write_index(out, ["arm"], "labels")
    table_md = (out / "arm" / "table.md").read_text()
    summary = (out / "summary.md").read_text()
    index = (out / "index.html").read_text()
    for label in HOSTILE_LABELS:
        # table.md is read in terminals too: literal once rendered, escaped only where needed, '|' as '/'
        assert re.search(rf"\| {re.escape(plain_markdown.markdown_text(label))} \| step \| [^|]+ \| ok \|", table_md)
        assert f"| {files.escape_markdown(label)} |" in summary
        assert html.escape(label) in index
    for text in (table_md, summary, index):
        assert not re.search(r"(?<!\\)<script>", text)  # no tag: escaped (Markdown) or as &lt; (HTML)
    assert result.best(meeting=False) == HOSTILE_LABELS[0]
    page = (out / "arm" / "animation.html").read_text()
    title = re.search(r"<title>(.*)</title>", page).group(1)
    assert title == html.escape(f"{result.plant.title}: the controllers on the text's step")
    assert page.count("const DATA = {") == 1
    data = json.loads(re.search(r"const DATA = (\{.*?\});\n", page).group(1))
    assert data["selected"] == HOSTILE_LABELS[0] and set(HOSTILE_LABELS) <= set(data["order"])
    assert len(data["runs"][HOSTILE_LABELS[0]]["t"]) > 10


# =========================================================================== working folders
@pytest.mark.slow
def test_the_command_runs_in_a_folder_with_a_space_and_a_semicolon_and_writes_only_out(workdir):
    done = cli(
        "uuv",
        "--scenario",
        "step",
        "--mc",
        "0",
        "--quick",
        "--quiet",
        "--out",
        "out",
        "--provider",
        "example_providers:lqr_only",
        cwd=workdir,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert sorted(p.name for p in workdir.iterdir()) == ["out"]
    assert sorted(p.name for p in (workdir / "out").iterdir()) == ["index.html", "summary.md", "uuv"]
    assert writers.check_study_folder(workdir / "out" / "uuv") == []


def _as_other_user() -> list | None:
    """The command prefix that runs as user 'nobody' (None when this process is not root)."""
    if os.geteuid() != 0:
        return None
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("running as root without setpriv: cannot run the command as another user")
    return [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups"]


def test_the_command_runs_from_a_read_only_folder_as_another_user():
    """The working folder is read-only (and the user not root, who could write anyway): the run
    writes only into --out, and a relative --out there is refused with exit 2."""
    prefix = _as_other_user() or []
    base = Path(tempfile.mkdtemp(prefix="studies read-only; "))
    try:
        os.chmod(base, 0o755)
        cwd, out, home = base / "read only; here", base / "out; there", base / "home"
        for folder in (cwd, out, home):
            folder.mkdir()
        os.chmod(out, 0o777)
        os.chmod(home, 0o777)
        os.chmod(cwd, 0o555)
        env = subprocess_env() | {
            "HOME": str(home),
            "MPLCONFIGDIR": str(home / "mpl"),
            "PYTHONDONTWRITEBYTECODE": "1",
            "XDG_CACHE_HOME": str(home / "cache"),
        }
        probe = subprocess.run(
            [*prefix, sys.executable, "-c", "import casadi, pandas, studies"],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
        )
        if probe.returncode != 0:
            pytest.skip(f"the interpreter or the repository is not usable by user nobody: {probe.stderr[-300:]}")
        done = subprocess.run(
            [
                *prefix,
                sys.executable,
                "-m",
                "studies",
                "uuv",
                "--scenario",
                "step",
                "--mc",
                "0",
                "--quick",
                "--quiet",
                "--jobs",
                "1",
                "--out",
                str(out),
                "--provider",
                "example_providers:lqr_only",
            ],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert done.returncode == 0, done.stderr[-3000:]
        assert list(cwd.iterdir()) == []
        assert writers.check_study_folder(out / "uuv") == []
        refused = subprocess.run(
            [*prefix, sys.executable, "-m", "studies", "uuv", "--out", "results"],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert refused.returncode == 2
        assert "cannot write to the output folder 'results'" in refused.stderr
    finally:
        os.chmod(base / "read only; here", 0o755)
        shutil.rmtree(base, ignore_errors=True)
