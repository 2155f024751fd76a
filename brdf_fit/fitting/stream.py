"""Streamed batch fitting: any number of problems, in blocks sized to memory, with a progress
bar and resumable output (layer 4; every block is one :func:`brdf_fit.fitting.batch.fit_batch`
call).

    wi, wo = geometry()                            # (M, 3): one gonioreflectometer geometry
    res = fit_stream(values, "ggx", "fits/", wi=wi, wo=wo)   # values: (N, M, C), memory-mapped
    res = fit_stream(lambda s, e: make(s, e), "ggx", "fits/", n_problems=10**6, wi=wi, wo=wo,
                     resume=True)                  # a source that makes the block [s, e)
    out = res.result()                             # a BatchFitResult of all N problems

**Sources.** ``values`` is an array-like of shape (N, M, C) or (N, M) sliced block by block
(a ``np.load(..., mmap_mode="r")`` array is read one block at a time), or a callable
``values(start, stop)`` returning the block ``[start, stop)``: its values (an array) or a dict
with ``"values"`` and any of ``"wi"``, ``"wo"``, ``"weight"``, ``"sigma"``. ``wi``, ``wo``
(and ``weight``, ``sigma``) are one array of shape (M, 3) (resp. (M, C)) shared by every
problem, or per-problem arrays (N, M, ...) sliced like ``values``. Shared geometry is passed
to ``fit_batch`` as (M, 3) and kept once on the device (not once per problem: 10^6 problems of
300 samples hold 14 GB of directions in float64, one geometry 14 kB). Any other keyword goes
to ``fit_batch`` (``fix``/``init`` must then be shared by all problems).

**Blocks.** All blocks have the same size (``block_size``; default: from ``memory_mb``, see
:func:`block_size_for`), balanced so that the last one is nearly full, and the last block is
padded by repeating its last problem: every block has the same shapes, so ``fit_batch``'s
compiled functions (cached per static problem and shape) compile once for the whole stream.
Padding problems are fitted and discarded.

**Output and resume.** With ``out`` (a folder), each finished block is written as
``block_{k:06d}.npz`` (parameters, standard errors, flags, loss, ...; see :func:`block_arrays`)
atomically (written to a temporary file in the folder, flushed, then renamed), and a
``manifest.json`` records the problem count, block size, model and options. A killed run
restarted with ``resume=True`` on the same folder skips every block already written and fits
the rest: nothing finished is lost and nothing is fitted twice. The manifest of a previous run
must match (same problem count, block size, model and options), and a folder holding a
previous run is refused without ``resume``. Without ``out`` the results are kept in memory.
Bad output folders (an existing file, a missing or read-only parent) are refused before any
fitting.

**Several processes.** ``shard=(index, count)`` makes this process one of ``count`` sharing
the folder: it fits the blocks ``k`` with ``k % count == index`` (of those not written yet),
so the processes exchange no data. The lead (index 0) settles the manifest (a new run, a
resumed one, or a refusal, as above) and removes stale temporary files; with ``sync`` (a
barrier of all processes, :func:`brdf_fit.fitting.distributed.barrier`) the others wait for
it, then check that the manifest is their run's, and every process waits at the end until all
blocks are written. A block is the same computation whichever process fits it, so the result
does not depend on ``count``; a run that lost a process is completed by ``resume`` with any
number of processes.

**Progress.** ``progress=True`` draws a bar on stderr (problems done, rate, ETA), updated after
every chunk of every block; a callable is called as ``progress(done, total, stage)`` like
``fit_batch``'s (the CLI's bar); None or False: silent.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import hashlib
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from brdf_fit.core.atomic import TEMP_MARK, atomic_path
from brdf_fit.fitting.batch import BatchFitResult, fit_batch
from brdf_fit.fitting.problem import FitError, model_source

__all__ = ["fit_stream", "StreamResult", "block_size_for", "plan_blocks", "block_arrays",
           "MEMORY_MB",
           "MANIFEST", "FORMAT"]

#: Default memory budget of one block (MB): inputs, prepared device copies and solver state.
MEMORY_MB = 512
#: Bytes per sample and channel a block holds at the peak (float64): the source's values, the
#: float copy fit_batch makes, the device copies (values, the weight mask, the prepared
#: log1p(f cos) and scale), the solver's gathers, and the next block's values read meanwhile
#: (prefetch); measured with the benchmark's GGX problems (peak RSS growth of the whole
#: process over its size before the stream, 16,144-problem blocks, shared geometry, 2 host
#: devices: 92 bytes with prefetch, 87 without, 2026-12-03) and rounded up.
BYTES_PER_VALUE = 96
#: ... and per sample of per-problem geometry (wi, wo and their device copies)
BYTES_PER_DIRECTION_PAIR = 160
#: Blocks are multiples of this many problems (whole groups on every device)
BLOCK_UNIT = 16
MANIFEST = "manifest.json"
FORMAT = "brdf_fit.fit_stream/1"


def block_size_for(n_samples: int, n_channels: int, shared_geometry: bool = True,
                   memory_mb: float = MEMORY_MB) -> int:
    """Problems per block that fit in ``memory_mb``: ``memory_mb`` over
    :data:`BYTES_PER_VALUE` x M x C (+ :data:`BYTES_PER_DIRECTION_PAIR` x M without shared
    geometry), a multiple of :data:`BLOCK_UNIT` (at least one unit). GGX, 300 samples, RGB,
    shared geometry, 512 MB: 6,208 problems."""
    per = n_samples * (BYTES_PER_VALUE * n_channels
                       + (0 if shared_geometry else BYTES_PER_DIRECTION_PAIR))
    n = int(memory_mb * 2**20 // max(per, 1))
    return max(BLOCK_UNIT, n // BLOCK_UNIT * BLOCK_UNIT)


def plan_blocks(n_problems: int, block_size: int) -> tuple[int, int]:
    """``(size, count)`` of the blocks of :func:`fit_stream`: at most ``block_size`` problems
    each, balanced so that the last (padded) block is nearly full, a multiple of
    :data:`BLOCK_UNIT` where that stays within ``block_size``."""
    block_size = min(int(block_size), n_problems)
    n_blocks = math.ceil(n_problems / block_size)
    bs = math.ceil(n_problems / n_blocks)
    if math.ceil(bs / BLOCK_UNIT) * BLOCK_UNIT <= block_size:
        bs = math.ceil(bs / BLOCK_UNIT) * BLOCK_UNIT
    return bs, math.ceil(n_problems / bs)


def block_arrays(res: BatchFitResult, n: int) -> dict[str, np.ndarray]:
    """The first ``n`` problems of a block's result as flat named arrays (what a block file
    holds): ``params/NAME``, ``stderr/NAME``, ``at_bound/NAME``, ``stderr_note/NAME`` (every
    free parameter, "" where defined),
    ``converged``, ``steps``, ``loss``, ``residual_rms``, ``n_samples``."""
    out = {f"params/{k}": np.asarray(v)[:n] for k, v in res.params.items()}
    out.update({f"stderr/{k}": np.asarray(v)[:n] for k, v in res.stderr.items()})
    out.update({f"at_bound/{k}": np.asarray(v)[:n] for k, v in res.at_bound.items()})
    out.update({f"stderr_note/{k}": np.asarray(res.stderr_note.get(k, np.full(
        np.shape(v), "")), dtype=str)[:n] for k, v in res.stderr.items()})
    for k in ("converged", "steps", "loss", "residual_rms", "n_samples"):
        out[k] = np.asarray(getattr(res, k))[:n]
    return out


@dataclasses.dataclass
class StreamResult:
    """Outcome of :func:`fit_stream`: where the blocks are (``out``) or the blocks themselves
    (``blocks``, without ``out``), and what this run did."""

    model_name: str
    n_problems: int
    block_size: int
    n_blocks: int
    fitted: list  # blocks fitted by this run
    skipped: list  # blocks found written already (resume)
    seconds: float
    metric: str
    solver: str
    n_params: int
    out: Path | None = None
    blocks: dict = dataclasses.field(default_factory=dict, repr=False)  # k -> arrays (no out)
    source: Any = dataclasses.field(default=None, repr=False)
    #: per fitted block: seconds, converged share
    log: list = dataclasses.field(default_factory=list, repr=False)

    def block(self, k: int) -> dict[str, np.ndarray]:
        """The arrays of block ``k`` (:func:`block_arrays`)."""
        if self.out is None:
            return self.blocks[k]
        with np.load(self.out / block_name(k)) as z:
            return {name: z[name] for name in z.files}

    def result(self) -> BatchFitResult:
        """All ``n_problems`` results as one :class:`~brdf_fit.fitting.batch.BatchFitResult`
        (read from the block files; ``rounds`` empty, ``seconds`` this run's)."""
        parts = [self.block(k) for k in range(self.n_blocks)]
        cat = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}

        def group(prefix):
            return {k[len(prefix) + 1:]: v for k, v in cat.items() if k.startswith(prefix + "/")}

        return BatchFitResult(
            model_name=self.model_name, params=group("params"), stderr=group("stderr"),
            converged=cat["converged"], steps=cat["steps"], loss=cat["loss"],
            residual_rms=cat["residual_rms"], n_samples=cat["n_samples"],
            n_params=self.n_params, metric=self.metric, solver=self.solver,
            seconds=self.seconds, at_bound=group("at_bound"),
            stderr_note={k: v for k, v in group("stderr_note").items() if (v != "").any()},
            source=self.source)


def block_name(k: int) -> str:
    return f"block_{k:06d}.npz"


class ProgressBar:
    """``progress(done, total, stage)`` drawing ``fit_stream: 12,345/1,000,000 problems
    (1.2%), 8,100/s, ETA 2m02s`` on ``stream`` (stderr), at most every ``every`` seconds; the
    rate counts the problems fitted since the bar started (not those skipped on resume)."""

    def __init__(self, label: str = "fit_stream", stream=None, every: float = 0.25):
        self.label, self.stream, self.every = label, stream or sys.stderr, every
        self.t0 = time.perf_counter()
        self.first = None
        self.last = -1.0
        self.width = 0
        self.final = False

    def __call__(self, done: int, total: int, stage: str = "") -> None:
        now = time.perf_counter()
        if self.first is None:
            self.first = done
        if now - self.last < self.every and (done < total or self.final):
            return
        self.final = done >= total
        self.last = now
        rate = (done - self.first) / max(now - self.t0, 1e-9)
        eta = (total - done) / rate if rate > 0 else float("nan")
        eta_s = "?" if not math.isfinite(eta) else f"{int(eta // 60)}m{int(eta % 60):02d}s"
        text = (f"{self.label}: {done:,}/{total:,} problems ({100 * done / max(total, 1):.1f}%),"
                f" {rate:,.0f}/s, ETA {eta_s}" + (f" [{stage}]" if stage else ""))
        self.stream.write("\r" + text.ljust(self.width))
        self.width = len(text)
        self.stream.flush()

    def close(self) -> None:
        if self.width:
            self.stream.write("\n")
            self.stream.flush()
            self.width = 0


def _check_out(out) -> Path:
    """The output folder, refused before any work: not an existing file, its parent an existing
    writable folder, itself writable if it exists."""
    p = Path(out)
    if p.exists() and not p.is_dir():
        raise FitError(f"{out}: the output names an existing file, not a folder")
    parent = p.parent if str(p.parent) else Path(".")
    if not p.exists() and not parent.is_dir():
        raise FitError(f"{out}: cannot write: folder {str(parent)!r} does not exist")
    if not os.access(p if p.exists() else parent, os.W_OK):
        raise FitError(f"{out}: cannot write: permission denied")
    return p


def _json_safe(x):
    """A JSON-able fingerprint of an option (arrays as nested lists)."""
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in sorted(x.items())}
    if isinstance(x, list | tuple):
        return [_json_safe(v) for v in x]
    if isinstance(x, np.ndarray) or hasattr(x, "shape"):
        return np.asarray(x).tolist()
    if isinstance(x, bool | int | float | str) or x is None:
        return x
    if isinstance(x, np.generic):
        return x.item()
    return repr(x)


def _write_atomic(path: Path, write) -> None:
    """``write(fh)`` into a temporary file beside ``path``, flushed to disk, renamed into place
    (:func:`brdf_fit.core.atomic.atomic_path`)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        write(fh)
        fh.flush()
        os.fsync(fh.fileno())


def _slicer(name, a, n, per_problem_ndim, m):
    """``take(s, e)`` of an array-like input: shared (returned whole) when it has
    ``per_problem_ndim - 1`` dims, else sliced along its first axis of length ``n``; ``m``
    samples per problem."""
    if a is None:
        return None, True
    shape = np.shape(a)
    if len(shape) < per_problem_ndim - 1 or shape[len(shape) - per_problem_ndim + 1] != m:
        raise FitError(f"{name}: expected shape (M, ...) shared by all problems or "
                       f"(N, M, ...), M = {m} samples, got {shape}")
    if len(shape) == per_problem_ndim - 1:
        arr = np.asarray(a, float)
        return (lambda s, e: arr), True
    if len(shape) == per_problem_ndim and shape[0] == n:
        return (lambda s, e: np.asarray(a[s:e], float)), False
    raise FitError(f"{name}: expected shape (M, ...) shared by all problems or (N, M, ...) "
                   f"with N = {n}, got {shape}")


def fit_stream(values, model, out=None, *, wi=None, wo=None, weight=None, sigma=None,
               n_problems: int | None = None, block_size: int | None = None,
               memory_mb: float = MEMORY_MB, resume: bool = False, progress=True,
               meta: dict | None = None, prefetch: bool = True,
               shard: tuple[int, int] | None = None, sync=None, **fit_kw) -> StreamResult:
    """Fit ``model`` to N problems streamed from ``values`` in equal blocks (see the module
    docstring): ``values`` an array-like (N, M, C) / (N, M) or a callable ``values(start, stop)``
    (then ``n_problems`` is required); ``wi``, ``wo``, ``weight``, ``sigma`` shared or
    per-problem arrays; ``out`` a folder for the block files and the manifest (None: in
    memory); ``block_size`` (default :func:`block_size_for` of ``memory_mb``); ``resume``:
    continue the run in ``out``; ``progress``: True (a bar on stderr), a callable
    ``progress(done, total, stage)``, or None/False; ``meta``: JSON-able facts about the
    source recorded in the manifest and required equal on resume (the CLI: its file list);
    ``prefetch``: read the next block on a worker thread while this one is fitted (a callable
    source is then called from that thread, one call at a time, in block order; False: every
    block is read on the calling thread between fits). ``shard``: ``(index, count)``, this
    process's share of a run of ``count`` processes (the module docstring, *Several
    processes*): it fits the blocks ``k`` with ``k % count == index``; ``sync(name)``: a
    barrier of all ``count`` processes (:func:`brdf_fit.fitting.distributed.barrier`), called
    once the manifest is settled and once every block is written.
    Other keywords go to :func:`~brdf_fit.fitting.batch.fit_batch` (``fix`` / ``init``: values
    shared by all problems; a per-problem array would not match a block)."""
    t0 = time.perf_counter()
    path = None if out is None else _check_out(out)  # before anything is read or fitted
    index, count = (0, 1) if shard is None else (int(shard[0]), int(shard[1]))
    if not (count >= 1 and 0 <= index < count):
        raise FitError(f"fit_stream: shard must be (index, count) with 0 <= index < count, "
                       f"got {shard}")
    if count > 1 and path is None:
        raise FitError("fit_stream: several processes need an output folder (out)")
    lead = index == 0
    if "progress" in fit_kw:
        raise FitError("fit_stream: pass progress= (the stream's), not fit_batch's")
    callable_source = callable(values)
    if callable_source:
        if n_problems is None:
            raise FitError("fit_stream: a callable source needs n_problems")
        N = int(n_problems)
        first = values(0, min(N, 1))
        first = first if isinstance(first, dict) else {"values": first}
        f1 = np.asarray(first["values"])
        M = f1.shape[1]
        C = f1.shape[2] if f1.ndim == 3 else 1
        geo_shared = wi is not None and np.ndim(wi) == 2
    else:
        shape = np.shape(values)
        if len(shape) not in (2, 3):
            raise FitError(f"fit_stream: values must be (N, M, C) or (N, M), got {shape}")
        N = shape[0] if n_problems is None else int(n_problems)
        if N != shape[0]:
            raise FitError(f"fit_stream: n_problems = {N} but values holds {shape[0]}")
        M = shape[1]
        C = shape[2] if len(shape) == 3 else 1
        geo_shared = np.ndim(wi) == 2
        if wi is None or wo is None:
            raise FitError("fit_stream: array values need wi and wo")
    if N < 1:
        raise FitError("fit_stream: no problems")
    takes = {}
    for name, a, nd in (("wi", wi, 3), ("wo", wo, 3), ("weight", weight, 3),
                        ("sigma", sigma, 3)):
        if a is not None and name in ("weight", "sigma") and np.ndim(a) == 1:
            a = np.asarray(a)[:, None]
        takes[name] = _slicer(name, a, N, nd, M)[0]
    if not callable_source:
        takes["values"] = _slicer("values", values, N, len(np.shape(values)), M)[0]
    if block_size is None:
        block_size = block_size_for(M, C, geo_shared, memory_mb)
    if not isinstance(block_size, int | np.integer) or block_size < 1:
        raise FitError(f"fit_stream: block_size must be a positive int, got {block_size!r}")
    bs, n_blocks = plan_blocks(N, int(block_size))

    src = model_source(model, fit_kw.get("bounds"))
    manifest = {
        "format": FORMAT, "model": src.name, "n_problems": N, "block_size": bs,
        "n_blocks": n_blocks, "n_samples": M, "n_channels": C,
        "options": _json_safe({k: v for k, v in fit_kw.items()}),
        "meta": _json_safe(meta or {}),
        # shared arrays by digest (per-problem ones come from the source: not checked)
        "shared": {k: hashlib.sha256(np.ascontiguousarray(v, float).tobytes()).hexdigest()
                   for k, v in (("wi", wi), ("wo", wo), ("weight", weight), ("sigma", sigma))
                   if v is not None and np.ndim(v) <= 2},
    }
    done_blocks: set[int] = set()
    if path is not None and not lead:
        # the lead (index 0) decides: a new run, a resumed one, or a refusal; the others wait
        # for it at the barrier, then take the manifest it settled (it must be this run's)
        if sync is not None:
            sync("brdf_fit.fit_stream.manifest")
        mpath = path / MANIFEST
        try:
            old = json.loads(mpath.read_text())
        except (OSError, ValueError) as e:
            raise FitError(f"{out}: process {index} of {count}: no readable {MANIFEST} "
                           f"({e}); the lead process (index 0) writes it") from None
        diff = sorted(k for k in set(old) | set(manifest) if old.get(k) != manifest.get(k))
        if diff:
            raise FitError(f"{out}: process {index} of {count}: the run in the folder differs "
                           f"in {', '.join(diff)}")
        done_blocks = {k for k in range(n_blocks) if (path / block_name(k)).exists()}
    elif path is not None:
        mpath = path / MANIFEST
        if mpath.exists():
            if not resume:
                raise FitError(f"{out}: holds a previous run ({MANIFEST}); pass resume=True "
                               "(--resume) to continue it, or choose a new folder")
            try:
                old = json.loads(mpath.read_text())
            except (OSError, ValueError) as e:
                raise FitError(f"{out}: unreadable {MANIFEST}: {e}") from None
            diff = sorted(k for k in set(old) | set(manifest)
                          if k not in ("source",) and old.get(k) != manifest.get(k))
            if diff:
                raise FitError(f"{out}: the previous run differs in {', '.join(diff)}; "
                               "resume needs the same problems, block size, model and options")
            done_blocks = {k for k in range(n_blocks) if (path / block_name(k)).exists()}
        elif path.exists() and any(p.name.startswith("block_") for p in path.iterdir()):
            raise FitError(f"{out}: holds block files but no {MANIFEST}; choose a new folder")
        path.mkdir(exist_ok=True)
        if count == 1 or sync is not None:  # no other process is writing yet
            for stale in path.glob(f".block_*{TEMP_MARK}*"):
                stale.unlink()
        if not mpath.exists():
            _write_atomic(mpath, lambda fh: fh.write(json.dumps(manifest, indent=1).encode()))
        if sync is not None and count > 1:
            sync("brdf_fit.fit_stream.manifest")

    def load(k):
        """Block ``k``'s arrays, as fit_batch takes them (padded to ``bs`` problems)."""
        s, e = k * bs, min(N, (k + 1) * bs)
        n = e - s
        blk = values(s, e) if callable_source else {}
        blk = blk if isinstance(blk, dict) else {"values": blk}
        arrays = {}
        for name in ("values", "wi", "wo", "weight", "sigma"):
            a = blk.get(name)
            if a is None and takes.get(name) is not None:
                a = takes[name](s, e)
            if a is not None:
                a = np.asarray(a, float)
                shared = name in ("wi", "wo") and a.ndim == 2
                if not shared and name != "values" and a.ndim == 2 and a.shape[0] != n:
                    shared = True  # (M, C) weight / sigma shared by every problem
                if not shared:
                    if a.shape[0] != n:
                        raise FitError(f"fit_stream: block {k}: {name} has {a.shape[0]} "
                                       f"problems, expected {n}")
                    if n < bs:  # pad by repeating the last problem: one shape, one compile
                        a = np.concatenate([a, np.repeat(a[-1:], bs - n, axis=0)])
                elif name in ("weight", "sigma"):
                    a = np.broadcast_to(a.reshape(a.shape[0], -1)[None],
                                        (bs, *a.reshape(a.shape[0], -1).shape))
            arrays[name] = a
        if "wi" not in arrays or "wo" not in arrays:
            raise FitError(f"fit_stream: block {k}: no wi / wo (pass them or return them "
                           "from the source)")
        return n, arrays

    pool = None
    bar = ProgressBar() if progress is True else (progress or None)
    res = StreamResult(model_name=src.name, n_problems=N, block_size=bs, n_blocks=n_blocks,
                       fitted=[], skipped=sorted(done_blocks), seconds=0.0,
                       metric=fit_kw.get("metric", "log"),
                       solver=fit_kw.get("solver", "batch-lm"), n_params=0, out=path,
                       source=src)
    finished = sum(min(bs, N - k * bs) for k in done_blocks)
    mine = [k for k in range(n_blocks) if k % count == index]
    try:
        if bar is not None:
            bar(finished, N, "start")
        todo = [k for k in mine if k not in done_blocks]
        # the next block is read (the source called, its arrays converted and padded) on a
        # worker thread while this one is fitted: one call at a time, in block order
        if prefetch and len(todo) > 1:
            pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="fit_stream-read")
        pending = pool.submit(load, todo[0]) if pool is not None and todo else None
        for i, k in enumerate(todo):
            if pending is not None:  # read while the previous block was fitted
                n, arrays = pending.result()
                pending = pool.submit(load, todo[i + 1]) if i + 1 < len(todo) else None
            else:
                n, arrays = load(k)

            def inner(d, total, stage, base=finished, n=n, k=k):
                if bar is not None:
                    # a block counts as done only once written
                    bar(base + min(d, n - 1), N, f"block {k + 1}/{n_blocks}: {stage}")

            tb = time.perf_counter()
            r = fit_batch(arrays["wi"], arrays["wo"], arrays["values"], model,
                          weight=arrays.get("weight"), sigma=arrays.get("sigma"),
                          progress=inner, **fit_kw)
            res.n_params = r.n_params
            part = block_arrays(r, n)
            if path is None:
                res.blocks[k] = part
            else:
                _write_atomic(path / block_name(k), lambda fh, part=part: np.savez(fh, **part))
            res.fitted.append(k)
            res.log.append({"block": k, "problems": n,
                            "seconds": round(time.perf_counter() - tb, 4),
                            "converged": float(np.mean(part["converged"]))})
            finished += n
            if bar is not None:
                bar(finished, N, f"block {k + 1}/{n_blocks} written")
    finally:
        if pool is not None:  # an error or interrupt: the block being read is abandoned
            pool.shutdown(wait=False, cancel_futures=True)
        if bar is not None and hasattr(bar, "close"):
            bar.close()
    if sync is not None and count > 1:
        sync("brdf_fit.fit_stream.done")  # every process's blocks are written
    if res.n_params == 0 and res.fitted == [] and path is not None and n_blocks and (
            (path / block_name(0)).exists()):
        b0 = res.block(0)
        res.n_params = int(sum(np.prod(v.shape[1:], dtype=int) for k, v in b0.items()
                               if k.startswith("stderr/")))
    res.seconds = time.perf_counter() - t0
    return res
