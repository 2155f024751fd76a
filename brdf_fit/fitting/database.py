"""A database run: many measured materials (files) fitted to several models, one table out.

A study of measured BRDFs fits a database of materials to a list of models and compares the
errors (Ngan et al., EGSR 2005; Löw et al., ACM TOG 31(1) 2012). :func:`fit_database` runs
every (file, model) pair with :func:`brdf_fit.fitting.single.fit` (a whole MERL file goes
through the chunked solver of :mod:`brdf_fit.fitting.chunked`) and reports each fit in every
error measure of :mod:`brdf_fit.fitting.errors`.

**Kept as it goes.** Each finished pair is written at once, atomically, as a small JSON file in
the run's folder (``<table>.parts/``, named by a hash of the file's path, the model and the fit
options); the table (CSV, and JSON beside it) is assembled from those files in the order of the
files and models given. A run that is stopped keeps every finished pair; the same command
again fits only what is missing (a pair fitted with other options is another pair). So the
table does not depend on how the pairs were shared out: ``shard=(i, n)`` fits every n-th
pair (one process of ``brdf-fit fit ... --processes n``, or one machine of several on a shared
folder), and any run assembles what all of them wrote. The fitted values are the same
computation wherever they run; only the ``seconds`` column differs between runs.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import os
import time
from collections.abc import Callable, Sequence

import numpy as np

from brdf_fit.core.atomic import write_text_atomic
from brdf_fit.data import GonioData
from brdf_fit.fitting.errors import ERRORS, model_errors
from brdf_fit.fitting.problem import entry_labels
from brdf_fit.fitting.result import FitResult, json_floats
from brdf_fit.fitting.single import fit
from brdf_fit.io import read

__all__ = ["DatabaseRun", "fit_database", "count_finished", "table_rows", "write_table",
           "PARTS_SUFFIX"]

#: the folder of finished pairs beside the table: ``results.csv`` -> ``results.csv.parts``
PARTS_SUFFIX = ".parts"
#: the table's fixed columns, before the error measures and the parameters
COLUMNS = ("material", "model", "converged", "steps", "seconds", "n_samples", "residual_rms",
           "undetermined", "message", "file")


@dataclasses.dataclass
class DatabaseRun:
    """What :func:`fit_database` did: the rows of every finished pair (in table order, missing
    pairs left out), how many were fitted now, found finished, and failed (a file that could not
    be read or a fit that raised; each with its message in ``failures``). ``unsaved``: the
    pairs fitted now whose part could not be written (a full disk: each with the reason); their
    rows are in ``rows`` all the same, but a later run fits them again."""

    rows: list[dict]
    fitted_now: int
    already_done: int
    failed: int
    failures: list[str]
    total: int
    unsaved: list[str] = dataclasses.field(default_factory=list)


def _material_names(paths: Sequence[str]) -> list[str]:
    """A name per file: its stem, or, where two files share a stem, its path."""
    stems = [os.path.splitext(os.path.basename(p))[0] for p in paths]
    return [s if stems.count(s) == 1 else os.fspath(p) for s, p in zip(stems, paths, strict=True)]


def _pair_key(path: str, model: str, options: dict) -> str:
    text = json.dumps([os.path.abspath(path), model, options], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def _row(material: str, path: str, result: FitResult, data: GonioData) -> dict:
    """One table row of a finished fit: the result's summary, its parameters and standard
    errors by entry label, and the fitted model's error in every measure of
    :data:`brdf_fit.fitting.errors.ERRORS` on the file's samples."""
    params, stderr = {}, {}
    for name, value in result.params.items():
        labels = entry_labels(name, np.shape(value), tuple(data.channels))
        params.update(zip(labels, np.asarray(value, float).reshape(-1).tolist(), strict=True))
        if name in result.stderr:
            se = json_floats(np.asarray(result.stderr[name], float).reshape(-1))
            stderr.update(zip(labels, se if isinstance(se, list) else [se], strict=True))
    return {
        "material": material, "model": result.model_name, "converged": bool(result.converged),
        "steps": int(result.steps), "seconds": round(float(result.seconds), 3),
        "n_samples": int(result.n_samples), "residual_rms": float(result.residual_rms),
        "undetermined": list(result.undetermined), "message": result.message,
        "file": os.fspath(path), "errors": model_errors(result.model, data),
        "params": params, "stderr": stderr, "metric": result.metric,
    }


def fit_database(paths: Sequence[str], models: Sequence[str], folder: str, *,
                 fit_options: dict | None = None, identity: dict | None = None,
                 shard: tuple[int, int] | None = None,
                 progress: Callable[[int, int, str], None] | None = None,
                 reader: Callable[[str], GonioData] = read) -> DatabaseRun:
    """Fit every file of ``paths`` to every model of ``models`` (registry names), keeping each
    finished pair in ``folder`` (module docstring); returns the rows of every pair finished
    there (now or before), in the order of the files, then the models.

    ``fit_options``: keyword arguments of :func:`brdf_fit.fitting.single.fit` (metric, init,
    max_steps, ...), part of each pair's identity; ``identity``: what stands for them there
    instead (JSON-ready, e.g. with what ``reader`` does to a file), default ``fit_options``.
    ``shard=(i, n)``: fit only the pairs ``i, i + n, ...`` (the rows returned are still all
    that are finished). ``progress(done,
    total, text)`` after every pair. A file that cannot be read, or a fit that raises a user
    error, is a failure of that pair, reported and not kept (the next run tries it again)."""
    from brdf_fit.core.validate import ParameterError
    from brdf_fit.data import DataError
    from brdf_fit.fitting.problem import FitError

    options = dict(fit_options or {})
    ident = dict(options if identity is None else identity)
    os.makedirs(folder, exist_ok=True)
    names = _material_names(paths)
    pairs = [(p, n, m) for p, n in zip(paths, names, strict=True) for m in models]
    i0, n_shards = shard if shard is not None else (0, 1)
    done_now = already = failed = 0
    failures: list[str] = []
    cache: dict[str, GonioData | Exception] = {}
    kept_here: dict[str, dict] = {}  # rows whose part could not be written (see unsaved)
    unsaved: list[str] = []

    def part_path(path, model):
        return os.path.join(folder, _pair_key(path, model, ident) + ".json")

    for k, (path, material, model) in enumerate(pairs):
        if k % n_shards != i0:
            continue
        target = part_path(path, model)
        if os.path.exists(target):
            already += 1
            text = f"{material} {model}: done before"
        else:
            if path not in cache:
                cache.clear()  # one file in memory at a time
                try:
                    cache[path] = reader(path)
                except (DataError, OSError) as e:
                    cache[path] = e
            data = cache[path]
            try:
                if isinstance(data, Exception):
                    raise data
                result = fit(data, model, **options)
                row = _row(material, path, result, data)
            except (DataError, FitError, ParameterError, OSError, ValueError) as e:
                failed += 1
                failures.append(f"{material} {model}: {e}")
                text = f"{material} {model}: FAILED ({e})"
            else:
                try:
                    write_text_atomic(target, json.dumps(row))
                except OSError as e:  # a full disk: the row is kept in memory, reported
                    kept_here[target] = row
                    unsaved.append(f"{material} {model}: {e.strerror or e}")
                done_now += 1
                text = (f"{material} {model}: rel. RMS {row['errors']['rel_rms']:.4g}, "
                        f"{'converged' if row['converged'] else 'NOT converged'}, "
                        f"{row['seconds']:.1f} s")
        if progress is not None:
            progress(k + 1, len(pairs), text)
    rows = []
    for path, _, model in pairs:
        target = part_path(path, model)
        if os.path.exists(target):
            with open(target, encoding="utf-8") as fh:
                rows.append(json.load(fh))
        elif target in kept_here:
            rows.append(kept_here[target])
    return DatabaseRun(rows=rows, fitted_now=done_now, already_done=already, failed=failed,
                       failures=failures, total=len(pairs), unsaved=unsaved)


def count_finished(paths: Sequence[str], models: Sequence[str], folder: str,
                   identity: dict) -> int:
    """How many of the pairs of ``paths`` x ``models`` with these options (``identity``, as
    :func:`fit_database` takes it) are kept in ``folder``."""
    return sum(os.path.exists(os.path.join(folder, _pair_key(p, m, dict(identity)) + ".json"))
               for p in paths for m in models)


def table_rows(rows: Sequence[dict]) -> tuple[list[str], list[list]]:
    """The CSV table of ``rows``: the header (:data:`COLUMNS`, one column per error measure,
    then one per parameter entry, in the order first met; ``stderr:`` columns after them) and
    the rows (empty cells where a model has no such parameter)."""
    params, ses = [], []
    for r in rows:
        params += [k for k in r["params"] if k not in params]
        ses += [k for k in r["stderr"] if k not in ses]
    header = [*COLUMNS, *ERRORS, *params, *(f"stderr:{k}" for k in ses)]
    out = []
    for r in rows:
        line = [r[c] if c != "undetermined" else " ".join(r[c]) for c in COLUMNS]
        line += [r["errors"].get(e, "") for e in ERRORS]
        line += [r["params"].get(k, "") for k in params]
        line += ["" if r["stderr"].get(k) is None else r["stderr"][k] for k in ses]
        out.append(line)
    return header, out


def write_table(path: str, rows: Sequence[dict], meta: dict) -> list[str]:
    """The table as CSV at ``path`` and as JSON beside it (``.json``: ``meta`` and the rows
    with every field), each written atomically; returns the paths written."""
    header, lines = table_rows(rows)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(lines)
    write_text_atomic(path, buf.getvalue())
    js = os.path.splitext(path)[0] + ".json"
    write_text_atomic(js, json.dumps({**meta, "written": time.strftime("%Y-%m-%dT%H:%M:%S"),
                                  "errors": dict(ERRORS), "rows": list(rows)}, indent=1))
    return [path, js]
