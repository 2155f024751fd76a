"""The documentation's promises that hold without building the site (``make docs`` builds it,
with warnings as errors): the README is a landing page, every Python block of the site is
executed by the build, every page of the site is in its navigation, and the README's links
resolve."""

import importlib.util
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _prepare():
    spec = importlib.util.spec_from_file_location("docs_prepare", DOCS / "_prepare.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_readme_is_a_landing_page():
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 150


def test_every_python_block_runs_in_the_build():
    """markdown-exec runs a block only with exec="on": a plain ```python block would show code
    that no build ever ran (docs/quadrature.md had one that could not import)."""
    fence = re.compile(r"^```python(.*)$", re.M)
    pages = [p for p in DOCS.rglob("*.md") if p.name != "index.md" or p.parent != DOCS]
    bad = [f"{p.relative_to(ROOT)}: ```python{m.group(1)}" for p in pages
           for m in fence.finditer(p.read_text(encoding="utf-8")) if 'exec="on"' not in m.group(1)]
    assert not bad, bad
    index = _prepare().index_text((ROOT / "README.md").read_text(encoding="utf-8"))
    blocks = fence.findall(index)
    assert blocks and all('exec="on"' in b for b in blocks)


def test_every_code_block_runs_in_the_build_or_is_output():
    """Every fenced block of the site (the README's, in the generated home page, included) is
    executed by the build (exec="on") or declared ```text (printed output, a diagram): no
    command or code is shown that the build did not run."""
    fence = re.compile(r"^```(\S*)(.*)$", re.M)
    pages = {p.relative_to(ROOT): p.read_text(encoding="utf-8") for p in DOCS.rglob("*.md")
             if not (p.name == "index.md" and p.parent == DOCS)
             and not str(p.relative_to(DOCS)).startswith("report/")}
    pages["index.md"] = _prepare().index_text((ROOT / "README.md").read_text(encoding="utf-8"))
    bad = []
    for name, text in pages.items():
        opening = True
        for m in fence.finditer(text):
            if opening and m.group(1) != "text" and 'exec="on"' not in m.group(2):
                bad.append(f"{name}: ```{m.group(1)}{m.group(2)}")
            opening = not opening
    assert not bad, bad


def test_every_page_is_in_the_navigation_and_readme_links_resolve():
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    listed = set(re.findall(r":\s*([\w/.-]+\.md)\s*$", nav, re.M))
    pages = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md")
             if not str(p.relative_to(DOCS)).startswith("report/")}
    assert pages - {"index.md"} <= listed, sorted(pages - listed)
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    for target in re.findall(r"\]\(([^)#]+)\)", readme):
        if not target.startswith("http"):
            assert (ROOT / target).exists(), target
