"""python -m studies: see `studies.cli`."""

import sys

from .cli import main

if __name__ == "__main__":
    try:
        code = main()
    except KeyboardInterrupt:
        # A Ctrl-C that CasADi held back and re-raised after the run had already stopped (or one before
        # the run began): nothing more is written, and the exit status is the interrupt's.
        from models import interrupts

        print("python -m studies: interrupted", file=sys.stderr)
        code = 143 if interrupts.terminated() else 130
    sys.exit(code)
