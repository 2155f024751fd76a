"""Generated pages of the documentation site, written by `make docs` before `mkdocs build`:

- ``docs/index.md``: the README with its links (and its HTML images' sources) made relative to
  ``docs/`` and its Python and shell blocks executed (generated, not committed: the landing
  page and the site's home never drift apart);
- ``docs/report/``: the benchmark report (``benchmarks/results/REPORT.md`` and its figures), as
  committed by ``python benchmarks/report.py`` (not re-measured by the docs build).
"""

import pathlib
import re
import shutil

ROOT = pathlib.Path(__file__).resolve().parents[1]


def index_text(readme: str) -> str:
    text = readme.replace("](docs/", "](").replace('src="docs/', 'src="')
    # the README's Python runs when the site is built (markdown-exec), its output shown
    text = text.replace("```python\n", '```python exec="on" source="above" result="text"\n')
    # and so does its set-up command (make demo: the main job, its output shown)
    text = text.replace("```bash\n", '```bash exec="on" source="above" result="text"\n')
    # links to files outside docs/ point at the repository
    return re.sub(r"\]\((?!https?:|#)([^)]*\.(?:py|json|toml|csv))\)", r"](../\1)", text)


def copy_report(dest: pathlib.Path) -> None:
    src = ROOT / "benchmarks" / "results"
    dest.mkdir(parents=True, exist_ok=True)
    text = (src / "REPORT.md").read_text(encoding="utf-8").replace("](report/", "](")
    (dest / "index.md").write_text(text, encoding="utf-8")
    for png in sorted((src / "report").glob("*.png")):
        shutil.copyfile(png, dest / png.name)
    # figures of the other benchmarks that the benchmarks page shows (database.png)
    for png in sorted(src.glob("*.png")):
        shutil.copyfile(png, dest / png.name)


if __name__ == "__main__":
    docs = ROOT / "docs"
    (docs / "index.md").write_text(index_text((ROOT / "README.md").read_text(encoding="utf-8")),
                                   encoding="utf-8")
    copy_report(docs / "report")
