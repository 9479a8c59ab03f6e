"""Build hooks of the docs site (mkdocs.yml): the pages that come from the code, written before
each build, so that they cannot drift from what runs:

* ``build/docs-source/fourwis``: the installed package's layout (its root and core from
  fourwis/, the layer folders envs/, estimation/, control/, training/ as its subpackages), as
  links into the checkout, for mkdocstrings' API pages;
* ``docs/reference/cli.md``: every ``fourwis`` subcommand's ``--help``;
* ``docs/reference/catalog.md``: the scenarios, estimators, controllers and logs, as
  ``fourwis list`` gives them;
* ``build/docs-snippets/observation.md``: the environment's observation tables, from
  ``envs.gym_env.STATE_SLOTS`` and ``SENSOR_SLOTS`` (included by docs/environment.md).

The results pages (docs/results/) are not written here: ``make docs`` runs the measured jobs
(docs/generate.py) and they are committed with their date, machine, commit and command.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("envs", "estimation", "control", "training")


def _package_view() -> None:
    view = ROOT / "build" / "docs-source" / "fourwis"
    view.mkdir(parents=True, exist_ok=True)
    targets = {path.name: path for path in (ROOT / "fourwis").iterdir() if path.name != "__pycache__"}
    targets.update({layer: ROOT / layer for layer in LAYERS})
    for name, target in targets.items():
        link = view / name
        if link.is_symlink() or link.exists():
            if link.is_symlink() and Path(os.readlink(link)) == target:
                continue
            link.unlink()
        link.symlink_to(target)


def _write(path: Path, text: str) -> None:
    if not path.exists() or path.read_text() != text:  # (an unchanged page keeps its time: no rebuild loop)
        path.write_text(text)


def _cli_reference() -> str:
    from fourwis.training.cli import build_parser

    parser = build_parser()
    lines = [
        "# Command line",
        "",
        "One console script, `fourwis`, with a subcommand per job. This page is written from the",
        "parser itself at every build of the docs (`docs/hooks.py`).",
        "",
        "```text",
        parser.format_help().rstrip(),
        "```",
    ]
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in subparsers.choices.items():
        lines += ["", f"## fourwis {name}", "", "```text", sub.format_help().rstrip(), "```"]
    return "\n".join(lines) + "\n"


def _catalog() -> str:
    from fourwis.training.catalog import FOOTNOTES, NO_LOGS, SECTIONS, rows

    lines = [
        "# What fourwis offers by name",
        "",
        "As `fourwis list` gives them, with the defaults read from the code that builds each one",
        "(written at every build of the docs).",
    ]
    for section in SECTIONS:
        entries = rows(section)
        lines += ["", f"## {section.capitalize()}", ""]
        if not entries:
            lines.append(NO_LOGS if section == "logs" else "(none)")
            continue
        lines += ["| name | what it is | defaults |", "|---|---|---|"]
        lines += [f"| `{name}` | {what} | {defaults} |" for name, what, defaults in entries]
        if FOOTNOTES[section]:
            lines += ["", FOOTNOTES[section].strip("()").capitalize() + "."]
    return "\n".join(lines) + "\n"


def _observation_tables() -> str:
    from fourwis.envs.gym_env import SENSOR_SLOTS, STATE_SLOTS

    def table(slots) -> list[str]:
        rows = ["| index | quantity | slot value |", "|---:|---|---|"]
        for index, slot in enumerate(slots):
            unit = "" if slot.unit == "-" else f" {slot.unit}"
            rows.append(f"| {index} | {slot.quantity} | quantity / {slot.scale:g}{unit} |")
        return rows

    lines = ['With `observation="estimated"` (the default) or `"true"`:', "", *table(STATE_SLOTS)]
    lines += ["", 'With `observation="sensors"`:', "", *table(SENSOR_SLOTS)]
    return "\n".join(lines) + "\n"


def on_startup(command, dirty) -> None:
    _package_view()
    reference = ROOT / "docs" / "reference"
    reference.mkdir(exist_ok=True)
    _write(reference / "cli.md", _cli_reference())
    _write(reference / "catalog.md", _catalog())
    snippets = ROOT / "build" / "docs-snippets"
    snippets.mkdir(parents=True, exist_ok=True)
    _write(snippets / "observation.md", _observation_tables())
