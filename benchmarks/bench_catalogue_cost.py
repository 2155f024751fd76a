"""Evaluation cost of every registry model relative to Lambert, under ``jax.jit``, in one run;
side by side with the relative costs Montes & Urena (2012) published
(:mod:`brdf_fit.verify.catalogue`).

    python benchmarks/bench_catalogue_cost.py [--n 65536] [--rounds 15] [--float32] [--out DIR]

For each non-delta entry at its registry defaults:

``eval``        ``jit(model.eval)`` on ``--n`` direction pairs (both directions uniform over the
                upper hemisphere, seeded), the model (as a renderer holds it:
                ``AbstractBRDF.prepared()``, i.e. with a table its plugin builds once per
                material already built) as a traced argument (so nothing is constant-folded
                into the kernel);
``eval_grad``   ``jit(grad(sum(eval)))`` with respect to every registry parameter: the cost a
                fit pays per residual evaluation in reverse mode.

Timing: ``--rounds`` rounds; in each round every entry is timed once (a call and
``block_until_ready``), in a shuffled order, so slow drifts of the machine's load hit all entries
alike; the figure is the minimum over rounds. Ratios are against ``lambert`` in the same run.
Montes & Urena's ratios come from their own scalar CPU code (spherical-angle conversions and
per-call overheads included); treat them as an ordering only.

Writes ``catalogue_cost.md`` and ``catalogue_cost.json`` to ``--out`` and the JSON also to
``brdf_fit/resources/catalogue_cost.json``, which the catalogue table reads
(``brdf-fit catalogue --write-readme docs/models.md``).

``--entries NAME ...`` times only those entries and ``lambert`` (same method, ratios against
``lambert`` in that run) and merges their rows into ``brdf_fit/resources/catalogue_cost.json``
(``--out``'s JSON with ``--no-package-data``); the other rows and the full run's reports are
kept, and the partial run is recorded under ``partial_runs``: how an entry added after the last
full run gets its cost without re-timing the whole registry.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_eval import _loadavg, hemisphere_directions, machine_info  # noqa: E402

from brdf_fit import registry  # noqa: E402
from brdf_fit.verify import catalogue  # noqa: E402


def _timed(fn, *args):
    t = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=65536)
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--float32", action="store_true", help="float32 arrays (default float64)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    ap.add_argument("--no-package-data", dest="write_package_data", action="store_false",
                    help="do not copy the JSON to brdf_fit/resources/catalogue_cost.json "
                         "(which the README's catalogue table reads)")
    ap.add_argument("--entries", nargs="+", default=None, metavar="NAME",
                    help="time only these entries (and lambert) and merge their rows into the "
                         "existing JSON files")
    args = ap.parse_args(argv)
    only = None if args.entries is None else {"lambert", *args.entries}
    dtype = jnp.float32 if args.float32 else jnp.float64
    info = machine_info()
    rng = np.random.default_rng(20261201)
    wi = jnp.asarray(hemisphere_directions(args.n, rng), dtype)
    wo = jnp.asarray(hemisphere_directions(args.n, rng), dtype)

    fns = {}
    for e in registry.entries():
        if "delta" in e.tags or (only is not None and e.name not in only):
            continue
        params = {k: jnp.asarray(v, dtype) for k, v in e.defaults().items()}

        def ev(m, a, b):
            return m.eval(a, b)

        def loss(p, a, b, e=e):
            return jnp.sum(e.build(**p).eval(a, b))

        f_eval = jax.jit(ev)
        f_grad = jax.jit(jax.grad(loss))
        model = e.build(**params).prepared()
        jax.block_until_ready(f_eval(model, wi, wo))  # compile
        jax.block_until_ready(f_grad(params, wi, wo))
        fns[e.name] = (params, model, f_eval, f_grad)
        print(f"compiled {e.name}", file=sys.stderr)

    names = list(fns)
    best = {n: [np.inf, np.inf] for n in names}
    for r in range(args.rounds):
        order = rng.permutation(len(names))
        for i in order:
            n = names[i]
            params, model, f_eval, f_grad = fns[n]
            best[n][0] = min(best[n][0], _timed(f_eval, model, wi, wo))
            best[n][1] = min(best[n][1], _timed(f_grad, params, wi, wo))
        print(f"round {r + 1}/{args.rounds}", file=sys.stderr)
    base_e, base_g = best["lambert"]
    rel = {n: {"eval": best[n][0] / base_e, "eval_grad": best[n][1] / base_e} for n in names}
    info["loadavg_end"] = _loadavg()

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cmd = "python benchmarks/bench_catalogue_cost.py " + shlex.join(argv or sys.argv[1:])
    if only is not None:
        return _merge(args, cmd.strip(), info, best, rel, names, out)
    doc = {
        "command": cmd.strip(),
        "machine": info,
        "n": args.n,
        "rounds": args.rounds,
        "dtype": str(jnp.dtype(dtype)),
        "seconds": {n: {"eval": best[n][0], "eval_grad": best[n][1]} for n in names},
        "relative": rel,
        "baseline": "lambert eval",
    }
    (out / "catalogue_cost.json").write_text(json.dumps(doc, indent=1) + "\n")
    if args.write_package_data:
        catalogue.COST_FILE.write_text(json.dumps(doc, indent=1) + "\n")

    pub = {}
    for row in catalogue.table(costs=rel):
        if row["entry"] is not None:
            pub[row["entry"]] = (row["row"], row["published_cost"])
    lines = [
        "# Evaluation cost of the catalogue, relative to Lambert",
        "",
        "Command:",
        "",
        "```",
        cmd.strip(),
        "```",
        "",
        f"- date: {info['date_utc']}",
        f"- CPU: {info['cpu_model']} ({info['cpu_count']} logical cores, "
        f"{info['cpus_usable']} usable); jax {info['jax']}, devices {info['jax_devices']}",
        f"- load average at start {info['loadavg_start']}, at end {info['loadavg_end']} "
        "(other jobs shared the machine when these are high; rounds interleave all models so "
        "that drift hits them alike)",
        f"- {args.n} direction pairs per call, {doc['dtype']}, minimum over {args.rounds} rounds; "
        f"Lambert eval: {base_e * 1e3:.3f} ms ({base_e / args.n * 1e9:.2f} ns per pair)",
        "- `eval+grad`: `jit(grad(sum(eval)))` w.r.t. every registry parameter, relative to "
        "Lambert's *eval*",
        "",
        "| entry | catalogue row | eval (x Lambert) | eval+grad (x Lambert) | ns per pair | "
        "published (Montes & Urena 2012) |",
        "| --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for n in sorted(names, key=lambda k: rel[k]["eval"]):
        row, p = pub.get(n, (None, None))
        lines.append(
            f"| `{n}` | {row or '-'} | {rel[n]['eval']:.2f} | {rel[n]['eval_grad']:.2f} | "
            f"{best[n][0] / args.n * 1e9:.1f} | {'-' if p is None else f'{p:g}x'} |"
        )
    lines += ["", "Raw numbers: `catalogue_cost.json`.", ""]
    (out / "catalogue_cost.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


def _merge(args, cmd, info, best, rel, names, out) -> int:
    """Merge the rows of a partial run (``--entries``) into the existing JSON files."""
    new = [n for n in names if n != "lambert"]
    run = {"command": cmd, "date_utc": info["date_utc"], "loadavg_start": info["loadavg_start"],
           "loadavg_end": info["loadavg_end"], "n": args.n, "rounds": args.rounds,
           "lambert_eval_seconds": best["lambert"][0], "entries": new}
    # the package data by default (what the catalogue reads); the full run's report in --out is
    # left as it was measured
    targets = [catalogue.COST_FILE] if args.write_package_data else [out / "catalogue_cost.json"]
    for path in targets:
        doc = json.loads(path.read_text())
        for n in new:
            doc["seconds"][n] = {"eval": best[n][0], "eval_grad": best[n][1]}
            doc["relative"][n] = rel[n]
        doc.setdefault("partial_runs", []).append(run)
        path.write_text(json.dumps(doc, indent=1) + "\n")
    for n in new:
        print(f"{n}: eval {rel[n]['eval']:.2f}x, eval+grad {rel[n]['eval_grad']:.2f}x lambert "
              f"({best[n][0] / args.n * 1e9:.1f} ns per pair)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
