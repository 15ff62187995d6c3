"""pyproject.toml against the code: every console script names a callable `main(argv=None)`, every
package ships its py.typed marker, and every third-party module the packages import is declared."""

import ast
import importlib
import inspect
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
PACKAGES = ("models", "designs", "mpc", "studies")
#: Import names whose distribution is named otherwise, for a module not installed here.
DISTRIBUTION_OF = {"PIL": "pillow"}


def requirement_name(requirement: str) -> str:
    """'dask[distributed]>=2024.1' -> 'dask' (PEP 503 normalized)."""
    name = requirement
    for stop in "[<>=!~; ":
        name = name.split(stop)[0]
    return name.strip().lower().replace("_", "-")


def with_extras(requirement: str) -> set[str]:
    """The requirement's distribution and those its extras pull in (dask[distributed] -> dask, distributed)."""
    name = requirement_name(requirement)
    extras = {e.strip() for e in requirement.partition("[")[2].partition("]")[0].split(",") if e.strip()}
    names = {name}
    for line in (metadata.requires(name) or []) if extras else []:
        marker = line.partition(";")[2].replace("'", '"')
        if any(f'extra == "{extra}"' in marker for extra in extras):
            names.add(requirement_name(line))
    return names


def declared(groups=()) -> set[str]:
    requirements = list(PROJECT["project"]["dependencies"])
    for group in groups:
        requirements += PROJECT["project"]["optional-dependencies"][group]
    return set().union(*(with_extras(r) for r in requirements))


def imported_modules(folders) -> set[str]:
    """Top-level names of every absolute import (lazy ones inside functions included)."""
    found = set()
    for folder in folders:
        for path in (ROOT / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Import):
                    found |= {alias.name.split(".")[0] for alias in node.names}
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    found.add(node.module.split(".")[0])
    return found


def third_party(modules) -> set[str]:
    first_party = set(PACKAGES) | {"tests", "benchmarks", "conftest"}
    return {m for m in modules if m not in sys.stdlib_module_names and m not in first_party and m != "__future__"}


def distributions(module: str) -> set[str]:
    found = metadata.packages_distributions().get(module) or [DISTRIBUTION_OF.get(module, module)]
    return {requirement_name(d) for d in found}


@pytest.mark.parametrize("script", sorted(PROJECT["project"]["scripts"]))
def test_console_script_targets_a_main_taking_argv(script):
    target = PROJECT["project"]["scripts"][script]
    module_name, _, attribute = target.partition(":")
    function = getattr(importlib.import_module(module_name), attribute)
    assert callable(function)
    parameters = inspect.signature(function).parameters
    assert list(parameters) == ["argv"] and parameters["argv"].default is None, target


def test_the_console_scripts_cover_the_command_line_entry_points():
    targets = set(PROJECT["project"]["scripts"].values())
    assert {"studies.cli:main", "studies.tuner:main", "studies.codesign_report:main"} <= targets


@pytest.mark.parametrize("package", PACKAGES)
def test_each_package_ships_its_py_typed_marker(package):
    assert (ROOT / package / "py.typed").is_file()
    assert "py.typed" in PROJECT["tool"]["setuptools"]["package-data"][package]


def test_the_packages_import_only_declared_distributions():
    # Bokeh (studies.designer) and Dask (--workers, --scheduler) are core dependencies: no extra needed.
    allowed = declared()
    missing = {m: distributions(m) for m in third_party(imported_modules(PACKAGES)) if not distributions(m) & allowed}
    assert not missing, f"imported but not declared in [project] dependencies: {missing}"


def test_the_tests_and_examples_import_only_declared_distributions():
    allowed = declared(["dev"])
    # Helper modules that tests import from beside them (from test_rti import ...) are not distributions.
    local = {path.stem for folder in ("tests", "examples") for path in (ROOT / folder).rglob("*.py")}
    modules = third_party(imported_modules(["tests", "examples"])) - local
    missing = {m: distributions(m) for m in modules if not distributions(m) & allowed}
    assert not missing, f"imported by tests or examples but not declared (dependencies or the dev extra): {missing}"


def test_the_page_templates_are_package_data():
    # The wheel (.ci/run installs one) carries exactly the files package-data names: every template must match.
    from fnmatch import fnmatch

    from studies import templates

    patterns = PROJECT["tool"]["setuptools"]["package-data"]["studies"]
    found = sorted(p.name for p in (ROOT / "studies" / "templates").iterdir() if p.suffix != ".py" and p.is_file())
    assert found and all(name.endswith(".html.j2") for name in found), found
    assert all(any(fnmatch(f"templates/{name}", pattern) for pattern in patterns) for name in found)
    assert all(templates.environment().get_template(name) for name in found)  # each one parses


def test_the_old_extras_are_kept_as_empty_aliases():
    # `pip install -e '.[designer]'` and `'.[dask]'` still resolve; what they installed is now core.
    extras = PROJECT["project"]["optional-dependencies"]
    assert extras["designer"] == [] and extras["dask"] == []
    core = declared()
    assert {"bokeh", "tornado", "dask", "distributed"} <= core, core
