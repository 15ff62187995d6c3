"""The tuner's run settings: their defaults, and how a run of ``python -m studies.tuner`` takes each one
from its command line, else from the case's stored record, else the default (`run_settings`), checked as
the command line checks them."""

from __future__ import annotations

import argparse
from typing import Any

from designs.tuning import HESSIANS, MAX_ITER, PATHS, WIDTHS, SolveOptions, check_widths

#: The step specs tuning enforces, as a fraction of the case's (the plants between the samples).
MARGIN = 0.95
#: The specs' form on the smoothed stages: one soft maximum per spec and run. Pointwise, the arm's 6 samples
#: of 4 runs make 22,122 inequalities on 3 gains (dense columns), and a stack sample of that phase one
#: found IPOPT in MUMPS's dense kernels.
PATHS_DEFAULT = "aggregated"
#: How the stored gains are tuned: compiled, the phase one first where the hand design misses a spec, with
#: L-BFGS (docs/guide.md's tuning section: with the exact Hessian the arm's failed).
TUNE_OPTIONS = SolveOptions(jit=True, phase_hessian="limited-memory")


def check_margin(margin: float, what: str = "the tuning margin") -> float:
    """`margin` when 0 < margin <= 1 (1: the case's own specs); ValueError naming it `what` otherwise."""
    if not 0 < margin <= 1:
        raise ValueError(f"{what} must be in (0, 1] (1: the case's own specs), got {margin!r}")
    return float(margin)


def widths_option(text: str) -> tuple[float, ...]:
    """--widths: comma-separated numbers > 0, strictly decreasing (`designs.tuning.check_widths`)."""
    try:
        return check_widths([float(part) for part in text.split(",")])
    except ValueError as err:  # a part that is not a number, or `check_widths`' refusal
        raise argparse.ArgumentTypeError(
            f"widths must be comma-separated numbers > 0, strictly decreasing, got {text!r} ({err})"
        ) from None


#: The tuning settings a run takes from the stored record when the command line does not give them: the
#: command-line option, the record's field (in "tuning", or the record's own) and the default without one.
STORED_SETTINGS = {
    "max_iter": ("--max-iter", ("tuning", "max_iter"), MAX_ITER),
    "phase_max_iter": ("--phase-max-iter", ("tuning", "phase_max_iter"), None),
    "margin": ("--margin", ("tuning_margin",), MARGIN),
    "widths": ("--widths", ("tuning", "widths"), WIDTHS),
    "paths": ("--paths", ("tuning", "paths"), PATHS_DEFAULT),
    "hessian": ("--hessian", ("tuning", "hessian"), "limited-memory"),
    "phase_hessian": ("--phase-hessian", ("tuning", "phase_hessian"), TUNE_OPTIONS.phase_hessian),
}


def run_settings(args: argparse.Namespace, record: dict | None) -> tuple[dict, list[str]]:
    """({setting: value} of one tuning run, the options taken from the stored record): each of
    `STORED_SETTINGS` from the command line where given, else from `record` (so that ``python -m
    studies.tuner PLANT`` re-runs the stored record's tuning), else its default. Values read from a
    record are checked as the command line checks them (ValueError)."""
    chosen, from_record = {}, []
    for key, (option, path, default) in STORED_SETTINGS.items():
        value = getattr(args, key)
        if value is None and record is not None:
            stored_value: Any = record
            for part in path:
                stored_value = stored_value.get(part) if isinstance(stored_value, dict) else None
            if key == "phase_max_iter" and stored_value == record.get("tuning", {}).get("max_iter"):
                stored_value = None  # the record's phase one followed its --max-iter: so does this run's
            if stored_value is not None:
                value = tuple(float(w) for w in stored_value) if key == "widths" else stored_value
                from_record.append(f"{option} {','.join(f'{w:g}' for w in value) if key == 'widths' else value}")
        chosen[key] = default if value is None else value
    check_settings(chosen)
    return chosen, from_record


def check_settings(chosen: dict) -> None:
    """ValueError naming the first setting of a run (`run_settings`) that the command line would refuse."""
    if int(chosen["max_iter"]) < 1:
        raise ValueError(f"--max-iter must be >= 1, got {chosen['max_iter']}")
    if chosen["phase_max_iter"] is not None and int(chosen["phase_max_iter"]) < 1:
        raise ValueError(f"--phase-max-iter must be >= 1, got {chosen['phase_max_iter']}")
    check_margin(chosen["margin"], "--margin")
    check_widths(chosen["widths"])
    if chosen["paths"] not in PATHS:
        raise ValueError(f"--paths must be one of {', '.join(PATHS)}, got {chosen['paths']!r}")
    for key in ("hessian", "phase_hessian"):
        if chosen[key] not in HESSIANS:
            raise ValueError(f"--{key.replace('_', '-')} must be one of {', '.join(HESSIANS)}, got {chosen[key]!r}")
