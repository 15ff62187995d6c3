"""Monte Carlo: a `Block`'s closed loop on many parameter samples, batched.

A chunk of samples runs in one call and the chunks run one after another;
`monte_carlo` holds every sample's results, `monte_carlo_chunks` one chunk's at
a time. With ``jit=True`` a chunk is one call of the compiled kernel of
`models.mc_kernel` (the closed loop in C over samples x steps, vectorized across
samples, `threads` ranges of samples in parallel). Without it, or where there is
no kernel (an operation the kernel's generator does not write, or no compiled
library: `MonteCarloPlan.engine` says which and why), the run of
`models.closed_loop.closed_loop_function` is mapped over the chunk (one CasADi
``map``, `threads` evaluations in parallel). Sample i's numbers do not depend on
the chunking, nor on which process runs it (``first_sample``): its noise is
drawn from the generator seeded with (seed, i).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from . import buffers
from .block import Block
from .checks import as_matrix, boolean, check_memory, format_bytes, integer
from .closed_loop import ClosedLoopResult, batch_outputs, closed_loop_function, first_faults
from .compile import NumpyCall
from .mc_kernel import KernelUnavailable, MonteCarloKernel, kernel
from .plant import Plant
from .run_setup import RunSetup

#: Working memory, in bytes, of one chunk of a Monte Carlo batch (CasADi's
#: output buffers and the noise of the chunk's samples; with the C kernel, the
#: chunk's results and noise, what `monte_carlo_chunks` holds at a time).
#: Results do not depend on the chunk size. Override by assignment.
MONTE_CARLO_CHUNK_BYTES = 64 * 2**20

#: Samples x steps per chunk at most: building a chunk's map costs time superlinear in its size
#: (CasADi stores the sparsity of every mapped input and output), while beyond this size a call's own
#: work already dwarfs the per-call overhead (measurements: docs/notes/models.md).
MONTE_CARLO_CHUNK_STEPS = 2**16


class MonteCarloResult(Sequence):
    """Closed-loop runs of one controller on M parameter samples, held as arrays.

    Indexing gives one sample as a `ClosedLoopResult` whose arrays are
    read-only views into the batch (no copies); iterating gives every sample.

    Attributes
    ----------
    t : (N+1,) s;  r : (N+1, n_reference);  d : (N, nu)   shared by every sample
    x : (M, N+1, nx) plant states
    xc : (M, N+1, n_state) controller states
    u : (M, N, nu) commands;  measured : (M, N, n_measured)
    params : (M, n_params) the actual parameters of each sample
    diverged_at : (M,) s, NaN where the sample did not diverge (the rule: `models.closed_loop`)
    first_sample : index of this batch's first sample in the whole sample set
        (non-zero for the chunks of `monte_carlo_chunks`)
    y : (M, N+1, ny) noise-free outputs (given, or computed on first use)
    """

    def __init__(
        self,
        *,
        plant: Plant,
        controller: str,
        t,
        r,
        d,
        x,
        xc,
        u,
        measured,
        params,
        diverged_at,
        first_sample: int = 0,
        y=None,
    ):
        self._plant = plant
        self.controller = controller
        self.t, self.r, self.d = t, r, d
        self.x, self.xc, self.u, self.measured = x, xc, u, measured
        self.params, self.diverged_at = params, diverged_at
        self.first_sample = first_sample
        self.input_limit = plant.input_limit.copy()
        self.state_names, self.output_names, self.input_names = plant.state_names, plant.output_names, plant.input_names
        self._y: np.ndarray | None = y
        self._step_time = np.full(len(t) - 1, np.nan)
        for arr in (
            self.t,
            self.r,
            self.d,
            self.x,
            self.xc,
            self.u,
            self.measured,
            self.params,
            self.diverged_at,
            self.input_limit,
            self._step_time,
            *(() if y is None else (y,)),
        ):
            arr.setflags(write=False)
        self._shared = {
            "t": self.t,
            "r": self.r,
            "d": self.d,
            "step_time": self._step_time,
            "status": None,
            "input_limit": self.input_limit,
            "state_names": self.state_names,
            "output_names": self.output_names,
            "input_names": self.input_names,
            "controller": self.controller,
        }

    @property
    def y(self) -> np.ndarray:
        """Noise-free outputs, (M, N+1, ny), computed on first use and kept (read-only)."""
        if self._y is None:
            y = batch_outputs(self._plant, self.x, self.params)
            y.setflags(write=False)
            self._y = y
        return self._y

    def __len__(self) -> int:
        return self.x.shape[0]

    def __getitem__(self, index):
        """Sample `index` as a `ClosedLoopResult` of read-only views (a list of them for a slice)."""
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        i = int(index)
        if not -len(self) <= i < len(self):
            raise IndexError(f"sample {index} of a batch of {len(self)}")
        i %= len(self)
        views = (self.x[i], self.y[i], self.u[i], self.measured[i], self.xc[i], self.params[i])
        return self._sample(*views, float(self.diverged_at[i]))

    def __iter__(self) -> Iterator[ClosedLoopResult]:
        views = zip(self.x, self.y, self.u, self.measured, self.xc, self.params, self.diverged_at.tolist())
        return (self._sample(*sample) for sample in views)

    def _sample(self, x, y, u, measured, xc, params, diverged_at: float) -> ClosedLoopResult:
        """One sample's `ClosedLoopResult` from its views and its time of divergence (NaN: none)."""
        run = object.__new__(ClosedLoopResult)
        # Every field at once: the frozen dataclass's __init__ sets them one by one through
        # object.__setattr__, which was half the time of reading a sample (tests/models/test_closed_loop.py
        # checks the fields against __init__'s).
        run.__dict__.update(
            self._shared,
            x=x,
            y=y,
            u=u,
            measured=measured,
            xc=xc,
            params=params,
            diverged_at=None if math.isnan(diverged_at) else diverged_at,
        )
        return run

    def __repr__(self) -> str:
        diverged = int(np.sum(~np.isnan(self.diverged_at)))
        return f"MonteCarloResult({self.controller!r}, {len(self)} samples x {len(self.t)} times, {diverged} diverged)"


def _batch_run(
    plant: Plant, controller: Block, n_steps: int, substeps: int, jit: bool, size: int, threads: int, noisy: bool
) -> NumpyCall:
    """`size` closed-loop runs in one call, `threads` at a time; cached on the plant.

    ``(x0 (nx,), XC0 (n_state, size), R (n_reference, N), noise, D (nu, N), P (n_params, size), gains)
    -> (X (nx, N size), XC, U, measured)``, noise (n_measured, N size) when `noisy`, else
    (n_measured, N) shared. Output columns are sample-major: sample i owns columns i N .. (i+1) N - 1.
    """
    key = (
        "closed_loop_batch",
        id(controller.casadi_step),
        controller.sample_period,
        n_steps,
        substeps,
        jit,
        size,
        threads,
        noisy,
    )
    cache = plant.function_cache
    if key not in cache:
        run = closed_loop_function(plant, controller, n_steps, substeps, jit)
        mapped = run.map(size, "thread", min(threads, size)) if size > 1 else run
        nx, nc, nm = plant.nx, controller.n_state, controller.n_measured
        args = [
            ca.MX.sym("x0", nx),
            ca.MX.sym("xc0", nc, size),
            ca.MX.sym("R", controller.n_reference, n_steps),
            ca.MX.sym("noise", nm, n_steps * size if noisy else n_steps),
            ca.MX.sym("D", plant.nu, n_steps),
            ca.MX.sym("p", plant.n_params, size),
            ca.MX.sym("gains", controller.gain_vector().size),
        ]
        fun = ca.Function(
            "closed_loop_batch",
            args,
            mapped.call(args),
            ["x0", "xc0", "R", "noise", "D", "p", "gains"],
            ["X", "XC", "U", "measured"],
        )
        cache[key] = (controller.casadi_step, NumpyCall(fun))
    return cache[key][1]


@dataclass(frozen=True)
class MonteCarloPlan:
    """A checked Monte Carlo request: what runs, the inputs every sample shares, and how to batch them.

    Attributes
    ----------
    plant : the truth, simulated at each sample's parameters
    controller : the Block that runs on every sample
    setup : the run inputs every sample shares (its seed an integer >= 0)
    samples : (M, n_params) actual parameters of each sample
    threads : evaluations run in parallel within a chunk
    jit : compile the closed loop to machine code first
    chunk : samples per batched call
    chunk_bytes : estimated working memory of one chunk's call, bytes
    first_sample : index of the first row of `samples` in the whole sample set (it sets the noise)
    kernel : the compiled kernel a chunk runs on (`models.mc_kernel`), or None for the CasADi map
    engine : what runs a chunk, in words: "C kernel", or "CasADi map" with the reason there is no kernel
    """

    plant: Plant
    controller: Block
    setup: RunSetup
    samples: np.ndarray
    threads: int
    jit: bool
    chunk: int
    chunk_bytes: float
    first_sample: int = 0
    kernel: MonteCarloKernel | None = None
    engine: str = "CasADi map"

    @classmethod
    def build(
        cls,
        plant: Plant,
        controller: Block,
        setup: RunSetup,
        param_samples,
        *,
        threads: int = 2,
        jit: bool = False,
        chunk_size: int | None = None,
        first_sample: int = 0,
    ) -> MonteCarloPlan:
        """Check the Monte Carlo's own arguments and size its chunks.

        Parameters
        ----------
        setup : from `RunSetup.build` for `plant` and `controller`
        param_samples : (M, n_params), M >= 1, every entry a valid value of its parameter
        jit : run the compiled kernel (`models.mc_kernel`) where there is one, else the compiled CasADi map
        chunk_size : samples per batched call; default the most that keeps one chunk within
            `MONTE_CARLO_CHUNK_BYTES` and, for the CasADi map, `MONTE_CARLO_CHUNK_STEPS` (at least `threads`)

        Raises
        ------
        TypeError, ValueError
            Naming the argument: no sample rows, an invalid parameter (with its row), a seed that is
            not an integer >= 0, a thread count or chunk size below 1.
        """
        samples = as_matrix(param_samples, plant.n_params, "param_samples")
        if samples.shape[0] == 0:
            raise ValueError("param_samples has no rows; give at least one parameter vector")
        must_be_positive = np.array([p.positive for p in plant.param_info], dtype=bool)
        invalid = np.any((samples < 0) | ((samples == 0) & must_be_positive), axis=1)
        if np.any(invalid):
            row = int(np.argmax(invalid))
            try:
                plant.param_vector(samples[row])
            except ValueError as err:
                raise ValueError(f"param_samples row {row}: {err}") from None
        threads = integer(threads, "threads", minimum=1)
        jit = boolean(jit, "jit")
        integer(setup.seed, "seed", minimum=0)  # each sample's noise is seeded with (seed, index)
        n, m, nc = setup.n_steps, samples.shape[0], controller.n_state
        nm = setup.n_measured
        compiled, engine = None, "CasADi map (jit=False)"
        if jit:
            try:
                compiled, engine = kernel(plant, controller, setup.substeps), "C kernel"
            except KernelUnavailable as err:
                engine = f"CasADi map (no C kernel: {err})"
        if compiled:  # the kernel writes into the results: a chunk holds its results and its noise
            work = _sample_bytes(plant, controller, setup) + (8.0 * n * nm if setup.noisy else 0.0)
        else:
            per_step = 3 * (plant.nx + nc) + 2 * plant.nu + (3 if setup.noisy else 2) * nm + controller.n_reference
            work = 8.0 * n * per_step
        if chunk_size is None:
            # The step budget bounds the cost of building a CasADi map; the kernel has none.
            by_steps = m if compiled else max(threads, MONTE_CARLO_CHUNK_STEPS // max(n, 1))
            chunk = int(min(m, max(1, min(by_steps, MONTE_CARLO_CHUNK_BYTES // work))))
        else:
            chunk = min(m, integer(chunk_size, "chunk_size", minimum=1))
        first_sample = integer(first_sample, "first_sample", minimum=0)
        return cls(plant, controller, setup, samples, threads, jit, chunk, chunk * work, first_sample, compiled, engine)

    def sample_bytes(self) -> float:
        """Bytes the results of one sample hold: x, xc, y over N+1 samples, u and measured over N."""
        return _sample_bytes(self.plant, self.controller, self.setup)

    def chunks(self) -> Iterator[tuple[int, int]]:
        """(start, stop) of each chunk of samples, in order."""
        m = self.samples.shape[0]
        for start in range(0, m, self.chunk):
            yield start, min(m, start + self.chunk)

    def allocate(self, m: int) -> tuple:
        """Uninitialized result arrays of m samples: x (m, N+1, nx), xc (m, N+1, n_state), u (m, N, nu),
        measured (m, N, n_measured), diverged_at (m,), and y (m, N+1, ny) when the kernel computes the
        outputs (else None: the result computes them on first use). With the kernel, y and measured are
        None where they repeat x (`read_off_states`): the result reads them off x."""
        n, nm = self.setup.n_steps, self.setup.n_measured
        y_off, measured_off = self.read_off_states()
        shapes = {
            "x": (m, n + 1, self.plant.nx),
            "xc": (m, n + 1, self.controller.n_state),
            "u": (m, n, self.plant.nu),
            "measured": None if measured_off else (m, n, nm),
            "diverged_at": (m,),
            "y": None if self.kernel is None or y_off else (m, n + 1, self.plant.ny),
        }
        arrays = iter(buffers.empty([shape for shape in shapes.values() if shape is not None]))
        return tuple(None if shape is None else next(arrays) for shape in shapes.values())

    def read_off_states(self) -> tuple[bool, bool]:
        """(y, measured): whether the kernel's results hold them as views of x instead of copies: the
        outputs where they are consecutive states (`output_states`), the measurement where it is the state
        or those outputs without noise. Writing them costs the kernel more than its arithmetic at 2,000
        steps a sample (docs/performance.md)."""
        if self.kernel is None:
            return False, False
        y_off = output_states(self.plant) is not None
        by_state = self.controller.measures == "state" or y_off
        return y_off, by_state and not self.setup.noisy

    def run_chunk(self, start: int, stop: int, out: tuple) -> None:
        """Run samples start..stop-1 into `out`, arrays as `allocate` gives for stop - start samples.

        One call of the batched closed loop (the kernel, or the CasADi map: `engine`); the controller's
        initial states come from each sample's first measurement, and diverged_at is the time of each
        sample's first fault (NaN if none).
        """
        plant, controller, setup = self.plant, self.controller, self.setup
        n, c = setup.n_steps, stop - start
        nx, nc, nm = plant.nx, controller.n_state, setup.n_measured
        params = self.samples[start:stop]
        noise = np.zeros((c, n, nm)) if setup.noisy else None
        if noise is not None:
            for j in range(c):
                noise[j] = setup.noise(sample=self.first_sample + start + j)
        xc0 = self._initial_states(params, None if noise is None or not n else noise[:, 0])
        x, xc, u, measured, diverged_at, y = out
        if self.kernel is not None:
            suspect = np.empty(c, dtype=np.uint8)
            arrays = {"x": x, "xc": xc, "y": y, "u": u, "measured": measured, "suspect": suspect}
            self.kernel.run(
                setup.x0, xc0, setup.r[:-1], noise, setup.d, params, controller.gain_vector(), arrays, self.threads
            )
            # The kernel flags every sample that may have faulted; the others are not read again.
            first = np.full(c, -1)
            rows = np.flatnonzero(suspect)
            if rows.size:
                first[rows] = first_faults(x[rows], u[rows], xc[rows])
        else:
            call = _batch_run(plant, controller, n, setup.substeps, self.jit, c, self.threads, setup.noisy)
            noise_arg = noise.reshape(c * n, nm).T if noise is not None else np.zeros((nm, n))
            X, XC, U, M = call(
                setup.x0, xc0.T, setup.r[:-1].T, noise_arg, setup.d.T, params.T, controller.gain_vector()
            )
            x[:, 0], x[:, 1:] = setup.x0, X.T.reshape(c, n, nx)
            xc[:, 0], xc[:, 1:] = xc0, XC.T.reshape(c, n, nc)
            u[:] = U.T.reshape(c, n, plant.nu)
            measured[:] = M.T.reshape(c, n, nm)
            first = first_faults(x, u, xc)
        diverged_at[:] = np.where(first >= 0, setup.t[np.maximum(first, 0)], np.nan)

    def _initial_states(self, params: np.ndarray, first_noise: np.ndarray | None) -> np.ndarray:
        """The controller's x_c at the first sample of each run, (c, n_state), from y_0 at `params` (c, n_params)
        plus `first_noise` (c, n_measured); one `initial_state` call per distinct y_0 (all samples share it
        without noise)."""
        plant, controller, setup = self.plant, self.controller, self.setup
        c = len(params)
        if controller.measures == "outputs":
            y0 = batch_outputs(plant, np.broadcast_to(setup.x0, (c, 1, plant.nx)), params)[:, 0]
        else:
            y0 = np.broadcast_to(setup.x0, (c, plant.nx))
        if first_noise is not None:
            y0 = y0 + first_noise
        if np.all(y0 == y0[0]):  # one call; np.unique would sort the rows first
            xc0 = np.asarray(controller.initial_state(y0[0], setup.r[0]), dtype=float).ravel()
            return np.broadcast_to(xc0, (c, controller.n_state)).copy()
        rows, inverse = np.unique(y0, axis=0, return_inverse=True)
        initial = np.array(
            [np.asarray(controller.initial_state(row, setup.r[0]), dtype=float).ravel() for row in rows]
        ).reshape(len(rows), controller.n_state)
        return initial[np.ravel(inverse)]

    def result(self, out: tuple, start: int, stop: int) -> MonteCarloResult:
        """The samples start..stop-1 of the plan, whose arrays `out` holds, as a `MonteCarloResult`
        (its first sample first_sample + start of the whole sample set)."""
        x, xc, u, measured, diverged_at, y = out
        y_off, measured_off = self.read_off_states()
        if y_off:
            y = x[:, :, output_states(self.plant)]
        if measured_off:
            measured = (x if self.controller.measures == "state" else y)[:, :-1, :]
        return MonteCarloResult(
            plant=self.plant,
            controller=self.controller.name,
            t=self.setup.t,
            r=self.setup.r,
            d=self.setup.d,
            x=x,
            xc=xc,
            u=u,
            measured=measured,
            params=np.array(self.samples[start:stop]),
            diverged_at=diverged_at,
            first_sample=self.first_sample + start,
            y=y,
        )


def _sample_bytes(plant: Plant, controller: Block, setup: RunSetup) -> float:
    """Bytes the results of one sample hold: x, xc, y over N+1 samples, u and measured over N."""
    n, nm = setup.n_steps, setup.n_measured
    return 8.0 * ((n + 1) * (plant.nx + controller.n_state + plant.ny) + n * (plant.nu + nm) + 1)


def output_states(plant: Plant) -> slice | None:
    """The states the outputs are, when y = h(x) is x[k], x[k+1], ... for every parameter: that slice of
    x, else None. Found from h's expression, cached on the plant."""
    key = ("output_states",)
    cache = plant.function_cache
    if key not in cache:
        x, p = ca.SX.sym("x", plant.nx), ca.SX.sym("p", plant.n_params)
        h = ca.densify(plant.casadi_h(x, p))
        places: list[int] = []
        for i in range(h.numel()):
            matches = [k for k in range(plant.nx) if ca.is_equal(h[i], x[k])]
            if not matches:
                break
            places.append(matches[0])
        whole = len(places) == h.numel() > 0
        consecutive = whole and places == list(range(places[0], places[0] + len(places)))
        cache[key] = slice(places[0], places[0] + len(places)) if consecutive else None
    return cache[key]


def _require_block(controller) -> None:
    """Refuse a controller the Monte Carlo cannot batch (TypeError): only a Block is one CasADi step."""
    if not isinstance(controller, Block):
        raise TypeError("monte_carlo batches Blocks; run other controllers with simulate_closed_loop")


def monte_carlo(
    plant: Plant,
    controller: Block,
    reference,
    duration: float,
    param_samples,
    *,
    x0=None,
    substeps: int = 10,
    input_disturbance=0.0,
    noise_std=0.0,
    seed: int = 0,
    threads: int = 2,
    jit: bool = False,
    chunk_size: int | None = None,
    first_sample: int = 0,
) -> MonteCarloResult:
    """Run `controller` on every parameter sample, a chunk of samples per batched CasADi map.

    Parameters
    ----------
    plant, controller, reference, duration, x0, substeps, input_disturbance, noise_std : as
        `simulate_closed_loop`, the same for every sample
    param_samples : array (M, n_params) of actual parameter vectors (see `models.uncertainty`)
    seed : integer >= 0; the noise of sample i is drawn from the generator seeded with (seed, i)
    threads : evaluations run in parallel within a chunk
    jit : compile the closed loop to machine code first (see `models.compile`)
    chunk_size : samples per batched call; default from `MONTE_CARLO_CHUNK_BYTES`. Results do not
        depend on it.
    first_sample : index of the first row of `param_samples` in a larger sample set: row j gets the
        noise of sample first_sample + j, so a set split into parts (for other processes) runs as a whole

    Returns
    -------
    MonteCarloResult: the batch as arrays; ``result[i]`` is sample i as a `ClosedLoopResult`, and a
    diverged sample has `diverged_at` set.

    Raises
    ------
    ResourceLimitError
        Before any work, when the results would need more than `models.checks.MEMORY_LIMIT_BYTES`;
        `monte_carlo_chunks` then runs the same samples holding one chunk at a time.
    """
    _require_block(controller)
    setup = RunSetup.build(
        plant,
        controller,
        reference,
        duration,
        x0=x0,
        substeps=substeps,
        input_disturbance=input_disturbance,
        noise_std=noise_std,
        seed=seed,
    )
    plan = MonteCarloPlan.build(
        plant,
        controller,
        setup,
        param_samples,
        threads=threads,
        jit=jit,
        chunk_size=chunk_size,
        first_sample=first_sample,
    )
    m, n = plan.samples.shape[0], plan.setup.n_steps
    per_sample = plan.sample_bytes()
    check_memory(
        m * per_sample + plan.chunk_bytes,
        f"monte_carlo of {m} samples x {n} steps ({format_bytes(per_sample)} per sample)",
        "run them with models.monte_carlo_chunks, which holds one chunk at a time",
    )
    out = plan.allocate(m)
    for start, stop in plan.chunks():
        plan.run_chunk(start, stop, tuple(None if a is None else a[start:stop] for a in out))
    return plan.result(out, 0, m)


def monte_carlo_chunks(
    plant: Plant,
    controller: Block,
    reference,
    duration: float,
    param_samples,
    *,
    x0=None,
    substeps: int = 10,
    input_disturbance=0.0,
    noise_std=0.0,
    seed: int = 0,
    threads: int = 2,
    jit: bool = False,
    chunk_size: int | None = None,
) -> Iterator[MonteCarloResult]:
    """`monte_carlo`, one chunk of samples at a time: memory stays bounded by the chunk.

    Arguments (plant, controller, reference, duration, param_samples, x0, substeps,
    input_disturbance, noise_std, seed, threads, jit, chunk_size) as `monte_carlo`; every argument is
    checked before the first chunk runs. Sample i
    gets the same noise and the same numbers as in `monte_carlo` (each chunk's `first_sample`
    says where it starts).

    Yields
    ------
    MonteCarloResult of samples first_sample .. first_sample + len - 1
    """
    _require_block(controller)
    setup = RunSetup.build(
        plant,
        controller,
        reference,
        duration,
        x0=x0,
        substeps=substeps,
        input_disturbance=input_disturbance,
        noise_std=noise_std,
        seed=seed,
    )
    plan = MonteCarloPlan.build(
        plant, controller, setup, param_samples, threads=threads, jit=jit, chunk_size=chunk_size
    )
    check_memory(
        plan.chunk * plan.sample_bytes() + plan.chunk_bytes,
        f"a Monte Carlo chunk of {plan.chunk} samples x {plan.setup.n_steps} steps",
        "give a smaller chunk_size",
    )

    def chunks():
        for start, stop in plan.chunks():
            out = plan.allocate(stop - start)
            plan.run_chunk(start, stop, out)
            yield plan.result(out, start, stop)

    return chunks()
