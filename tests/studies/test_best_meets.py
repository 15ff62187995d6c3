""" "Best" is the lowest step ITAE among controllers whose every row meets its specs, on the console and on the
heat map: a violating row with the lowest ITAE is never called best, nor a controller that meets the step but
violates its specs elsewhere, and with no meeting row nothing is."""

import dataclasses
import math
import re
import types

import pandas as pd

from models import specs
from studies import batch, cli, overview, runner


def _table(verdicts):
    return pd.DataFrame(
        {
            "controller": ["fast", "middle", "slow"],
            "scenario": ["step"] * 3,
            "status": ["ok"] * 3,
            "verdict": verdicts,
            "verdict_detail": ["" if v == specs.MEETS else "overshoot 25 % > 10 %" for v in verdicts],
            "itae": [0.1, 0.3, 0.5],
        }
    )


def _result(table):
    fields = {f.name: None for f in dataclasses.fields(runner.StudyResult) if f.name != "table"}
    fields |= {
        "study": types.SimpleNamespace(plant="plant"),
        "controllers": {},
        "notes": [],
        "timing": {},
        "left_out": (),
    }
    return runner.StudyResult(table=table, **fields)


def test_the_console_names_the_best_meeting_row_and_says_when_none_meets():
    table = _table([specs.VIOLATES, specs.MEETS, specs.MEETS])
    line = cli._plant_line(batch.plant_report(_result(table), answers=False))
    assert line.endswith("best step ITAE: middle") and "fast" not in line
    table = _table([specs.VIOLATES] * 3)
    line = cli._plant_line(batch.plant_report(_result(table), answers=False))
    assert line.endswith("best step ITAE: none, no step row meets the specs")
    assert not any(name in line for name in ("fast", "middle", "slow"))


def test_the_heat_maps_one_times_is_a_meeting_row_and_absent_when_none_meets():
    table = _table([specs.VIOLATES, specs.MEETS, specs.MEETS])
    ratios = overview.relative_itae(table)
    assert ratios["middle"] == 1.0 and ratios["slow"] == 0.5 / 0.3
    html = overview.heat_map([("plant", {"title": "plant"}, table)])
    cell = html[html.index('data-controller="middle"') :]
    assert cell[: cell.index("</td>")].endswith("1×")
    table = _table([specs.VIOLATES] * 3)
    assert all(math.isnan(r) for r in overview.relative_itae(table).values())
    html = overview.heat_map([("plant", {"title": "plant"}, table)])
    numbers = re.findall(r'class="mark"[^>]*>[^<]*</span> ([^<]*)</td>', html)
    assert numbers == ["", "", ""]
