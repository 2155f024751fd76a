"""Command-line interface: thin wrappers that parse, call the library, print tables or JSON.

    brdf-fit models [--json]
    brdf-fit eval MODEL [--param NAME=VALUE ...] [--theta-i-deg ...] [--theta-o-deg ...] [--json]
    brdf-fit check MODEL [--param NAME=VALUE ...] [--check NAME ...] [--json]
    brdf-fit check --all [--json]
    brdf-fit synth RECIPE -o FILE [--json]
    brdf-fit fit DATA --model NAME [--fix NAME=VALUE ...] [--init NAME=VALUE ...]
                 [--metric log|cuberoot|relative|absolute|huber|cauchy] [--solver NAME]
                 [--max-zenith-deg X]
                 [--guess grid|none] [--multistart K] [--check NAME ...] [--json]
    brdf-fit fit-batch DATA... --model NAME [--fix ...] [--init ...] [--metric ...]
                 [--guess grid|none] [--skip-bad] [--out FILE.csv|.json] [--json] [--quiet]
                 [--out-dir DIR [--block-size N] [--resume]]
    brdf-fit demo [--out DIR] [--json]
    brdf-fit select DATA [--candidates A,B,..|--family NAME] [--budget X] [--plot PNG] [--json]
    brdf-fit plot MODEL [MODEL ...] [--param NAME=VALUE] [--data FILE [--fit]] -o PNG
    brdf-fit render [MODEL [--param NAME=VALUE ...] | --fit FIT.json] -o PNG|EXR [--size N]
                 [--light-zenith-deg X] [--light-azimuth-deg X] [--irradiance E] [--json]
    brdf-fit lut dfg -o FILE [--size N] [--masking M] [--layout NAME] [--channels A,B] [--json]
    brdf-fit lut albedo|eavg MODEL --axis NAME=N[:LO:HI] ... [--param NAME=VALUE] -o FILE
    brdf-fit convert phong-to-ggx [--source modified-phong|blinn-phong|...] [--exponents N ...]
                 [--metric log] [--max-zenith-deg 80] [--json]

``synth`` turns a dataset recipe (``.json``/``.toml``, see :mod:`data_synth.recipes`) into a
``.csv`` or ``.npz`` file; ``fit`` reads ``.csv``, ``.npz`` (or its ``.json`` sidecar) or MERL
``.binary`` data and fits a registry model (:func:`brdf_fit.fit.fit`); ``demo`` is the main job on
an embedded default: synthesise noisy gold, fit several models, rank them, convert the Phong
exponent to a GGX width, check the best model, write ``demo.json`` and plots. VALUEs are a number
or comma-separated numbers (one per channel). User errors (bad file, unknown model, parameter,
metric, check) print one line ``brdf-fit: error: ...`` and exit with status 2.

One module per command (``models``, ``catalogue``, ``evaluate`` (eval), ``check``, ``synth``,
``fit`` and ``fit_database``, ``fit_batch`` with ``fit_batch_stream`` and ``fit_batch_arrays``,
``demo``, ``convert``, ``select``, ``plot``, ``render``, ``lut``): each holds its parser
(``add_parser``), its run (``run``) and its output. What they share is in the underscored
modules (``_common``: errors, argument types, files; ``_progress``; ``_export``; ``_processes``;
``_batch_rows`` and ``_batch_stream`` for fit-batch); :mod:`brdf_fit.cli.main` assembles the
parser and runs a command. The library is imported inside each command, on purpose: ``brdf-fit
--help`` and argument errors then answer in about 0.2 s instead of paying for JAX first."""

from brdf_fit.cli._common import CLIError, read_data
from brdf_fit.cli.check import CHECK_NAMES
from brdf_fit.cli.convert import REPRESENTS_TOL
from brdf_fit.cli.main import build_parser, cache_dir, main, run

__all__ = ["CHECK_NAMES", "CLIError", "REPRESENTS_TOL", "build_parser", "cache_dir", "main",
           "read_data", "run"]
