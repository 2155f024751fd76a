"""The XLA options the toolkit's processes run with, set before JAX starts.

XLA's CPU backend (jaxlib 0.10.2) compiles loop fusions with its MLIR "fusion emitters" by
default. On this package's programs its older elemental emitters compile faster and run faster
(2 cores, AMD EPYC, AVX-512; issues 41 and 44):

* one pass of the chunked fit's sums over a whole MERL file (1.1 million samples of Mitsuba's GGX
  conductor, loss and normal equations of 3 forward-mode tangents): 0.28 s against 0.35-0.50 s
  (two processes, five passes each);
* ``brdf-fit fit`` of that file with empty caches (compilation included): 2.58-2.66 s of fitting
  against 3.05-3.15 s;
* ``pytest tests/models -n 2`` (702 tests, mostly compiling): 151 s against 204 s, all passing.

:func:`configure` appends :data:`FLAG` to ``$XLA_FLAGS``; XLA reads it once, when JAX first
creates its CPU client, so it acts only where it runs before that: the command line calls it
before anything imports JAX, the test suite in its ``conftest.py``. A library user who wants the
same sets ``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false`` before importing JAX. It does
nothing where the user's ``$XLA_FLAGS`` already names the option (their choice stands), where
``$BRDF_FIT_XLA_DEFAULTS`` is ``0``, or where the installed jaxlib is not of a series in
:data:`VERIFIED` (XLA aborts the process on a flag it does not know, so the flag is only given
to a jaxlib known to have it; a new series is added after measuring it there).
"""

from __future__ import annotations

import os
import sys

__all__ = ["FLAG", "VERIFIED", "OPT_OUT_ENV", "configure"]

#: the option set (XLA's elemental loop emitters instead of its MLIR fusion emitters)
FLAG = "--xla_cpu_use_fusion_emitters=false"
#: jaxlib (major, minor) series where FLAG is known to XLA and was measured (module docstring)
VERIFIED = frozenset({(0, 10)})
#: ``0`` turns :func:`configure` off
OPT_OUT_ENV = "BRDF_FIT_XLA_DEFAULTS"


def _jaxlib_series() -> tuple[int, int] | None:
    try:
        from importlib.metadata import version

        major, minor = version("jaxlib").split(".")[:2]
        return int(major), int(minor)
    except Exception:  # not installed, or a version string of another form
        return None


def configure(environ=None) -> bool:
    """Append :data:`FLAG` to ``XLA_FLAGS`` in ``environ`` (default ``os.environ``) where it
    can still act and is wanted (module docstring); whether it did."""
    env = os.environ if environ is None else environ
    if "jax" in sys.modules and environ is None:
        return False  # JAX may have created its client already: too late to mean anything
    if env.get(OPT_OUT_ENV, "1").strip() == "0":
        return False
    current = env.get("XLA_FLAGS", "")
    if FLAG.split("=")[0] in current:
        return False
    if _jaxlib_series() not in VERIFIED:
        return False
    env["XLA_FLAGS"] = f"{current} {FLAG}".strip()
    return True
