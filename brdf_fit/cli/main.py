"""The ``brdf-fit`` program: the parser assembled from the commands' modules, the
compilation cache, warnings and signals, and user errors as one line with exit status 2."""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
from typing import NoReturn

from brdf_fit import _xla
from brdf_fit._version import __version__
from brdf_fit.cli import (
    catalogue,
    check,
    convert,
    demo,
    evaluate,
    fit,
    fit_batch,
    lut,
    models,
    plot,
    render,
    select,
    synth,
)
from brdf_fit.cli._common import (
    Terminated,
    memory_size,
    stop_signals,
    user_errors,
)
from brdf_fit.cli._processes import LAUNCHED_ENV

#: the commands in the order ``brdf-fit --help`` lists them; each module has ``add_parser(sub)``
#: (its options, with ``func=run``) and ``run(args)``
COMMANDS = (models, catalogue, evaluate, check, synth, fit, fit_batch, demo, convert, select,
            plot, render, lut)

#: the program's one-line description (``brdf-fit --help``)
DESCRIPTION = ("Command-line interface: thin wrappers that parse, call the library, print "
               "tables or JSON.")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="brdf-fit", description=DESCRIPTION)
    p.add_argument("--version", action="version", version=f"brdf-fit {__version__}")
    p.add_argument("--no-cache", action="store_true",
                   help="do not keep compiled programs between runs (default: kept in "
                        "$BRDF_FIT_CACHE_DIR or ~/.cache/brdf_fit/jax; BRDF_FIT_NO_CACHE=1 "
                        "also turns it off)")
    p.add_argument("--max-memory", type=memory_size, default=None, metavar="SIZE",
                   help="the most memory an input may make a command allocate, checked before "
                        "it is (e.g. 8G, 500M; default: half the machine's memory, or "
                        "$BRDF_FIT_MAX_MEMORY)")
    sub = p.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return p


#: where compiled XLA programs are kept between runs (JAX's persistent compilation cache)
CACHE_ENV = "BRDF_FIT_CACHE_DIR"


NO_CACHE_ENV = "BRDF_FIT_NO_CACHE"


#: the folder of exported solver programs (brdf_fit.fitting._export.ENV)
EXPORT_ENV = "BRDF_FIT_EXPORT_DIR"


def cache_dir() -> str | None:
    """The persistent compilation cache folder: ``$BRDF_FIT_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/brdf_fit/jax`` (``~/.cache/brdf_fit/jax``); None when
    ``$BRDF_FIT_NO_CACHE`` is set (to anything but 0 or an empty string)."""
    import os

    if os.environ.get(NO_CACHE_ENV, "") not in ("", "0"):
        return None
    if os.environ.get(CACHE_ENV):
        return os.environ[CACHE_ENV]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "brdf_fit", "jax")


def _enable_compilation_cache(enabled: bool) -> None:
    """Turn on JAX's persistent compilation cache for this process, through the environment
    JAX reads when it is first imported (so ``--help`` and argument errors still import no JAX).
    Every program is cached (minimum compile time 0): the CLI's compiles are many and short,
    and a second run of the same command with the same shapes then compiles nothing. Without
    effect when JAX is already imported (the tests call ``main`` in-process). Also names the
    folder of exported (traced and lowered) solver programs, ``<cache>/exported``
    (``$BRDF_FIT_EXPORT_DIR``, :mod:`brdf_fit.fitting._export`), so that a warm ``fit`` does
    not trace the model either; ``--no-cache`` unsets it."""
    import os

    path = cache_dir() if enabled else None
    if path is None:
        os.environ.pop(EXPORT_ENV, None)  # --no-cache: no exported programs either
        return
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return  # an unwritable cache is no error: the command runs without it
    # traced and lowered solver programs (brdf_fit.fitting._export), next to XLA's compiled ones
    os.environ.setdefault(EXPORT_ENV, os.path.join(path, "exported"))
    if "jax" in sys.modules:
        return
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", path)
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Warnings the library raises for the user (a clamped parameter, ...) as one line."""
    print(f"brdf-fit: warning: {' '.join(str(message).split())}", file=file or sys.stderr)


def _interrupted(args, status: int) -> int:
    """One line for an interrupted command (130: SIGINT, 143: SIGTERM), saying how to go on
    where the command keeps its work in a folder; the JSON answer under --json."""
    if os.environ.get(LAUNCHED_ENV):  # stopped by its launcher, which says it for the run
        return status
    what = "interrupted" if status == 130 else "terminated"
    out_dir = getattr(args, "out_dir", None)
    msg = (f"{what}; the blocks written are kept in {out_dir}: the same command with --resume "
           "continues" if out_dir else what)
    print(f"brdf-fit: {msg}", file=sys.stderr)
    if getattr(args, "json", False):
        print(json.dumps({"error": msg, "exit_status": status}))
    return status


def _io_failure(args, exc: OSError) -> int:
    """One line (and the JSON answer) for a file the command could not read or write where no
    result was computed to print (each command prints its result when only its final outputs
    fail: :class:`~brdf_fit.cli._common.Outputs`); exit status 1. A run that keeps its work in
    a folder says so."""
    msg = (f"{exc.filename}: {exc.strerror or exc}" if exc.filename is not None
           else " ".join(str(exc).split()))
    out_dir = getattr(args, "out_dir", None)
    if out_dir and any(pathlib.Path(out_dir).glob("block_*.npz")):
        msg += (f"; the blocks written are kept in {out_dir}: the same command with --resume "
                "continues")
    print(f"brdf-fit: error: {msg}", file=sys.stderr)
    if getattr(args, "json", False):
        print(json.dumps({"error": msg, "exit_status": 1}))
    return 1


#: exit statuses of a command stopped by SIGINT (130) or SIGTERM (143)
STOPPED = (130, 143)


def run(argv: list[str] | None = None) -> NoReturn:
    """The program (the ``brdf-fit`` script and ``python -m brdf_fit.cli``): :func:`main`, then
    the process ends with its status.

    A command stopped by SIGINT or SIGTERM ends with ``os._exit`` once its output is flushed,
    skipping the interpreter's shutdown. The stop may come while XLA compiles: jaxlib (0.10.2)
    compiles on a thread of its own and the caller's wait for it ends on a signal, so the
    compile goes on after the command has returned. The interpreter's shutdown then destroys
    the JAX client under that thread, which dies on a null or freed function pointer: the
    process ends with SIGSEGV (status 139 and a core file where core dumps are on) instead of
    130 / 143 (``tests/cli/test_cli_interrupt.py`` shows both). What a stopped command keeps is
    written and closed before :func:`main` returns, and a launcher has ended its processes."""
    status = main(argv)
    if status in STOPPED:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):  # a closed pipe or stream: nothing more to say
                pass
        os._exit(status)
    sys.exit(status)


def main(argv: list[str] | None = None) -> int:
    """Run one command and return its exit status (the tests call it in-process; the program
    is :func:`run`)."""
    import warnings

    args = build_parser().parse_args(argv)
    args._argv = None if argv is None else list(argv)
    if args.max_memory is not None:  # read by brdf_fit.core.limits; children inherit it
        os.environ["BRDF_FIT_MAX_MEMORY"] = str(args.max_memory)
    _xla.configure()  # before JAX starts: the XLA options the toolkit runs with (brdf_fit._xla)
    _enable_compilation_cache(not args.no_cache)
    shown = warnings.showwarning
    warnings.showwarning = _show_warning
    try:
        with stop_signals():  # SIGTERM raises Terminated; a stop lost in a callback comes again
            return _dispatch(args)
    finally:
        warnings.showwarning = shown


def _dispatch(args) -> int:
    """The command, with a stop, a user error and a failed write each turned into its status."""
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return _interrupted(args, 130)
    except Terminated:
        return _interrupted(args, 143)
    except KeyError as exc:  # unknown model (registry.UnknownModelError)
        print(f"brdf-fit: error: {exc}", file=sys.stderr)
        if getattr(args, "json", False):
            print(json.dumps({"error": str(exc).strip("'\""), "exit_status": 2}))
        return 2
    except BrokenPipeError:  # output piped into `head` and closed early: not an error
        sys.stderr.close()
        return 0
    except OSError as exc:  # a write failed before any result (a full disk): one line, exit 1
        return _io_failure(args, exc)
    except Exception as exc:
        if isinstance(exc, user_errors()):
            msg = " ".join(str(exc).split("\n"))
            print(f"brdf-fit: error: {msg}", file=sys.stderr)
            if getattr(args, "json", False):  # a script that parses stdout gets an answer too
                print(json.dumps({"error": msg, "exit_status": 2}))
            return 2
        raise
