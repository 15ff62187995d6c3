"""python -m studies: see `studies.cli`."""

import signal
import sys

from .cli import interrupted_status, main


def _exit_with(code: int) -> None:
    """Exit with `code` whatever SIGINT arrives from now on.

    During shutdown the interpreter puts back SIGINT's default action, so a SIGINT then would end
    the process by the signal (-2) after its status was decided: SIGINT is ignored from here on.
    """
    while True:
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            break
        except KeyboardInterrupt:  # one that arrived just before: the status already says interrupted or not
            continue
    sys.exit(code)


if __name__ == "__main__":
    try:
        code = main()
    except KeyboardInterrupt:
        # A Ctrl-C that CasADi held back and re-raised after the run had already stopped (or one before
        # the run began): nothing more is written, and the exit status is the interrupt's.
        print("python -m studies: interrupted", file=sys.stderr)
        code = interrupted_status()
    _exit_with(code)
