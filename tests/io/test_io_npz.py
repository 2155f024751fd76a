"""npz + JSON sidecar: exact round trip, schema version and provenance, mismatch detection."""

import json

import numpy as np
import pytest

from brdf_fit.data import DataError, GonioData, wavelength_channels
from brdf_fit.io.npz import SCHEMA, SCHEMA_VERSION, read_npz, sidecar_path, write_npz


def _data(sigma=True, channels=("R", "G", "B")):
    rng = np.random.default_rng(0)
    n, nc = 25, len(channels)
    d = GonioData.from_angles_deg(rng.uniform(0, 80, n), rng.uniform(0, 360, n),
                                  rng.uniform(0, 80, n), rng.uniform(0, 360, n),
                                  rng.lognormal(-1, 1, (n, nc)), channels=channels,
                                  sigma=rng.uniform(0.01, 0.02, (n, nc)) if sigma else None,
                                  weight=rng.uniform(0, 2, (n, nc)),
                                  metadata={"instrument": "virtual", "truth": {"gain": [1, 2]},
                                            "arr": np.arange(3)})
    return d


@pytest.mark.parametrize("sigma", [True, False])
def test_roundtrip_is_bit_exact(tmp_path, sigma):
    d = _data(sigma=sigma)
    npz, side = write_npz(d, tmp_path / "scan.npz", provenance={"recipe": {"seed": 3}})
    assert npz.endswith("scan.npz") and side.endswith("scan.json")
    for path in (npz, side, tmp_path / "scan"):  # either file, or the stem, opens the pair
        r = read_npz(path)
        for name in ("wi", "wo", "value", "weight"):
            np.testing.assert_array_equal(getattr(r, name), getattr(d, name))
        if sigma:
            np.testing.assert_array_equal(r.sigma, d.sigma)
        else:
            assert r.sigma is None
        assert r.channels == d.channels
        assert r.metadata["instrument"] == "virtual" and r.metadata["arr"] == [0, 1, 2]
        assert r.metadata["truth"] == {"gain": [1, 2]}
        assert r.metadata["provenance"]["recipe"] == {"seed": 3}
        assert r.metadata["provenance"]["library"] == "brdf_fit"
        assert r.metadata["schema_version"] == SCHEMA_VERSION and r.metadata["format"] == "npz"


def test_sidecar_content_and_determinism(tmp_path):
    d = _data(channels=wavelength_channels([450, 550]))
    write_npz(d, tmp_path / "a.npz")
    doc = json.loads((tmp_path / "a.json").read_text())
    assert doc["schema"] == SCHEMA and doc["schema_version"] == SCHEMA_VERSION
    assert doc["n"] == 25 and doc["channels"] == ["450nm", "550nm"]
    assert doc["arrays"] == {"wi": [25, 3], "wo": [25, 3], "value": [25, 2],
                             "weight": [25, 2], "sigma": [25, 2]}
    assert "1/sr" in doc["units"]["value"] and "version" in doc["provenance"]
    assert sidecar_path(tmp_path / "a.npz") == tmp_path / "a.json"
    # same data -> same sidecar (no time stamps)
    write_npz(d, tmp_path / "b.npz")
    doc_b = json.loads((tmp_path / "b.json").read_text())
    doc.pop("npz_file"), doc_b.pop("npz_file")
    assert doc == doc_b


def test_errors_name_file_and_problem(tmp_path):
    d = _data()
    write_npz(d, tmp_path / "s.npz")
    side = tmp_path / "s.json"
    doc = json.loads(side.read_text())

    def with_doc(**changes):
        side.write_text(json.dumps({**doc, **changes}))

    with_doc(schema_version=SCHEMA_VERSION + 1)
    with pytest.raises(DataError, match=r"s.json: schema_version 2 is newer than this reader"):
        read_npz(tmp_path / "s.npz")
    with_doc(schema="something.else")
    with pytest.raises(DataError, match=r"not a brdf_fit.gonio sidecar"):
        read_npz(tmp_path / "s.npz")
    with_doc(n=24, npz_sha256=None)
    with pytest.raises(DataError, match=r"array 'wi' has shape \(25, 3\), the sidecar says "
                                        r"\(24, 3\)"):
        read_npz(tmp_path / "s.npz")
    with_doc()
    # replace the arrays behind the sidecar's back
    write_npz(GonioData(d.wi, d.wo, d.value * 2, channels=d.channels), tmp_path / "t.npz")
    (tmp_path / "t.npz").replace(tmp_path / "s.npz")
    with pytest.raises(DataError, match=r"SHA-256 .* does not match the sidecar"):
        read_npz(tmp_path / "s.npz")
    side.write_text("{not json")
    with pytest.raises(DataError, match=r"s.json: the sidecar is not valid JSON"):
        read_npz(tmp_path / "s.npz")
    with pytest.raises(DataError, match=r"cannot read the JSON sidecar of missing.npz"):
        read_npz(tmp_path / "missing.npz")
    # invalid data is caught by validation, named by sample
    bad = GonioData(d.wi, d.wo, -d.value, channels=d.channels)
    write_npz(bad, tmp_path / "neg.npz")
    with pytest.raises(DataError, match=r"neg.npz: sample 0: value .* is negative"):
        read_npz(tmp_path / "neg.npz")
    assert read_npz(tmp_path / "neg.npz", validate=False).n == 25
    with pytest.raises(DataError, match="must be JSON serialisable"):
        write_npz(d.with_metadata(obj=object()), tmp_path / "o.npz")
