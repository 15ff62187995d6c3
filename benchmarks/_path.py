"""Imported first by the benchmarks that import our packages.

Run as a script (``python benchmarks/mpc.py``), a benchmark has this folder first
on sys.path, where benchmarks/mpc.py and benchmarks/studies.py would be found
instead of the `mpc` and `studies` packages. Importing this module drops the folder.
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:] = [entry for entry in sys.path if os.path.abspath(entry or os.curdir) != HERE]
