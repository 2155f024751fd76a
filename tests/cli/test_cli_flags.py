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
