"""Programs compiled, per command and per test file (issue 41): where the time of a cold start
and of the test suite goes, as numbers a regression changes.

    python benchmarks/bench_compiles.py [--commands NAME ...] [--tests [PYTEST ARGS ...]]
                                        [--out DIR]

**Commands.** Each ``brdf-fit`` command below runs in a fresh process with an empty
compilation cache (``--no-cache``), instrumented by ``jax.monitoring``: the programs XLA
compiled, the seconds spent tracing (Python to jaxpr), lowering (jaxpr to MLIR) and compiling
(XLA), and the command's wall seconds (JAX imported first, not counted)::

    models, eval ggx, check ggx --check energy, synth (gold_4axis), fit (ggx on it),
    fit-again (a second fit of 90% of the samples in the same process), convert (phong-to-ggx,
    2 exponents), select (lambert, ggx), lut (dfg 32), demo --no-plots

**Tests** (``--tests``, then pytest's arguments; default the default set on every core): the
suite runs with ``$BRDF_FIT_COMPILE_REPORT`` (tests/conftest.py), and the files are listed by
seconds spent compiling, with the programs each compiled and its tests' wall seconds.

Writes ``compiles.md`` and ``compiles.json`` into ``--out`` (default ``benchmarks/results``).
"""

from __future__ import annotations

import argparse
import collections
import datetime
import json
import os
import pathlib
import platform
import subprocess
import sys
import tempfile

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from bench_latency import _cpu as cpu_name  # noqa: E402  (the CPU's model name)

#: a child process: JAX imported, the listeners on, then the command (or two: fit-again)
_PROBE = r"""
import contextlib, io, json, sys, time
import jax
from collections import defaultdict
events, counts = defaultdict(float), defaultdict(int)
def listener(name, secs, **kw):
    events[name] += secs
    counts[name] += 1
jax.monitoring.register_event_duration_secs_listener(listener)
from brdf_fit.cli import main
runs = json.loads(sys.argv[1])
out = []
for argv in runs:
    before_e, before_c = dict(events), dict(counts)
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        rc = main(["--no-cache", *argv])
    wall = time.perf_counter() - t0
    d = lambda m, k: m.get(k, 0) - (before_e if m is events else before_c).get(k, 0)
    out.append({"rc": rc, "wall_s": wall,
                "compiles": d(counts, "/jax/core/compile/backend_compile_duration"),
                "compile_s": d(events, "/jax/core/compile/backend_compile_duration"),
                "trace_s": d(events, "/jax/core/compile/jaxpr_trace_duration"),
                "lower_s": d(events, "/jax/core/compile/jaxpr_to_mlir_module_duration")})
print(json.dumps(out))
"""


def commands(tmp: pathlib.Path) -> dict[str, list[list[str]]]:
    """name -> the command lines run in one process (the last one is reported)."""
    data = str(tmp / "gold.csv")
    part = str(tmp / "gold_90.csv")
    return {
        "models": [["models"]],
        "eval": [["eval", "ggx"]],
        "check": [["check", "ggx", "--check", "energy", "--quiet"]],
        "synth": [["synth", str(ROOT / "examples" / "gold_4axis.toml"), "-o",
                   str(tmp / "synth.csv")]],
        "fit": [["fit", data, "--model", "ggx", "--quiet"]],
        "fit-again": [["fit", data, "--model", "ggx", "--quiet"],
                      ["fit", part, "--model", "ggx", "--quiet"]],
        "convert": [["convert", "phong-to-ggx", "--exponents", "10", "100", "--quiet"]],
        "select": [["select", data, "--candidates", "lambert,ggx", "--no-checks",
                    "--no-anisotropy", "--quiet"]],
        "lut": [["lut", "dfg", "--size", "32", "-o", str(tmp / "dfg.npz"), "--quiet"]],
        "demo": [["demo", "--out", str(tmp / "demo"), "--no-plots", "--quiet"]],
    }


def _inputs(tmp: pathlib.Path) -> None:
    """gold.csv (examples/gold_4axis.toml) and gold_90.csv, its first 90% of samples."""
    subprocess.run([sys.executable, "-m", "brdf_fit.cli", "--no-cache", "synth",
                    str(ROOT / "examples" / "gold_4axis.toml"), "-o", str(tmp / "gold.csv")],
                   check=True, capture_output=True)
    lines = (tmp / "gold.csv").read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if not ln.startswith("#")]
    keep = body[:1] + body[1:][: int(0.9 * (len(body) - 1))]
    (tmp / "gold_90.csv").write_text("\n".join(head + keep) + "\n")


def run_commands(names, tmp: pathlib.Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION",
                                                                      "BRDF_FIT_CACHE"))}
    cmds = commands(tmp)
    out = {}
    for name in names:
        p = subprocess.run([sys.executable, "-c", _PROBE, json.dumps(cmds[name])], env=env,
                           capture_output=True, text=True, cwd=tmp)
        if p.returncode:
            raise SystemExit(f"{name}: the probe failed:\n{p.stderr[-3000:]}")
        runs = json.loads(p.stdout.strip().splitlines()[-1])
        out[name] = {"argv": cmds[name][-1], **runs[-1],
                     "first": runs[0] if len(runs) > 1 else None}
        r = out[name]
        print(f"{name:10s} rc {r['rc']}  {r['compiles']:4d} programs  compile "
              f"{r['compile_s']:6.2f} s  trace {r['trace_s']:5.2f} s  lower "
              f"{r['lower_s']:5.2f} s  wall {r['wall_s']:6.2f} s", flush=True)
    return out


def run_tests(pytest_args, tmp: pathlib.Path) -> dict:
    report = tmp / "compiles.jsonl"
    env = {**os.environ, "BRDF_FIT_COMPILE_REPORT": str(report)}
    args = pytest_args or ["-q", "-n", "auto", "--maxprocesses=4", "--dist", "loadfile"]
    p = subprocess.run([sys.executable, "-m", "pytest", *args], env=env, cwd=ROOT,
                       capture_output=True, text=True)
    tail = p.stdout.strip().splitlines()[-1:] if p.stdout.strip() else []
    files: dict = collections.defaultdict(lambda: collections.Counter())
    for line in report.read_text().splitlines():
        row = json.loads(line)
        files[row["file"]].update({k: v for k, v in row.items()
                                   if isinstance(v, int | float) and k != "worker"})
    rows = sorted(({"file": f, **{k: round(v, 3) for k, v in c.items()}}
                   for f, c in files.items() if c["compiles"] or c["tests"]),
                  key=lambda r: -r.get("compile_s", 0))
    total = collections.Counter()
    for r in rows:
        total.update({k: v for k, v in r.items() if k != "file"})
    return {"pytest_args": args, "summary": tail[0] if tail else "", "rc": p.returncode,
            "files": rows, "total": {k: round(v, 2) for k, v in total.items()}}


def render(doc: dict) -> str:
    lines = ["# Programs compiled, per command and per test file (issue 41)", "",
             f"Command: `{doc['command']}`  ", f"Date: {doc['date']}  ",
             f"Machine: {doc['cpu']}, {doc['cores']} cores, Python {doc['python']}, "
             f"jax {doc['jax']}", ""]
    if doc.get("commands"):
        lines += ["## Commands, each in a fresh process with an empty cache (`--no-cache`)", "",
                  "Seconds of the command itself (JAX imported before it). `fit-again`: the "
                  "second of two fits in one process, of 90% of the first one's samples.", "",
                  "| command | programs compiled | compile s | trace s | lower s | wall s |",
                  "|---|---:|---:|---:|---:|---:|"]
        for name, r in doc["commands"].items():
            lines.append(f"| {name} | {r['compiles']} | {r['compile_s']:.2f} | "
                         f"{r['trace_s']:.2f} | {r['lower_s']:.2f} | {r['wall_s']:.2f} |")
        lines.append("")
    t = doc.get("tests")
    if t:
        tot = t["total"]
        share = (tot.get("compile_s", 0) + tot.get("trace_s", 0) + tot.get("lower_s", 0)) / max(
            tot.get("wall_s", 1e-9), 1e-9)
        lines += ["## Test files, by seconds compiling", "",
                  f"`pytest {' '.join(t['pytest_args'])}`: {t['summary']}. In all: "
                  f"{int(tot.get('compiles', 0))} programs compiled "
                  f"({int(tot.get('loads', 0))} more loaded from the persistent cache), "
                  f"{tot.get('compile_s', 0):.0f} s compiling, {tot.get('trace_s', 0):.0f} s "
                  f"tracing, {tot.get('lower_s', 0):.0f} s lowering, "
                  f"of {tot.get('wall_s', 0):.0f} s "
                  f"of test time summed over the workers ({100 * share:.0f}% tracing, lowering "
                  "and compiling).", "",
                  "| file | tests | programs compiled | compile s | loaded from cache | load s | "
                  "trace s | lower s | test s |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for r in t["files"][:40]:
            lines.append(f"| {r['file']} | {int(r.get('tests', 0))} | {int(r.get('compiles', 0))} "
                         f"| {r.get('compile_s', 0):.1f} | {int(r.get('loads', 0))} | "
                         f"{r.get('load_s', 0):.1f} | {r.get('trace_s', 0):.1f} | "
                         f"{r.get('lower_s', 0):.1f} | {r.get('wall_s', 0):.1f} |")
        if len(t["files"]) > 40:
            lines.append(f"| ({len(t['files']) - 40} more files in the .json) | | | | | | | | |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--commands", nargs="*", default=None,
                    help="the commands to measure (default all; none with --tests only)")
    ap.add_argument("--tests", nargs=argparse.REMAINDER, default=None,
                    help="also run the test suite (pytest's arguments follow; default the "
                         "default set on every core)")
    ap.add_argument("--out", default=str(HERE / "results"))
    args = ap.parse_args(argv)
    import jax

    doc = {"command": "python benchmarks/bench_compiles.py " + " ".join(argv or sys.argv[1:]),
           "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
           "cpu": cpu_name(), "cores": os.cpu_count(), "python": platform.python_version(),
           "jax": jax.__version__}
    with tempfile.TemporaryDirectory(prefix="bench_compiles_") as d:
        tmp = pathlib.Path(d)
        names = list(commands(tmp)) if args.commands is None else args.commands
        if args.tests is not None and args.commands is None:
            names = []
        if names:
            _inputs(tmp)
            doc["commands"] = run_commands(names, tmp)
        if args.tests is not None:
            doc["tests"] = run_tests(args.tests, tmp)
            print(doc["tests"]["summary"], flush=True)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "compiles" if args.tests is None else "compiles_tests"
    (out / f"{stem}.json").write_text(json.dumps(doc, indent=1) + "\n")
    (out / f"{stem}.md").write_text(render(doc))
    print(render(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
