"""The condensing kernel's library (mpc.condensing) comes through models.compile's checked loader: a
damaged cache entry is rebuilt with a warning, and the kernel is there again (before: opened with its own
ctypes.CDLL, a damaged entry made the MPC rows vanish, run after run).

Build and load happen in child processes, so that a crash on a damaged library fails the test."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import models
import mpc
from mpc.rti import RealTimeIteration

REPO = Path(__file__).resolve().parent.parent.parent

CHILD = """
import json, sys, warnings
import numpy as np
sys.path.insert(0, {tests!r})
import mpc
from mpc.rti import RealTimeIteration
from test_rti import pendulum_problem
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    _, ocp = pendulum_problem(soft=True, rate=np.array([0.3]))
    tr = mpc.Transcription(ocp, mpc.MultipleShooting(intervals=30))
    rti = RealTimeIteration(tr, compiled=True)
    kernel = rti.condensing
    lin = np.random.default_rng(3).normal(size=(2, kernel.lin_size)) if kernel else None
    value = kernel(lin).ravel().tolist() if kernel else None
print(json.dumps({{"warnings": [[type(w.message).__name__, str(w.message)] for w in caught], "value": value}}))
"""


def child(cache: Path) -> dict:
    env = {key: value for key, value in os.environ.items() if key not in ("CC", "CODESIGN_CONTROL_CACHE")}
    env |= {"PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1", "CODESIGN_CONTROL_CACHE": str(cache)}
    body = CHILD.format(tests=str(REPO / "tests" / "mpc"))
    done = subprocess.run([sys.executable, "-c", body], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"the child process ended with {done.returncode}:\n{done.stderr[-3000:]}"
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None, reason="needs a C compiler")
@pytest.mark.parametrize("kind", ["truncated", "random bytes"])
def test_a_damaged_condensing_entry_is_rebuilt_and_the_kernel_comes_back(kind):
    folder = Path(tempfile.mkdtemp(prefix="condensing-cache-"))
    try:
        cache = folder / "cache"
        first = child(cache)
        assert first["value"] is not None and first["warnings"] == []
        (library,) = [
            p
            for p in cache.rglob("*.so")
            if p.is_file() and not any(s.startswith(".") for s in p.parts) and b"condense\x00" in p.read_bytes()
        ]
        data = library.read_bytes()
        library.write_bytes(data[: len(data) // 2] if kind == "truncated" else os.urandom(len(data)))
        second = child(cache)
        assert [c for c, _ in second["warnings"]] == ["CacheEntryRebuilt"], second["warnings"]
        assert "rebuilt" in second["warnings"][0][1]
        assert second["value"] == first["value"]
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def test_the_kernel_is_opened_by_the_one_loader(monkeypatch):
    """mpc.condensing opens its library through models.compile.load_library (checked, rebuilt when
    damaged), not with a ctypes.CDLL of its own."""
    sys.path.insert(0, str(REPO / "tests" / "mpc"))
    from test_rti import pendulum_problem

    loaded = []
    original = models.compile.load_library

    def recording(files, *args, **kwargs):
        library = original(files, *args, **kwargs)
        loaded.append((sorted(files), library))
        return library

    monkeypatch.setattr(models.compile, "load_library", recording)
    _, ocp = pendulum_problem(soft=True, rate=np.array([0.3]))
    rti = RealTimeIteration(mpc.Transcription(ocp, mpc.MultipleShooting(intervals=30)), compiled=True)
    if rti.condensing is None:
        pytest.skip("no compiler")
    assert [names for names, _ in loaded if names == ["condense.c"]] == [["condense.c"]]
