"""Compiling generated C: CasADi Functions and NLP solvers to machine code, exported controllers.

One mechanism for every piece of C the project builds (a closed loop's
``jit``, the tuning NLP, exported controllers):

- the C source is generated in memory (`casadi.CodeGenerator.dump`), never
  into the working directory;
- the compiler runs as ``subprocess.run([cc, ...], check=True)``, arguments
  as a list (no shell), in a private build directory under the cache;
- the library is cached under a hash of the sources, the flags, the
  compiler's identity and the machine, in an entry folder with a record of
  its size and SHA-256, moved into the cache with one atomic rename, so a
  second run (or a second process) does not recompile and two processes
  compiling at once are safe;
- before a cached library is opened it is checked (`check_entry`): its size
  and SHA-256 against the record, and its ELF header and tables
  (`models.elf`), since ``dlopen`` of a damaged library can kill the process
  before any error is raised. An entry that fails is rebuilt, with one
  `CacheEntryRebuilt` warning naming it and what was wrong;
- every compiled library comes from one function, `load_library`, which
  returns a `CompiledLibrary` (its checked path for CasADi's loaders, its
  ctypes handle for direct calls);
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

import ctypes
import errno
import functools
import hashlib
import json
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

from . import elf, interrupts
from .dense_products import faster_products

#: Libraries run on the machine that compiles them (the machine is part of the cache key),
#: so -march=native is safe.
FLAGS = ("-O3", "-march=native")
#: Flags every shared library gets, whatever the optimization flags.
LIBRARY_FLAGS = ("-shared", "-fPIC")
#: Bump when the way libraries are built or cached changes, so old cache entries are not reused.
#: 2: an entry is a folder holding the library and the record of its size and SHA-256.
LAYOUT_VERSION = "2"
#: The names of a cache entry's library and its record, inside the entry's folder.
LIBRARY_NAME = "library.so"
RECORD_NAME = "entry.json"
#: Build directories older than this (s) are left over from a killed process and removed.
STALE_BUILD_AGE = 24 * 3600.0


class CompilationUnavailable(RuntimeWarning):
    """Compiling was impossible; CasADi's virtual machine runs instead (same results, slower)."""


class CompilationError(RuntimeError):
    """A compiler was found but building the library failed; the message has its first error lines."""


class CacheEntryRebuilt(RuntimeWarning):
    """A cached library failed its check before loading (size, SHA-256, ELF headers) and was rebuilt;
    the message names the entry and what was wrong."""


@dataclass
class Counters:
    """What this process did: compiler runs, cache hits, damaged entries rebuilt and fallbacks to the
    virtual machine."""

    compiled: int = 0
    cache_hits: int = 0
    fallbacks: int = 0
    rebuilt: int = 0


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


# ---------------------------------------------------------------------------- cache entries
def entry_record(library: str | os.PathLike) -> Path:
    """The record beside the cached library `library`: JSON with its size (bytes) and SHA-256 when built."""
    return Path(library).with_name(RECORD_NAME)


def check_entry(library: str | os.PathLike) -> str | None:
    """What is wrong with the cached library `library` (a path `build_library` returned), in words; None
    when it is the file that was built and its ELF headers hold (`models.elf.check_image`).

    The size and SHA-256 are compared with the entry's record (`entry_record`): they catch what the
    headers cannot (machine code or constants overwritten in place). The file is read once, so the
    three checks see the same bytes.
    """
    try:
        record = json.loads(entry_record(library).read_text(encoding="utf-8"))
        size, digest = int(record["size"]), str(record["sha256"])
    except (OSError, ValueError, KeyError, TypeError):
        return "it has no readable record of its size and SHA-256"
    try:
        data = Path(library).read_bytes()
    except OSError as err:
        return f"cannot read the library: {err.strerror or err}"
    if len(data) != size:
        return f"the library has {len(data)} bytes, {size} when it was built"
    if hashlib.sha256(data).hexdigest() != digest:
        return "the library's SHA-256 is not the one recorded when it was built (its contents changed)"
    problem = elf.check_image(data)
    return None if problem is None else f"the library's ELF headers are damaged: {problem}"


def _write_record(library: Path, command: list[str], flags: tuple, sources: list[str]) -> None:
    """Write the record of the freshly built `library` beside it (`entry_record`)."""
    data = library.read_bytes()
    record = {
        "library": library.name,
        "size": len(data),
        "sha256": hashlib.sha256(data).hexdigest(),
        "compiler": command[0],
        "flags": list(flags),
        "sources": sources,
    }
    entry_record(library).write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")


def _discard(entry: Path, cache: Path) -> None:
    """Take the cache entry `entry` out of the cache: renamed into a fresh build folder (one atomic step, so
    no process sees half of it), then removed. Nothing happens when it is already gone."""
    aside = Path(tempfile.mkdtemp(prefix=".build-discard-", dir=cache))
    try:
        os.rename(entry, aside / "entry")
    except FileNotFoundError:
        pass
    finally:
        shutil.rmtree(aside, ignore_errors=True)


def _install(built: Path, entry: Path, cache: Path) -> None:
    """Rename the complete entry folder `built` to `entry`. When another process installed it meanwhile,
    theirs is kept if it passes `check_entry`, else replaced."""
    try:
        os.rename(built, entry)
        return
    except OSError as err:
        if err.errno not in (errno.EEXIST, errno.ENOTEMPTY, errno.ENOTDIR):
            raise
    if entry.is_dir() and check_entry(entry / LIBRARY_NAME) is None:
        return
    _discard(entry, cache)
    os.rename(built, entry)


def _cache_key(command: list[str], identity: str, flags: tuple, files: dict[str, str]) -> str:
    """The cache entry's name: a hash of the layout, the compiler, the machine, the flags and the sources."""
    digest = hashlib.sha256()
    for part in (LAYOUT_VERSION, identity, _machine_identity(), " ".join(command), "\0".join(flags)):
        digest.update(part.encode() + b"\0\0")
    for name in sorted(files):
        digest.update(name.encode() + b"\0" + files[name].encode() + b"\0\0")
    return f"lib{digest.hexdigest()[:32]}"


# ---------------------------------------------------------------------------- building libraries
def build_library(files: dict[str, str], flags=FLAGS, *, fallback: bool = True) -> Path | None:
    """A shared library of C sources, from the cache (checked) or compiled into it.

    Open it with `load_library`, which calls this; the path alone is for a loader of its own (CasADi's,
    through `load_library`'s `CompiledLibrary.path`). A cached entry that fails `check_entry` is rebuilt,
    with one `CacheEntryRebuilt` warning saying which and why.

    Parameters
    ----------
    files : file name -> text; every ``.c`` file is compiled, the others (headers) are
        only present beside them. Names are plain file names, no directories.
    flags : compiler flags besides ``-shared -fPIC`` (default `FLAGS`)
    fallback : True: return None (after one `CompilationUnavailable` warning per
        reason and process) when no library can be built; False: raise instead

    Returns
    -------
    Path of the library in the cache (``<cache>/lib<hash>/library.so``), or None.

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
    entry = cache / _cache_key(command, identity, flags, files)
    library = entry / LIBRARY_NAME
    damaged = None
    if entry.exists() or entry.is_symlink():
        damaged = check_entry(library)
        if damaged is None:
            STATS.cache_hits += 1
            return library
    try:
        if damaged is not None:
            _discard(entry, cache)
        _remove_stale_builds(cache)
        _compile_entry(command, flags, files, sources, entry, cache)
    except subprocess.CalledProcessError as err:
        lines = [line for line in (err.stderr or "").splitlines() if "error" in line.lower()] or (
            err.stderr or ""
        ).splitlines()
        unavailable(
            "failed",
            f"compiling with {command[0]!r} failed (exit {err.returncode}): {' | '.join(lines[:3]) or 'no message'}",
        )
        return None
    except CompilationError as err:
        unavailable("failed", str(err))
        return None
    except OSError as err:
        unavailable("cache", f"cannot build in the cache directory {str(cache)!r}: {err.strerror or err}")
        return None
    if damaged is not None:
        STATS.rebuilt += 1
        warnings.warn(
            f"the cached library {str(entry)!r} failed its check before loading ({damaged}); it was rebuilt",
            CacheEntryRebuilt,
            stacklevel=3,
        )
    return library


def _compile_entry(command: list[str], flags: tuple, files: dict[str, str], sources: list, entry: Path, cache: Path):
    """Compile `sources` (of `files`) into a complete entry folder in a private build folder, record it and
    install it as `entry` (`_install`). The build folder is removed on every exit path, an interrupt
    included; subprocess.run kills the compiler when interrupted.

    Raises
    ------
    subprocess.CalledProcessError
        When the compiler fails.
    CompilationError
        When its output is not a library this interpreter can open (`models.elf.check_image`).
    """
    with tempfile.TemporaryDirectory(prefix=".build-", dir=cache) as build:
        for name, text in files.items():
            Path(build, name).write_text(text, encoding="utf-8")
        built = Path(build, "entry")
        built.mkdir()
        STATS.compiled += 1
        subprocess.run(
            [*command, *flags, *LIBRARY_FLAGS, "-o", str(built / LIBRARY_NAME), *sources, "-lm"],
            check=True,
            cwd=build,
            capture_output=True,
            text=True,
            stdin=subprocess.DEVNULL,
        )
        _write_record(built / LIBRARY_NAME, command, flags, sources)
        problem = check_entry(built / LIBRARY_NAME)
        if problem is not None:
            raise CompilationError(f"the compiler {command[0]!r} wrote no library this interpreter can open: {problem}")
        _install(built, entry, cache)


@dataclass(frozen=True)
class CompiledLibrary:
    """A compiled library, checked (`check_entry`) and, for ctypes, opened (`load_library`).

    Attributes
    ----------
    path : the library in the cache; CasADi's loaders (``casadi.external``, ``casadi.nlpsol``) open it
        from here
    handle : its ``ctypes.CDLL`` for direct calls (see `function`), or None when it was loaded for
        CasADi (``load_library(..., ctypes_handle=False)``: CasADi opens and closes it with its Functions)
    """

    path: Path
    handle: ctypes.CDLL | None

    def function(self, name: str, argtypes, restype=None):
        """The library's C function `name` with its ctypes signature: `argtypes` (a list of ctypes types)
        and `restype` (a ctypes type, None for void)."""
        if self.handle is None:
            raise ValueError(f"{self.path} was loaded for CasADi (ctypes_handle=False): it has no ctypes handle")
        fun = getattr(self.handle, name)
        fun.argtypes, fun.restype = list(argtypes), restype
        return fun


def load_library(
    files: dict[str, str], flags=FLAGS, *, fallback: bool = True, ctypes_handle: bool = True
) -> CompiledLibrary | None:
    """The one loader of compiled code: the library of C sources `files` built or taken from the cache
    (`build_library`, which checks it and rebuilds a damaged entry before anything opens it), then
    opened with ctypes.

    Parameters
    ----------
    files, flags : as `build_library`
    fallback : True: None (after one `CompilationUnavailable` warning per reason and process) when no
        library can be built or opened; False: raise instead
    ctypes_handle : False for a library CasADi's loaders open from `CompiledLibrary.path` (`jit`,
        `jit_nlpsols`): not opened here, so that it is unmapped with the last Function using it

    Returns
    -------
    CompiledLibrary or None

    Raises
    ------
    CompilationError
        With ``fallback=False``, naming why there is no library (no compiler, the cache, compiler
        errors, a library the system refuses to open, as on a noexec mount).
    """
    path = build_library(files, flags, fallback=fallback)
    if path is None or not ctypes_handle:
        return None if path is None else CompiledLibrary(path, None)
    try:
        handle = ctypes.CDLL(str(path))
    except OSError as err:
        message = f"cannot load the compiled library {str(path)!r}: {str(err).splitlines()[0]}"
        if not fallback:
            raise CompilationError(message) from None
        _warn_once("load", message)
        return None
    return CompiledLibrary(path, handle)


def _generated(functions: list[ca.Function], prefix: str) -> str:
    """C source of `functions` generated in memory (nothing is written to the working directory), its dense
    products as `models.dense_products` writes them."""
    generator = ca.CodeGenerator(f"{prefix}.c", {"with_header": False})
    for fun in functions:
        generator.add(fun)
    return faster_products(generator.dump())


def jit(fun: ca.Function, flags=FLAGS) -> ca.Function:
    """A compiled copy of `fun` with the same name, inputs and outputs.

    `fun` itself (CasADi's virtual machine) when compiling is impossible, with
    one `CompilationUnavailable` warning per reason and process. The copy has
    no derivatives: differentiate `fun`.
    """
    library = load_library({"function.c": _generated([fun], "codesign_jit")}, flags, ctypes_handle=False)
    if library is None:
        return fun
    try:
        return ca.external(fun.name(), str(library.path))
    except RuntimeError as err:
        if interrupts.is_interrupt(err):
            raise KeyboardInterrupt from err
        _warn_once("load", f"cannot load the compiled library {str(library.path)!r}: {str(err).splitlines()[0]}")
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
    library = load_library({"nlp.c": _generated(functions, "codesign_nlp")}, flags, ctypes_handle=False)
    if library is None:
        return {name: solver if name == names[0] else ca.nlpsol(name, plugin, problem, options[name]) for name in names}
    solvers = {}
    for name in names:
        # "expand" already shaped the generated code; on a loaded library it would try to expand
        # the compiled oracle, which has no symbolic graph.
        loaded_options = {key: value for key, value in options[name].items() if key != "expand"}
        try:
            solvers[name] = ca.nlpsol(name, plugin, str(library.path), loaded_options)
        except RuntimeError as err:
            if interrupts.is_interrupt(err):
                raise KeyboardInterrupt from err
            _warn_once("load", f"cannot load the compiled library {str(library.path)!r}: {str(err).splitlines()[0]}")
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
