"""Controllers exported as self-contained C: a header and a fixed-size step function.

A `Block`'s step ``(x_c, y, r) -> (x_c_next, u)`` with its current gains
baked in is generated as C by CasADi; a thin wrapper keeps the controller
state in a struct the caller owns::

    #include "pid.h"
    static pid_state state;                      /* one per controller instance */
    pid_set_state(&state, PID_INITIAL_STATE);    /* or an x_c of your own */
    every PID_SAMPLE_PERIOD seconds:
        status = pid_step(&state, y, r, u);      /* 0: u holds the command */

Everything has a fixed size known at export: the state and CasADi's work
arrays are members of the struct, nothing is allocated, the source needs
only ``<math.h>`` (link with ``-lm``) and compiles as C99. `ExportedC.load`
compiles and opens it with `models.compile.load_library` and returns the C
step as a `models.Controller` (through ctypes), which is how the tests hold it
against the Python block. `mpc.export` builds linear MPC on the same pieces.
"""

from __future__ import annotations

import ctypes
import math
import re
import unicodedata
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from . import compile as compiling
from .block import Block
from .dense_products import faster_products
from .files import write_text

#: C keywords a controller name must not be.
C_KEYWORDS = frozenset(
    """auto break case char const continue default do double else enum extern float for goto if
inline int long register restrict return short signed sizeof static struct switch typedef union unsigned void
volatile while""".split()
)
#: Longest C prefix `c_name` accepts.
C_NAME_LENGTH = 48
#: Flags the tests and `ExportedC.load` compile exported controllers with: optimized for this machine
#: (it is part of the cache key, `models.compile`), and ISO C without contracted multiply-adds, so the C
#: rounds as CasADi's virtual machine does (vector instructions round each operation as scalar ones).
LOAD_FLAGS = ("-O3", "-march=native", "-ffp-contract=off", "-std=c99")


class UnsupportedExport(ValueError):
    """The controller uses something the C export does not provide; the message names it."""


def c_name(name: str) -> str:
    """`name` if it is a usable C identifier prefix, else ValueError naming it."""
    if (
        not isinstance(name, str)
        or not re.fullmatch(r"[A-Za-z][A-Za-z0-9]*(_[A-Za-z0-9]+)*", name)
        or len(name) > C_NAME_LENGTH
        or name in C_KEYWORDS
    ):
        raise ValueError(
            f"name must be a C identifier prefix (a letter, then letters, digits and single "
            f"underscores, at most {C_NAME_LENGTH} characters, not a C keyword), got {name!r}"
        )
    return name


def c_identifiers(texts) -> list[str]:
    """A C prefix (`c_name`'s rule) for each of `texts` (free text: a controller's label), distinct.

    Each is the text folded to ASCII (accents dropped), in lower case, with every run of other
    characters one underscore and none at either end: "PID (no anti-windup)" -> "pid_no_anti_windup".
    One starting with a digit gets "c_" in front, an empty one is "controller", a C keyword gets "_c"
    after it; at most `C_NAME_LENGTH` characters. A name an earlier text already has gets "_2", "_3" ...

    Parameters
    ----------
    texts : iterable of str

    Returns
    -------
    list of str, in the order of `texts`
    """
    out: list[str] = []
    for text in texts:
        ascii_text = unicodedata.normalize("NFKD", str(text)).encode("ascii", "ignore").decode("ascii")
        base = re.sub(r"[^a-z0-9]+", "_", ascii_text.lower()).strip("_") or "controller"
        base = f"c_{base}" if base[0].isdigit() else base
        base = f"{base}_c" if base in C_KEYWORDS else base
        name, count = base[:C_NAME_LENGTH].rstrip("_"), 1
        while name in out:
            count += 1
            suffix = f"_{count}"
            name = base[: C_NAME_LENGTH - len(suffix)].rstrip("_") + suffix
        out.append(c_name(name))
    return out


def c_number(value: float) -> str:
    """A double as C source that reads back to the same bits (shortest round-trip form)."""
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"cannot write the non-finite number {value} as a C constant")
    text = repr(value)
    return text if any(c in text for c in ".en") else text + ".0"


def c_array(name: str, values, kind: str = "double", storage: str = "static const") -> str:
    """The C definition ``storage kind name[n] = {...};`` of `values` (row-major), at least one entry."""
    arr = np.asarray(values).ravel()
    if kind == "double":
        arr = arr.astype(float)
        if not np.all(np.isfinite(arr)):
            c_number(arr[~np.isfinite(arr)][0])  # raises, naming the value
        items = list(map(repr, arr.tolist()))  # a finite float's repr has "." or "e": c_number's text
    else:
        items = [str(int(v)) for v in arr]
    items = items or ["0"]
    lines = [", ".join(items[i : i + 6]) for i in range(0, len(items), 6)]
    body = ",\n    ".join(lines)
    return f"{storage} {kind} {name}[{len(items)}] = {{\n    {body}\n}};\n"


def generated_code(functions: list[ca.Function], prefix: str) -> str:
    """C of CasADi Functions (SX, no allocation), generated in memory with internal symbols `prefix`_*, its
    dense products as `models.dense_products` writes them.

    Raises
    ------
    UnsupportedExport
        When CasADi cannot generate one of them, or the code would allocate memory.
    """
    generator = ca.CodeGenerator(f"{prefix}.c", {"with_header": False, "with_export": False})
    for fun in functions:
        try:
            generator.add(fun)
        except RuntimeError as err:
            raise UnsupportedExport(
                f"CasADi cannot generate C for {fun.name()}: {str(err).strip().splitlines()[-1]}"
            ) from None
    code = faster_products(generator.dump())
    allocating = sorted({call for call in ("malloc(", "calloc(", "realloc(", "free(") if call in code})
    if allocating:
        raise UnsupportedExport(
            f"the generated C of {', '.join(f.name() for f in functions)} allocates memory ({', '.join(allocating)})"
        )
    return code


def work_sizes(fun: ca.Function) -> dict[str, int]:
    """CasADi's work array sizes of `fun` (argument and result pointers, integers, reals), each >= 1."""
    return {
        "arg": max(1, fun.sz_arg()),
        "res": max(1, fun.sz_res()),
        "iw": max(1, fun.sz_iw()),
        "w": max(1, fun.sz_w()),
    }


def block_kernel(block: Block, name: str) -> ca.Function:
    """The block's step with its gains baked in, as an SX Function (xc, y, r) -> (xc_next, u).

    Raises
    ------
    UnsupportedExport
        Naming what cannot become plain C: free symbols, or calls CasADi cannot expand
        (Python callbacks, external functions).
    """
    step = block.casadi_step
    if not step.is_a("SXFunction"):
        try:
            step = step.expand()
        except RuntimeError as err:
            raise UnsupportedExport(
                f"{block.name}: its step calls something that is not plain arithmetic "
                f"({str(err).strip().splitlines()[-1]}); only CasADi expressions can be "
                "exported"
            ) from None
    if step.has_free():
        raise UnsupportedExport(f"{block.name}: its step has free symbols {step.get_free()}")
    # What expand could not inline stays a call; only CasADi's own expression graphs become plain C.
    calls = [
        f"{f.name()} ({f.class_name()})"
        for f in step.find_functions()
        if f.class_name() not in ("SXFunction", "MXFunction")
    ]
    if calls:
        raise UnsupportedExport(
            f"{block.name}: its step calls something that is not plain arithmetic: "
            f"{', '.join(calls)}; only CasADi expressions can be exported"
        )
    xc = ca.SX.sym("xc", block.n_state)
    y = ca.SX.sym("y", block.n_measured)
    r = ca.SX.sym("r", block.n_reference)
    xc_next, u = step(xc, y, r, ca.DM(block.gain_vector()))
    return ca.Function(f"{name}_kernel", [xc, y, r], [xc_next, u], ["xc", "y", "r"], ["xc_next", "u"])


@dataclass(frozen=True)
class ExportedC:
    """An exported controller: the header and source text and what they declare.

    Attributes
    ----------
    name : the C prefix (files ``name.h``, ``name.c``; functions ``name_step`` ...)
    controller : the exported controller's own name
    header, source : C text
    n_state, n_measured, n_reference, n_input : sizes of x_c, y, r, u
    sample_period : s
    measures : "outputs" or "state" (what y is)
    initial_state : x_c the header offers as ``NAME_INITIAL_STATE``, or None
    has_init : the C has ``name_init(state, y0, r0)`` computing x_c from the first measurement
    status_codes : code -> meaning of ``name_step``'s return value
    """

    name: str
    controller: str
    header: str
    source: str
    n_state: int
    n_measured: int
    n_reference: int
    n_input: int
    sample_period: float
    measures: str
    initial_state: np.ndarray | None = None
    has_init: bool = False
    status_codes: dict = field(default_factory=dict)

    def files(self) -> dict[str, str]:
        """File name -> text: ``name.h`` and ``name.c``."""
        return {f"{self.name}.h": self.header, f"{self.name}.c": self.source}

    def write(self, directory) -> list[Path]:
        """Write the header and source into `directory` (created if needed); the paths written."""
        return [write_text(Path(directory) / file, text) for file, text in self.files().items()]

    def load(self, initial_state: Callable | None = None, flags=LOAD_FLAGS) -> CompiledController:
        """Compile and open the C (`models.compile.load_library`: cached, checked) as a `models.Controller`.

        Parameters
        ----------
        initial_state : callable (y0, r0) -> x_c for a block's first sample, typically the exported
            block's own ``initial_state``; default `initial_state` (the header's constant). Not used
            when the C computes it (`has_init`).
        flags : compiler flags

        Raises
        ------
        models.compile.CompilationError
            When no library can be built (no compiler, no cache, compiler errors).
        """
        library = compiling.load_library(self.files(), (*flags, *self.build_flags()), fallback=False)
        assert library is not None  # fallback=False raises instead of returning None
        return CompiledController(self, library, initial_state)

    def build_flags(self) -> tuple[str, ...]:
        """Compiler arguments the C needs beside the optimization flags (a library it calls): none for a
        Block; an MPC's name DAQP (`mpc.export.build_flags`)."""
        return ()


def _header(
    name: str, described: str, sizes: dict, members: list[str], declarations: list[str], defines: dict | None = None
) -> str:
    """The C header ``name.h``: include guard, ``NAME_<key>`` defines of `sizes` and `defines`, the state
    struct ``name_state`` of `members`, and the function `declarations`."""
    guard = f"{name.upper()}_H"
    lines = [
        f"/* {name}.h: {described}",
        " * Exported by codesign-control. Fixed sizes, no allocation; see models.export and mpc.export. */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        "#ifdef __cplusplus",
        'extern "C" {',
        "#endif",
        "",
    ]
    for key, value in sizes.items():
        lines.append(f"#define {name.upper()}_{key} {value}")
    for key, value in (defines or {}).items():
        lines.append(f"#define {name.upper()}_{key} {value}")
    lines += ["", "/* One per controller instance, owned by the caller. */", "typedef struct {"]
    lines += [f"    {member}" for member in members]
    lines += [f"}} {name}_state;", ""]
    lines += declarations
    lines += ["", "#ifdef __cplusplus", "}", "#endif", "", f"#endif /* {guard} */", ""]
    return "\n".join(lines)


def export_block(block: Block, name: str, *, initial_measurement=None, initial_reference=None) -> ExportedC:
    """A `Block` (PID, transfer-function block, cascade, state feedback, observer ...) as C.

    Parameters
    ----------
    block : the controller, with the gains it has now
    name : C prefix of the files and functions
    initial_measurement, initial_reference : (y0, r0) for ``NAME_INITIAL_STATE`` =
        ``block.initial_state(y0, r0)`` (default zeros)

    Raises
    ------
    UnsupportedExport
        For a controller that is not a Block (an MPC: use `mpc.export`), or a step that is
        not plain CasADi arithmetic.
    """
    name = c_name(name)
    if not isinstance(block, Block):
        kind = type(block).__name__
        hint = " (use mpc.export.export_linear_mpc)" if kind == "LinearMPC" else ""
        raise UnsupportedExport(
            f"{getattr(block, 'name', kind)}: only models.Block controllers are exported here; {kind} is not one{hint}"
        )
    kernel = block_kernel(block, name)
    work = work_sizes(kernel)
    y0 = (
        np.zeros(block.n_measured)
        if initial_measurement is None
        else np.asarray(initial_measurement, dtype=float).reshape(block.n_measured)
    )
    r0 = (
        np.zeros(block.n_reference)
        if initial_reference is None
        else np.asarray(initial_reference, dtype=float).reshape(block.n_reference)
    )
    xc0 = np.asarray(block.initial_state(y0, r0), dtype=float).reshape(block.n_state)
    upper = name.upper()
    n_store = max(1, block.n_state)
    signal = "the plant's outputs" if block.measures == "outputs" else "the plant's full state"
    header = _header(
        name,
        f"controller '{block.name}' ({type(block).__module__}.{type(block).__name__}).",
        {
            "N_STATE": block.n_state,
            "N_MEASURED": block.n_measured,
            "N_REFERENCE": block.n_reference,
            "N_INPUT": block.n_input,
        },
        [
            f"double xc[{n_store}];  /* controller state x_c ({block.n_state} values) */",
            f"double work[{work['w']}];  /* CasADi's work arrays */",
            f"long long int iwork[{work['iw']}];",
        ],
        [
            f"/* x_c of the Python block at its first sample for y0 = {np.array2string(y0, separator=', ')}, "
            f"r0 = {np.array2string(r0, separator=', ')}. */",
            f"extern const double {upper}_INITIAL_STATE[{n_store}];",
            "",
            f"/* Set the controller state x_c ({upper}_N_STATE values). */",
            f"void {name}_set_state({name}_state *state, const double *xc);",
            "/* Copy the controller state x_c out. */",
            f"void {name}_get_state(const {name}_state *state, double *xc);",
            f"/* One sample, every {upper}_SAMPLE_PERIOD s: y ({upper}_N_MEASURED values, {signal}),",
            f" * r ({upper}_N_REFERENCE values) -> u ({upper}_N_INPUT values, saturated as the block does).",
            " * Returns 0, or CasADi's non-zero evaluation flag (then u and the state are unchanged). */",
            f"int {name}_step({name}_state *state, const double *y, const double *r, double *u);",
            f"/* sizeof({name}_state), for loaders. */",
            f"unsigned long {name}_state_size(void);",
        ],
        {"SAMPLE_PERIOD": c_number(block.sample_period)},
    )
    source = "\n".join(
        [
            f"/* {name}.c: controller '{block.name}', generated by codesign-control (models.export). */",
            f'#include "{name}.h"',
            "",
            generated_code([kernel], f"{name}_casadi"),
            c_array(f"{upper}_INITIAL_STATE", xc0 if block.n_state else [0.0], storage="const"),
            f"void {name}_set_state({name}_state *state, const double *xc) {{",
            "    int i;",
            f"    for (i = 0; i < {block.n_state}; ++i) state->xc[i] = xc[i];",
            "}",
            "",
            f"void {name}_get_state(const {name}_state *state, double *xc) {{",
            "    int i;",
            f"    for (i = 0; i < {block.n_state}; ++i) xc[i] = state->xc[i];",
            "}",
            "",
            f"int {name}_step({name}_state *state, const double *y, const double *r, double *u) {{",
            f"    const casadi_real *arg[{work['arg']}];",
            f"    casadi_real *res[{work['res']}];",
            f"    double xc_next[{n_store}], u_next[{block.n_input}];",
            "    int i, flag;",
            "    arg[0] = state->xc; arg[1] = y; arg[2] = r;",
            "    res[0] = xc_next; res[1] = u_next;",
            f"    flag = {name}_kernel(arg, res, state->iwork, state->work, 0);",
            "    if (flag) return flag;",
            f"    for (i = 0; i < {block.n_state}; ++i) state->xc[i] = xc_next[i];",
            f"    for (i = 0; i < {block.n_input}; ++i) u[i] = u_next[i];",
            "    return 0;",
            "}",
            "",
            f"unsigned long {name}_state_size(void) {{ return (unsigned long) sizeof({name}_state); }}",
            "",
        ]
    )
    return ExportedC(
        name=name,
        controller=block.name,
        header=header,
        source=source,
        n_state=block.n_state,
        n_measured=block.n_measured,
        n_reference=block.n_reference,
        n_input=block.n_input,
        sample_period=block.sample_period,
        measures=block.measures,
        initial_state=xc0,
        status_codes={0: "ok"},
    )


class CompiledController:
    """A compiled exported controller behind the `models.Controller` protocol (ctypes).

    The controller state travels through the simulator as x_c, as for any
    controller; each step copies it into the C struct, steps, and copies it out.
    `step_info()` reports the C step's status code.
    """

    def __init__(self, exported: ExportedC, library: compiling.CompiledLibrary, initial_state: Callable | None = None):
        self.exported = exported
        self.name = f"{exported.controller} (C)"
        self.sample_period = exported.sample_period
        self.measures = exported.measures
        self.n_reference, self.n_state = exported.n_reference, exported.n_state
        self._library = library
        prefix, pointer = exported.name, ctypes.c_void_p

        def function(suffix, argtypes, restype=None):
            # The library's function prefix_suffix with its ctypes signature.
            return library.function(f"{prefix}_{suffix}", argtypes, restype)

        size = function("state_size", [], ctypes.c_ulong)()
        self._memory = ctypes.create_string_buffer(size)
        self._set = function("set_state", [pointer, pointer])
        self._get = function("get_state", [pointer, pointer])
        self._step = function("step", [pointer, pointer, pointer, pointer], ctypes.c_int)
        self._init = function("init", [pointer, pointer, pointer], ctypes.c_int) if exported.has_init else None
        self._initial_state = initial_state
        self._xc = np.zeros(max(1, exported.n_state))
        self._u = np.zeros(exported.n_input)
        self._code = 0

    def _vector(self, value, size: int) -> np.ndarray:
        """`value` as a contiguous float vector of `size` entries, for a C pointer."""
        return np.ascontiguousarray(np.asarray(value, dtype=float).reshape(size))

    def initial_state(self, y0, r0) -> np.ndarray:
        """x_c at the first sample: from the C (`has_init`), the given callable, or the header's constant."""
        y0 = self._vector(y0, self.exported.n_measured)
        r0 = self._vector(r0, self.exported.n_reference)
        if self._init is not None:
            code = self._init(ctypes.addressof(self._memory), y0.ctypes.data, r0.ctypes.data)
            if code:
                raise ValueError(
                    f"{self.name}: init returned {code} ({self.exported.status_codes.get(code, 'unknown code')})"
                )
            self._get(ctypes.addressof(self._memory), self._xc.ctypes.data)
            return self._xc[: self.n_state].copy()
        if self._initial_state is not None:
            return np.asarray(self._initial_state(y0, r0), dtype=float).reshape(self.n_state)
        return np.asarray(self.exported.initial_state, dtype=float).copy()

    def step(self, xc, y, r) -> tuple[np.ndarray, np.ndarray]:
        """One sample through the C step: (x_c_next, u)."""
        memory = ctypes.addressof(self._memory)
        state = np.ascontiguousarray(np.asarray(xc, dtype=float).reshape(self.n_state))
        y = self._vector(y, self.exported.n_measured)
        r = self._vector(r, self.exported.n_reference)
        self._set(memory, state.ctypes.data)
        u = np.zeros(self.exported.n_input)
        self._code = int(self._step(memory, y.ctypes.data, r.ctypes.data, u.ctypes.data))
        self._get(memory, self._xc.ctypes.data)
        return self._xc[: self.n_state].copy(), u

    def step_info(self) -> dict:
        """The last step's status code and its meaning."""
        return {
            "code": self._code,
            "status": self.exported.status_codes.get(self._code, "unknown code"),
            "success": self._code == 0,
        }
