"""python -m studies: see `studies.cli`."""

import signal
import sys

from .cli import main


def _exit_with(code: int) -> None:
    """Exit with `code` whatever SIGINT arrives from now on.

    Seen once on CI: a run printed its 'interrupted' line (status 130) and then died of SIGINT (-2),
    which is what a SIGINT does once the interpreter has put back SIGINT's default action during
    shutdown. The status is decided here, so SIGINT is ignored until the process is gone.
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
        from models import interrupts

        print("python -m studies: interrupted", file=sys.stderr)
        code = 143 if interrupts.terminated() else 130
    _exit_with(code)
