"""An exported controller's steps run by a small C program: the commands, each step's time measured
inside C (``clock_gettime``: the wall clock and the thread's CPU time), and the allocator's calls counted
(GNU ld's ``--wrap``).

The program is given the measurements and references of a closed loop (recorded from a run of the
same controller, in Python or through ctypes): the exported step is deterministic, so it replays that
loop's commands, without Python, ctypes or the GIL in the timed step.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models import compile as mc
from models.export import ExportedC, c_array

from . import export

#: Linker arguments that count malloc, calloc, realloc and free (GNU ld; Linux).
WRAP = "-Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc,--wrap=free"

PROGRAM = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "%(p)s.h"
static long allocations = 0, releases = 0;
#ifdef COUNT_ALLOCATIONS
void *__real_malloc(size_t); void *__real_calloc(size_t, size_t); void *__real_realloc(void *, size_t);
void __real_free(void *);
void *__wrap_malloc(size_t n) { ++allocations; return __real_malloc(n); }
void *__wrap_calloc(size_t n, size_t size) { ++allocations; return __real_calloc(n, size); }
void *__wrap_realloc(void *p, size_t n) { ++allocations; return __real_realloc(p, n); }
void __wrap_free(void *p) { if (p) ++releases; __real_free(p); }
#endif
#define STEPS %(steps)d
#define NY %(ny)d
#define NR %(nr)d
#define NU %(nu)d
%(data)s
static %(p)s_state state;
static double commands[STEPS * NU];
static long long nanoseconds[STEPS], cpu_nanoseconds[STEPS];
static int codes[STEPS];
int main(void) {
    struct timespec began, ended, cpu_began, cpu_ended;
    long init_allocations, init_releases;
    int k, i;
    int code = %(p)s_init(&state, MEASUREMENTS, REFERENCES_GIVEN);
    init_allocations = allocations;
    init_releases = releases;
    for (k = 0; k < STEPS; ++k) {
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu_began);
        clock_gettime(CLOCK_MONOTONIC, &began);
        codes[k] = %(p)s_step(&state, MEASUREMENTS + k * NY, REFERENCES_GIVEN + k * NR, commands + k * NU);
        clock_gettime(CLOCK_MONOTONIC, &ended);
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu_ended);
        nanoseconds[k] = (ended.tv_sec - began.tv_sec) * 1000000000LL + (ended.tv_nsec - began.tv_nsec);
        cpu_nanoseconds[k] = (cpu_ended.tv_sec - cpu_began.tv_sec) * 1000000000LL
                             + (cpu_ended.tv_nsec - cpu_began.tv_nsec);
    }
    printf("%%d %%ld %%ld %%ld %%ld\n", code, init_allocations, init_releases, allocations, releases);
    for (k = 0; k < STEPS; ++k) {
        printf("%%d %%lld %%lld", codes[k], nanoseconds[k], cpu_nanoseconds[k]);
        for (i = 0; i < NU; ++i) printf(" %%.17g", commands[k * NU + i]);
        printf("\n");
    }
    %(p)s_free(&state);
    return 0;
}
"""


@dataclass(frozen=True)
class Replay:
    """What the C program reports.

    init_code : ``name_init``'s status;  codes : (steps,) each step's status
    commands : (steps, nu);  step_seconds : (steps,) each step's time inside C, s (wall clock, the
    process's pre-emption included);  cpu_seconds : (steps,) each step's CPU time (the thread's clock), s
    init_allocations : allocator calls during ``name_init``;  step_allocations : during the steps
    """

    init_code: int
    codes: np.ndarray
    commands: np.ndarray
    step_seconds: np.ndarray
    cpu_seconds: np.ndarray
    init_allocations: int
    step_allocations: int


def replay(
    exported: ExportedC, measurements, references, directory, *, flags=mc.FLAGS, count_allocations=None
) -> Replay:
    """Compile a program that runs `exported`'s init on measurements[0] and its step on every row,
    run it, and read what it reports.

    Parameters
    ----------
    exported : an exported controller with ``name_init`` (`mpc.export` or `mpc.export_nmpc`)
    measurements : (steps, ny) what the step is given (measurements[0] also starts it)
    references : (steps, nr)
    directory : where the sources and the program are written
    flags : compiler flags (default models.compile's)
    count_allocations : wrap the allocator (default: on Linux)

    Raises
    ------
    models.compile.CompilationError
        When no compiler is found.
    """
    program = build_replay(
        exported, measurements, references, directory, flags=flags, count_allocations=count_allocations
    )
    return run_replay(program)


def build_replay(
    exported: ExportedC, measurements, references, directory, *, flags=mc.FLAGS, count_allocations=None
) -> Path:
    """The program of `replay`, compiled (its arguments as `replay`'s): its path, for `run_replay`."""
    y = np.asarray(measurements, dtype=float).reshape(-1, exported.n_measured)
    r = np.asarray(references, dtype=float).reshape(len(y), exported.n_reference)
    count = sys.platform == "linux" if count_allocations is None else bool(count_allocations)
    directory = Path(directory)
    exported.write(directory)
    program = PROGRAM % dict(
        p=exported.name,
        steps=len(y),
        ny=exported.n_measured,
        nr=exported.n_reference,
        nu=exported.n_input,
        data=c_array("MEASUREMENTS", y) + c_array("REFERENCES_GIVEN", r),
    )
    (directory / "replay.c").write_text(program)
    compiler = mc.compiler()
    if compiler is None:
        raise mc.CompilationError("no C compiler found")
    arguments = [*compiler, *flags, "-std=c99", f"-I{export.daqp_include_directory()}", "-o", "replay"]
    arguments += ["replay.c", f"{exported.name}.c", export.daqp_library(), "-lm"]
    if count:
        arguments += ["-DCOUNT_ALLOCATIONS", WRAP]
    subprocess.run(arguments, cwd=directory, check=True, capture_output=True, text=True)
    return directory / "replay"


def run_replay(program: Path) -> Replay:
    """Run a program of `build_replay` (again: each run starts from init) and read what it reports."""
    lines = subprocess.run([str(program)], check=True, capture_output=True, text=True).stdout.splitlines()
    init_code, init_allocations, _, allocations, _ = (int(v) for v in lines[0].split())
    rows = np.array([[float(v) for v in line.split()] for line in lines[1:]]).reshape(len(lines) - 1, -1)
    return Replay(
        init_code=init_code,
        codes=rows[:, 0].astype(int),
        commands=rows[:, 3:],
        step_seconds=rows[:, 1] * 1e-9,
        cpu_seconds=rows[:, 2] * 1e-9,
        init_allocations=init_allocations,
        step_allocations=allocations - init_allocations,
    )
