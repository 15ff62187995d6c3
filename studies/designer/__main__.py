"""``python -m studies.designer [PLANT] [CONTROLLER]``: serve the control designer on 127.0.0.1."""

from __future__ import annotations

import argparse
import sys

from .. import cases
from . import catalog

#: The module of the optional "designer" extra (Bokeh, Tornado) that is not installed, or "".
MISSING = ""
try:
    from .app import listen, serve
except ModuleNotFoundError as err:
    if err.name is None or err.name.split(".")[0] not in ("bokeh", "tornado"):
        raise
    MISSING = err.name.split(".")[0]


def main(argv=None) -> int:
    """Parse the command line `argv` (default ``sys.argv[1:]``), design the plant's controllers and serve
    the page until interrupted; exit status 2 (a usage message) for a bad argument."""
    parser = argparse.ArgumentParser(
        prog="python -m studies.designer",
        description="Move a gain, see the nonlinear response, the verdict and the loop.",
    )
    parser.add_argument("plant", nargs="?", default="arm", help=f"case study (default arm): {', '.join(cases.names())}")
    parser.add_argument(
        "controller",
        nargs="?",
        default=None,
        help="controller label, e.g. PD (default the case's first controller with gains)",
    )
    parser.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (default 0: a free port)")
    args = parser.parse_args(argv)
    if args.plant not in cases.names():
        parser.error(f"unknown plant {args.plant!r}; choose from {', '.join(cases.names())}")
    if not 0 <= args.port <= 65535:
        parser.error(f"--port must be in 0..65535, got {args.port}")
    if MISSING:
        parser.error(f"the designer's page needs {MISSING} (pip install 'codesign-control[designer]')")

    try:  # before designing: a port in use is a usage error, not a traceback after minutes of work
        listening = listen(args.port)
    except OSError as err:
        parser.error(f"--port {args.port}: {err.strerror}; choose a free port, or 0 for any")
    try:
        print(f"designing the {args.plant} controllers ...", flush=True)
        try:
            labels, _ = catalog(args.plant)
        except ValueError as err:
            parser.error(str(err))
        label = args.controller or labels[0]
        if label not in labels:
            parser.error(f"{args.plant} has no controller {label!r} with gains; choose from {', '.join(labels)}")
        serve(catalog, list(cases.names()), args.plant, label, listening=listening)
    finally:
        for sock in listening[0]:
            sock.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
