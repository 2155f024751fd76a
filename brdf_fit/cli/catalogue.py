"""``brdf-fit catalogue``: the Montes & Urena (2012) catalogue, as a table or the README's
generated section."""

from __future__ import annotations

from brdf_fit.cli._common import (
    CLIError,
    Outputs,
    check_output_file,
    strict_json,
)


def run(args) -> int:
    from brdf_fit.verify import catalogue

    if args.write_readme:
        import pathlib

        readme = pathlib.Path(args.write_readme)
        if not readme.is_file():
            raise CLIError(f"{readme}: no such file (--write-readme rewrites the catalogue "
                           "section of an existing README)")
        check_output_file(str(readme), (readme.suffix.lower(),), "--write-readme")
        text = readme.read_text(encoding="utf-8", errors="replace")
        if catalogue.README_BEGIN not in text or catalogue.README_END not in text:
            raise CLIError(f"{readme}: no generated catalogue section (markers "
                           f"{catalogue.README_BEGIN!r} ... {catalogue.README_END!r})")
    records = catalogue.table()
    if args.write_readme:
        outs = Outputs(note="the catalogue is printed instead")
        changed = []
        outs.write("--write-readme", args.write_readme, lambda: changed.append(
            catalogue.update_readme(args.write_readme, catalogue.markdown(records))))
        if not changed:
            print(catalogue.markdown(records), end="")
            return outs.status()
        print(f"{args.write_readme}: catalogue section {'updated' if changed[0] else 'unchanged'}")
        return 0
    if args.json:
        print(strict_json({"summary": catalogue.summary(records), "rows": records}))
        return 0
    print(catalogue.markdown(records), end="")
    return 0


def add_parser(sub) -> None:
    k = sub.add_parser("catalogue", help="the Montes & Urena (2012) catalogue: which models are "
                                         "implemented, their checks, samplers and costs")
    k.add_argument("--json", action="store_true", help="machine-readable rows")
    k.add_argument("--write-readme", metavar="README", default=None,
                   help="rewrite the generated catalogue section of this file")
    k.set_defaults(func=run)
