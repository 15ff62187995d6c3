"""The Monte Carlo's compiled kernel: a Block's closed loop over samples x steps in one C loop.

The closed-loop sample of `models.closed_loop` (y_k = h(x_k), the measurement,
the controller's step, saturation and the plant's RK4 sub-steps) is written as
straight-line C from the instructions of its SX Functions, inside a loop over
`LANES` samples at once: every quantity is an array over the lanes (structure of
arrays, samples innermost), so the compiler turns each operation into one
vector instruction; sine, cosine, exp and log go to the C library's vector
variants (glibc's libmvec) where there are some. A C loop runs the lanes' blocks
and the steps, reading each sample's parameters and noise and writing the
results in the `MonteCarloResult` layout; Python calls it once per range of
samples, a thread per range, through ctypes (which releases the GIL).

A sample's numbers do not depend on the lane it runs in, nor on the other
samples of its block: every lane runs the same instructions, and a block with
fewer samples fills its last lanes with copies of its last sample. They agree
with CasADi's run of the same Functions to rounding (the compiler may fuse a
multiply and an add).

`kernel` builds (or takes from the plant's cache) the kernel of a Block, or
says why there is none: an operation this generator does not write, or no
library (no compiler, a compiler error). The library comes from
`models.compile.load_library`, so it is cached and checked like every other.
"""

from __future__ import annotations

import ctypes
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import casadi as ca
import numpy as np

from . import compile as compiling
from .block import Block, saturate
from .plant import Plant

#: Samples one pass of the kernel's body computes together: 8 doubles fill an AVX-512 register, or two AVX2
#: registers.
LANES = 8

#: Functions the C library has vector variants of (glibc's libmvec on x86-64): declared
#: ``omp declare simd`` so that the lane loop calls them on vectors.
VECTOR_MATH = ("sin", "cos", "exp", "log")

#: The kernel's compiler flags: the project's; vector loops marked with ``omp simd`` (no OpenMP runtime);
#: no errno from the math functions (a side effect that would stop vectorization); no builtin sine and
#: cosine (which gcc would fuse into a scalar sincos); 512-bit vectors where the machine has them (gcc
#: prefers 256 bits otherwise); and a division by a value used more than once as one reciprocal and
#: multiplications (rounding differs from the division's in the last bit). Each halved the kernel's time
#: on the development machine (figures: docs/performance.md).
KERNEL_FLAGS = (
    *compiling.FLAGS,
    "-fopenmp-simd",
    "-fno-math-errno",
    *(f"-fno-builtin-{f}" for f in VECTOR_MATH),
    "-mprefer-vector-width=512",
    "-freciprocal-math",
)

_UNARY = {
    ca.OP_NEG: "(-{0})",
    ca.OP_SQ: "({0}*{0})",
    ca.OP_TWICE: "(2.*{0})",
    ca.OP_INV: "(1./{0})",
    ca.OP_NOT: "(!{0})",
    ca.OP_FABS: "fabs({0})",
    ca.OP_SQRT: "sqrt({0})",
    ca.OP_FLOOR: "floor({0})",
    ca.OP_CEIL: "ceil({0})",
    ca.OP_SIGN: "({0}<0 ? -1. : {0}>0 ? 1. : {0})",
    ca.OP_ASSIGN: "{0}",
    **{
        getattr(ca, f"OP_{name.upper()}"): f"{name}({{0}})"
        for name in (
            "sin",
            "cos",
            "tan",
            "asin",
            "acos",
            "atan",
            "exp",
            "log",
            "sinh",
            "cosh",
            "tanh",
            "asinh",
            "acosh",
            "atanh",
            "erf",
            "log1p",
            "expm1",
        )
    },
}
_BINARY = {
    ca.OP_ADD: "({0}+{1})",
    ca.OP_SUB: "({0}-{1})",
    ca.OP_MUL: "({0}*{1})",
    ca.OP_DIV: "({0}/{1})",
    ca.OP_LT: "({0}<{1})",
    ca.OP_LE: "({0}<={1})",
    ca.OP_EQ: "({0}=={1})",
    ca.OP_NE: "({0}!={1})",
    # Not && and ||: their short circuit is control flow, which stops vectorization. Same values.
    ca.OP_AND: "(({0}!=0) & ({1}!=0))",
    ca.OP_OR: "(({0}!=0) | ({1}!=0))",
    ca.OP_IF_ELSE_ZERO: "({0} ? {1} : 0.)",
    ca.OP_POW: "pow({0},{1})",
    ca.OP_CONSTPOW: "pow({0},{1})",
    ca.OP_FMIN: "fmin({0},{1})",
    ca.OP_FMAX: "fmax({0},{1})",
    ca.OP_ATAN2: "atan2({0},{1})",
    ca.OP_FMOD: "fmod({0},{1})",
    ca.OP_COPYSIGN: "copysign({0},{1})",
    ca.OP_HYPOT: "hypot({0},{1})",
}
_OPERATOR_NAMES = {getattr(ca, name): name for name in dir(ca) if name.startswith("OP_")}


class KernelUnavailable(Exception):
    """There is no compiled kernel for this closed loop; the message says why (the batched CasADi map runs)."""


def _constant(value: float) -> str:
    """A double as C that reads back to the same bits, infinities and NaN included."""
    if math.isnan(value):
        return "NAN"
    if math.isinf(value):
        return "INFINITY" if value > 0 else "(-INFINITY)"
    text = repr(float(value))
    return text if any(c in text for c in ".en") else text + ".0"


def _expanded(fun: ca.Function) -> ca.Function:
    """`fun` as an SX Function without free symbols, or KernelUnavailable naming what stops it."""
    if not fun.is_a("SXFunction"):
        try:
            fun = fun.expand()
        except RuntimeError as err:
            raise KernelUnavailable(
                f"{fun.name()} is not plain arithmetic: {str(err).strip().splitlines()[-1]}"
            ) from None
    if fun.has_free():
        raise KernelUnavailable(f"{fun.name()} has free symbols {fun.get_free()}")
    return fun


def body(fun: ca.Function, inputs: list[str], outputs: list[str]) -> list[str]:
    """C statements computing the SX Function `fun` for lane j, from its instructions.

    Parameters
    ----------
    fun : an SX Function with dense outputs
    inputs, outputs : per input and output of `fun`, a C format of its nonzero k (``"s[{k}][j]"``)

    Raises
    ------
    KernelUnavailable
        Naming an operation this generator does not write (a call of another Function, say).
    """
    fun = _expanded(fun)
    for i in range(fun.n_out()):
        if not fun.sparsity_out(i).is_dense():
            raise KernelUnavailable(f"{fun.name()}: output {fun.name_out(i)} is not dense")
    lines = [f"double {', '.join(f'w{k}' for k in range(max(1, fun.sz_w())))};"]
    for k in range(fun.n_instructions()):
        op, args, res = fun.instruction_id(k), fun.instruction_input(k), fun.instruction_output(k)
        if op == ca.OP_INPUT:
            lines.append(f"w{res[0]} = {inputs[args[0]].format(k=args[1])};")
        elif op == ca.OP_OUTPUT:
            lines.append(f"{outputs[res[0]].format(k=res[1])} = w{args[0]};")
        elif op == ca.OP_CONST:
            lines.append(f"w{res[0]} = {_constant(fun.instruction_constant(k))};")
        elif op in _UNARY:
            lines.append(f"w{res[0]} = {_UNARY[op].format(f'w{args[0]}')};")
        elif op in _BINARY:
            lines.append(f"w{res[0]} = {_BINARY[op].format(f'w{args[0]}', f'w{args[1]}')};")
        else:
            raise KernelUnavailable(
                f"{fun.name()} uses {_OPERATOR_NAMES.get(op, op)}, which the Monte Carlo kernel does not write"
            )
    return lines


_SOURCE = r"""/* The closed loop of one controller over samples x steps (generated by models.mc_kernel). */
#include <math.h>
#include <string.h>
#if defined(__x86_64__) && defined(__GLIBC__)
%(vector_math)s
#endif
#define LANES %(lanes)d
#define NX %(nx)d
#define NC %(nc)d
#define NS (NX + NC)
#define NM %(nm)d
#define NY %(ny)d
#define NU %(nu)d
#define NR %(nr)d
#define NP %(np)d

/* Samples first..last-1 of m (first a multiple of LANES), n steps each. Results in the layout of
   models.MonteCarloResult: X (m, n+1, NX), XC (m, n+1, NC), Y (m, n+1, NY), U (m, n, NU), MEAS (m, n, NM).
   noise (m, n, NM) or NULL for none; R (n, NR), D (n, NU), x0 (NX,) and G shared; xc0 (m, NC), P (m, NP). */
void %(name)s_run(int m, int n, int first, int last, const double *restrict x0, const double *restrict xc0,
                  const double *restrict R, const double *restrict noise, const double *restrict D,
                  const double *restrict P, const double *restrict G, double *restrict X, double *restrict XC,
                  double *restrict Y, double *restrict U, double *restrict MEAS)
{
    double s[NS + 1][LANES], sn[NS + 1][LANES], p[NP + 1][LANES], y[NY + 1][LANES], ms[NM + 1][LANES];
    double u[NU + 1][LANES], nz[NM + 1][LANES];
    long idx[LANES];
    int b, c, j, k, q;
    (void) m;
    for (b = first; b < last; b += LANES) {
        c = last - b < LANES ? last - b : LANES;
        for (j = 0; j < LANES; ++j) idx[j] = b + (j < c ? j : c - 1);
        for (q = 0; q < NP; ++q)
            for (j = 0; j < LANES; ++j) p[q][j] = P[idx[j] * NP + q];
        for (j = 0; j < LANES; ++j) {
            for (q = 0; q < NX; ++q) s[q][j] = x0[q];
            for (q = 0; q < NC; ++q) s[NX + q][j] = xc0[idx[j] * NC + q];
        }
        memset(nz, 0, sizeof nz);
        for (k = 0; k <= n; ++k) {
            const double *restrict r = R + (long) k * NR, *restrict d = D + (long) k * NU;
#pragma omp simd
            for (j = 0; j < LANES; ++j) {
%(output_body)s
            }
            for (j = 0; j < c; ++j) {
                long at = (long) (b + j) * (n + 1) + k;
                for (q = 0; q < NX; ++q) X[at * NX + q] = s[q][j];
                for (q = 0; q < NC; ++q) XC[at * NC + q] = s[NX + q][j];
                for (q = 0; q < NY; ++q) Y[at * NY + q] = y[q][j];
            }
            if (k == n) break;
            if (noise)
                for (j = 0; j < LANES; ++j)
                    for (q = 0; q < NM; ++q) nz[q][j] = noise[(idx[j] * n + k) * NM + q];
            for (q = 0; q < NM; ++q)
                for (j = 0; j < LANES; ++j) ms[q][j] = %(measured)s[q][j] + nz[q][j];
#pragma omp simd
            for (j = 0; j < LANES; ++j) {
%(step_body)s
            }
            for (j = 0; j < c; ++j) {
                long at = (long) (b + j) * n + k;
                for (q = 0; q < NU; ++q) U[at * NU + q] = u[q][j];
                for (q = 0; q < NM; ++q) MEAS[at * NM + q] = ms[q][j];
            }
            memcpy(s, sn, sizeof s);
        }
    }
}
"""


def kernel_source(plant: Plant, controller: Block, substeps: int, name: str = "codesign_mc") -> str:
    """The C source of the kernel of `controller` on `plant` with `substeps` RK4 steps per sample.

    Raises
    ------
    KernelUnavailable
        When the closed loop uses an operation `body` does not write.
    """
    step = closed_loop_step(plant, controller, substeps)
    x, p = ca.SX.sym("x", plant.nx), ca.SX.sym("p", plant.n_params)
    h = ca.Function("outputs", [x, p], [ca.densify(plant.casadi_h(x, p))])
    indent = " " * 16
    vector_math = "\n".join(
        f"#pragma omp declare simd notinbranch\ndouble {f}(double) __attribute__((const));" for f in VECTOR_MATH
    )
    output_body = body(h, ["s[{k}][j]", "p[{k}][j]"], ["y[{k}][j]"])
    step_body = body(
        step,
        ["s[{k}][j]", "ms[{k}][j]", "r[{k}]", "d[{k}]", "p[{k}][j]", "G[{k}]"],
        ["sn[{k}][j]", "u[{k}][j]"],
    )
    return _SOURCE % {
        "vector_math": vector_math,
        "lanes": LANES,
        "name": name,
        "nx": plant.nx,
        "nc": controller.n_state,
        "nm": controller.n_measured,
        "ny": plant.ny,
        "nu": plant.nu,
        "nr": controller.n_reference,
        "np": plant.n_params,
        "measured": "y" if controller.measures == "outputs" else "s",
        "output_body": "\n".join(indent + line for line in output_body),
        "step_body": "\n".join(indent + line for line in step_body),
    }


def closed_loop_step(plant: Plant, controller: Block, substeps: int) -> ca.Function:
    """One closed-loop sample after the measurement, as an SX Function.

    ``(s, meas, r, d, p, gains) -> (s_next, u)``: s = (x, x_c) (nx + n_state,), meas (n_measured,) what the
    controller reads, r (n_reference,), d (nu,) the input disturbance, p (n_params,); the controller's step
    gives (x_c_next, u) and the plant takes `substeps` RK4 steps over the sample period with
    ``saturate(u) + d``. `closed_loop_function` and the compiled Monte Carlo kernel (`kernel`)
    are both built on it.
    """
    rk4 = plant.step_function(controller.sample_period, substeps)
    nx, nc = plant.nx, controller.n_state
    s = ca.SX.sym("s", nx + nc)
    meas = ca.SX.sym("meas", controller.n_measured)
    r = ca.SX.sym("r", controller.n_reference)
    d = ca.SX.sym("d", plant.nu)
    p = ca.SX.sym("p", plant.n_params)
    g = ca.SX.sym("gains", controller.gain_vector().size)
    x, xc = s[:nx], s[nx:]
    xc_next, u = controller.casadi_step(xc, meas, r, g)
    x_next = rk4(x, saturate(u, plant.input_limit) + d, p)
    return ca.Function(
        "closed_loop_advance",
        [s, meas, r, d, p, g],
        [ca.vertcat(x_next, xc_next), u],
        ["s", "meas", "r", "d", "p", "gains"],
        ["s_next", "u"],
    )


_DOUBLES = ctypes.POINTER(ctypes.c_double)


def _pointer(arr: np.ndarray | None):
    """A C double pointer to the contiguous float64 array `arr` (None: NULL)."""
    return None if arr is None else arr.ctypes.data_as(_DOUBLES)


@dataclass(frozen=True)
class MonteCarloKernel:
    """A compiled closed loop of one Block on one plant over samples x steps (see the module docstring).

    Attributes
    ----------
    library : the compiled library (from `models.compile.load_library`)
    nx, nc, nm, ny, nu, nr, n_params : sizes of x, x_c, the measurement, y, u, r, p
    """

    library: compiling.CompiledLibrary
    nx: int
    nc: int
    nm: int
    ny: int
    nu: int
    nr: int
    n_params: int

    def run(self, x0, xc0, R, noise, D, P, G, out: dict, threads: int = 1) -> None:
        """Run the samples of P into `out`, `threads` ranges of samples in parallel.

        Parameters
        ----------
        x0 : (nx,);  xc0 : (m, nc);  R : (n, nr);  noise : (m, n, nm) or None;  D : (n, nu);  P : (m, n_params)
        G : the controller's gain vector
        out : arrays "x" (m, n+1, nx), "xc" (m, n+1, nc), "y" (m, n+1, ny), "u" (m, n, nu), "measured"
            (m, n, nm), C-contiguous float64, written in place
        """
        fun = self.library.function("codesign_mc_run", [ctypes.c_int] * 4 + [_DOUBLES] * 12)
        m, n = P.shape[0], R.shape[0]
        keep = [np.ascontiguousarray(a, dtype=float) for a in (x0, xc0, R, D, P, G)]
        keep.append(np.zeros(1))  # a valid pointer for empty arrays
        x0_, xc0_, R_, D_, P_, G_, spare = keep
        noise_ = None if noise is None else np.ascontiguousarray(noise, dtype=float)
        outs = [out[name] for name in ("x", "xc", "y", "u", "measured")]
        for arr in outs:
            if not (arr.flags.c_contiguous and arr.dtype == np.float64):
                raise ValueError("the kernel writes C-contiguous float64 arrays")

        def pointer(arr):
            return _pointer(arr if arr.size else spare)

        args = [pointer(a) for a in (x0_, xc0_, R_)] + [_pointer(noise_)]
        args += [pointer(a) for a in (D_, P_, G_)] + [pointer(a) for a in outs]
        blocks = -(-m // LANES)
        parts = max(1, min(int(threads), blocks))
        edges = [LANES * (blocks * i // parts) for i in range(parts)] + [m]

        def call(i: int) -> None:
            fun(m, n, edges[i], min(edges[i + 1], m), *args)

        if parts == 1:
            call(0)
        else:
            with ThreadPoolExecutor(parts) as pool:
                list(pool.map(call, range(parts)))


def kernel(plant: Plant, controller: Block, substeps: int) -> MonteCarloKernel:
    """The compiled kernel of `controller` on `plant`, cached on the plant (as is the reason it has none).

    Raises
    ------
    KernelUnavailable
        Naming why there is none: an operation the generator does not write, or no compiled library
        (the compiler's or the cache's reason).
    """
    key = ("mc_kernel", id(controller.casadi_step), controller.sample_period, substeps)
    cache = plant.function_cache
    if key not in cache:
        try:
            source = kernel_source(plant, controller, substeps)
            library = compiling.load_library({"mc_kernel.c": source}, KERNEL_FLAGS, fallback=False)
            assert library is not None
            built: MonteCarloKernel | str = MonteCarloKernel(
                library,
                plant.nx,
                controller.n_state,
                controller.n_measured,
                plant.ny,
                plant.nu,
                controller.n_reference,
                plant.n_params,
            )
        except (KernelUnavailable, compiling.CompilationError) as err:
            built = str(err)
        # Holding the step Function keeps its id from being reused while cached.
        cache[key] = (controller.casadi_step, built)
    built = cache[key][1]
    if isinstance(built, str):
        raise KernelUnavailable(built)
    return built
