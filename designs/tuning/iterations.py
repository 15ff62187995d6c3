"""IPOPT's iterates as they come: recorded for the answer's fallbacks and reported to a progress callback."""

from __future__ import annotations

import time
from collections.abc import Callable

import casadi as ca
import numpy as np


class IterationLog:
    """The iterates of one `solve` call: (x, f, perf_counter) each, reported to `progress` as they come, and
    beside them (`largest_g`) each iterate's largest constraint value (-inf without constraints).

    progress : optional callable(iteration, objective IPOPT saw, seconds since `started`)
    started : time.perf_counter() the seconds count from (default: now)

    `watch`, when set, is called with each iterate and its objective; True asks IPOPT to stop there.
    """

    def __init__(self, progress: Callable[[int, float, float], None] | None = None, started: float | None = None):
        self.progress = progress
        self.started = time.perf_counter() if started is None else started
        self.iterates: list[tuple[np.ndarray, float, float]] = []
        self.largest_g: list[float] = []
        self.watch: Callable[[np.ndarray, float], bool] | None = None

    def add(self, x: np.ndarray, value: float, largest_g: float = -np.inf) -> bool:
        """Record IPOPT's (scaled) decision `x`, the objective it saw there and its largest constraint value;
        True: stop IPOPT here."""
        self.iterates.append((x, value, time.perf_counter()))
        self.largest_g.append(largest_g)
        if self.progress is not None:
            self.progress(len(self.iterates) - 1, value, self.iterates[-1][2] - self.started)
        return bool(self.watch is not None and self.watch(x, value))


class IterationRecorder(ca.Callback):
    """IPOPT iteration callback passing every iterate and the objective IPOPT saw there to `log`.

    A solver keeps its callback for life; a cached solver (`TuningProblem.cached`) serves one `solve`
    call after another, each pointing `log` at its own `IterationLog`.

    nx, ng, n_p : sizes of the NLP's decision, constraints and parameters
    """

    def __init__(self, nx: int, ng: int, n_p: int):
        ca.Callback.__init__(self)
        self.log: IterationLog | None = None
        self.sizes = {"x": nx, "lam_x": nx, "g": ng, "lam_g": ng, "p": n_p, "lam_p": n_p, "f": 1}
        self.construct("recorder", {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.sizes[ca.nlpsol_out(i)], 1)

    def eval(self, arg):
        # A nonzero return makes IPOPT stop with User_Requested_Stop.
        g = np.asarray(arg[2]).ravel()
        largest = float(np.max(g)) if g.size else -np.inf
        stop = self.log is not None and self.log.add(np.asarray(arg[0]).ravel().copy(), float(arg[1]), largest)
        return [1 if stop else 0]
