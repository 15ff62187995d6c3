"""The whole command as the README runs it, on all six plants (slow: minutes)."""

import json

import pandas as pd
import pytest
from test_cli import run_cli

import studies

PER_PLANT = (
    "table.csv",
    "table.md",
    "answers.json",
    "answers.md",
    "monte_carlo.csv",
    "loops.csv",
    "step.png",
    "steps.png",
    "disturbance.png",
    "noise.png",
    "monte_carlo.png",
    "root_locus.png",
    "poles.png",
    "animation.gif",
    "animation.html",
    "run.json",
)


@pytest.mark.slow
def test_quick_run_of_all_six_studies_writes_every_file(tmp_path):
    out = tmp_path / "results"
    done = run_cli("--quick", "--out", str(out), "--provider", "example_providers:controllers", timeout=1800)
    assert done.returncode == 0, done.stderr[-3000:]
    for plant in studies.names():
        for name in PER_PLANT:
            assert (out / plant / name).stat().st_size > 0, f"{plant}/{name}"
        assert (out / plant / "bode_input.png").exists(), plant
        table = pd.read_csv(out / plant / "table.csv")
        assert set(table.scenario) == {"step", "steps", "disturbance", "noise", "mc"}
        info = json.loads((out / plant / "run.json").read_text())
        assert info["settings"]["quick"] is True and (info["best"] is None or info["best"] in set(table.controller))
        numeral = info["numeral"]
        answers = (out / plant / "answers.md").read_text()
        assert f"{numeral}.5" in answers and f"{numeral}.7" in answers
        assert f"{numeral}.5" not in done.stdout  # answers go to the files unless --answers or -v
    assert (out / "summary.md").exists() and (out / "index.html").exists()
    assert not list(out.rglob("*.tmp*"))
    # After the progress bar: a line per plant with its rows that are not ok (a remark in two lines at most),
    # the paths, the total time: about a screen.
    lines = done.stdout.splitlines()
    assert len(lines) <= 9 * len(studies.names()) + 2, done.stdout
    assert [line.split(":")[0] for line in lines if not line.startswith(" ")][:6] == list(studies.names())


@pytest.mark.slow
def test_one_job_and_two_jobs_write_the_same_tables(tmp_path):
    tables = []
    for jobs in ("1", "2"):
        out = tmp_path / f"jobs{jobs}"
        done = run_cli(
            "arm",
            "uuv",
            "--scenario",
            "step,mc",
            "--mc",
            "12",
            "--out",
            str(out),
            "--quiet",
            "--jobs",
            jobs,
            "--provider",
            "example_providers:controllers",
            timeout=900,
        )
        assert done.returncode == 0, done.stderr[-3000:]
        tables.append({p: pd.read_csv(out / p / "table.csv") for p in ("arm", "uuv")})
    for plant in ("arm", "uuv"):
        columns = [
            "controller",
            "scenario",
            "status",
            "rise_time_s",
            "settling_time_s",
            "overshoot_pct",
            "iae",
            "peak_u",
            "samples",
        ]
        pd.testing.assert_frame_equal(tables[0][plant][columns], tables[1][plant][columns])
