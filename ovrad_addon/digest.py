"""Digests of arrays: the keys that tell whether kept or cached results still fit their inputs.

A key is stored with the data it guards (a kept block of C, a solve's fingerprint), so the bytes
fed to the hash for a given input must never change.
"""

from __future__ import annotations

import hashlib

import numpy as np


def hasher(size: int = 20):
    """A BLAKE2b hash of `size` bytes, the one every key uses."""
    return hashlib.blake2b(digest_size=size)


def add_array(h, a, dtype: bool = True) -> None:
    """Feed one array to the hash h: its dtype (unless dtype=False) and shape, then its bytes, so
    equal bytes of another type or shape give another key; None feeds b"none"."""
    if a is None:
        h.update(b"none")
        return
    a = np.ascontiguousarray(a)
    h.update((f"{a.dtype.str}{a.shape}" if dtype else str(a.shape)).encode())
    h.update(a.tobytes())
