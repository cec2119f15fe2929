"""`make bench` (bench/run.py) and its modules.

Benchmarks run as the command line does: one BLAS thread per process unless the user set
another number (see ``ditherlab/cli.py``); set here, before numpy is first imported.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
