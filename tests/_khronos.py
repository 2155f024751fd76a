"""The Khronos glTF validator (npm ``gltf-validator``), run with node when it can be.

:func:`khronos_validate` installs the validator into a cache folder
(``$BRDF_FIT_NODE_CACHE`` or ``~/.cache/brdf_fit/node``) on first use with ``npm install``
(the npm registry is one of this machine's registries) and returns its report's issue counts;
None when node or npm is missing or the install fails (callers then fall back to, or skip on,
the JSON-schema check, and say so).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

PACKAGE = "gltf-validator@2.0.0-dev.3.10"

_SCRIPT = """
const validator = require('gltf-validator');
const fs = require('fs');
const path = process.argv[2];
validator.validateBytes(new Uint8Array(fs.readFileSync(path)), {
  uri: path,
  externalResourceFunction: (uri) => Promise.reject(new Error('no external resources')),
}).then((r) => { console.log(JSON.stringify({
  validator: 'Khronos glTF-Validator ' + r.validatorVersion,
  numErrors: r.issues.numErrors, numWarnings: r.issues.numWarnings,
  numInfos: r.issues.numInfos, messages: r.issues.messages })); })
  .catch((e) => { console.error(String(e)); process.exit(2); });
"""


def _cache() -> Path:
    return Path(os.environ.get("BRDF_FIT_NODE_CACHE",
                               Path.home() / ".cache" / "brdf_fit" / "node"))


def _installed() -> Path | None:
    if shutil.which("node") is None:
        return None
    folder = _cache()
    if not (folder / "node_modules" / "gltf-validator").is_dir():
        if shutil.which("npm") is None:
            return None
        folder.mkdir(parents=True, exist_ok=True)
        try:
            subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--prefix",
                            str(folder), PACKAGE], check=True, capture_output=True,
                           timeout=180)
        except (subprocess.SubprocessError, OSError):
            return None
    script = folder / "validate.js"
    if not script.exists() or script.read_text() != _SCRIPT:
        script.write_text(_SCRIPT)
    return script


def khronos_validate(path) -> dict | None:
    """The validator's report on the glTF file ``path`` (issue counts and messages), or None
    when it cannot be run here."""
    script = _installed()
    if script is None:
        return None
    proc = subprocess.run(["node", str(script), str(path)], capture_output=True, text=True,
                          timeout=120, cwd=script.parent)
    if proc.returncode != 0:
        raise RuntimeError(f"gltf-validator failed on {path}: {proc.stderr.strip()}")
    return json.loads(proc.stdout)
