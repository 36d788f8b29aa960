"""Running the project's compiled (numba) kernels: numba's ``workqueue`` threading layer (unless
``NUMBA_THREADING_LAYER`` is set; it needs no TBB or OpenMP runtime), one parallel kernel at a time, on as many
threads as torch uses (``torch.set_num_threads`` governs both; all numba threads when torch is not loaded)."""

from __future__ import annotations

import os
import sys
import threading

import numba

if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"
_LAUNCH = threading.Lock()


def launch(kernel, *args):
    """``kernel(*args)`` under the launch lock, on torch's thread count; returns what the kernel returns."""
    torch = sys.modules.get("torch")
    threads = torch.get_num_threads() if torch is not None else numba.config.NUMBA_NUM_THREADS
    with _LAUNCH:
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
        return kernel(*args)
