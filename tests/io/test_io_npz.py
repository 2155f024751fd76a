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


def _with_member(path, name, array=None, raw=None):
    """Rewrite the .npz at ``path`` with one more member (an array, or raw bytes) and the
    sidecar's checksum refreshed, as a hostile or damaged file would come."""
    import hashlib
    import zipfile

    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED) as z:
        if array is not None:
            import io

            buf = io.BytesIO()
            np.save(buf, array, allow_pickle=True)
            z.writestr(name, buf.getvalue())
        else:
            z.writestr(name, raw)
    side = sidecar_path(path)
    doc = json.loads(side.read_text())
    doc["npz_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    side.write_text(json.dumps(doc))


def test_hostile_members_are_refused_before_decompression(tmp_path, monkeypatch):
    """A zip bomb (a member of 512 MiB of zeros in half a MB), an unknown member, an object array,
    a member larger than its header, a sidecar implying more than the memory limit, a bad
    channels or metadata field: one line each naming the problem, in a child whose peak memory
    stays that of its imports (issue 45: the bomb went through, decompressed, at 4.4 GB)."""
    import subprocess
    import sys
    import zipfile

    from _helpers import PEAK_RSS_CODE, peak_kib

    d = _data()
    bomb = tmp_path / "bomb.npz"
    write_npz(d, bomb)
    with zipfile.ZipFile(bomb, "a", compression=zipfile.ZIP_DEFLATED) as z:
        with z.open("extra.npy", "w", force_zip64=True) as fh:
            block = b"\0" * 2**24
            for _ in range(32):  # 512 MiB of zeros in ~0.5 MB: decompressed, it would pass
                fh.write(block)  # the peak bound below (the was 4 GiB; same path)
    _with_member(bomb, "x.txt", raw=b"")  # refresh the checksum (and one more unknown member)
    assert bomb.stat().st_size < 2**20
    code = PEAK_RSS_CODE + ("from brdf_fit.io.npz import read_npz\n"
                            "from brdf_fit.data import DataError\n"
                            "try:\n"
                            "    read_npz(_s.argv[1])\n"
                            "except DataError as e:\n"
                            "    print(e)\n"
                            "_peak()\n")
    out = subprocess.run([sys.executable, "-c", code, str(bomb)], capture_output=True,
                         text=True, check=True)
    assert "unknown member(s) ['extra', 'x.txt']" in out.stdout, out.stdout
    assert peak_kib(out.stderr) < 300 * 1024, out.stderr

    cases = {
        "obj.npz": ("value", np.array([object()] * 75).reshape(25, 3), "dtype object"),
    }
    for fname, (member, arr, words) in cases.items():
        p = tmp_path / fname
        write_npz(d, p)
        # replace the member: rebuild the zip without it, then add the hostile one
        with zipfile.ZipFile(p) as z:
            keep = {i.filename: z.read(i) for i in z.infolist() if i.filename != member + ".npy"}
        with zipfile.ZipFile(p, "w") as z:
            for k, v in keep.items():
                z.writestr(k, v)
        _with_member(p, member + ".npy", array=arr)
        with pytest.raises(DataError, match=words):
            read_npz(p)
    # a member that stores more than its header says
    p = tmp_path / "long.npz"
    write_npz(d, p)
    with zipfile.ZipFile(p) as z:
        keep = {i.filename: z.read(i) for i in z.infolist()}
    keep["wi.npy"] = keep["wi.npy"] + b"\0" * 10**5
    with zipfile.ZipFile(p, "w") as z:
        for k, v in keep.items():
            z.writestr(k, v)
    _with_member(p, "pad.npy", raw=b"")
    with pytest.raises(DataError, match="unknown member"):
        read_npz(p)
    with zipfile.ZipFile(p, "w") as z:
        for k, v in keep.items():
            z.writestr(k, v)
    side = sidecar_path(p)
    doc = json.loads(side.read_text())
    import hashlib

    doc["npz_sha256"] = hashlib.sha256(p.read_bytes()).hexdigest()
    side.write_text(json.dumps(doc))
    with pytest.raises(DataError, match=r"member 'wi' stores 100,\d+ bytes for a 600-byte"):
        read_npz(p)
    # sidecar fields: a size past the limit, bad channels, bad metadata
    p = tmp_path / "s.npz"
    write_npz(d, p)
    side = sidecar_path(p)
    doc = json.loads(side.read_text())
    for change, words in (({"n": 10**12, "npz_sha256": None}, r"has shape \(25, 3\), the "
                                                               r"sidecar says \(1000000000000"),
                          ({"channels": 5}, "channels must be a non-empty list"),
                          ({"metadata": [1, 2]}, "metadata must be a JSON object")):
        side.write_text(json.dumps({**doc, **change}))
        with pytest.raises(DataError, match=words):
            read_npz(p)
    side.write_text(json.dumps(doc))
    monkeypatch.setenv("BRDF_FIT_MAX_MEMORY", "1K")  # the arrays: 25 x (3 + 3 + 3 x 3) x 8 B
    with pytest.raises(DataError, match=r"s.npz: its arrays would take 3 kB, over the memory limit "
                                        r"of 1.02 kB \(raise it with --max-memory"):
        read_npz(p)
    # not a zip at all
    (tmp_path / "junk.npz").write_bytes(b"\x93NUMPY not a zip")
    (tmp_path / "junk.json").write_text(json.dumps({**doc, "npz_sha256": None}))
    with pytest.raises(DataError, match="not a zip archive"):
        read_npz(tmp_path / "junk.npz")
