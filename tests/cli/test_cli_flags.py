"""fit-batch row flags: not converged, at bound, rms far above the batch median, few samples
(the 3-sample member of the batch fault test converges with small errors; only its sample count
gives it away)."""

from brdf_fit.cli._batch_rows import flag_rows as _flag_rows


def row(rms, n=300, converged=True, at_bound=()):
    return {"residual_rms": rms, "n_samples": n, "converged": converged,
            "at_bound": list(at_bound), "params": {"alpha": 0.2, "f0": [0.5, 0.5, 0.5]}}


def test_flags():
    rows = [row(0.01), row(0.011), row(0.012), row(0.5), row(1e-4, n=3),
            row(0.01, converged=False, at_bound=("f0",))]
    _flag_rows(rows)
    assert rows[0]["flags"] == [] and rows[1]["flags"] == []
    assert rows[3]["flags"] == ["rms > 10x median"]
    assert rows[4]["flags"] == ["few samples (3 for 4 parameters)"]
    assert rows[5]["flags"] == ["not converged", "at bound"]


def test_every_json_answer_is_strict_json():
    """Every command's ``--json`` answer and JSON file goes through ``strict_json`` (a non-finite
    number as null: JSON has no NaN, and Python's json.dumps writes it, which strict parsers
    reject): no command module calls ``json.dumps`` itself (``select`` was the first; a
    4-minute run once ended in ``ValueError: Out of range float values``). The two
    ``json.dumps`` left are main.py's error lines (strings only) and fit_batch_arrays's OpenEXR
    header attribute (names and paths)."""
    import ast
    import pathlib

    import brdf_fit.cli as cli

    allowed = {"_common.py": 1, "main.py": 4, "fit_batch_arrays.py": 1}
    for path in sorted(pathlib.Path(cli.__file__).parent.glob("*.py")):
        calls = [n for n in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                 if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
                 and n.func.attr == "dumps" and getattr(n.func.value, "id", None) == "json"]
        assert len(calls) == allowed.get(path.name, 0), (path.name, [c.lineno for c in calls])
