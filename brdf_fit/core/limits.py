"""The memory an input may make this package allocate, checked before it is allocated.

A file or a request implies a size before any of it is read or made (a ``.npz`` member's header,
a MERL file's length, a plan's grid, a table's axes). Readers and generators compare that size
with :func:`max_memory_bytes` and refuse past it with one line naming both (issue 45: a 4 GiB
zip member, a hemisphere grid of 10^15 samples and a 6 GiB MERL file each exhausted the
machine's memory or were read whole before being refused).

The limit is :data:`DEFAULT_FRACTION` of the machine's physical memory, or the size given in
the environment variable :data:`ENV` (``brdf-fit --max-memory SIZE`` sets it), e.g. ``8G``,
``500M`` or a number of bytes.
"""

from __future__ import annotations

import os
import re

__all__ = ["ENV", "DEFAULT_FRACTION", "LimitError", "max_memory_bytes", "parse_size",
           "check_bytes", "human"]

#: the environment variable holding the limit (a size: ``8G``, ``500M``, ``123456``)
ENV = "BRDF_FIT_MAX_MEMORY"
#: the default limit as a fraction of the machine's physical memory: an input may use half of
#: it (the rest is the interpreter, JAX's compiled programs and the work on the data, which is a
#: small multiple of the data for every command)
DEFAULT_FRACTION = 0.5
_UNITS = {"": 1, "B": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


class LimitError(ValueError):
    """An input implies more memory than the limit: a user error (one line, exit status 2)."""


def parse_size(text: str) -> int:
    """``"8G"``, ``"500M"``, ``"1.5G"``, ``"123456"`` (bytes; K, M, G, T are powers of 1024,
    an optional trailing ``B`` or ``iB``) -> bytes. A bad size is a :class:`LimitError`."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([KMGT]?)(?:I?B)?\s*", str(text).upper())
    if not m:
        raise LimitError(f"{text!r} is not a size (e.g. 8G, 500M or a number of bytes)")
    value = float(m.group(1)) * _UNITS[m.group(2)]
    if value <= 0:
        raise LimitError(f"a memory limit must be positive, got {text!r}")
    return int(value)


def _physical_bytes() -> int | None:
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def max_memory_bytes() -> int:
    """The limit in force: ``$BRDF_FIT_MAX_MEMORY``, else :data:`DEFAULT_FRACTION` of the
    physical memory (8 GiB where the machine does not say)."""
    text = os.environ.get(ENV)
    if text:
        return parse_size(text)
    phys = _physical_bytes()
    return int(DEFAULT_FRACTION * phys) if phys else 8 * 2**30


def human(n: float) -> str:
    """``n`` bytes for a message: ``4.3 GB``, ``512 MB``, ``12 kB`` (powers of 1000)."""
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} bytes"


def check_bytes(nbytes: float, what: str) -> None:
    """Refuse ``what`` (a phrase naming the input and what it implies, e.g. ``"scan.npz: array
    'value' (10^9 x 3 float64)"``) when ``nbytes`` exceed the limit."""
    limit = max_memory_bytes()
    if nbytes > limit:
        raise LimitError(f"{what} would take {human(nbytes)}, over the memory limit of "
                         f"{human(limit)} (raise it with --max-memory SIZE or ${ENV})")
