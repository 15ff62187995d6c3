"""A damaged compile cache (models.compile): every entry is checked (size, SHA-256, ELF structure) before
it is loaded, and an entry that fails is rebuilt with one warning saying so.

Each damage is done here, between two child processes: the first builds the entry, the second loads it
after the damage. A crash of the second (SIGSEGV, SIGBUS, SIGTRAP on dlopen or on the first call) is a
failed test, not a dead pytest. Values are compared with CasADi's virtual machine and with an undamaged
build; where the machine code and the constants are in the file is read with ``readelf`` (binutils),
not with the module's own ELF reader.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import re
import shutil
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

import models
from models import compile as mc
from models import elf

REPO = Path(models.__file__).resolve().parent.parent

#: The function compiled: its constants 2.5 and 1.75 are doubles in the library's read-only data.
FUNCTION = """
import casadi as ca
x = ca.SX.sym("x", 3)
fun = ca.Function("affine_sine", [x], [2.5 * x + 1.75 + ca.sin(x) * x**2], ["x"], ["y"])
point = [0.3, -1.2, 2.5]
"""

JIT = (
    FUNCTION
    + """
compiled = mc.jit(fun)
value = np.asarray(compiled(point)).ravel().tolist()
machine = np.asarray(fun(point)).ravel().tolist()
report["compiled_function"] = compiled.class_name() != fun.class_name()
"""
)

NLPSOL = """
import casadi as ca
x = ca.MX.sym("x", 2)
problem = {"x": x, "f": (x[0] - 0.7) ** 2 + 10 * (x[1] - x[0] ** 2) ** 2, "g": x[0] + x[1]}
options = {"ipopt": {"print_level": 0, "sb": "yes", "tol": 1e-12}, "print_time": False}
solver = mc.jit_nlpsol("rosenbrock", "ipopt", problem, options)
plain = ca.nlpsol("rosenbrock", "ipopt", problem, options)
args = dict(x0=[0.0, 0.0], lbg=-np.inf, ubg=1.0)
value = np.asarray(solver(**args)["x"]).ravel().tolist()
machine = np.asarray(plain(**args)["x"]).ravel().tolist()
"""

EXPORT = """
import casadi as ca
import models
from models import export

class PD(models.Block):
    def __init__(self):
        super().__init__(sample_period=0.01, n_state=1, n_measured=1, n_reference=1, n_input=1,
                         gains={"kp": 4.0, "kd": 0.2})
    def expr(self, xc, y, r, gains):
        error = r[0] - y[0]
        return ca.vertcat(error), models.saturate(gains["kp"] * error + gains["kd"] * (error - xc[0]) / 0.01, 1.0)

block = PD()
loaded = export.export_block(block, "pd").load()
value, machine = [], []
for y, r, xc in ((0.1, 0.3, 0.0), (-0.2, 0.1, 0.05), (0.0, 0.0, 0.2)):
    value += [float(v) for v in np.concatenate(loaded.step([xc], [y], [r]))]
    machine += [float(np.asarray(v).ravel()[0]) for v in block.casadi_step([xc], [y], [r], block.gain_vector())]
"""

HEAD = """
import json, warnings
import numpy as np
from models import compile as mc
report = {}
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
"""

TAIL = """
report.update(
    value=value, machine=machine,
    warnings=[(w.category.__name__, str(w.message)) for w in caught if issubclass(w.category, RuntimeWarning)],
    compiled=mc.STATS.compiled, cache_hits=mc.STATS.cache_hits, fallbacks=mc.STATS.fallbacks,
)
print(json.dumps(report))
"""


def child(body: str, cache: Path, **env_changes) -> dict:
    """Run `body` (which sets `value` and `machine`) in a fresh interpreter with `cache` as the compile cache;
    its report. Asserts it exited normally: a crash on loading a damaged library fails here."""
    indented = "\n".join("    " + line for line in body.strip().splitlines())
    env = {key: value for key, value in os.environ.items() if key not in ("CC", "CODESIGN_CONTROL_CACHE")}
    env |= {"PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1", "CODESIGN_CONTROL_CACHE": str(cache)}
    env |= env_changes
    done = subprocess.run(
        [sys.executable, "-c", HEAD + indented + TAIL], env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, f"the child process ended with {done.returncode}:\n{done.stderr[-3000:]}"
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.fixture
def cache():
    """A private, empty compile cache (removed at the end)."""
    path = Path(tempfile.mkdtemp(prefix="compile-cache-"))
    yield path / "cache"
    shutil.rmtree(path, ignore_errors=True)


def libraries(cache: Path) -> list[Path]:
    """The shared libraries in the cache, whatever its layout."""
    return sorted(p for p in cache.rglob("*.so") if p.is_file() and not any(s.startswith(".") for s in p.parts))


def sections(library: Path) -> dict[str, tuple[int, int]]:
    """Section name -> (file offset, size) as readelf reads them."""
    listing = subprocess.run(["readelf", "-S", "-W", str(library)], capture_output=True, text=True, check=True)
    found = {}
    for line in listing.stdout.splitlines():
        match = re.match(r"\s*\[\s*\d+\]\s+(\S+)\s+\S+\s+[0-9a-f]+\s+([0-9a-f]+)\s+([0-9a-f]+)", line)
        if match:
            found[match.group(1)] = (int(match.group(2), 16), int(match.group(3), 16))
    return found


def damage(library: Path, kind: str) -> None:
    """Damage `library` in place as `kind` says."""
    data = bytearray(library.read_bytes())
    if kind == "truncated":
        data = data[: len(data) // 2]
    elif kind == "machine code overwritten":
        offset, size = sections(library)[".text"]
        data[offset : offset + size] = b"\xcc" * size  # int3: SIGTRAP wherever it runs
    elif kind == "constants altered":
        for old, new in ((2.5, -7.25), (1.75, 3.125)):
            packed = struct.pack("<d", old)
            assert packed in data, f"the constant {old} is not in the library"
            data = data.replace(packed, struct.pack("<d", new))
    elif kind == "0 bytes":
        data = bytearray()
    elif kind == "random bytes":
        data = bytearray(random.Random(0).randbytes(len(data)))
    else:
        raise AssertionError(kind)
    library.write_bytes(bytes(data))


DAMAGES = ["truncated", "machine code overwritten", "constants altered", "0 bytes", "random bytes"]


@pytest.mark.skipif(shutil.which("readelf") is None, reason="readelf (binutils) locates the sections to damage")
@pytest.mark.parametrize("kind", DAMAGES)
def test_a_damaged_cache_entry_is_detected_rebuilt_and_warned(cache, kind):
    first = child(JIT, cache)
    assert first["compiled"] == 1 and first["compiled_function"] and first["warnings"] == []
    (library,) = libraries(cache)
    intact = library.read_bytes()
    damage(library, kind)
    assert library.read_bytes() != intact
    second = child(JIT, cache)
    # One warning, saying the entry was rebuilt and why; the rebuilt library gives the undamaged build's
    # values, and CasADi's virtual machine's.
    assert [category for category, _ in second["warnings"]] == ["CacheEntryRebuilt"], second["warnings"]
    message = second["warnings"][0][1]
    assert "rebuilt" in message and str(library.parent) in message, message
    assert second["compiled"] == 1 and second["fallbacks"] == 0 and second["compiled_function"]
    assert second["value"] == first["value"]
    assert max(abs(a - b) for a, b in zip(second["value"], second["machine"])) <= 1e-13
    # The entry was repaired, not bypassed: the next process loads it without a word.
    third = child(JIT, cache)
    assert third["warnings"] == [] and third["compiled"] == 0 and third["cache_hits"] == 1
    assert third["value"] == first["value"]
    assert libraries(cache) == [library]


@pytest.mark.skipif(shutil.which("readelf") is None, reason="readelf (binutils) locates the sections to damage")
@pytest.mark.parametrize("body, kind", [(NLPSOL, "truncated"), (EXPORT, "machine code overwritten")])
def test_an_nlp_solver_and_an_exported_controller_are_rebuilt_too(cache, body, kind):
    """The two other loaders: CasADi's nlpsol on a library, and ctypes (an exported controller)."""
    first = child(body, cache)
    assert first["compiled"] == 1 and first["warnings"] == []
    (library,) = libraries(cache)
    damage(library, kind)
    second = child(body, cache)
    assert [category for category, _ in second["warnings"]] == ["CacheEntryRebuilt"], second["warnings"]
    assert second["compiled"] == 1 and second["value"] == first["value"]
    assert max(abs(a - b) for a, b in zip(second["value"], second["machine"])) <= 1e-9


def test_a_damaged_entry_without_a_compiler_is_never_loaded(cache):
    """Rebuilding is impossible (no compiler): the virtual machine runs, with the one warning that says so,
    and the damaged library is not opened."""
    child(JIT, cache)
    (library,) = libraries(cache)
    damage(library, "random bytes")
    report = child(JIT, cache, CC="/nonexistent/cc")
    assert [category for category, _ in report["warnings"]] == ["CompilationUnavailable"]
    assert "no C compiler" in report["warnings"][0][1]
    assert not report["compiled_function"] and report["value"] == report["machine"]


def test_an_entry_records_the_size_and_digest_of_its_library(cache, monkeypatch):
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(cache))
    library = mc.build_library({"a.c": "double twice(double x) { return 2 * x; }"})
    record = json.loads(mc.entry_record(library).read_text())
    data = library.read_bytes()
    assert record["size"] == len(data) and record["sha256"] == hashlib.sha256(data).hexdigest()
    assert mc.check_entry(library) is None


@pytest.mark.skipif(shutil.which("readelf") is None, reason="readelf (binutils) locates the sections to damage")
@pytest.mark.parametrize("kind", ["truncated", "0 bytes", "random bytes"])
def test_the_elf_check_refuses_what_dlopen_would_choke_on(tmp_path, cache, monkeypatch, kind):
    """`models.elf.check_shared_library` alone (no record involved): the header and section table of an
    intact library pass, a truncated, empty or random file does not."""
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(cache))
    library = mc.build_library({"a.c": "double twice(double x) { return 2 * x; }"})
    assert elf.check_shared_library(library) is None
    copy = tmp_path / "copy.so"
    shutil.copy(library, copy)
    damage(copy, kind)
    assert elf.check_shared_library(copy) is not None
