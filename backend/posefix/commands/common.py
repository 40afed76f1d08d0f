"""What several command areas share."""

from __future__ import annotations

import os
import sys


def single_threaded_blas() -> None:
    """One BLAS thread unless the user chose otherwise (before numpy is first imported).

    The engine's linear algebra is 6x6 blocks, thin (n,3) products and a banded Cholesky:
    BLAS threads only spin against each other (and against the CSV parser) on them.
    """
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
        os.environ.setdefault("OMP_NUM_THREADS", "1")
