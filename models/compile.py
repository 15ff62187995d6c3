"""Compiling generated C: CasADi Functions and NLP solvers to machine code, exported controllers.

One mechanism for every piece of C the project builds (a closed loop's
``jit``, the tuning NLP, exported controllers):

- the C source is generated in memory (`casadi.CodeGenerator.dump`), never
  into the working directory;
- the compiler runs as ``subprocess.run([cc, ...], check=True)``, arguments
  as a list (no shell), in a private build directory under the cache;
- the library is cached under a hash of the sources, the flags, the
  compiler's identity and the machine, and moved into the cache with one
  atomic rename, so a second run (or a second process) does not recompile
  and two processes compiling at once are safe;
- when compiling is impossible (no compiler, no writable private cache, a
  compiler error), `jit` and `jit_nlpsol` return CasADi's virtual-machine
  Function instead and say so once per process with a
  `CompilationUnavailable` warning: a run never fails because of it.

The compiler is ``$CC`` when set (split into words, never given to a shell),
else ``cc``, ``gcc`` or ``clang`` from the PATH. The cache is
``$CODESIGN_CONTROL_CACHE`` when set, else ``$XDG_CACHE_HOME/codesign-control``
(``~/.cache/codesign-control``); it must be an absolute path, owned by the
user and writable by no one else.

Compiling costs time once per Function (then the cache answers) and makes
long runs several times faster than CasADi's virtual machine, so it is asked
for (``jit=True``), not assumed; figures in docs/notes/models.md. A compiled
copy has no derivatives (differentiate the original).
"""

from __future__ import annotations

import functools
import hashlib
import os
import platform
import shlex
import shutil
import stat
import subprocess
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from . import interrupts

#: Libraries run on the machine that compiles them (the machine is part of the cache key),
#: so -march=native is safe.
FLAGS = ("-O3", "-march=native")
#: Flags every shared library gets, whatever the optimization flags.
LIBRARY_FLAGS = ("-shared", "-fPIC")
#: Bump when the way libraries are built changes, so old cache entries are not reused.
LAYOUT_VERSION = "1"
#: Build directories older than this (s) are left over from a killed process and removed.
STALE_BUILD_AGE = 24 * 3600.0


class CompilationUnavailable(RuntimeWarning):
    """Compiling was impossible; CasADi's virtual machine runs instead (same results, slower)."""


class CompilationError(RuntimeError):
    """A compiler was found but building the library failed; the message has its first error lines."""


@dataclass
class Counters:
    """What this process did: compiler runs, cache hits and fallbacks to the virtual machine."""

    compiled: int = 0
    cache_hits: int = 0
    fallbacks: int = 0


#: Counters of this process (tests read them; nothing depends on them).
STATS = Counters()
_WARNED: set[str] = set()


# ---------------------------------------------------------------------------- compiler and cache
def compiler() -> list[str] | None:
    """The C compiler command as an argument list, or None when there is none.

    ``$CC`` when set and non-empty (its first word resolved on the PATH), else
    the first of ``cc``, ``gcc``, ``clang`` on the PATH.
    """
    override = os.environ.get("CC", "").strip()
    if override:
        words = shlex.split(override)
        found = shutil.which(words[0])
        return [found, *words[1:]] if found else None
    for name in ("cc", "gcc", "clang"):
        found = shutil.which(name)
        if found:
            return [found]
    return None


@functools.lru_cache(maxsize=8)
def _compiler_identity(command: tuple[str, ...]) -> str | None:
    """The compiler's ``--version`` banner (part of the cache key), None when it does not run."""
    try:
        done = subprocess.run(
            [*command, "--version"], check=True, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=60
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip()


@functools.lru_cache(maxsize=1)
def _machine_identity() -> str:
    """CPU model and instruction-set flags: a cache shared over NFS must not hand one machine
    another's -march=native code."""
    parts = [platform.machine(), platform.system()]
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as handle:
            for line in handle:
                if line.startswith(("model name", "flags")):
                    parts.append(line.strip())
                if len(parts) >= 4:
                    break
    except OSError:
        parts.append(platform.processor())
    return "\n".join(parts)


def cache_directory() -> Path:
    """Where compiled libraries are kept (see the module docstring); not created here."""
    override = os.environ.get("CODESIGN_CONTROL_CACHE", "")
    if override:
        return Path(override)
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    if xdg and os.path.isabs(xdg):
        return Path(xdg) / "codesign-control"
    try:
        return Path.home() / ".cache" / "codesign-control"
    except RuntimeError:  # no home directory: a per-user folder in the temporary directory
        return Path(tempfile.gettempdir()) / f"codesign-control-{os.getuid()}"


def _private_directory(path: Path) -> str | None:
    """Create `path` (mode 700) if needed; the reason it cannot serve as a private cache, or None."""
    if not path.is_absolute():
        return f"the cache directory {str(path)!r} is not an absolute path"
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        info = path.stat()
    except OSError as err:
        return f"cannot create the cache directory {str(path)!r}: {err.strerror or err}"
    if hasattr(os, "getuid") and info.st_uid != os.getuid():
        return f"the cache directory {str(path)!r} belongs to another user"
    if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"the cache directory {str(path)!r} is writable by other users"
    if not os.access(path, os.W_OK | os.X_OK):
        return f"the cache directory {str(path)!r} is not writable"
    return None


def _remove_stale_builds(cache: Path) -> None:
    """Remove build directories older than `STALE_BUILD_AGE` under `cache` (left by killed processes)."""
    now = time.time()
    for entry in cache.glob(".build-*"):
        try:
            if now - entry.stat().st_mtime > STALE_BUILD_AGE:
                shutil.rmtree(entry, ignore_errors=True)
        except OSError:
            pass


def _warn_once(kind: str, message: str) -> None:
    """Count a fallback to the virtual machine; warn (`CompilationUnavailable`) the first time for `kind`."""
    STATS.fallbacks += 1
    if kind not in _WARNED:
        _WARNED.add(kind)
        warnings.warn(
            f"{message}; running CasADi's virtual machine instead (same results, slower). This warning is shown once.",
            CompilationUnavailable,
            stacklevel=4,
        )


# ---------------------------------------------------------------------------- building libraries
def build_library(files: dict[str, str], flags=FLAGS, *, fallback: bool = True) -> Path | None:
    """A shared library of C sources, from the cache or compiled into it.

    Parameters
    ----------
    files : file name -> text; every ``.c`` file is compiled, the others (headers) are
        only present beside them. Names are plain file names, no directories.
    flags : compiler flags besides ``-shared -fPIC`` (default `FLAGS`)
    fallback : True: return None (after one `CompilationUnavailable` warning per
        reason and process) when no library can be built; False: raise instead

    Returns
    -------
    Path of the library in the cache, or None.

    Raises
    ------
    CompilationError
        With ``fallback=False``, naming the reason (no compiler, the cache, compiler errors).
    ValueError
        For a file name with a directory part, or no ``.c`` file.
    """
    for name in files:
        if not name or os.path.basename(name) != name or name in (".", ".."):
            raise ValueError(f"files: {name!r} must be a plain file name without directories")
    sources = sorted(name for name in files if name.endswith(".c"))
    if not sources:
        raise ValueError(f"files: need at least one .c file, got {sorted(files)}")
    flags = tuple(str(f) for f in flags)

    def unavailable(kind: str, message: str) -> None:
        # No library: raise (fallback=False) or warn once per reason.
        if not fallback:
            raise CompilationError(message)
        _warn_once(kind, message)

    command = compiler()
    identity = _compiler_identity(tuple(command)) if command else None
    if command is None or identity is None:
        unavailable(
            "compiler",
            "no C compiler found (set CC, or put cc or gcc on the PATH)"
            if command is None
            else f"the C compiler {command[0]!r} does not run",
        )
        return None
    cache = cache_directory()
    problem = _private_directory(cache)
    if problem:
        unavailable("cache", problem)
        return None
    digest = hashlib.sha256()
    for part in (LAYOUT_VERSION, identity, _machine_identity(), " ".join(command), "\0".join(flags)):
        digest.update(part.encode() + b"\0\0")
    for name in sorted(files):
        digest.update(name.encode() + b"\0" + files[name].encode() + b"\0\0")
    library = cache / f"lib{digest.hexdigest()[:32]}.so"
    if library.exists():
        STATS.cache_hits += 1
        return library
    _remove_stale_builds(cache)
    try:
        # Removed on every exit path, an interrupt included; subprocess.run kills the compiler
        # when interrupted.
        with tempfile.TemporaryDirectory(prefix=".build-", dir=cache) as build:
            for name, text in files.items():
                Path(build, name).write_text(text, encoding="utf-8")
            output = Path(build, "library.so")
            STATS.compiled += 1
            subprocess.run(
                [*command, *flags, *LIBRARY_FLAGS, "-o", str(output), *sources, "-lm"],
                check=True,
                cwd=build,
                capture_output=True,
                text=True,
                stdin=subprocess.DEVNULL,
            )
            os.replace(output, library)
    except subprocess.CalledProcessError as err:
        lines = [line for line in (err.stderr or "").splitlines() if "error" in line.lower()] or (
            err.stderr or ""
        ).splitlines()
        unavailable(
            "failed",
            f"compiling with {command[0]!r} failed (exit {err.returncode}): {' | '.join(lines[:3]) or 'no message'}",
        )
        return None
    except OSError as err:
        unavailable("cache", f"cannot build in the cache directory {str(cache)!r}: {err.strerror or err}")
        return None
    return library


def _generated(functions: list[ca.Function], prefix: str) -> str:
    """C source of `functions` generated in memory (nothing is written to the working directory)."""
    generator = ca.CodeGenerator(f"{prefix}.c", {"with_header": False})
    for fun in functions:
        generator.add(fun)
    return generator.dump()


def jit(fun: ca.Function, flags=FLAGS) -> ca.Function:
    """A compiled copy of `fun` with the same name, inputs and outputs.

    `fun` itself (CasADi's virtual machine) when compiling is impossible, with
    one `CompilationUnavailable` warning per reason and process. The copy has
    no derivatives: differentiate `fun`.
    """
    library = build_library({"function.c": _generated([fun], "codesign_jit")}, flags)
    if library is None:
        return fun
    try:
        return ca.external(fun.name(), str(library))
    except RuntimeError as err:  # a cache on a noexec mount, for example
        if interrupts.is_interrupt(err):
            raise KeyboardInterrupt from err
        _warn_once("load", f"cannot load the compiled library {str(library)!r}: {str(err).splitlines()[0]}")
        return fun


def jit_nlpsol(name: str, plugin: str, problem: dict, options: dict, flags=FLAGS) -> ca.Function:
    """``casadi.nlpsol(name, plugin, problem, options)`` with its functions compiled.

    The solver's oracle and every function it evaluates (objective, constraints,
    their derivatives) are generated and compiled into one cached library,
    which the returned solver loads. The virtual-machine solver (after one
    warning) when compiling is impossible.
    """
    return jit_nlpsols(plugin, problem, {name: options}, flags)[name]


def jit_nlpsols(plugin: str, problem: dict, options: dict[str, dict], flags=FLAGS) -> dict[str, ca.Function]:
    """Several solvers of one problem, name -> solver, that differ only in options not changing which
    functions they evaluate (tolerances, warm starts; not the Hessian's kind): `jit_nlpsol`'s library is
    generated and compiled once and loaded by each. Generating it takes minutes for a large problem
    with exact second derivatives."""
    names = list(options)
    solver = ca.nlpsol(names[0], plugin, problem, options[names[0]])
    functions = [solver.oracle()] + [solver.get_function(f) for f in solver.get_function()]
    library = build_library({"nlp.c": _generated(functions, "codesign_nlp")}, flags)
    if library is None:
        return {name: solver if name == names[0] else ca.nlpsol(name, plugin, problem, options[name]) for name in names}
    solvers = {}
    for name in names:
        # "expand" already shaped the generated code; on a loaded library it would try to expand
        # the compiled oracle, which has no symbolic graph.
        loaded_options = {key: value for key, value in options[name].items() if key != "expand"}
        try:
            solvers[name] = ca.nlpsol(name, plugin, str(library), loaded_options)
        except RuntimeError as err:
            if interrupts.is_interrupt(err):
                raise KeyboardInterrupt from err
            _warn_once("load", f"cannot load the compiled library {str(library)!r}: {str(err).splitlines()[0]}")
            solvers[name] = ca.nlpsol(name, plugin, problem, options[name])
    return solvers


# ---------------------------------------------------------------------------- fast numeric calls
class NumpyCall:
    """Evaluate a dense CasADi Function with numpy inputs into fresh numpy outputs.

    Skips CasADi's DM conversion, which costs as much as a short compiled run
    (about 1 ms for a 6 x 2000 result). Inputs are read column-major like
    CasADi; outputs come back with the Function's (rows, columns) shapes.
    Not re-entrant: one call at a time per instance.
    """

    def __init__(self, fun: ca.Function):
        for i in range(fun.n_out()):
            if not fun.sparsity_out(i).is_dense():
                raise ValueError(f"{fun.name()}: output {fun.name_out(i)} is not dense")
        self.fun = fun
        self._buffer, self._trigger = fun.buffer()
        self._in_sizes = [(fun.size1_in(i), fun.size2_in(i)) for i in range(fun.n_in())]
        self._out_sizes = [(fun.size1_out(i), fun.size2_out(i)) for i in range(fun.n_out())]

    def __call__(self, *args) -> list[np.ndarray]:
        """Evaluate on numpy arrays (each read column-major into its input's shape); the outputs as arrays."""
        if len(args) != len(self._in_sizes):
            raise ValueError(f"{self.fun.name()} takes {len(self._in_sizes)} inputs, got {len(args)}")
        keep = []
        for i, (arg, (rows, cols)) in enumerate(zip(args, self._in_sizes)):
            arr = np.asarray(arg, dtype=float)
            if arr.size != rows * cols:
                raise ValueError(
                    f"{self.fun.name()}: input {self.fun.name_in(i)} needs {rows}x{cols} values, got shape {arr.shape}"
                )
            flat = np.ascontiguousarray(arr.reshape(rows, cols).ravel(order="F"))
            keep.append(flat)
            self._buffer.set_arg(i, memoryview(flat))  # type: ignore[call-arg, arg-type]  # (pointer, size) from the view
        outs = []
        for i, (rows, cols) in enumerate(self._out_sizes):
            out = np.empty((cols, rows))
            outs.append(out)
            self._buffer.set_res(i, memoryview(out))  # type: ignore[call-arg, arg-type]  # (pointer, size) from the view
        self._trigger()
        return [o.T for o in outs]
