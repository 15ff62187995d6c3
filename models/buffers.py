"""Result arrays in memory the process already holds: a Monte Carlo's buffer is kept after its results go.

A Monte Carlo writes its results into fresh memory: 80 MB for the benchmark's 1,000 samples of 20 s. The
system faults and zeroes every fresh page before the kernel writes it (and a virtual machine's host may
back it first), which cost the benchmark's early runs more than the kernel's arithmetic
(docs/performance.md). `empty` hands out arrays as views of one buffer; once the last view of it is gone
(the result and every array taken from it), the buffer goes to a free list of at most `KEPT_BYTES`, and the
next request of a similar size is written into it instead of fresh memory.
"""

from __future__ import annotations

import math
import threading
import weakref

import numpy as np

#: Bytes of free buffers kept for later requests; the oldest go first beyond it, and a larger buffer is
#: never kept. ``models.buffers.KEPT_BYTES = 0`` keeps none (every request gets fresh memory).
KEPT_BYTES = 256 * 2**20

#: Bytes every array's start is a multiple of (a cache line).
ALIGNMENT = 64

_free: list[np.ndarray] = []  # byte buffers no array uses, oldest first
_lock = threading.RLock()  # a collection inside _take may give a buffer back


class _Lease:
    """A buffer lent to arrays: NumPy keeps it as their base, so it lives as long as the last of them."""

    def __init__(self, raw: np.ndarray, nbytes: int):
        address = raw.ctypes.data
        self.__array_interface__ = {
            "data": (address + (-address) % ALIGNMENT, False),
            "shape": (nbytes,),
            "typestr": "|u1",
            "version": 3,
        }
        weakref.finalize(self, _give_back, raw).atexit = False


def _give_back(raw: np.ndarray) -> None:
    with _lock:
        if raw.nbytes > KEPT_BYTES:
            return
        _free.append(raw)
        while sum(b.nbytes for b in _free) > KEPT_BYTES:
            _free.pop(0)


def _take(nbytes: int) -> np.ndarray:
    """A free buffer for nbytes aligned (up to twice that, the smallest), or fresh memory."""
    nbytes += ALIGNMENT
    with _lock:
        fits = [b for b in _free if nbytes <= b.nbytes <= 2 * nbytes]
        if fits:
            raw = min(fits, key=lambda b: b.nbytes)
            for i, b in enumerate(_free):
                if b is raw:  # by identity: a collection meanwhile may have given a buffer back and trimmed
                    return _free.pop(i)
    return np.empty(nbytes, dtype=np.uint8)


def empty(shapes, dtype=np.float64) -> list[np.ndarray]:
    """Uninitialized C-contiguous arrays of `shapes` (tuples of ints) and `dtype`, views of one buffer, each
    starting at a multiple of `ALIGNMENT` bytes: a kept buffer of a similar size where one is free (its
    earlier arrays all gone), else fresh memory."""
    dtype = np.dtype(dtype)
    sizes = [math.prod(shape) * dtype.itemsize for shape in shapes]
    starts = np.cumsum([0, *(-(-size // ALIGNMENT) * ALIGNMENT for size in sizes)])
    lease = _Lease(_take(int(starts[-1])), int(starts[-1]))
    memory = np.asarray(lease)
    return [
        memory[start : start + size].view(dtype).reshape(shape)
        for start, size, shape in zip(starts.tolist(), sizes, shapes)
    ]


def kept_bytes() -> int:
    """Bytes of free buffers kept now."""
    with _lock:
        return sum(b.nbytes for b in _free)
