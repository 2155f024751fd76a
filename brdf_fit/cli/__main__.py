"""``python -m brdf_fit.cli``: the ``brdf-fit`` program (the launchers start their processes
so, with the interpreter that runs them)."""

from brdf_fit.cli.main import run

run()
