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


#: Third-party modules that take from 0.1 to 1 s each to import, and the page writers: --list and --help
#: need none of them (the case files' designs import them at their first use, `models.deferred`).
HEAVY = ("control", "scipy", "pandas", "matplotlib", "sympy", "cvxpy", "osqp", "distributed", "jinja2")


@pytest.mark.parametrize("argv", [["--list"], ["--list", "pendulum"], ["--help"]])
def test_list_and_help_read_the_registry_and_import_nothing_heavy(argv):
    """--list and --help import the registered cases (the one list of plants), and none of the heavy
    third-party modules (the writers defer theirs): which modules a command imports does not depend on
    the machine, its time does."""
    import subprocess
    import sys

    from conftest import REPO, subprocess_env

    script = (
        "import sys\n"
        "from studies import cli\n"
        "try:\n"
        f"    cli.main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
        "print('studies.cases.pendulum' in sys.modules)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, env=subprocess_env(), capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    imported, cases_imported = done.stdout.strip().splitlines()[-2:]
    assert imported == "[]" and cases_imported == "True"
    if argv[0] == "--list":
        assert "pendulum: II.8(h) step 2 m" in done.stdout
    else:
        text = " ".join(done.stdout.split())  # argparse wraps the help's lines
        assert "plants to study (default all: arm, pendulum, satellite, uuv, ballbeam, crane)" in text
