"""``brdf-fit models``: the registered models and their parameters."""

from __future__ import annotations

import json

from brdf_fit.cli._common import (
    fmt,
    load_registry,
)


def run(args) -> int:
    reg = load_registry()
    entries = reg.entries()
    if args.json:
        print(json.dumps([e.to_dict() for e in entries], indent=2))
        return 0
    print(f"{len(entries)} models (brdf-fit eval MODEL --param NAME=VALUE):\n")
    width = max(len(e.name) for e in entries)
    for e in entries:
        alias = f"  (aliases: {', '.join(e.aliases)})" if e.aliases else ""
        print(f"{e.name:<{width}}  {e.description}{alias}")
        for p in e.params:
            ch = " [channels]" if p.channels else ""
            print(f"{'':<{width}}    {p.name} = {fmt(p.default_value())}  in {p.interval()}{ch}"
                  f"  {p.doc}")
        print(f"{'':<{width}}    ref: {e.reference}")
    return 0


def add_parser(sub) -> None:
    m = sub.add_parser("models", help="list the registered models and their parameters")
    m.add_argument("--json", action="store_true", help="machine-readable output")
    m.set_defaults(func=run)
