"""Synthetic street: scratch memory reused from frame to frame.

A full-size frame needs some tens of MB of temporary (n,) arrays. Allocated afresh for every frame, the
memory goes back to the system between frames and comes back as new pages the kernel must zero: that cost
~25 % of a frame's CPU time. `Scratch` hands out views of one pooled buffer instead; each frame (`reset`)
starts again at its beginning. Nothing handed out may be used after the next `reset`.
"""

from __future__ import annotations

import math

import numpy as np

_ALIGN = 64  # bytes: every array starts on a cache line


class Scratch:
    """A bump allocator of (n,) arrays over a reusable byte buffer, grown to the largest frame's need."""

    def __init__(self) -> None:
        self._pool = np.empty(0, np.uint8)
        self._used = 0  # bytes handed out from the pool since the last reset
        self._overflow = 0  # bytes allocated outside the pool since then (the pool was too small)

    def reset(self) -> None:
        """Start over at the pool's beginning (grow it first when the last frame did not fit)."""
        if self._overflow:
            self._pool = np.empty(self._used + self._overflow, np.uint8)
        self._used = self._overflow = 0

    def empty(self, shape: int | tuple[int, ...], dtype: type | np.dtype) -> np.ndarray:
        """An uninitialised C-contiguous array of that shape and dtype, valid until the next `reset`."""
        dt = np.dtype(dtype)
        shape = (shape,) if isinstance(shape, int) else shape
        nbytes = math.prod(shape) * dt.itemsize
        start = -(-self._used // _ALIGN) * _ALIGN
        if start + nbytes > self._pool.size:
            self._overflow += nbytes + _ALIGN
            return np.empty(shape, dt)
        self._used = start + nbytes
        return self._pool[start : start + nbytes].view(dt).reshape(shape)
