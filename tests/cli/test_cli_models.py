"""``brdf-fit models`` answers from the packaged listing without importing JAX (issue 41); the
listing must equal the live registry, entry for entry."""

import json
import subprocess
import sys

from brdf_fit.cli import main
from brdf_fit.cli.models import LISTING, live_listing, read_listing

REGENERATE = 'python -c "from brdf_fit.cli.models import write_listing; write_listing()"'


def test_the_packaged_listing_is_the_live_registry():
    packaged = json.loads(LISTING.read_text(encoding="utf-8"))
    live = live_listing()
    assert [e["name"] for e in packaged] == [e["name"] for e in live], REGENERATE
    for a, b in zip(packaged, live, strict=True):
        assert a == b, f"{a['name']}: the packaged listing differs; regenerate: {REGENERATE}"


def test_a_changed_entry_is_seen(monkeypatch):
    """The negative control: a live entry that differs from the file fails the comparison."""
    from brdf_fit import registry

    entry_class = type(registry.get("ggx"))
    original = entry_class.to_dict

    def changed(self):
        d = original(self)
        return {**d, "description": "changed"} if self.name == "ggx" else d

    monkeypatch.setattr(entry_class, "to_dict", changed)
    assert read_listing() != live_listing()


def test_models_imports_no_jax(capsys):
    code = ("import sys\nfrom brdf_fit.cli import main\nrc = main(['models'])\n"
            "assert rc == 0, rc\nassert 'jax' not in sys.modules, 'jax imported'\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "ggx" in r.stdout and "ref:" in r.stdout
    assert main(["models", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == live_listing()
