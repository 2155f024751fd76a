"""``brdf-fit models``: the registered models and their parameters.

The list is read from ``brdf_fit/resources/registry.json``, the registry's own description of
its entries (:meth:`brdf_fit.core.params.Entry.to_dict`, in registration order) written by
:func:`write_listing`, so that the command answers without importing JAX and every model
module (0.2 s instead of about 2 s; issue 41). ``tests/cli/test_cli_models.py`` holds the file
equal to the live registry: a change to an entry fails there until the file is written again
(``python -c "from brdf_fit.cli.models import write_listing; write_listing()"``)."""

from __future__ import annotations

import json
import pathlib

from brdf_fit.cli._common import fmt, strict_json

#: the registry's listing, packaged beside the other resources
LISTING = pathlib.Path(__file__).resolve().parents[1] / "resources" / "registry.json"


def live_listing() -> list[dict]:
    """Every registry entry's ``to_dict()``, in registration order (imports the registry)."""
    from brdf_fit import registry

    return [e.to_dict() for e in registry.entries()]


def read_listing() -> list[dict]:
    """The packaged listing (:data:`LISTING`), or the live one if the file is missing."""
    try:
        return json.loads(LISTING.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return live_listing()


def write_listing(path=LISTING) -> None:
    """Write the live registry's listing to ``path`` (the packaged file by default)."""
    from brdf_fit.core.atomic import write_text_atomic

    write_text_atomic(path, strict_json(live_listing(), indent=1) + "\n")


def run(args) -> int:
    entries = read_listing()
    if args.json:
        print(strict_json(entries))
        return 0
    print(f"{len(entries)} models (brdf-fit eval MODEL --param NAME=VALUE):\n")
    width = max(len(e["name"]) for e in entries)
    for e in entries:
        alias = f"  (aliases: {', '.join(e['aliases'])})" if e["aliases"] else ""
        print(f"{e['name']:<{width}}  {e['description']}{alias}")
        for p in e["params"]:
            ch = " [channels]" if p["channels"] else ""
            print(f"{'':<{width}}    {p['name']} = {fmt(p['default'])}  in {p['interval']}{ch}"
                  f"  {p['doc']}")
        print(f"{'':<{width}}    ref: {e['reference']}")
    return 0


def add_parser(sub) -> None:
    m = sub.add_parser("models", help="list the registered models and their parameters")
    m.add_argument("--json", action="store_true", help="machine-readable output")
    m.set_defaults(func=run)
