"""``brdf-fit synth``: a dataset synthesised from a recipe."""

from __future__ import annotations

from brdf_fit.cli._common import (
    Outputs,
    check_data_format,
    check_output_file,
    strict_json,
    use_x64,
)


def run(args) -> int:
    use_x64()
    from data_synth.recipes import synthesize

    check_data_format(args.output)  # the format error before the work
    check_output_file(args.output, (".csv", ".npz"), "-o")
    data = synthesize(args.recipe)
    meta = data.metadata
    # the data are not kept after a failed write: the recipe (its seed) makes them again
    outs = Outputs(note="the same recipe makes the same data again")
    from brdf_fit import io
    from brdf_fit.data import DataError

    outs.write("-o", args.output, lambda: io.write(
        data, args.output,
        provenance={"command": "brdf-fit synth", "recipe_file": str(args.recipe)}),
        also=(DataError,))
    files = outs.written
    summary = {"files": files, "n_samples": data.n, "channels": list(data.channels),
               "model": meta["model"], "seed": meta["seed"], "plan": meta["plan"]["name"],
               "noise": [m["type"] for m in meta["noise"]] if meta["noise"] else []}
    if args.json:
        print(strict_json(outs.annotate(summary)))
    else:
        noise = ", ".join(summary["noise"]) or "none"
        print(f"{'wrote ' + ', '.join(files) if files else 'NOT written'}: {data.n} samples, "
              f"{data.n_channels} channel(s) ({','.join(data.channels)}), model "
              f"{meta['model']}, seed {meta['seed']}, plan {summary['plan']}, noise {noise}")
    return outs.status()


def add_parser(sub) -> None:
    y = sub.add_parser("synth", help="synthesise a dataset from a recipe (.json/.toml)")
    y.add_argument("recipe", help="recipe file (.json or .toml): model, params, seed, plan, "
                                  "noise; examples in examples/ (see data_synth.recipes)")
    y.add_argument("-o", "--output", required=True, metavar="FILE",
                   help="output data file: .csv or .npz (+ .json sidecar)")
    y.add_argument("--json", action="store_true", help="machine-readable summary")
    y.set_defaults(func=run)
