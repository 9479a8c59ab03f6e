"""README.md and the docs site against the code: README's length and first commands, its and the
docs pages' Python blocks run, the links they cite exist, the results pages carry provenance,
the site builds with --strict, and no docstring holds a dated measurement history."""

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fourwis.envs.scenarios import SCENARIOS, make_scenario

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
#: a ```python block, unless the line before it is ``<!-- not run: why -->`` (say, it needs a cluster)
PYTHON_BLOCK = re.compile(r"^(?<!-->\n)```python\n(.*?)^```", re.S | re.M)
#: the layers' and the root package's source, whose docstrings the history check reads
PAGES = [README, *sorted(DOCS.rglob("*.md"))]
LAYERS = ("fourwis", "envs", "estimation", "control", "training")
SOURCES = [path for layer in LAYERS for path in (ROOT / layer).rglob("*.py")]


def test_the_readme_is_short_and_opens_with_the_two_commands():
    lines = README.read_text().splitlines()
    first_block = README.read_text().split("```")[1]
    assert len(lines) <= 150, len(lines)
    assert first_block.startswith("bash\nmake compare") and "\nmake test" in first_block, first_block


@pytest.mark.parametrize("page", [p for p in PAGES if PYTHON_BLOCK.search(p.read_text())], ids=lambda p: p.name)
def test_the_python_blocks_run(page, tmp_path, monkeypatch, capsys):
    """Every ```python block of README.md and of the docs pages runs, in order, in one namespace
    per page (away from the checkout's root, as a user's script would)."""
    blocks = PYTHON_BLOCK.findall(page.read_text())
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__readme__"}
    for block in blocks:
        exec(compile(block, str(page), "exec"), namespace)


def test_the_readme_headline_is_the_generated_one():
    """The headline table between README's markers is docs/results/headline.md, which
    docs/generate.py writes (a re-measurement reruns it; nobody types the table)."""
    text = README.read_text()
    start, end = "<!-- headline:start -->\n", "<!-- headline:end -->"
    table = text[text.index(start) + len(start) : text.index(end)]
    assert table == (DOCS / "results" / "headline.md").read_text()
    assert 3 <= len(table.splitlines()) <= 8  # a header, its rule and at most six rows


def test_the_files_the_readme_links_exist():
    links = re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", README.read_text())
    assert links and not [link for link in links if not (ROOT / link).exists()]


def test_each_results_page_carries_its_provenance():
    """A results page names the command, commit, date and host of every run it shows."""
    for page in sorted((DOCS / "results").glob("*.md")):
        if page.name == "headline.md":
            continue
        text = page.read_text()
        for field in ("command", "commit", "date"):
            assert re.search(rf"^- {field}: ", text, re.M) or f"{field}:" in text, (page.name, field)
        assert re.search(r"^- (host|machine): ", text, re.M), page.name


def test_the_plant_page_names_each_scenario_that_refuses_a_callable_mu():
    """docs/plant.md says scenario arguments take a callable mu(x, y); a builder that refuses
    one (ValueError) is named there as the exception."""
    text = " ".join((DOCS / "plant.md").read_text().split())
    sentence = text[text.index("Scenario arguments take") :].split(".")[0]
    refused = []
    for name in SCENARIOS:
        try:
            make_scenario(name, mu=lambda x, y: np.full_like(x, 0.5))
        except ValueError:
            refused.append(name)
    assert refused and all(f"`{name}`" in sentence for name in refused), (refused, sentence)


def _docstrings(path: Path):
    """(name, text) of the module's, classes' and functions' docstrings and of its ``#:``
    attribute comments (which the API pages show as the attributes' documentation)."""
    source = path.read_text()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            doc = ast.get_docstring(node)
            if doc:
                yield getattr(node, "name", path.stem), doc
    for number, line in enumerate(source.splitlines(), 1):
        if line.lstrip().startswith("#:"):
            yield f"line {number}", line


def test_no_docstring_holds_a_dated_measurement_history():
    """Docstrings say what, units, shapes and why; how a choice was measured, and when, is in
    docs/decisions/. A date in a docstring is a history that belongs there."""
    dated = [
        f"{path.relative_to(ROOT)}:{name}"
        for path in SOURCES
        for name, doc in _docstrings(path)
        if re.search(r"\b20\d\d-\d\d-\d\d\b", doc)
    ]
    assert not dated, dated


def test_the_site_builds_strictly(tmp_path):
    """mkdocs build --strict: no broken link or anchor, no missing API object (mkdocstrings)."""
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-4000:]
    assert (tmp_path / "site" / "reference" / "envs" / "index.html").exists()
