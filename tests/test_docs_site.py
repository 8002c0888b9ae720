"""The docs site builds without a warning (``mkdocs build --strict``: every page in the nav, every link and anchor
between pages found, the API reference generated from the docstrings), and the README's links resolve."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def _missing_docs_tools() -> list[str]:
    return [name for name in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python")
            if _find(name) is None]


def _find(name: str):
    try:
        return importlib.util.find_spec(name)
    except ModuleNotFoundError:   # a parent package is missing
        return None


def test_docs_site_builds_strict(tmp_path):
    missing = _missing_docs_tools()
    if missing:
        pytest.skip(f"the docs tools are not installed ({', '.join(missing)}): `uv sync --group docs` "
                    "(or the test group) installs mkdocs, mkdocs-material and mkdocstrings[python]")
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
                          str(REPO_ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
                         cwd=REPO_ROOT, capture_output=True, text=True, timeout=600,
                         env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-5000:]
    for page in ("index", "envs", "physics", "teleoperation", "datasets", "training", "interventions", "evaluation",
                 "rendering", "benchmarks", "api"):
        assert (tmp_path / "site" / f"{page}.html").is_file(), page
    api = (tmp_path / "site" / "api.html").read_text()
    assert "DatasetReader" in api and "run_study" in api, "the API reference was not generated from the docstrings"
    # the docstrings' Sphinx roles are links (docs/sphinx_roles.py), not raw ":meth:`...`" text
    assert not re.search(r":(meth|func|class|mod|attr|data):`", api)
    assert 'class="autorefs autorefs-internal"' in api
    assert (tmp_path / "site" / "quickstart.html").is_file()   # the site has its own quick start


def _anchors(markdown: Path) -> set[str]:
    """The heading anchors GitHub (and MkDocs' toc) give a Markdown file's headings."""
    headings = re.findall(r"^#{1,6}\s+(.+?)\s*$", re.sub(r"```.*?```", "", markdown.read_text(), flags=re.S),
                          flags=re.M)
    return {re.sub(r"[^\w\- ]", "", h.lower()).replace(" ", "-") for h in headings}


@pytest.mark.parametrize("page", ["README.md", *sorted(p.relative_to(REPO_ROOT).as_posix()
                                                       for p in (REPO_ROOT / "docs").glob("*.md"))])
def test_relative_links_resolve(page):
    """Every relative link and image of the README and the docs pages names a file that exists (and, with
    ``#anchor``, a heading of it)."""
    path = REPO_ROOT / page
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    targets = re.findall(r"\]\(([^)\s]+)\)", text) + re.findall(r"""src=["']([^"']+)["']""", text)
    broken = []
    for target in targets:
        if re.match(r"[a-z]+:", target):   # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        resolved = (path.parent / file).resolve() if file else path
        if not resolved.exists():
            broken.append(f"{target}: no such file")
        elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
            broken.append(f"{target}: no heading #{anchor}")
    assert not broken, f"{page}: " + "; ".join(broken)
