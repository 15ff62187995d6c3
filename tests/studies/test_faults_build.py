"""A provider's Block whose CasADi expression raises when built: a failed row naming its provider, and
the other controllers of the study run."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import example_providers
import pytest
from conftest import subprocess_env

import models
import studies
from studies import plain_markdown, provider_calls, runner

STEP_ONLY = runner.Options(scenarios=("step",), mc=0)


class Unbuildable(example_providers.StateFeedback):
    """The example LQR, whose expression raises as a designer's formula dividing by zero would."""

    def expr(self, xc, y, r, gains):
        raise ZeroDivisionError("the designer's formula divides by zero")


def broken_block(case, known: models.Plant | None = None) -> dict:
    """The example LQR as a Block whose expression raises when its step is built."""
    lqr = example_providers.controllers(case, known)["LQR"]
    broken = Unbuildable.__new__(Unbuildable)
    broken.__dict__.update({k: v for k, v in vars(lqr).items() if k != "casadi_step"})
    return {"broken block": broken}


def arm_study(*providers):
    return dataclasses.replace(studies.get("arm"), providers=tuple(providers))


def test_a_block_whose_expression_raises_is_a_failed_row_naming_its_provider_and_the_rest_runs():
    # before: the error escaped the row (building its step to free its closed loop) and stopped the whole
    # run, every other controller lost and this one not named
    result = runner.run_study(arm_study(example_providers.lqr_only, broken_block), STEP_ONLY)
    status = dict(zip(result.table.controller, result.table.status))
    assert status["LQR"] == "ok"
    assert status["broken block"] == "failed: ZeroDivisionError: the designer's formula divides by zero"
    provider = provider_calls.name_of(broken_block)
    (note,) = [n for n in result.notes if n.startswith(f"{provider}: 'broken block' failed to build")]
    assert "ZeroDivisionError: the designer's formula divides by zero; at " in note and __file__ in note


def test_with_strict_the_same_block_stops_the_run():
    with pytest.raises(ZeroDivisionError, match="divides by zero"):
        runner.run_study(
            arm_study(example_providers.lqr_only, broken_block), dataclasses.replace(STEP_ONLY, strict=True)
        )


def test_the_check_leaves_the_providers_block_as_it_came():
    """The expression is built on a copy: the Block handed to the run (and pickled to workers) carries
    no CasADi Function from the check."""
    lqr = example_providers.controllers(studies.get("arm"), None)["LQR"]
    assert provider_calls.unbuildable("p", {"LQR": lqr}) == []
    assert "casadi_step" not in vars(lqr)


@pytest.mark.slow
@pytest.mark.parametrize(("strict", "status"), [((), 0), (("--strict",), 1)])
def test_the_command_goes_on_past_the_block_and_exits_1_only_with_strict(tmp_path, strict, status):
    done = subprocess.run(
        [sys.executable, "-m", "studies", "arm", "--scenario", "step", "--mc", "0", "--quick", "--quiet"]
        + ["--out", "out", "--provider", "test_faults_build:broken_block", *strict],
        cwd=tmp_path,
        env=subprocess_env(),
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert done.returncode == status, done.stderr[-3000:]
    if not strict:
        table = (tmp_path / "out/arm/table.csv").read_text()
        assert "broken block,step" in table and "failed: ZeroDivisionError" in table
        assert "LQR" in table and ",ok," in table  # the case's own controllers ran
        note = plain_markdown.markdown_text("test_faults_build:broken_block: 'broken block' failed to build")
        assert note in (tmp_path / "out/arm/table.md").read_text()
