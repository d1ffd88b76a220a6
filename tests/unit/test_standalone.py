"""The project stands alone: its files cite the dissertation and the project's own docs/,
never notes kept outside the repository, and every docs/ file or entry they cite exists.

Entries are cited as ``docs/<topic>.md, <letter(s)><number>`` (e.g. "docs/reference/ambiguities.md,
A21" or a range "docs/journal/measurements.md, M1-M3"); an entry is a markdown heading that
starts with its label. The experiment catalogue covers every bundled scenario.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# Built from pieces so that this file does not match its own patterns.
_OUTSIDE = re.compile(
    "|".join(
        [
            r"\b" + "SP" + r"EC\b",  # the design digest, by name or "... section N"
            "FIELD" + "_NOTES",
            "STYLE" + r"\.md",
            r"\.\./" + "shared",
            r"(?<![\w.])/" + "work/",  # a machine path
        ]
    )
)
_DOC = re.compile(r"docs/((?:[\w.-]+/)?[\w.-]+\.md)")
_ENTRY = re.compile(r"docs/((?:[\w.-]+/)?[\w.-]+\.md),\s+([A-Z]{1,2}\d+(?:\.\d+)?)(?:-([A-Z]{1,2}\d+(?:\.\d+)?))?")


def _tracked() -> list[Path]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    out = subprocess.run(
        ["git", "ls-files", "*.py", "*.md", "*.toml"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    files = [ROOT / line for line in out.splitlines() if line]
    return [f for f in files if f.is_file()]


def test_no_file_points_outside_the_repository():
    offending = [
        f"{f.relative_to(ROOT)}:{n}: {line.strip()}"
        for f in _tracked()
        for n, line in enumerate(f.read_text(encoding="utf-8").splitlines(), 1)
        if _OUTSIDE.search(line)
    ]
    assert not offending, "cite the dissertation or docs/ instead:\n" + "\n".join(offending)


def _headings(doc: Path) -> set[str]:
    labels = set()
    for line in doc.read_text(encoding="utf-8").splitlines():
        m = re.match(r"#+\s+([A-Z]{1,2}\d+(?:\.\d+)?)\b", line)
        if m:
            labels.add(m.group(1))
    return labels


def test_every_cited_doc_and_entry_exists():
    files = _tracked()
    assert (ROOT / "docs" / "README.md").is_file(), "docs/README.md indexes docs/"
    missing = []
    cited = 0
    for f in files:
        text = f.read_text(encoding="utf-8")
        for m in _DOC.finditer(text):
            cited += 1
            if not (ROOT / "docs" / m.group(1)).is_file():
                missing.append(f"{f.relative_to(ROOT)}: docs/{m.group(1)} does not exist")
        for m in _ENTRY.finditer(text):
            doc = ROOT / "docs" / m.group(1)
            if not doc.is_file():
                continue  # reported above
            labels = _headings(doc)
            for label in filter(None, (m.group(2), m.group(3))):
                if label not in labels:
                    missing.append(f"{f.relative_to(ROOT)}: docs/{m.group(1)} has no entry {label}")
    assert cited > 0, "the code cites docs/ somewhere"
    assert not missing, "\n".join(sorted(set(missing)))


def test_docs_index_lists_every_doc():
    index = (ROOT / "docs" / "README.md").read_text(encoding="utf-8")
    docs = sorted(str(p.relative_to(ROOT / "docs")) for p in (ROOT / "docs").glob("*/*.md"))
    assert docs, "docs/ holds topic files"
    unlisted = [name for name in docs if f"({name})" not in index]
    assert not unlisted, f"docs/README.md does not link {unlisted}"


def test_experiment_catalogue_covers_every_bundled_scenario():
    catalogue = (ROOT / "docs" / "reference" / "experiments.md").read_text(encoding="utf-8")
    entries = {m.group(1).lower() for m in re.finditer(r"^###\s+(E\d+\.\d+)\b", catalogue, re.M)}
    configs = sorted((ROOT / "configs").glob("*.toml"))
    assert configs, "configs/ holds the bundled scenarios"
    missing = []
    for f in configs:
        experiment = tomllib.loads(f.read_text(encoding="utf-8")).get("experiment")
        if f"`{f.name}`" not in catalogue:
            missing.append(f"{f.name} is not in docs/reference/experiments.md")
        if experiment is not None and str(experiment).lower() not in entries:
            missing.append(f"{f.name}: experiment {experiment!r} has no entry in docs/reference/experiments.md")
    assert not missing, "\n".join(missing)
