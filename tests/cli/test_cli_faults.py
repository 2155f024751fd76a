"""Fault injection (issue 45): every command that writes files, run on a "full disk".

One child process makes its inputs, then lowers its file-size limit to 0 bytes
(``RLIMIT_FSIZE``, with ``SIGXFSZ`` ignored), so that from then on every write to a file fails
with ``EFBIG`` as a write to a full disk fails with ``ENOSPC``: the operating system's own
failure, not a patched function, reaching every writer (the atomic temporary files, numpy,
matplotlib, the run lock). It then runs each command in turn (in-process, so JAX is imported
and its programs compiled once). Each must end with its result printed (the JSON with
``--json``), one line ``brdf-fit: error:`` naming the output that failed and why, exit status 1,
no traceback, and no file or temporary left behind.
"""

import json
import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]

CHILD = r"""
import contextlib, io, json, resource, shutil, signal, sys, traceback
from brdf_fit.cli import main

signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails, not the process
assert main(["synth", sys.argv[1], "-o", "g.csv"]) == 0
shutil.copy("g.csv", "h.csv")
resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))  # from here on every file write fails
results = []
for argv in json.loads(sys.argv[2]):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except BaseException:
            rc = "raised"
            traceback.print_exc(file=err)
    results.append({"rc": rc, "out": out.getvalue(), "err": err.getvalue()})
print(json.dumps(results))
"""

#: (command line, what its JSON answer must hold (None: no --json), the outputs named)
CASES = [
    (["synth", "RECIPE", "-o", "s.csv", "--json"],
     lambda d: d["n_samples"] == 631 and d["files"] == [], ["-o s.csv"]),
    (["fit", "g.csv", "--model", "lambert", "--export", "f.xml", "--json", "--quiet"],
     lambda d: d["converged"] and len(d["params"]["rho"]) == 3, ["--export f.xml"]),
    (["fit-batch", "g.csv", "h.csv", "--model", "lambert", "--out", "r.csv", "--json",
      "--quiet"],
     lambda d: [r["file"] for r in d["results"]] == ["g.csv", "h.csv"], ["--out r.csv"]),
    (["fit", "g.csv", "h.csv", "--model", "lambert", "--table", "T.csv", "--json", "--quiet"],
     lambda d: d["fitted_now"] == 2 and len(d["rows"]) == 2,
     ["2 finished pair(s) could not be kept", "--table T.csv", "--table T.png"]),
    (["select", "g.csv", "--candidates", "lambert,ggx", "--plot", "s.png", "--mitsuba", "s.xml",
      "--gltf", "s.gltf", "--no-checks", "--no-anisotropy", "--json", "--quiet"],
     lambda d: d["choice"] == "ggx" and d["exports"] == [],
     ["--plot s.png", "--mitsuba s.xml", "--gltf s.gltf"]),
    (["plot", "lambert", "-o", "p.png"], None, ["-o p.png", "-o p_hemisphere.png"]),
    (["lut", "dfg", "--size", "8", "-o", "t.npz", "--json", "--quiet"],
     lambda d: d["table"] == "dfg" and d["files"] == [], ["-o t.npz"]),
    # a streamed run fails before any fit (its manifest): nothing computed, exit status 1
    (["fit-batch", "g.csv", "h.csv", "--model", "lambert", "--out-dir", "od", "--json",
      "--quiet"], lambda d: "blocks written" not in d["error"], ["od/manifest.json"]),
    (["demo", "--out", "dd", "--no-plots", "--json", "--quiet"],
     lambda d: d["best"] and len(d["fits"]) >= 3, ["--out dd/demo.json"]),
]


@pytest.mark.slow
def test_a_full_disk_loses_nothing_computed(tmp_path):
    recipe = str(ROOT / "examples" / "gold_4axis.toml")
    argvs = [[recipe if a == "RECIPE" else a for a in argv] for argv, _, _ in CASES]
    env = {**os.environ, "BRDF_FIT_NO_CACHE": "1"}
    run = subprocess.run([sys.executable, "-c", CHILD, recipe, json.dumps(argvs)],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    results = json.loads(run.stdout.splitlines()[-1])
    for (argv, holds, named), r in zip(CASES, results, strict=True):
        what = " ".join(argv[:2])
        assert "Traceback" not in r["err"], f"{what}:\n{r['err'][-3000:]}"
        assert r["rc"] == 1, f"{what}: exit status {r['rc']}\n{r['err'][-2000:]}"
        lines = [ln for ln in r["err"].splitlines() if ln.startswith("brdf-fit: error:")]
        assert len(lines) == 1, f"{what}: {r['err'][-2000:]}"
        for name in named:
            assert name in lines[0], f"{what}: {name!r} not in {lines[0]!r}"
        assert "cannot write" in lines[0] or "File too large" in lines[0], lines[0]
        if holds is not None:  # the result itself, on stdout
            doc = json.loads(r["out"])
            assert doc["exit_status"] == 1 and doc["error"] in lines[0], (what, doc["error"])
            assert holds(doc), f"{what}: {r['out'][:2000]}"
    # nothing half-written and no temporary file anywhere: the outputs are all absent or empty
    inputs = {"g.csv", "h.csv"}
    left = [p for p in tmp_path.rglob("*") if p.is_file() and p.name not in inputs
            and p.name != ".brdf_fit.lock"]
    assert not left, left
