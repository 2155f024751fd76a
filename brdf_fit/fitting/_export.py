"""Solver programs kept between processes as exported StableHLO (``jax.export``), so that a
second ``brdf-fit fit`` of the same static problem skips tracing and lowering the model code.

JAX's persistent compilation cache (which the command line turns on) skips only the XLA
compilation: every new process still traces the solver (optimistix's Levenberg-Marquardt loop
around the model's residuals) to a jaxpr and lowers it to MLIR before it can look the program
up, measured 1.2 of the 3 s of a warm ``brdf-fit fit``. An :class:`ExportedCall` wraps one
jitted function: on its first call with a given argument signature it loads the exported
program from the cache folder (or exports it there), and calls it through ``jax.jit(exp.call)``
(a trace of a single call primitive). The same program runs whether it was just exported or
loaded, so a first and a second process give the same numbers; the exported program is the
jitted function's own lowering, so it also gives the numbers of the plain jitted path.

The file name is a hash of everything that decides the program: the caller's static key
(:func:`brdf_fit.fitting.single._compiled`'s: model, free/fixed layout, metric, options), the
arguments' tree structure, shapes, dtypes and weak types, the jax and jaxlib versions, the
x64 flag, the backend, the package version and a hash of the package's source files (any edit
of any module gives new names: a stale program is never used). Each file carries a SHA-256 of
its payload; a file that fails it, fails to load, or does not match the arguments is ignored
(and rewritten), and any error while exporting falls back to the plain jitted function:
the cache can make a call faster, never wrong or failing.

Programs are kept in one subfolder per *generation* (``gen-<hash>``: the jax and jaxlib versions,
the package version and the source hash, the parts of the key that every program of one
installation shares). A program of another generation can never be used again by this
installation, so when a program is written the folder keeps only the :data:`KEEP_GENERATIONS`
most recently used generations (two installations sharing one folder each keep theirs) and
deletes the rest, and the files of the earlier flat layout: without it every edit of the
package left 30-220 kB per program behind, for good. Only names this module writes are ever
deleted.

Off unless a folder is named in ``$BRDF_FIT_EXPORT_DIR`` (the command line sets it inside its
cache folder, ``--no-cache`` and ``BRDF_FIT_NO_CACHE=1`` leave it unset). The payload is
:meth:`jax.export.Exported.serialize` (JAX's own flatbuffer format, versioned by JAX; no code is
unpickled), read back with :func:`jax.export.deserialize`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pathlib
import re
import shutil
from collections.abc import Callable
from typing import Any

from brdf_fit.core.atomic import write_bytes_atomic

#: the environment variable naming the folder of exported programs (unset: no cache)
ENV = "BRDF_FIT_EXPORT_DIR"
_MAGIC = b"brdf_fit-exported-2\n"
#: generations (subfolders) kept when a program is written: the current one and the most
#: recently used others (another installation sharing the folder, or a version switched back to)
KEEP_GENERATIONS = 3
#: names this module writes: a generation folder, a program of the flat layout (before
#: generations), a temporary file of an interrupted write
_GEN_RE = re.compile(r"gen-[0-9a-f]{16}")
_FLAT_RE = re.compile(r"[A-Za-z_]+-[0-9a-f]{40}\.bin|\.tmp-.*")

_SOURCE_HASH: str | None = None


def source_hash() -> str:
    """SHA-256 of the package's Python sources (relative paths and contents), once a process."""
    global _SOURCE_HASH
    if _SOURCE_HASH is None:
        root = pathlib.Path(__file__).resolve().parents[1]
        h = hashlib.sha256()
        for p in sorted(root.rglob("*.py")):
            h.update(str(p.relative_to(root)).encode())
            h.update(b"\0")
            h.update(p.read_bytes())
            h.update(b"\0")
        _SOURCE_HASH = h.hexdigest()
    return _SOURCE_HASH


def cache_dir() -> str | None:
    return os.environ.get(ENV) or None


def _leaf_sig(x) -> tuple:
    if isinstance(x, bool | int | float | complex):
        return ("py", type(x).__name__)
    shape = getattr(x, "shape", None)
    dtype = getattr(x, "dtype", None)
    if shape is None or dtype is None:
        raise TypeError(f"no signature for {type(x).__name__}")
    return (tuple(shape), str(dtype), bool(getattr(x, "weak_type", False)))


def signature(args) -> str:
    import jax

    leaves, tree = jax.tree.flatten(args)
    return repr((str(tree), tuple(_leaf_sig(x) for x in leaves)))


def _key(name: str, static: str, sig: str) -> str:
    """The file name's hash: the program's own parts and the installation's (its
    :func:`generation`: jax, jaxlib and package versions, source hash)."""
    import jax

    material = repr((name, static, sig, bool(jax.config.jax_enable_x64), jax.default_backend(),
                     generation()))
    return hashlib.sha256(material.encode()).hexdigest()[:40]


def generation() -> str:
    """The name of this installation's subfolder (see the module docstring)."""
    import jax
    import jaxlib

    from brdf_fit._version import __version__

    material = repr((jax.__version__, jaxlib.__version__, __version__, source_hash()))
    return "gen-" + hashlib.sha256(material.encode()).hexdigest()[:16]


def prune(folder: str, keep: int = KEEP_GENERATIONS) -> list[str]:
    """Delete from ``folder`` every generation but the current one and the ``keep - 1`` most
    recently used others, and the files of the flat layout; the names deleted. Errors (a file
    in use, no permission) leave that entry: pruning never fails a call."""
    current = generation()
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    gens = []
    for e in entries:
        try:
            if e.is_dir(follow_symlinks=False) and _GEN_RE.fullmatch(e.name):
                if e.name != current:
                    gens.append((e.stat(follow_symlinks=False).st_mtime, e.path, e.name))
            elif e.is_file(follow_symlinks=False) and _FLAT_RE.fullmatch(e.name):
                os.unlink(e.path)
                removed.append(e.name)
        except OSError:
            continue
    gens.sort(reverse=True)
    for _, path, name in gens[max(keep - 1, 0):]:
        shutil.rmtree(path, ignore_errors=True)
        if not os.path.exists(path):
            removed.append(name)
    return removed


def _read(path: str, sig_leaves: int):
    """The Exported in ``path``; None when missing, corrupt or not matching."""
    try:
        blob = pathlib.Path(path).read_bytes()
    except OSError:
        return None
    head = len(_MAGIC) + 32
    if len(blob) < head or not blob.startswith(_MAGIC):
        return None
    digest, payload = blob[len(_MAGIC):head], blob[head:]
    if hashlib.sha256(payload).digest() != digest:
        return None
    import jax

    try:
        exp = jax.export.deserialize(bytearray(payload))
    except Exception:
        return None

    if not isinstance(exp, jax.export.Exported) or len(exp.in_avals) != sig_leaves:
        return None
    return exp


def _write(path: str, exp) -> None:
    payload = bytes(exp.serialize())
    blob = _MAGIC + hashlib.sha256(payload).digest() + payload
    os.makedirs(os.path.dirname(path), exist_ok=True)
    write_bytes_atomic(path, blob)  # a concurrent reader sees the old file or the new one


#: custom-call targets allowed in exported programs (each failed export costs a trace and a
#: lowering: the float64 LAPACK routines of the solvers' QR and SVD are allowed from the start)
_ALLOWED: list[str] = [f"lapack_{p}{r}_ffi" for p in "sd" for r in
                       ("geqrf", "orgqr", "ormqr", "gesdd", "gesvd", "syevd", "getrf", "potrf",
                        "trsm", "geqp3")]


def _export(jitted, args, tries: int = 8):
    """``jax.export.export(jitted)(*args)``, allowing the custom calls (LAPACK's QR in the
    least-squares solves) that have no cross-version stability guarantee: a program is only
    ever used by the jax and jaxlib versions that wrote it (they are in its key)."""
    import re

    import jax

    allowed = list(_ALLOWED)
    for _ in range(tries):
        checks = [jax.export.DisabledSafetyCheck.custom_call(t) for t in allowed]
        try:
            return jax.export.export(jitted, disabled_checks=checks)(*args)
        except ValueError as exc:
            text = str(exc)
            if "custom calls" not in text:
                raise
            new = sorted(set(re.findall(r"custom_call @([A-Za-z0-9_.$-]+)", text)) - set(allowed))
            if not new:
                raise
            allowed += new
            _ALLOWED.extend(new)  # the next export of this process passes at once
    raise ValueError("too many custom-call targets")


@dataclasses.dataclass
class ExportedCall:
    """``jitted`` called through a program exported to (or loaded from) :func:`cache_dir`.
    ``static``: a text that, with the arguments' signature, decides the program (None: never
    cached; the plain ``jitted``). ``stats`` counts "loaded", "exported", "fallback"."""

    jitted: Callable
    name: str
    static: str | None
    _calls: dict = dataclasses.field(default_factory=dict)
    stats: dict = dataclasses.field(default_factory=lambda: {"loaded": 0, "exported": 0,
                                                             "fallback": 0})

    def _program(self, folder: str, args) -> Callable:
        import jax

        try:
            sig = signature(args)
        except TypeError:
            return self.jitted
        got = self._calls.get(sig)
        if got is not None:
            return got
        gen = os.path.join(folder, generation())
        path = os.path.join(gen, f"{self.name}-{_key(self.name, self.static, sig)}.bin")
        n_leaves = len(jax.tree.leaves(args))
        exp = _read(path, n_leaves)
        if exp is not None:
            self.stats["loaded"] += 1
            try:
                os.utime(gen)  # used now: the generation's age is its last use
            except OSError:
                pass
        else:
            try:
                exp = _export(self.jitted, args)
                _write(path, exp)
                self.stats["exported"] += 1
            except Exception:
                exp = None
            else:
                prune(folder)
        fn = self.jitted if exp is None else jax.jit(exp.call)
        if exp is None:
            self.stats["fallback"] += 1
        self._calls[sig] = fn
        return fn

    def __call__(self, *args) -> Any:
        folder = cache_dir()
        if folder is None or self.static is None:
            return self.jitted(*args)
        fn = self._program(folder, args)
        if fn is self.jitted:
            return fn(*args)
        args = _committed(args)
        try:
            return fn(*args)
        except Exception:  # a program that loads but does not run: the plain path, from now on
            self.stats["fallback"] += 1
            self._calls[signature(args)] = self.jitted
            return self.jitted(*args)


def export_key(problem, key) -> str | None:
    """The text that decides the programs of a fit of ``problem`` (a
    :class:`~brdf_fit.fitting.problem.FitProblem`) across processes (:class:`ExportedCall`;
    ``key``: the caller's static key, whose first item is ``problem.key``), or None where it
    cannot be trusted to: only the package's own registry models (a model registered by a
    script, or a built model, may change without the package's source hash changing), and only
    a key whose text holds no object addresses."""
    src = problem.source
    if not (isinstance(key[0][0], tuple) and key[0][0][:1] == ("registry",)):
        return None
    builder = getattr(getattr(src, "entry", None), "builder", None)
    module = getattr(builder, "__module__", None) or ""
    if not module.startswith("brdf_fit."):
        return None
    text = repr(key)
    return None if " at 0x" in text else text


def _committed(args):
    """``args`` with every JAX array committed to its device (no copy: the same buffer).

    An exported program's outputs come back committed, and ``jax.jit`` lowers a program once
    for uncommitted and again for committed arguments of one shape: a solver that feeds a
    program's outputs back into it (the chunked fit's ``sums``, ``propose`` and ``update``,
    first called with arrays made by ``jnp.asarray``) loaded each program twice. Measured
    (issue 44): 0.07 s of a whole-MERL fit's 2.0 s in the second ``sums`` alone."""
    import jax

    def commit(x):
        if isinstance(x, jax.Array) and not x.committed:
            return jax.device_put(x, next(iter(x.devices())))
        return x

    return jax.tree.map(commit, args)
