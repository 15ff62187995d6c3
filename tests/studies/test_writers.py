"""The writer: JSON conventions, atomic files, and the files a study leaves."""

import copy
import dataclasses
import json
import math

import control
import numpy as np
import pandas as pd
import pytest
from example_providers import controllers as example_controllers

import studies
from models import files
from studies import runner, writers

REQUIRED_COLUMNS = [
    "controller",
    "scenario",
    "rise_time_s",
    "settling_time_s",
    "overshoot_pct",
    "ss_error",
    "iae",
    "itae",
    "peak_u",
    "u_limit",
    "saturated_frac",
    "energy",
    "violation",
    "step_ms",
]


def test_json_conventions():
    value = {
        "kp": np.float64(0.3),
        "n": np.int64(3),
        "ok": np.bool_(True),
        "poles": np.array([-1 + 2j, -1 - 2j]),
        "inf": math.inf,
        "minus": -np.inf,
        "nan": float("nan"),
        "K": np.array([[1.5, 2.0]]),
        "G": control.tf([2.0], [1.0, 3.0]),
        4: (1, 2.5),
    }
    decoded = json.loads(files.dumps(value))
    assert decoded == {
        "kp": 0.3,
        "n": 3,
        "ok": True,
        "poles": [[-1.0, 2.0], [-1.0, -2.0]],
        "inf": "inf",
        "minus": "-inf",
        "nan": "nan",
        "K": [[1.5, 2.0]],
        "G": {"num": [2.0], "den": [1.0, 3.0]},
        "4": [1, 2.5],
    }
    with pytest.raises(TypeError, match="cannot write object"):
        files.dumps({"x": object()})


def test_an_interrupted_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "table.csv"
    files.write_text(target, "old\n")
    with pytest.raises(RuntimeError, match="interrupted"):
        with files.atomic_path(target) as tmp:
            tmp.write_text("half a ta")
            raise RuntimeError("interrupted")
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["table.csv"]
    files.write_text(target, "new\n")
    assert target.read_text() == "new\n"


def test_check_writable_names_the_folder(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    with pytest.raises(OSError, match="cannot write to the output folder .*a-file/out"):
        files.check_writable(blocker / "out")
    assert files.check_writable(tmp_path / "new" / "folder").is_dir()


def test_format_number():
    assert [files.format_number(v) for v in (math.nan, math.inf, 0.0, 1234567.0, 0.000123456, 3, "x")] == [
        "—",
        "∞",
        "0",
        "1.235e6",
        "0.0001235",
        "3",
        "x",
    ]


def test_a_study_writes_every_file(arm_study):
    result, out = arm_study
    folder = out / "arm"
    for name in (
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
        "bode_input.png",
        "root_locus.png",
        "poles.png",
        "animation.gif",
        "animation.html",
        "run.json",
    ):
        assert (folder / name).stat().st_size > 0, name
    for name in ("summary.md", "index.html"):
        assert (out / name).stat().st_size > 0
    assert not list(out.rglob("*.tmp*"))
    table = pd.read_csv(folder / "table.csv")
    # Compute times change from run to run: they are in timings.csv, not in table.csv.
    assert set(REQUIRED_COLUMNS) - {"step_ms"} <= set(table.columns) and "step_ms" not in table
    assert len(table) == len(result.table) == 5 * len(result.controllers)
    np.testing.assert_allclose(table.iae, result.table.iae)
    timings = pd.read_csv(folder / "timings.csv")
    rows = timings[timings["sample"].isna()]
    assert list(rows.controller) == list(result.table.controller)
    np.testing.assert_allclose(rows.step_ms, result.table.step_ms, rtol=1e-9)
    markdown = (folder / "table.md").read_text()
    assert "Every row is a closed-loop simulation of the nonlinear" in markdown and "never a linear model" in markdown
    assert "ss error (deg)" in markdown  # angles in degrees, labelled
    lqr = result.table[(result.table.controller == "LQR") & (result.table.scenario == "step")].iloc[0]
    from studies.writers import verdict_text

    assert f"| LQR | step | {verdict_text(lqr.verdict)} | ok | {files.format_number(lqr.rise_time_s)} |" in markdown
    # Verdicts first (a grid, then what each row misses), metrics second.
    assert markdown.index("## Verdicts against the specs") < markdown.index("## Metrics")
    grid = f"| LQR | {verdict_text(lqr.verdict)} |"
    assert grid in markdown and markdown.index(grid) < markdown.index("## Metrics")
    for row in result.table[result.table.verdict != "meets specs"].itertuples():
        assert f"- {row.controller} / {row.scenario}: {verdict_text(row.verdict)}" in markdown
    assert files.format_number(math.degrees(lqr.ss_error)) in markdown


def test_answers_json_keys_items_and_holds_hand_derived_values(arm_study):
    _, out = arm_study
    answers = json.loads((out / "arm" / "answers.json").read_text())
    m, ell, g, b = 0.5, 0.3, 9.8, 0.01
    # I.5: level arm at rest needs τe = m g ℓ / 2; I.6: θ/τ = (3/(m ℓ²)) / (s² + 3b/(m ℓ²) s).
    assert answers["I.5"]["u_e"]["tau"] == pytest.approx(m * g * ell / 2)
    tf = answers["I.6"]["theta/tau"]
    assert tf["num"] == pytest.approx([3 / (m * ell**2)])
    assert tf["den"] == pytest.approx([1.0, 3 * b / (m * ell**2), 0.0])
    assert np.ravel(answers["I.7"]["B"]) == pytest.approx([0.0, 3 / (m * ell**2)])
    assert any(row["item"].startswith("I.15") for row in answers["errata"])
    assert "_conventions" in answers


def test_summary_and_index_link_what_exists(arm_study):
    _, out = arm_study
    summary = (out / "summary.md").read_text()
    assert "| controller | arm |" in summary and "| LQR |" in summary
    index = (out / "index.html").read_text()
    import re

    for link in re.findall(r'(?:href|src)="([^"#]+)"', index):
        assert (out / link).exists(), link


def test_the_pages_escape_as_the_standard_library_does():
    # The template engine's rule is html.escape's: quotes as &quot; and &#x27; (not MarkupSafe's &#34;, &#39;).
    from studies import templates

    assert templates.escape("<b>x</b> & \"q\" 'a'") == "&lt;b&gt;x&lt;/b&gt; &amp; &quot;q&quot; &#x27;a&#x27;"
    assert templates.escape(templates.Escaped("&amp;")) == "&amp;"  # markup is left as it is


def test_a_title_or_label_with_html_in_it_is_escaped_in_every_page(tmp_path):
    import copy
    import dataclasses
    import re

    from example_providers import controllers as example_controllers

    import studies
    from studies import runner, writers

    label, title = "<b>x</b> & y", "<b>Arm</b> & co"
    found = example_controllers("arm")
    case = dataclasses.replace(studies.get("arm"), providers=())
    result = runner.run_study(
        case, runner.Options(scenarios=("step",), mc=0), controllers={label: found["LQR fast"], "LQR": found["LQR"]}
    )
    plant = copy.copy(result.plant)
    plant.title = title
    # Every row meeting its specs, so the label is the page's best.
    result = dataclasses.replace(result, plant=plant, table=result.table.assign(verdict="meets specs"))
    out = tmp_path / "out"
    writers.write_study(result, out, run_id="escaped")
    writers.write_index(out, ["arm"], "escaped")
    pages = {name: (out / name).read_text(encoding="utf-8") for name in ("index.html", "arm/animation.html")}
    for name, page in pages.items():
        assert "<b>" not in page, name  # neither the title's nor the label's markup is markup
        assert "&lt;b&gt;Arm&lt;/b&gt; &amp; co" in page, name
    index = pages["index.html"]
    assert '<h2 id="arm">&lt;b&gt;Arm&lt;/b&gt; &amp; co</h2>' in index
    assert 'data-controller="&lt;b&gt;x&lt;/b&gt; &amp; y"' in index  # the heat map
    assert "<td>&lt;b&gt;x&lt;/b&gt; &amp; y</td>" in index  # the verdict grid and the step's metrics
    assert (
        "Best in the step scenario (lowest ITAE among rows meeting the specs): &lt;b&gt;x&lt;/b&gt; &amp; y</p>"
        in index
    )
    animation = pages["arm/animation.html"]
    assert re.search(r"<title>(.*)</title>", animation).group(1) == (
        "&lt;b&gt;Arm&lt;/b&gt; &amp; co: the controllers on the text&#x27;s step"
    )
    data = json.loads(re.search(r"const DATA = (\{.*?\});\n", animation).group(1))
    assert data["selected"] == label and data["order"] == [label, "LQR"]  # the script's data hold the label itself


def test_a_title_with_html_is_shown_literally_in_the_markdown_headings(tmp_path):
    """table.md and answers.md: the title is escaped in their headings (and table.md's caption), as the
    labels are in their tables; before, '# <b>Arm</b> & co: controllers compared' was written raw."""
    case = dataclasses.replace(studies.get("arm"), providers=())
    result = runner.run_study(
        case, runner.Options(scenarios=("step",), mc=0), controllers={"LQR": example_controllers("arm")["LQR"]}
    )
    plant = copy.copy(result.plant)
    plant.title = "<b>Arm</b> & co"
    result = dataclasses.replace(result, plant=plant)
    writers.write_study(result, tmp_path, run_id="escaped")
    table = (tmp_path / "arm" / "table.md").read_text(encoding="utf-8")
    answers = (tmp_path / "arm" / "answers.md").read_text(encoding="utf-8")
    escaped = r"\<b\>Arm\</b\> \& co"
    assert table.splitlines()[0] == f"# {escaped}: controllers compared"
    assert answers.splitlines()[0] == f"# Homework answers: {escaped}"
    assert f"the nonlinear {escaped} (" in table
    assert "<b>" not in table and "<b>" not in answers


def test_importing_the_writers_imports_no_matplotlib_pillow_or_jinja2():
    # They are imported at the first figure, GIF or page: the command line checks its arguments without them.
    import subprocess
    import sys

    code = (
        "import sys; import studies.writers, studies.plots, studies.overview, studies.animation; "
        "print(sorted(m for m in ('matplotlib', 'PIL', 'jinja2') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split("\n")[-2] == "[]", done.stdout + done.stderr


def test_the_tables_step_writes_the_tables_without_compute_times(arm_study, tmp_path):
    import dataclasses

    from studies import writers

    result, _ = arm_study
    files = writers.write_tables(result, tmp_path)
    assert list(files) == ["table.csv", "monte_carlo.csv", "timings.csv", "answers.json", "answers.md"]
    table = pd.read_csv(tmp_path / "table.csv")
    assert list(table.columns) == [c for c in result.table.columns if c not in ("wall_s", "step_ms", "step_ms_max")]
    np.testing.assert_allclose(table.itae, result.table.itae)
    assert (tmp_path / "answers.md").read_text().startswith(f"# Homework answers: {result.plant.title}\n")
    without_samples = dataclasses.replace(result, samples=result.samples.iloc[0:0])
    assert "monte_carlo.csv" not in writers.write_tables(without_samples, tmp_path)


def test_the_animation_step_says_why_there_is_no_animation(arm_study, tmp_path):
    import dataclasses

    from studies import writers

    result, _ = arm_study
    undrawn = dataclasses.replace(result, study=dataclasses.replace(result.study, drawing=None))
    assert writers.write_animation(undrawn, tmp_path) == ({}, ["no animation: the arm case has no drawing"])
    unrun = dataclasses.replace(result, runs={k: r for k, r in result.runs.items() if k[1] != "step"})
    assert writers.write_animation(unrun, tmp_path) == ({}, ["no animation: no controller completed the step scenario"])
    assert list(tmp_path.iterdir()) == []


def test_the_loop_step_writes_the_rows_it_returns(arm_study, tmp_path):
    from studies import writers

    result, _ = arm_study
    files, rows, _ = writers.write_loop_analysis(result, tmp_path, dpi=40)
    assert {"bode_input.png", "loops.csv", "root_locus.png", "poles.png"} <= set(files)
    assert all((tmp_path / name).stat().st_size > 0 for name in files.values())
    written = pd.read_csv(tmp_path / "loops.csv")
    assert list(written.controller) == [r["controller"] for r in rows] and set(written.controller) <= set(
        result.controllers
    )
    # A closed loop is stable exactly when its slowest pole s = ln(z)/Ts is in the left half plane.
    assert list(written.stable) == list(written.slowest_pole_real < 0)


def test_the_run_record_holds_the_digest_of_every_file(arm_study, tmp_path):
    import hashlib

    from studies import writers

    result, _ = arm_study
    (tmp_path / "a.txt").write_text("one")
    (tmp_path / "b.csv").write_bytes(b"x,y\n1,2\n")
    record = writers.run_record(result, tmp_path, {"a": "a.txt", "b": "b.csv"}, ["a note"], "some-run")
    assert record["sha256"] == {
        "a.txt": hashlib.sha256(b"one").hexdigest(),
        "b.csv": hashlib.sha256(b"x,y\n1,2\n").hexdigest(),
    }
    assert (record["run_id"], record["notes"], record["plant"], record["best"]) == (
        "some-run",
        ["a note"],
        "arm",
        result.best("step"),
    )


def test_table_md_says_the_remark_of_a_controller_whose_rows_meet_their_specs_once():
    """A row that meets its specs lists no detail, so its controller's remark (a tuned design's certificate
    about the whole parameter box) is said once under the grid; a failing controller's rows already say it
    first in their details, and it is not repeated."""
    table = pd.DataFrame(
        {
            "controller": ["tuned", "tuned", "PD", "PD", "LQR"],
            "remark": ["certificate A", "certificate A", "refused B", "refused B", None],
        }
    )
    assert writers._remarks(table, shown={"PD"}) == {"tuned": "certificate A"}
    assert writers._remarks(table.drop(columns="remark"), shown=set()) == {}
