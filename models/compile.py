"""Just-in-time compilation of CasADi Functions with the system C compiler.

Compiling costs 0.3-1.5 s per Function and makes long runs 3-20x faster than
CasADi's virtual machine; worth it for benchmarks, Monte Carlo and tuning
loops, not for a single short run.
"""

from __future__ import annotations

import shutil

import numpy as np

import casadi as ca

#: The JIT runs on the machine that compiles it, so -march=native is safe.
FLAGS = ["-O3", "-march=native"]


def jit(fun: ca.Function) -> ca.Function:
    """A JIT-compiled copy of `fun` with the same inputs and outputs.

    Raises
    ------
    RuntimeError
        When no C compiler (``cc``/``gcc``) is on the PATH.
    """
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        raise RuntimeError("jit=True needs a C compiler (cc or gcc) on the PATH")
    args = fun.mx_in()
    return ca.Function(fun.name() + "_jit", args, fun.call(args), fun.name_in(), fun.name_out(),
                       {"jit": True, "compiler": "shell", "jit_cleanup": True,
                        "jit_options": {"flags": FLAGS, "verbose": False}})


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
        if len(args) != len(self._in_sizes):
            raise ValueError(f"{self.fun.name()} takes {len(self._in_sizes)} inputs, got {len(args)}")
        keep = []
        for i, (arg, (rows, cols)) in enumerate(zip(args, self._in_sizes)):
            arr = np.asarray(arg, dtype=float)
            if arr.size != rows * cols:
                raise ValueError(f"{self.fun.name()}: input {self.fun.name_in(i)} needs {rows}x{cols} "
                                 f"values, got shape {arr.shape}")
            flat = np.ascontiguousarray(arr.reshape(rows, cols).ravel(order="F"))
            keep.append(flat)
            self._buffer.set_arg(i, memoryview(flat))
        outs = []
        for i, (rows, cols) in enumerate(self._out_sizes):
            out = np.empty((cols, rows))
            outs.append(out)
            self._buffer.set_res(i, memoryview(out))
        self._trigger()
        return [o.T for o in outs]
