"""``python -m studies.designer [PLANT] [CONTROLLER]``: serve the control designer on 127.0.0.1."""

from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    import studies

    parser = argparse.ArgumentParser(prog="python -m studies.designer",
                                     description="Move a gain, see the nonlinear response, the verdict and the loop.")
    parser.add_argument("plant", nargs="?", default="arm",
                        help=f"case study (default arm): {', '.join(studies.names())}")
    parser.add_argument("controller", nargs="?", default=None,
                        help="controller label, e.g. PD (default the case's first controller with gains)")
    parser.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (default 0: a free port)")
    args = parser.parse_args(argv)
    if args.plant not in studies.names():
        parser.error(f"unknown plant {args.plant!r}; choose from {', '.join(studies.names())}")
    if not 0 <= args.port <= 65535:
        parser.error(f"--port must be in 0..65535, got {args.port}")

    from . import Designer, designed_blocks, pole_placement
    from .app import serve

    print(f"designing the {args.plant} controllers ...", flush=True)
    case = studies.get(args.plant)
    blocks = designed_blocks(case)
    if not blocks:
        parser.error(f"{args.plant} has no controller with gains")
    label = args.controller or next(iter(blocks))
    if label not in blocks:
        parser.error(f"{args.plant} has no controller {label!r} with gains; choose from {', '.join(blocks)}")
    baseline = next((blocks.get(s.baseline) for s in case.loops if s.baseline), None)

    def designer(name: str) -> Designer:
        # One per page and controller: placing poles changes a designer's design.
        return Designer(case, blocks[name], name, baseline=baseline, **pole_placement(case, name))

    serve(designer, list(blocks), label, port=args.port)
    return 0


if __name__ == "__main__":
    sys.exit(main())
