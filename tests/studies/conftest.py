"""Fixtures of the study tests: example providers on the path, one small written study,
and the system's headless Chromium driven through Selenium and its chromedriver."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))  # example_providers, importable as the CLI would import a provider

EXAMPLE = "example_providers:controllers"


@pytest.fixture(scope="session")
def arm_study(tmp_path_factory):
    """The arm study with the example controllers, 8 Monte Carlo samples, written to a folder."""
    import studies
    from studies import writers

    out = tmp_path_factory.mktemp("results")
    result = studies.run_study("arm", providers=(EXAMPLE,), mc=8, seed=5, quick=True, out=out)
    writers.write_summary(out, studies.names())
    writers.write_index(out, studies.names())
    return result, out


def subprocess_env() -> dict:
    """Environment for running ``python -m studies`` from the repository root with the example providers."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(HERE), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["MPLBACKEND"] = "Agg"
    return env


# ----------------------------------------------------------------------------- headless Chromium
def chromium_paths() -> tuple[str | None, str | None]:
    """The Chromium executable and its chromedriver (Debian's chromium and chromium-driver), or None."""
    browser = next(
        (path for name in ("chromium", "chromium-browser", "google-chrome") if (path := shutil.which(name))), None
    )
    driver = shutil.which("chromedriver") or (
        "/usr/bin/chromedriver" if Path("/usr/bin/chromedriver").exists() else None
    )
    return browser, driver


class Page:
    """One headless Chromium page: open a file, run scripts, read console errors."""

    def __init__(self, driver):
        self.driver = driver

    def open(self, url: str) -> None:
        self.driver.get(url)

    def evaluate(self, expression: str):
        """The value of a JavaScript expression (statements allowed before it, separated by ';')."""
        body, _, last = expression.strip().rstrip(";").rpartition(";")
        return self.driver.execute_script(f"{body}; return ({last});" if body else f"return ({last});")

    def wait(self, expression: str):
        """The value a JavaScript promise expression resolves to."""
        return self.driver.execute_async_script(
            f"const done = arguments[arguments.length - 1]; Promise.resolve({expression}).then(done);"
        )

    def errors(self) -> list[str]:
        """Console errors and uncaught exceptions seen so far."""
        return [entry["message"] for entry in self.driver.get_log("browser") if entry["level"] == "SEVERE"]


@pytest.fixture
def browser(tmp_path):
    webdriver = pytest.importorskip("selenium.webdriver")
    executable, driver_path = chromium_paths()
    if executable is None or driver_path is None:
        pytest.skip("Chromium or chromedriver is not installed (CI installs chromium and chromium-driver)")
    options = webdriver.ChromeOptions()
    options.binary_location = executable
    for flag in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--window-size=1200,900",
        f"--user-data-dir={tmp_path / 'profile'}",
    ):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(executable_path=driver_path))
    driver.set_script_timeout(30)
    try:
        yield Page(driver)
    finally:
        driver.quit()
