"""The per-file results of ``fit-batch``: files read, geometry shared, one row per file
with its flags, and the table written (``--out``)."""

from __future__ import annotations

import numpy as np

from brdf_fit.cli._common import (
    CLIError,
    extension,
    read_data,
    strict_json,
    user_errors,
)


def read_many(paths, skip_bad: bool):
    """Read every file; a bad one is reported with its path. Without ``skip_bad`` any bad file
    stops the command before anything is fitted (nothing computed is lost)."""
    good, bad = [], []
    for path in paths:
        try:
            data = read_data(path)
            data.validate()
            good.append((path, data))
        except user_errors() as e:
            bad.append(f"{path}: {e}" if not str(e).startswith(path) else str(e))
    if bad and not skip_bad:
        raise CLIError(f"{len(bad)} of {len(paths)} file(s) could not be read (--skip-bad fits "
                       "the others):\n  " + "\n  ".join(bad))
    if not good:
        raise CLIError("no readable data file:\n  " + "\n  ".join(bad))
    return good, bad


def batch_rows(paths, res, channels) -> list[dict]:
    from brdf_fit.fitting.problem import entry_labels  # loaded with fit_batch already
    from brdf_fit.fitting.result import json_floats

    rows = []
    und = res.undetermined
    for b, path in enumerate(paths):
        rows.append({
            "file": path, "model": res.model_name,
            "params": {k: np.asarray(v[b]).tolist() for k, v in res.params.items()},
            "stderr": {k: json_floats(v[b]) for k, v in res.stderr.items()},
            "stderr_note": {k: np.asarray(v[b]).tolist() for k, v in res.stderr_note.items()
                            if (np.asarray(v[b]) != "").any()},
            "converged": bool(res.converged[b]), "steps": int(res.steps[b]),
            "metric": res.metric, "residual_rms": float(res.residual_rms[b]),
            "n_samples": int(res.n_samples[b]), "channels": list(channels),
            "at_bound": [k for k, v in res.at_bound.items() if np.asarray(v[b]).any()],
            "undetermined": [
                lab for k, v in und.items()
                for lab, bad in zip(entry_labels(k, np.shape(v[b]), channels),
                                    np.asarray(v[b]).reshape(-1), strict=True) if bad],
        })
    return rows


#: a batch member is flagged when its residual rms exceeds this many times the batch median
RMS_FLAG_FACTOR = 10.0


#: ... or when it has fewer than this many samples per free scalar parameter (a 3-sample file
#: is fitted exactly, with small standard errors, and no other flag catches it)
MIN_SAMPLES_PER_PARAM = 3


def flag_rows(rows) -> None:
    """Add ``flags`` to each fit-batch row: "not converged", "at bound", "undetermined: ..."
    (:data:`brdf_fit.fitting.problem.UNDETERMINED_RULE`), "rms > 10x median" (the median over
    every file of the run) and "few samples"."""
    if not rows:
        return
    med = float(np.median([r["residual_rms"] for r in rows]))
    for r in rows:
        k = sum(np.asarray(v).size for v in r["params"].values())
        flags = []
        if not r["converged"]:
            flags.append("not converged")
        if r["at_bound"]:
            flags.append("at bound")
        if r.get("undetermined"):
            flags.append(f"undetermined: {', '.join(r['undetermined'])}")
        if med > 0 and r["residual_rms"] > RMS_FLAG_FACTOR * med:
            flags.append(f"rms > {RMS_FLAG_FACTOR:g}x median")
        if r["n_samples"] < MIN_SAMPLES_PER_PARAM * k:
            flags.append(f"few samples ({r['n_samples']} for {k} parameters)")
        r["flags"] = flags


def note_text(v) -> str:
    """A stderr_note entry (one reason, or one per channel; "" where defined) as text."""
    a = [str(x) for x in np.atleast_1d(np.asarray(v, object))]
    return a[0] if len(set(a)) == 1 else ",".join(x or "-" for x in a)


def write_batch_table(rows, path: str) -> None:
    """The rows to ``path`` (``--out``: .json as they are, .csv one column per parameter and
    channel), whole or not at all."""
    import csv
    import io

    from brdf_fit.core.atomic import write_text_atomic

    if extension(path) == ".json":
        write_text_atomic(path, strict_json(rows, indent=1))
        return
    if extension(path) != ".csv":
        raise CLIError(f"{path}: --out expects .csv or .json")
    cols = ["file", "converged", "steps", "residual_rms", "n_samples"]
    flat = []
    for r in rows:
        d = {k: r[k] for k in cols}
        for kind in ("params", "stderr"):
            for name, v in r[kind].items():
                a = np.atleast_1d(np.asarray(v, float))
                for j, x in enumerate(a):
                    key = name if a.size == 1 else f"{name}_{r['channels'][j].lower()}" if (
                        len(r["channels"]) == a.size) else f"{name}_{j}"
                    d[key if kind == "params" else f"stderr_{key}"] = f"{x:.10g}"
        d["at_bound"] = ";".join(r["at_bound"])
        d["undetermined"] = ";".join(r.get("undetermined", []))
        d["stderr_note"] = ";".join(f"{k}: {note_text(v)}" for k, v in r["stderr_note"].items())
        d["flags"] = ";".join(r.get("flags", []))
        flat.append(d)
    fields = list(dict.fromkeys(k for d in flat for k in d))
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, fieldnames=fields)
    w.writeheader()
    w.writerows(flat)
    write_text_atomic(path, buf.getvalue())


def batch_geometry(ds):
    """``(wi, wo)`` of data sets ``ds`` for fit_batch: one (M, 3) pair when every file has
    exactly the first one's directions (a gonioreflectometer's texels), which fit_batch keeps
    once and for which it uses its finer shared-geometry guess; else stacked (B, M, 3)."""
    wi0, wo0 = ds[0].wi, ds[0].wo
    if all(np.array_equal(d.wi, wi0) and np.array_equal(d.wo, wo0) for d in ds[1:]):
        return wi0, wo0
    return np.stack([d.wi for d in ds]), np.stack([d.wo for d in ds])
