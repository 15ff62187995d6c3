"""The registry of case studies is the only list of plants: its order, its lookups, and the CLI's list."""

import pytest

import models
import studies
from studies.case import numeral_value


def test_the_six_cases_in_the_texts_order():
    assert studies.names() == ("arm", "pendulum", "satellite", "uuv", "ballbeam", "crane")
    numerals = [numeral_value(studies.get(n).numeral) for n in studies.names()]
    assert numerals == [1, 2, 3, 4, 5, 6]


@pytest.mark.parametrize("name", studies.names())
def test_every_case_tracks_a_coordinate_of_its_plant(name):
    case = studies.get(name)
    assert case.plant == name and case.tracked in models.get(name).coordinate_names
    assert case.step > 0 and case.design_step > 0 and case.input_disturbance > 0
    assert {s.name for s in case.scenarios} <= set(studies.SCENARIO_NAMES)


def test_bad_names_are_refused_with_the_valid_ones():
    with pytest.raises(ValueError, match="unknown plant 'segway'; valid plants: arm, pendulum"):
        studies.get("segway")
    with pytest.raises(ValueError, match="Roman numeral"):
        numeral_value("7")
    with pytest.raises(TypeError, match="needs a studies.CaseStudy"):
        studies.register("arm")


def test_roman_numerals():
    assert [numeral_value(n) for n in ("I", "IV", "IX", "XIV", "XL")] == [1, 4, 9, 14, 40]


def test_the_listing_read_from_the_case_files_agrees_with_the_imported_registry():
    from studies import listing

    assert listing.names() == studies.names()
    for name in studies.names():
        case, listed = studies.get(name), listing.get(name)
        assert (listed.numeral, listed.source, listed.controllers) == (
            case.numeral,
            case.source,
            tuple(case.controllers),
        )
        assert listed.scenarios == tuple(s.name for s in case.scenarios)


def test_list_imports_neither_the_cases_nor_the_numerics():
    """--list reads the case files' text: no CasADi, python-control or design is imported (it takes well under
    a second instead of the seconds those imports cost)."""
    import subprocess
    import sys

    from conftest import REPO, subprocess_env

    script = (
        "import sys; from studies import cli; cli.main(['--list']);"
        "print(sorted(m for m in ('casadi', 'control', 'scipy', 'models', 'designs', 'studies.cases')"
        " if m in sys.modules))"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, env=subprocess_env(), capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]"
    assert "pendulum: II.8(h) step 2 m" in done.stdout
