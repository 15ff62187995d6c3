"""A study on a damaged compile cache (issue 31, class 1): ``python -m studies uuv`` with every cached
library damaged runs to exit 0, says that each entry was rebuilt, and writes the table an undamaged
run writes, byte for byte, its MPC rows included (the linear MPC's condensing kernel is one of the
entries, opened with ctypes by mpc.condensing)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from conftest import subprocess_env

from models import compile as mc


def study(cwd: Path, cache: Path, out: str) -> subprocess.CompletedProcess:
    """``python -m studies uuv --quick --out OUT`` with `cache` as the compile cache."""
    env = subprocess_env() | {"CODESIGN_CONTROL_CACHE": str(cache)}
    return subprocess.run(
        [sys.executable, "-m", "studies", "uuv", "--quick", "--out", out],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=1200,
    )


@pytest.mark.slow  # two quick uuv runs, each compiling its libraries: about a minute
def test_a_uuv_study_on_damaged_cache_entries_rebuilds_them_and_writes_the_same_table(tmp_path):
    cache = tmp_path / "cache"
    first = study(tmp_path, cache, "undamaged")
    assert first.returncode == 0, first.stderr[-3000:]
    libraries = sorted(p for p in cache.rglob("*.so") if not any(s.startswith(".") for s in p.parts))
    assert any(b"condense" in p.read_bytes() for p in libraries)  # the linear MPC's kernel is cached too
    # Damage each library: the first truncated (a SIGBUS on dlopen before), the others overwritten in
    # their middle (their machine code or tables: a crash or wrong numbers).
    for k, library in enumerate(libraries):
        data = bytearray(library.read_bytes())
        if k == 0:
            data = data[: len(data) // 2]
        else:
            middle = len(data) // 2
            data[middle - 2048 : middle + 2048] = b"\xcc" * 4096
        library.write_bytes(bytes(data))
    second = study(tmp_path, cache, "damaged")
    assert second.returncode == 0, second.stderr[-3000:]
    rebuilt = [line for line in second.stderr.splitlines() if "CacheEntryRebuilt" in line]
    assert len(rebuilt) == len(libraries), second.stderr[-3000:]
    assert all(any(str(p.parent) in line for line in rebuilt) for p in libraries)
    table = (tmp_path / "damaged" / "uuv" / "table.csv").read_bytes()
    assert table == (tmp_path / "undamaged" / "uuv" / "table.csv").read_bytes()
    assert b"linear MPC" in table and b"nonlinear MPC" in table
    assert all(mc.check_entry(p) is None for p in libraries)
