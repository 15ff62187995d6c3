"""python -m studies: see `studies.cli`."""

import signal
import sys

from .cli import interrupted_status, main


def _exit_with(code: int) -> None:
    """Exit with `code` whatever SIGINT arrives from now on.

    During shutdown the interpreter puts back SIGINT's default action, so a SIGINT then would end
    the process by the signal (-2) after its status was decided: SIGINT is ignored from here on.

    CPython 3.11-3.12 also end a ``python -m`` program by SIGINT, whatever its SystemExit says, when
    the last code run from a string (``exec``/``eval`` of source: dataclasses' and namedtuple's
    generated methods, at an import) ended by a KeyboardInterrupt that was then caught: a flag of
    the interpreter's, reset when the next string runs. One empty string run clears it.
    """
    while True:
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            break
        except KeyboardInterrupt:  # one that arrived just before: the status already says interrupted or not
            continue
    exec("pass", {})  # noqa: S102  (clears CPython's "unhandled KeyboardInterrupt" flag; see above)
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
