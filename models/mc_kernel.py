"""The Monte Carlo's compiled kernel: a Block's closed loop over samples x steps in one C loop.

The closed-loop sample of `models.closed_loop` (y_k = h(x_k), the measurement,
the controller's step, saturation and the plant's RK4 sub-steps) is written as
straight-line C from the instructions of its SX Functions (`vector_code`), on
vectors of samples: every value is a vector of the machine's width (GCC's
vector extensions, one register: 8 doubles with AVX-512), one sample per
lane, and every instruction one vector operation. `GROUPS` vectors run side by
side, each statement written once per vector, so that their independent
chains of operations interleave. What depends only on the parameters, the
gains and constants is computed once per block of samples, not every step. A
sine and a cosine of the same value are one inlined ``v_sincos`` (fdlibm's
reduction and polynomials, with the C library's for arguments beyond 1e5 or
not finite); exp and log go to the C library's vector variants (glibc's
libmvec), other functions lane by lane. A C loop runs the blocks of samples
and the steps, reading each sample's parameters and noise and writing the
results in the `MonteCarloResult` layout; Python calls it once per range of
samples, a thread per range, through ctypes (which releases the GIL).

A sample's numbers do not depend on the lane it runs in, nor on the other
samples of its block: every lane of every group runs the same operations
(the groups' statements are the same text, and gcc fuses a multiply and an
add wherever all the product's readers are sums in its basic block, which is
the same for every group), and a block with fewer samples fills its last
lanes with copies of its last sample. They agree with CasADi's run of the same
Functions to rounding (fused multiply-adds, a multiplication by a reciprocal
instead of a division, the kernel's own sine and cosine).

`kernel` builds (or takes from the plant's cache) the kernel of a Block, or
says why there is none: an operation this generator does not write, or no
library (no compiler, a compiler error). The library comes from
`models.compile.load_library`, so it is cached and checked like every other.
"""

from __future__ import annotations

import ctypes
import math
import os
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import casadi as ca
import numpy as np

from . import compile as compiling
from .block import Block, saturate
from .plant import Plant
from .simulate import DIVERGENCE_BOUND

#: Vectors of samples the kernel's body computes side by side, each statement once per vector: their
#: independent chains of operations keep the vector units busy while one chain waits for an operand
#: (figures: docs/performance.md). A block of samples is ``GROUPS`` vectors of ``LANES`` doubles, ``LANES``
#: the machine's (8 with AVX-512, 4 with AVX, 2 else), as `MonteCarloKernel.block` says.
GROUPS = 2

#: Ranges of samples per thread in a kernel call: the threads take them in turn (`MonteCarloKernel.run`).
PARTS_PER_THREAD = 8

#: Functions the C library has vector variants of (glibc's libmvec on x86-64): declared
#: ``omp declare simd`` so that the per-lane loops (`_lane_helper`) call them on vectors. Sine and cosine
#: are the kernel's own (``v_sincos``).
VECTOR_MATH = ("exp", "log")

#: The kernel's compiler flags: the project's; vector loops marked with ``omp simd`` (no OpenMP runtime);
#: no errno from the math functions (a side effect that would stop vectorization); 512-bit vectors where
#: the machine has them (gcc prefers 256 bits otherwise); no deferral of fused multiply-adds in chains
#: (gcc's tuning for some machines, which depends on the order of the statements: off, gcc fuses a
#: product into a sum wherever all the product's readers are sums in its basic block, the same in every
#: group); and gcc's scheduler before register allocation, with its register-pressure model (fewer
#: spills of the groups' vectors). Figures: docs/performance.md.
KERNEL_FLAGS = (
    *compiling.FLAGS,
    "-fopenmp-simd",
    "-fno-math-errno",
    "-mprefer-vector-width=512",
    "--param=avoid-fma-max-bits=0",
    "-fschedule-insns",
    "-fsched-pressure",
)

#: Scalar C of the operations that have no vector form below, for one lane ``l`` (a per-lane loop
#: `_lane_helper` writes): the C library's functions, and sign, whose zero keeps its sign.
_SCALAR = {
    ca.OP_SQRT: "sqrt({0})",
    ca.OP_FLOOR: "floor({0})",
    ca.OP_CEIL: "ceil({0})",
    ca.OP_SIGN: "({0}<0 ? -1. : {0}>0 ? 1. : {0})",
    **{
        getattr(ca, f"OP_{name.upper()}"): f"{name}({{0}})"
        for name in (
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
    ca.OP_POW: "pow({0},{1})",
    ca.OP_CONSTPOW: "pow({0},{1})",
    ca.OP_FMIN: "fmin({0},{1})",
    ca.OP_FMAX: "fmax({0},{1})",
    ca.OP_ATAN2: "atan2({0},{1})",
    ca.OP_FMOD: "fmod({0},{1})",
    ca.OP_COPYSIGN: "copysign({0},{1})",
    ca.OP_HYPOT: "hypot({0},{1})",
}
#: Operations on whole vectors (GCC's vector extensions): arithmetic, and the comparisons and logic as
#: CasADi computes them, 1. for true and 0. for false (`TRUTH` of a lane mask). Not && and ||: the
#: vectors have none; the values are those of CasADi's.
_VECTOR = {
    ca.OP_NEG: "-{0}",
    ca.OP_SQ: "{0} * {0}",
    ca.OP_TWICE: "2. * {0}",
    ca.OP_INV: "1. / {0}",
    ca.OP_NOT: "TRUTH({0} == 0.)",
    ca.OP_FABS: "(vd) ((vu) {0} & ~(vu) bc(-0.))",
    ca.OP_ASSIGN: "{0}",
    ca.OP_ADD: "{0} + {1}",
    ca.OP_SUB: "{0} - {1}",
    ca.OP_MUL: "{0} * {1}",
    ca.OP_DIV: "{0} / {1}",
    ca.OP_LT: "TRUTH({0} < {1})",
    ca.OP_LE: "TRUTH({0} <= {1})",
    ca.OP_EQ: "TRUTH({0} == {1})",
    ca.OP_NE: "TRUTH({0} != {1})",
    ca.OP_AND: "TRUTH(({0} != 0.) & ({1} != 0.))",
    ca.OP_OR: "TRUTH(({0} != 0.) | ({1} != 0.))",
    ca.OP_IF_ELSE_ZERO: "(vd) ((vu) ({0} != 0.) & (vu) {1})",
}
_BINARY = {ca.OP_POW, ca.OP_CONSTPOW, ca.OP_FMIN, ca.OP_FMAX, ca.OP_ATAN2, ca.OP_FMOD, ca.OP_COPYSIGN, ca.OP_HYPOT}
_BINARY |= {op for op, text in _VECTOR.items() if "{1}" in text}
_OPERATOR_NAMES = {getattr(ca, name): name for name in dir(ca) if name.startswith("OP_")}
#: Instructions that are no arithmetic (not counted as operations).
_NOT_ARITHMETIC = (ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST, ca.OP_PARAMETER)


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


def _lane_helper(op: int) -> str:
    """A C function applying operation `op` lane by lane (``v_<name>``), in a loop gcc vectorizes where
    it can (the C library's vector variants of `VECTOR_MATH`)."""
    name = _OPERATOR_NAMES[op].lower()
    if op in _BINARY:
        return (
            f"static inline vd v_{name}(vd a, vd b)\n{{\n    vd r;\n    int l;\n#pragma omp simd\n"
            f"    for (l = 0; l < LANES; ++l) r[l] = {_SCALAR[op].format('a[l]', 'b[l]')};\n    return r;\n}}"
        )
    return (
        f"static inline vd v_{name}(vd a)\n{{\n    vd r;\n    int l;\n#pragma omp simd\n"
        f"    for (l = 0; l < LANES; ++l) r[l] = {_SCALAR[op].format('a[l]')};\n    return r;\n}}"
    )


@dataclass
class VectorCode:
    """C statements computing an SX Function on vectors of samples (`vector_code`).

    Attributes
    ----------
    once : statements whose values stay the same over a run's steps (they read only the inputs named
        fixed, and constants): run once per block of samples
    each : the other statements, run every step
    once_operations, each_operations : the arithmetic operations they run (the Function's instructions
        other than inputs, outputs and constants, a sine counting as one; a division by a value that
        stays the same, or by a value divided by more than once, is a multiplication, and the
        reciprocal one more operation)
    helpers : the per-lane C functions they call (`_lane_helper`), by operation
    """

    once: list[str]
    each: list[str]
    once_operations: int
    each_operations: int
    helpers: dict[int, str]


@dataclass
class _Graph:
    """The instructions of an SX Function as a graph: per instruction (by index) its operation, the
    instructions it reads, those reading it (-1 for an output) and whether its value stays the same over
    the steps."""

    ops: dict[int, int]
    operands: dict[int, list[int]]
    users: dict[int, list[int]]
    steady: set[int]
    outputs: list[tuple[int, int, int]]  # (output, nonzero, instruction)

    @classmethod
    def of(cls, fun: ca.Function, fixed: set[int]) -> _Graph:
        """The graph of `fun`, whose inputs `fixed` stay the same over the steps (KernelUnavailable
        naming an operation the generator does not write)."""
        graph = cls({}, {}, {}, set(), [])
        slot: dict[int, int] = {}  # work slot -> the instruction whose value it holds
        for k in range(fun.n_instructions()):
            op, args, res = fun.instruction_id(k), fun.instruction_input(k), fun.instruction_output(k)
            if op == ca.OP_OUTPUT:
                graph.users[slot[args[0]]].append(-1)
                graph.outputs.append((res[0], res[1], slot[args[0]]))
                continue
            if op not in (ca.OP_INPUT, ca.OP_CONST, ca.OP_SIN, ca.OP_COS, *_VECTOR, *_SCALAR):
                raise KernelUnavailable(
                    f"{fun.name()} uses {_OPERATOR_NAMES.get(op, op)}, which the Monte Carlo kernel does not write"
                )
            graph.ops[k], graph.users[k] = op, []
            operands = [] if op in (ca.OP_INPUT, ca.OP_CONST) else [slot[a] for a in args[: 2 if op in _BINARY else 1]]
            graph.operands[k] = operands
            for o in operands:
                graph.users[o].append(k)
            if (
                op == ca.OP_CONST
                or (op == ca.OP_INPUT and args[0] in fixed)
                or (operands and graph.steady.issuperset(operands))
            ):
                graph.steady.add(k)
            slot[res[0]] = k
        return graph


def vector_code(fun: ca.Function, inputs: list[str], outputs: list[str], fixed: set[int], prefix: str) -> VectorCode:
    """C statements computing the SX Function `fun` on vectors, from its instructions.

    Every value is a C variable of its own (``<prefix><instruction>@``, where ``@`` stands for the
    group's suffix, `grouped`), a vector of ``LANES`` doubles (``vd``). A sine and a cosine of the same
    value are one call of ``v_sincos``. A division by a value that stays the same over the steps is a
    multiplication by its reciprocal, computed once per block; by a value divided by more than once, a
    multiplication by its reciprocal, computed once per step (rounding differs from the division's in
    the last bit).

    Parameters
    ----------
    fun : an SX Function with dense outputs
    inputs : per input of `fun`, a C format of its nonzero k as a vector (``"s{k}@"``, ``"bc(r[{k}])"``)
    outputs : per output, a C format of the vector its nonzero k is assigned to
    fixed : the inputs that stay the same over the steps (what depends on them alone runs once)
    prefix : of the variables' names

    Raises
    ------
    KernelUnavailable
        Naming an operation this generator does not write (a call of another Function, say).
    """
    fun = _expanded(fun)
    for i in range(fun.n_out()):
        if not fun.sparsity_out(i).is_dense():
            raise KernelUnavailable(f"{fun.name()}: output {fun.name_out(i)} is not dense")
    graph = _Graph.of(fun, fixed)
    divisions = Counter(graph.operands[k][1] for k, op in graph.ops.items() if op == ca.OP_DIV)
    code = VectorCode([], [], 0, 0, {})
    names: dict[int, str] = {}  # instruction -> the variable holding its value
    shared: dict[tuple, str] = {}  # (operation, operand) -> the variable of a result computed once
    for k, op in graph.ops.items():
        once = k in graph.steady
        lines = code.once if once else code.each
        operands = [names.get(o, "") for o in graph.operands[k]]
        names[k] = f"{prefix}{k}@"
        if op not in _NOT_ARITHMETIC:
            code.once_operations += once
            code.each_operations += not once
        if op == ca.OP_INPUT:
            text = inputs[fun.instruction_input(k)[0]].format(k=fun.instruction_input(k)[1])
        elif op == ca.OP_CONST:
            text = f"bc({_constant(fun.instruction_constant(k))})"
        elif op in (ca.OP_SIN, ca.OP_COS):
            if (op, operands[0]) not in shared:
                sine = shared[ca.OP_SIN, operands[0]] = f"{prefix}s{k}@"
                cosine = shared[ca.OP_COS, operands[0]] = f"{prefix}c{k}@"
                lines += [f"vd {sine}, {cosine};", f"v_sincos({operands[0]}, &{sine}, &{cosine});"]
            names[k] = shared[op, operands[0]]
            continue
        elif op == ca.OP_DIV and (divisions[graph.operands[k][1]] > 1 or graph.operands[k][1] in graph.steady):
            if (op, operands[1]) not in shared:
                shared[op, operands[1]] = f"{operands[1][:-1]}r@"
                steady = graph.operands[k][1] in graph.steady
                (code.once if steady else lines).append(f"vd {shared[op, operands[1]]} = 1. / {operands[1]};")
                code.once_operations += steady
                code.each_operations += not steady
            text = f"{operands[0]} * {shared[op, operands[1]]}"
        elif op in _VECTOR:
            text = _VECTOR[op].format(*operands)
        else:
            code.helpers.setdefault(op, _lane_helper(op))
            text = f"v_{_OPERATOR_NAMES[op].lower()}({', '.join(operands)})"
        lines.append(f"vd {names[k]} = {text};")
    code.each += [f"{outputs[i].format(k=nz)} = {names[k]};" for i, nz, k in graph.outputs]
    return code


def grouped(lines: list[str], groups: int, first: int = 0) -> list[str]:
    """Each line once per group of samples, its ``@`` the group's suffix (``_0``, ``_1``, ...), the
    groups' copies of a line one after the other: the groups' independent chains of operations
    interleave, so that one group's operations run while another's wait for their operands.
    ``first``: the number of the first group."""
    return [line.replace("@", f"_{g}") for line in lines for g in range(first, first + groups)]


_PREAMBLE = r"""/* The closed loop of one controller over samples x steps (generated by models.mc_kernel). */
#include <math.h>
#include <string.h>
#if defined(__x86_64__) && defined(__GLIBC__)
%(vector_math)s
#endif
/* Doubles in one of the machine's vector registers: gcc computes a wider vector's comparisons lane by
   lane, so each vector is one register, and the groups (GROUPS of them) give the parallel work. */
#if defined(__AVX512F__)
#define LANES 8
#elif defined(__AVX__)
#define LANES 4
#else
#define LANES 2
#endif
#define GROUPS %(groups)d
#define BLOCK (GROUPS * LANES)
typedef double vd __attribute__((vector_size(8 * LANES)));
typedef unsigned long long vu __attribute__((vector_size(8 * LANES)));

static inline vd bc(double x)
{
    vd r;
    int l;
    for (l = 0; l < LANES; ++l) r[l] = x;
    return r;
}

/* 1. where the lane mask m is set, else 0., as CasADi's comparisons give. */
#define TRUTH(m) ((vd) ((vu) (m) & (vu) bc(1.)))

/* Lanes with |x| above it, or not finite, take the C library's sine and cosine. */
#define SINCOS_LIMIT 1e5

/* Whether |x| <= SINCOS_LIMIT in every lane (false for a NaN): one comparison and a test of its mask. */
#if defined(__AVX512F__)
#include <immintrin.h>
#define WITHIN(x) (_mm512_cmp_pd_mask(_mm512_abs_pd((__m512d) (x)), _mm512_set1_pd(SINCOS_LIMIT), _CMP_LE_OQ) == 0xFF)
#elif defined(__AVX__)
#include <immintrin.h>
#define WITHIN(x) (_mm256_movemask_pd(_mm256_cmp_pd(_mm256_andnot_pd(_mm256_set1_pd(-0.), (__m256d) (x)), \
                                                     _mm256_set1_pd(SINCOS_LIMIT), _CMP_LE_OQ)) == 0xF)
#else
static inline int within(vd x)
{
    int l, every = 1;
    for (l = 0; l < LANES; ++l) every &= fabs(x[l]) <= SINCOS_LIMIT;
    return every;
}
#define WITHIN(x) within(x)
#endif


/* Sine and cosine of every lane, written here so that they inline and share their work: x reduced by
   the nearest multiple q of pi/2 in three parts (fdlibm's __ieee754_rem_pio2 constants: q times the
   first is exact for |q| < 2^20), then fdlibm's polynomials on [-pi/4, pi/4] (__kernel_sin,
   __kernel_cos, errors below one unit in the last place) swapped and signed by q modulo 4. */
static inline void v_sincos(vd x, vd *sine, vd *cosine)
{
    const vd shift = bc(6755399441055744.0); /* 1.5 * 2^52: adding it rounds to an integer */
    vd t = x * 6.36619772367581382433e-01 + shift;
    vd q = t - shift;
    vu n = (vu) t; /* q modulo 4 in the two lowest bits */
    vd y = x - q * 1.57079632673412561417e+00;
    y = y - q * 6.07710050630396597660e-11;
    y = y - q * 2.02226624879595063154e-21;
    vd z = y * y, w = z * z;
    vd sp = y + z * y * (-1.66666666666666324348e-01 + z * (8.33333333332248946124e-03 +
        z * (-1.98412698298579493134e-04 + z * (2.75573137070700676789e-06 + z * (-2.50507602534068634195e-08 +
        z * 1.58969099521155010221e-10)))));
    vd r = z * (4.16666666666666019037e-02 + z * (-1.38888888888741095749e-03 + z * 2.48015872894767294178e-05)) +
        w * w * (-2.75573143513906633035e-07 + z * (2.08757232129817482790e-09 + z * -1.13596475577881948265e-11));
    vd hz = 0.5 * z, one = 1. - hz;
    vd cp = one + (((1. - one) - hz) + z * r);
    vu zero = (vu) (y == 0.), odd = (vu) ((n & 1) != 0);
    int l;
    sp = (vd) (((vu) sp & ~zero) | ((vu) y & zero)); /* the sign of a zero kept */
    *sine = (vd) ((((vu) cp & odd) | ((vu) sp & ~odd)) ^ ((n & 2) << 62));
    *cosine = (vd) ((((vu) sp & odd) | ((vu) cp & ~odd)) ^ (((n + 1) & 2) << 62));
    if (__builtin_expect(!WITHIN(x), 0))
        for (l = 0; l < LANES; ++l)
            if (!(fabs(x[l]) <= SINCOS_LIMIT)) {
                (*sine)[l] = sin(x[l]);
                (*cosine)[l] = cos(x[l]);
            }
}
"""


_RUN = r"""
#define NX %(nx)d
#define NC %(nc)d
#define NM %(nm)d
#define NY %(ny)d
#define NU %(nu)d
#define NR %(nr)d
#define NP %(np)d

int %(name)s_block(void) { return BLOCK; }

/* The kernel's sine and cosine of x[0..n-1] into s and c (what the step runs, for checking it). */
void %(name)s_sincos(int n, const double *restrict x, double *restrict s, double *restrict c)
{
    int i, l;
    for (i = 0; i < n; i += LANES) {
        vd a = bc(0.), sine, cosine;
        for (l = 0; l < LANES && i + l < n; ++l) a[l] = x[i + l];
        v_sincos(a, &sine, &cosine);
        for (l = 0; l < LANES && i + l < n; ++l) {
            s[i + l] = sine[l];
            c[i + l] = cosine[l];
        }
    }
}

/* Samples first..last-1 of m (first a multiple of BLOCK), n steps each. Results in the layout of
   models.MonteCarloResult: X (m, n+1, NX), XC (m, n+1, NC), Y (m, n+1, NY), U (m, n, NU), MEAS (m, n, NM).
   noise (m, n, NM) or NULL for none; R (n, NR), D (n, NU), x0 (NX,) and G shared; xc0 (m, NC), P (m, NP).
   SUSPECT (m,), or NULL: 1 for a sample that may have faulted (some x_k non-finite or beyond bound, or
   u_k or xc_k non-finite: then the sum of the squares of x_k, plus xc_k and u_k times 0, is not at most
   bound2; the converse may fail), else 0. A group's vectors end in its number (s0_1: the first state
   of group 1's samples). */
void %(name)s_run(int m, int n, int first, int last, const double *restrict x0, const double *restrict xc0,
                  const double *restrict R, const double *restrict noise, const double *restrict D,
                  const double *restrict P, const double *restrict G, double *restrict X,
                  double *restrict XC, double *restrict Y, double *restrict U, double *restrict MEAS,
                  double bound2, unsigned char *restrict SUSPECT)
{
    long idx[BLOCK];
    int b, c, j, k;
    (void) m;
    for (b = first; b < last; b += BLOCK) {
%(variables)s
        c = last - b < BLOCK ? last - b : BLOCK;
        for (j = 0; j < BLOCK; ++j) idx[j] = b + (j < c ? j : c - 1);
%(start)s
%(once)s
        for (k = 0;; ++k) {
            const double *restrict r = R + (long) k * NR, *restrict d = D + (long) k * NU;
%(outputs)s
%(store_states)s
%(check)s
            if (k == n) break;
            if (noise) {
%(noise)s
            }
%(measure)s
%(step)s
%(store_inputs)s
%(advance)s
        }
        if (SUSPECT) {
%(suspect)s
        }
    }
}
"""

#: The parts of `_RUN` written once per group: ``@`` is the group's suffix, ``GROUP`` its number.
_PER_GROUP = {
    "variables": "vd {variables};",
    "start": """for (j = 0; j < LANES; ++j) {{
    long i = idx[GROUP * LANES + j];
    {start}
}}""",
    "store_states": """for (j = 0; j < LANES && j < c - GROUP * LANES; ++j) {{
    long at = (long) (b + GROUP * LANES + j) * (n + 1) + k;
    {store_states}
}}""",
    "noise": """for (j = 0; j < LANES; ++j) {{
    const double *restrict e = noise + ((long) idx[GROUP * LANES + j] * n + k) * NM;
    {noise}
}}""",
    "measure": "{measure}",
    "store_inputs": """for (j = 0; j < LANES && j < c - GROUP * LANES; ++j) {{
    long at = (long) (b + GROUP * LANES + j) * n + k;
    {store_inputs}
}}""",
    "advance": "{advance}",
    "check": "flag@ |= ~(vu) ({check} <= bound2);",
    "suspect": """for (j = 0; j < LANES && j < c - GROUP * LANES; ++j)
    SUSPECT[b + GROUP * LANES + j] = flag@[j] != 0;""",
}


def kernel_source(plant: Plant, controller: Block, substeps: int, name: str = "codesign_mc") -> str:
    """The C source of the kernel of `controller` on `plant` with `substeps` RK4 steps per sample.

    Raises
    ------
    KernelUnavailable
        When the closed loop uses an operation `vector_code` does not write.
    """
    return _kernel_parts(plant, controller, substeps, name)[0]


def _kernel_parts(plant: Plant, controller: Block, substeps: int, name: str) -> tuple[str, VectorCode, VectorCode]:
    """The kernel's C source and the code of its two Functions (the outputs y = h(x), the step)."""
    nx, nc, nm, ny, nu = plant.nx, controller.n_state, controller.n_measured, plant.ny, plant.nu
    sizes = {"nx": nx, "nc": nc, "nm": nm, "ny": ny, "nu": nu, "nr": controller.n_reference, "np": plant.n_params}
    x, p = ca.SX.sym("x", nx), ca.SX.sym("p", plant.n_params)
    h = ca.Function("outputs", [x, p], [ca.densify(plant.casadi_h(x, p))])
    outputs = vector_code(h, ["s{k}@", "p{k}@"], ["y{k}@"], {1}, "h")
    step = vector_code(
        closed_loop_step(plant, controller, substeps),
        ["s{k}@", "ms{k}@", "bc(r[{k}])", "bc(d[{k}])", "p{k}@", "bc(G[{k}])"],
        ["sn{k}@", "u{k}@"],
        {4, 5},
        "f",
    )

    def each(*forms: tuple[str, int, int]) -> str:
        """Each (format, count, first) as count statements, q from 0 and i from first."""
        return " ".join(form.format(q=q, i=first + q) for form, count, first in forms for q in range(count))

    vectors = {"s": nx + nc, "sn": nx + nc, "p": plant.n_params, "y": ny, "ms": nm, "u": nu, "nz": nm}
    # x_k's squares, and xc_k and u_{k-1} times 0 (0., or NaN where they are not finite)
    check = [f"s{q}@ * s{q}@" for q in range(nx)] + [f"s{nx + q}@ * 0." for q in range(nc)]
    check += [f"u{q}@ * 0." for q in range(nu)]
    measured = "y" if controller.measures == "outputs" else "s"
    fields = {
        "variables": ", ".join(f"{v}{q}@" for v, count in vectors.items() for q in range(count)) + "; vu flag@ = {0}",
        "start": each(
            ("p{q}@[j] = P[i * NP + {q}];", plant.n_params, 0),
            ("s{q}@[j] = x0[{q}];", nx, 0),
            ("s{i}@[j] = xc0[i * NC + {q}];", nc, nx),
            ("nz{q}@[j] = 0.;", nm, 0),
            ("u{q}@[j] = 0.;", nu, 0),
        ),
        "store_states": each(("X[at * NX + {q}] = s{q}@[j];", nx, 0), ("XC[at * NC + {q}] = s{i}@[j];", nc, nx))
        + (" if (Y) { " + each(("Y[at * NY + {q}] = y{q}@[j];", ny, 0)) + " }" if ny else ""),
        "noise": each(("nz{q}@[j] = e[{q}];", nm, 0)),
        "measure": each((f"ms{{q}}@ = {measured}{{q}}@ + nz{{q}}@;", nm, 0)),
        "store_inputs": each(("U[at * NU + {q}] = u{q}@[j];", nu, 0))
        + (" if (MEAS) { " + each(("MEAS[at * NM + {q}] = ms{q}@[j];", nm, 0)) + " }" if nm else ""),
        "advance": each(("s{q}@ = sn{q}@;", nx + nc, 0)),
        "check": "(" + " + ".join(check) + ")",
        "suspect": "",
    }
    indents = {"variables": 8, "start": 8, "noise": 16, "suspect": 12}

    def groups(part: str) -> str:
        text = _PER_GROUP[part].format(**{part: fields[part]}).splitlines()
        lines = [line.replace("GROUP", str(g)) for g in range(GROUPS) for line in grouped(text, 1, g)]
        return "\n".join(" " * indents.get(part, 12) + line for line in lines)

    def statements(lines: list[str], indent: int) -> str:
        return "\n".join(" " * indent + line for line in grouped(lines, GROUPS))

    vector_math = "\n".join(
        f"#pragma omp declare simd notinbranch\ndouble {f}(double) __attribute__((const));" for f in VECTOR_MATH
    )
    helpers = {**outputs.helpers, **step.helpers}
    source = _PREAMBLE % {"vector_math": vector_math, "groups": GROUPS}
    source += "".join(f"\n{text}\n" for text in helpers.values())
    source += _RUN % {
        "name": name,
        **sizes,
        **{part: groups(part) for part in _PER_GROUP},
        "once": statements(outputs.once + step.once, 8),
        "outputs": statements(outputs.each, 12),
        "step": statements(step.each, 12),
    }
    return source, outputs, step


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
    block : samples the kernel computes together (its vector lanes times its groups, as compiled)
    step_operations : arithmetic operations the kernel runs per sample and step (the outputs', the
        measurement's and the closed-loop step's, a sine counts as one), without those it runs once
        per block
    block_operations : those it runs once per block of samples: what depends only on the parameters,
        the gains and constants
    """

    library: compiling.CompiledLibrary
    nx: int
    nc: int
    nm: int
    ny: int
    nu: int
    nr: int
    n_params: int
    block: int
    step_operations: int
    block_operations: int

    def sincos(self, x) -> tuple[np.ndarray, np.ndarray]:
        """The sine and cosine the kernel computes of each entry of `x` (for checking them)."""
        x = np.ascontiguousarray(x, dtype=float).ravel()
        sine, cosine = np.empty_like(x), np.empty_like(x)
        self.library.function("codesign_mc_sincos", [ctypes.c_int] + [_DOUBLES] * 3)(
            x.size, _pointer(x), _pointer(sine), _pointer(cosine)
        )
        return sine, cosine

    def run(self, x0, xc0, R, noise, D, P, G, out: dict, threads: int = 1) -> None:
        """Run the samples of P into `out`, `threads` ranges of samples in parallel.

        Parameters
        ----------
        x0 : (nx,);  xc0 : (m, nc);  R : (n, nr);  noise : (m, n, nm) or None;  D : (n, nu);  P : (m, n_params)
        G : the controller's gain vector
        out : arrays "x" (m, n+1, nx), "xc" (m, n+1, nc), "y" (m, n+1, ny), "u" (m, n, nu), "measured"
            (m, n, nm), C-contiguous float64, written in place ("y" and "measured" may be None: not
            written, as where the caller reads them off "x"); and, if given, "suspect" (m,) uint8: 0
            for a sample that did not fault (no x_k non-finite or beyond `DIVERGENCE_BOUND`, no u_k or
            xc_k non-finite), 1 for one that may have (`models.closed_loop.first_faults` says when)
        """
        signature = [ctypes.c_int] * 4 + [_DOUBLES] * 12 + [ctypes.c_double, ctypes.POINTER(ctypes.c_uint8)]
        fun = self.library.function("codesign_mc_run", signature)
        m, n = P.shape[0], R.shape[0]
        keep = [np.ascontiguousarray(a, dtype=float) for a in (x0, xc0, R, D, P, G)]
        keep.append(np.zeros(1))  # a valid pointer for empty arrays
        x0_, xc0_, R_, D_, P_, G_, spare = keep
        noise_ = None if noise is None else np.ascontiguousarray(noise, dtype=float)
        outs = [out[name] for name in ("x", "xc", "y", "u", "measured")]
        for arr in outs:
            if arr is not None and not (arr.flags.c_contiguous and arr.dtype == np.float64):
                raise ValueError("the kernel writes C-contiguous float64 arrays")

        def pointer(arr):
            return None if arr is None else _pointer(arr if arr.size else spare)

        suspect = out.get("suspect")
        if suspect is not None and not (suspect.flags.c_contiguous and suspect.dtype == np.uint8):
            raise ValueError("the kernel writes its suspect flags into a C-contiguous uint8 array")
        args = [pointer(a) for a in (x0_, xc0_, R_)] + [_pointer(noise_)]
        args += [pointer(a) for a in (D_, P_, G_)] + [pointer(a) for a in outs]
        args += [
            DIVERGENCE_BOUND**2,
            None if suspect is None else suspect.ctypes.data_as(ctypes.POINTER(ctypes.c_uint8)),
        ]
        blocks = -(-m // self.block)
        threads = max(1, min(int(threads), blocks))
        # More ranges than threads, taken in turn by whichever thread is free: a thread slowed by other
        # work on its core takes fewer (a sample's numbers do not depend on its range).
        parts = min(blocks, PARTS_PER_THREAD * threads)
        edges = [self.block * (blocks * i // parts) for i in range(parts)] + [m]

        def call(i: int) -> None:
            fun(m, n, edges[i], min(edges[i + 1], m), *args)

        if threads == 1:
            fun(m, n, 0, m, *args)
        else:
            list(_workers(threads).map(call, range(parts)))


_pools: dict[tuple[int, int], ThreadPoolExecutor] = {}


def _workers(threads: int) -> ThreadPoolExecutor:
    """This process's pool of `threads` threads for kernel calls, made on first use and kept: starting
    threads took about 1 ms each, a tenth of the benchmark's Monte Carlo when every call made its own.
    Keyed by the process too, since a forked child has the pool but not its threads."""
    key = (os.getpid(), threads)
    return _pools.get(key) or _pools.setdefault(key, ThreadPoolExecutor(threads, thread_name_prefix="mc-kernel"))


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
            source, outputs, step = _kernel_parts(plant, controller, substeps, "codesign_mc")
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
                library.function("codesign_mc_block", [], ctypes.c_int)(),
                outputs.each_operations + step.each_operations + controller.n_measured,  # and meas = y + noise
                outputs.once_operations + step.once_operations,
            )
        except (KernelUnavailable, compiling.CompilationError) as err:
            built = str(err)
        # Holding the step Function keeps its id from being reused while cached.
        cache[key] = (controller.casadi_step, built)
    built = cache[key][1]
    if isinstance(built, str):
        raise KernelUnavailable(built)
    return built
