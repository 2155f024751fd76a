"""What every command shares: the user error (:class:`CLIError`), argument types, the
registry, ``NAME=VALUE`` parameters, number formatting, float64, output files checked
before any work, data read and written with one-line errors, and the fit options."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys

import numpy as np


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return v


def memory_size(text: str) -> str:
    """A memory size as ``--max-memory`` takes it: checked by the rule that reads it back
    (:func:`brdf_fit.core.limits.parse_size`), kept as text for the environment."""
    from brdf_fit.core.limits import LimitError, parse_size

    try:
        parse_size(text)
    except LimitError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text.strip()


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""


class Terminated(BaseException):
    """SIGTERM, raised in the main thread (as KeyboardInterrupt is for SIGINT) so that a
    command stops the same way: what is finished kept, one line, exit status 143."""


def raise_terminated(signum, frame):
    """The SIGTERM handler of every command: :class:`Terminated` in the main thread."""
    raise Terminated()


#: seconds after a stop is lost in a callback that it is raised again (SIGALRM): long enough
#: for the interpreter to leave the hook that saw it, short beside any person's wait
REDELIVER_S = 0.01


@contextlib.contextmanager
def stop_signals():
    """A command's signal handling: SIGTERM raises :class:`Terminated` in the main thread (as
    SIGINT raises KeyboardInterrupt), and a stop that lands in a callback is raised again.

    Python runs a signal's handler in whatever the main thread is doing, which may be a
    callback whose exceptions the interpreter does not propagate: a garbage-collection callback
    (JAX registers one, ``_xla_gc_callback``) or a ``__del__``. The stop exception was then
    printed as "Exception ignored in ..." with a traceback and lost, and the process ran on
    (a ``--processes`` worker until its launcher's SIGKILL). While this is active,
    :data:`sys.unraisablehook` takes such a stop silently and raises it again
    :data:`REDELIVER_S` later from a SIGALRM handler (a timer, not a signal sent from the hook:
    ``signal.raise_signal`` runs the handler at once, inside the hook). A redelivery that lands
    in a callback again is taken the same way. Anything else goes to the previous hook.
    Outside the main thread signals are left to whoever owns them, and nothing is installed."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous_term = signal.signal(signal.SIGTERM, raise_terminated)
    previous_hook = sys.unraisablehook
    lost: list[type[BaseException]] = []  # a stop taken by the hook, not yet raised again
    in_hook = [False]
    previous_alarm = []  # SIGALRM's handler before the first redelivery was armed

    def raise_lost(signum, frame):
        if in_hook[0]:  # the timer ran out inside the hook itself: later
            signal.setitimer(signal.ITIMER_REAL, REDELIVER_S)
        elif lost:
            raise lost.pop()()

    def take_lost_stop(unraisable):
        exc_type = unraisable.exc_type
        if (exc_type is None or not issubclass(exc_type, (Terminated, KeyboardInterrupt))
                or not hasattr(signal, "setitimer")):
            previous_hook(unraisable)
            return
        in_hook[0] = True
        try:
            lost[:] = [exc_type]
            if not previous_alarm:
                previous_alarm.append(signal.signal(signal.SIGALRM, raise_lost))
            signal.setitimer(signal.ITIMER_REAL, REDELIVER_S)
        finally:
            in_hook[0] = False

    sys.unraisablehook = take_lost_stop
    try:
        yield
    finally:
        sys.unraisablehook = previous_hook
        if previous_alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous_alarm[0])
        signal.signal(signal.SIGTERM, previous_term)


def load_registry():
    from brdf_fit import registry

    return registry


def parse_params(items: list[str] | None, entry, flag: str = "--param") -> dict:
    """``NAME=VALUE`` pairs; VALUE is a number or comma-separated numbers (one per channel).
    ``flag`` names the option in error messages."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise CLIError(f"{flag} expects NAME=VALUE, got {item!r}")
        name, _, text = item.partition("=")
        name = name.strip()
        entry.param(name)  # unknown names raise with the valid list
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            raise CLIError(
                f"{flag} {name}: {text!r} is not a number or comma-separated numbers"
            ) from None
        out[name] = vals[0] if len(vals) == 1 else np.asarray(vals)
    return out


def fmt(v) -> str:
    a = np.atleast_1d(np.asarray(v, dtype=float))
    return ",".join(f"{x:.4g}" for x in a) if a.size > 1 else f"{a[0]:.4g}"


def short_params(params: dict) -> str:
    return ", ".join(f"{k}={fmt(v)}" for k, v in params.items())


def check_angles(name, values):
    for v in values:
        if not (0.0 <= v <= 90.0):
            raise CLIError(f"{name}: {v} deg is outside [0, 90] (below the horizon or negative)")


def use_x64() -> None:
    """Synthesis and fitting run in float64 (solver tolerances and standard errors assume it)."""
    import jax

    jax.config.update("jax_enable_x64", True)


def extension(path: str) -> str:
    import pathlib

    return pathlib.Path(path).suffix.lower()


def check_output_file(path: str, exts: tuple[str, ...], flag: str) -> None:
    """Refuse an output file before any work: a known extension, not a folder, and a folder to
    write it in that exists and is writable (nothing computed is then lost on the write)."""
    import pathlib

    p = pathlib.Path(path)
    if extension(path) not in exts:
        raise CLIError(f"{path}: {flag} expects {' or '.join(exts)}")
    if p.is_dir():
        raise CLIError(f"{path}: {flag} names a folder, not a file")
    parent = p.parent if str(p.parent) else pathlib.Path(".")
    if parent.exists() and not parent.is_dir():
        raise CLIError(f"{path}: cannot write: {str(parent)!r} is a file, not a folder")
    if not parent.is_dir():
        raise CLIError(f"{path}: cannot write: folder {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise CLIError(f"{path}: cannot write: permission denied")


def check_output_dir(path: str, flag: str) -> None:
    """Refuse an output folder before any work: not an existing file, creatable, writable."""
    import pathlib

    p = pathlib.Path(path)
    if p.exists() and not p.is_dir():
        raise CLIError(f"{path}: {flag} names an existing file, not a folder")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CLIError(f"{path}: cannot create the folder ({e.strerror or e})") from None
    if not os.access(p, os.W_OK):
        raise CLIError(f"{path}: cannot write into the folder: permission denied")


def read_data(path: str):
    """:func:`brdf_fit.io.read`, with its errors as one-line CLI errors."""
    from brdf_fit import io
    from brdf_fit.data import DataError

    try:
        return io.read(path)
    except DataError as e:
        raise CLIError(str(e)) from None


def check_data_format(path: str) -> None:
    """Refuse a data file :func:`brdf_fit.io.write` cannot write (its extension), as a CLI
    error, before any work."""
    from brdf_fit import io
    from brdf_fit.data import DataError

    try:
        io.check_writable_format(path)
    except DataError as e:
        raise CLIError(str(e)) from None


def check_names(names) -> list[str]:
    from brdf_fit.verify import checks

    for c in names or []:
        if c not in checks.CHECKS:
            raise CLIError(f"unknown check {c!r}; valid checks: {', '.join(checks.CHECKS)}")
    return list(names or [])


def entry_fix_init(args):
    reg = load_registry()
    entry = reg.get(args.model)
    fix = parse_params(args.fix, entry, "--fix")
    init = parse_params(args.init, entry, "--init")
    both = sorted(set(fix) & set(init))
    if both:
        raise CLIError(f"parameter(s) {', '.join(both)} given both --fix and --init")
    return entry, fix, init


def add_fit_options(p, what: str, models: str = "registry name (see 'brdf-fit models')") -> None:
    """The options ``fit`` and ``fit-batch`` share (``what``: what the zenith cut does to a
    sample, "drop" or "mask"; ``models``: the help of ``--model``)."""
    p.add_argument("--model", required=True, help=models)
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="hold a parameter at a value (comma-separated for channels); repeatable")
    p.add_argument("--init", action="append", metavar="NAME=VALUE",
                   help="start value of a parameter (default: see --guess); repeatable")
    p.add_argument("--guess", default="grid", help="start of the parameters without --init: grid "
                                                    "(default: a coarse design on a subsample) "
                                                    "or none (the registry defaults)")
    p.add_argument("--metric", default="log",
                   help="log (default), cuberoot, relative, absolute, or the robust huber / "
                        "cauchy losses of the log residual (for outliers; not with sigma)")
    p.add_argument("--max-zenith-deg", type=float, default=None,
                   help=f"{what} samples with either direction beyond this zenith angle")
    p.add_argument("--cos-weight", action="store_true", help="weight residuals by cos(theta_i)")
    p.add_argument("--max-steps", type=positive_int, default=256, metavar="N",
                   help="stop a fit after N solver steps (default 256; it is then reported as "
                        "not converged)")


def user_errors() -> tuple[type[BaseException], ...]:
    """Exception classes that mean a user error (one line, exit 2). Looked up among the modules
    already imported, so the CLI imports nothing for them: an exception of a module that was
    never imported cannot have been raised."""
    errors: list[type[BaseException]] = [CLIError]
    for module, names in (("brdf_fit.core.validate", ("ParameterError",)),
                          ("brdf_fit.core.limits", ("LimitError",)),
                          ("brdf_fit.core.runlock", ("FolderBusy",)),
                          ("brdf_fit.fitting.problem", ("FitError",)),
                          ("brdf_fit.data", ("DataError",)),
                          ("data_synth.recipes", ("RecipeError",)),
                          ("data_synth.plans", ("PlanError",)),
                          ("data_synth.noise", ("NoiseError",)),
                          ("brdf_fit.convert.phong_to_ggx", ("ConversionError",))):
        mod = sys.modules.get(module)
        errors.extend(getattr(mod, n) for n in names if mod is not None and hasattr(mod, n))
    return tuple(errors)


def command_line(args) -> str:
    """The command as the user gave it (``brdf-fit ...``, shell-quoted), for a report page:
    ``main(argv)``'s arguments, or the process's."""
    import shlex

    argv = args._argv if getattr(args, "_argv", None) is not None else sys.argv[1:]
    return shlex.join(["brdf-fit", *argv])


def dense_data_of(data, path):
    """``data`` read from ``path`` as dense data a report renders from themselves and draws
    the slice of (:func:`brdf_fit.render.dense_data`: a MERL table or an RGL material) when
    they are a MERL or RGL file, else None."""
    if data.metadata.get("format") not in ("merl", "rgl"):
        return None
    from brdf_fit.render import dense_data

    return dense_data(path)


def strict_json(doc, indent: int = 2) -> str:
    """``doc`` as strict JSON (no NaN or Infinity, which JSON has not): every non-finite float
    written as null, the rule each result's ``to_dict`` follows for an undefined number. A
    value a ``to_dict`` missed then costs its own field, not the whole answer of a long run
    (a 4-minute ``select --scene`` once ended in ``ValueError: Out of range float values``)."""
    def clean(o):
        if isinstance(o, float):
            return o if math.isfinite(o) else None
        if isinstance(o, dict):
            return {k: clean(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [clean(v) for v in o]
        return o

    return json.dumps(clean(doc), indent=indent, allow_nan=False)


class Outputs:
    """The files a command writes once its work is done. Each write goes through
    :mod:`brdf_fit.core.atomic` (whole or not at all); a failure (a full disk, a vanished
    folder, a permission) is kept with its option and reason instead of raised, so that the
    command still prints what it computed, names every output that failed and why, and exits
    with status 1 (:meth:`status`): nothing computed is lost to a failed write."""

    def __init__(self, note: str | None = "the result is printed instead"):
        self.written: list[str] = []
        self.failed: list[str] = []
        self.note = note  # what the user still has after a failure

    def write(self, flag: str, path, write, elsewhere=None, also: tuple = ()) -> bool:
        """Call ``write()``, which writes ``path`` (and returns the paths it wrote, or None for
        ``path`` alone); False after a failure. ``elsewhere(other_path)``, for a result that
        took long to compute (a lookup table): after a failure it writes the same output into a
        new folder of the system's temporary directory, and the error line says where.
        ``also``: the exception classes a library writer turns an ``OSError`` into (its message
        names the path and the reason)."""
        try:
            wrote = write()
        except (OSError, *also) as e:
            msg = (f"{flag} {path}: cannot write ({e.strerror or e})" if isinstance(e, OSError)
                   else f"{flag} {e}")
            if elsewhere is not None:
                import tempfile

                try:
                    other = os.path.join(tempfile.mkdtemp(prefix="brdf_fit-"),
                                         os.path.basename(os.fspath(path)))
                    kept = elsewhere(other)
                    msg += f"; written to {', '.join(map(str, kept or [other]))} instead"
                except OSError as e2:
                    msg += f"; nor in the temporary folder ({e2.strerror or e2})"
            self.failed.append(msg)
            return False
        self.written += [str(p) for p in wrote] if wrote else [str(path)]
        return True

    def figure(self, flag: str, path, figure) -> bool:
        """:meth:`write` of a matplotlib figure (:func:`save_figure`)."""
        return self.write(flag, path, lambda: save_figure(figure, path))

    @property
    def error(self) -> str | None:
        """The one line saying which outputs failed, or None."""
        if not self.failed:
            return None
        return "; ".join(self.failed) + (f"; {self.note}" if self.note else "")

    def annotate(self, doc: dict) -> dict:
        """``doc`` (a command's JSON answer) with ``error`` and ``exit_status`` after a failure."""
        if self.failed:
            doc.update(error=self.error, exit_status=1)
        return doc

    def status(self, status: int = 0) -> int:
        """The command's exit status: ``status``, or 1 (at least) after a failed write, which is
        then reported on stderr as one line."""
        if not self.failed:
            return status
        print(f"brdf-fit: error: {self.error}", file=sys.stderr)
        return max(status, 1)


#: resolution of every figure the command line writes (dots per inch)
FIGURE_DPI = 110


def save_figure(figure, path) -> None:
    """Write a matplotlib ``figure`` (a :class:`matplotlib.figure.Figure` of
    :mod:`brdf_fit.plot`, which pyplot does not hold) to ``path`` whole or not at all
    (:func:`brdf_fit.core.atomic.atomic_path`; the format from the extension)."""
    from brdf_fit.core.atomic import atomic_path

    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=FIGURE_DPI, format=extension(str(path)).lstrip(".") or None)
