"""python -m studies.errata: rewrite docs/errata.md (see `studies.errata.main`).

A package's ``__main__`` so that the module the case files import, `studies.errata`, is the one
that runs: its `Erratum` rows are the ones `document` recognises.
"""

import sys

from . import main

if __name__ == "__main__":
    sys.exit(main())
