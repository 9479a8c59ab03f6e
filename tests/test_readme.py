"""README.md against the code: what it says the scenarios take, the files it cites."""

import re
from pathlib import Path

import numpy as np

from fourwis.envs.scenarios import SCENARIOS, make_scenario

README = Path(__file__).resolve().parent.parent / "README.md"


def test_the_readme_names_each_scenario_that_refuses_a_callable_mu():
    """README's Scenarios section says ``mu`` takes a callable mu(x, y); a builder that refuses
    one (ValueError) is named there as an exception."""
    text = " ".join(README.read_text().split())
    start = text.index("`mu` takes a friction coefficient")
    sentence = text[start : text.index("every builder also takes", start)]
    refused = []
    for name in SCENARIOS:
        try:
            make_scenario(name, mu=lambda x, y: np.full_like(x, 0.5))
        except ValueError:
            refused.append(name)
    assert refused and all(f"`{name}`" in sentence for name in refused), (refused, sentence)


def test_the_documents_the_readme_cites_exist():
    """A document README cites by name (an upper-case NAME.md, not a report a command writes)
    is in the repository (it had cited a DESIGN.md that is not)."""
    cited = set(re.findall(r"\b[A-Z][A-Z0-9_]*\.md\b", README.read_text())) - {"README.md"}
    assert cited and not [name for name in sorted(cited) if not (README.parent / name).is_file()]
