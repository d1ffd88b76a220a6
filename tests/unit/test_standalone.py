"""The project stands alone: its files cite the dissertation and the project's own docs/,
never notes kept outside the repository, and every docs/ file or entry they cite exists.

An entry is a markdown heading that starts with its label (``### A38 — Ch. 6: ...``).
Labels are unique across docs/ (one letter per kind of entry, listed in docs/README.md;
E ids are the experiments' own ids, the scenario key ``experiment``).

A label is cited with a name taken from its heading, then the label in parentheses:
``docs/reference/ambiguities.md, robot lost in role assignment (A38)``, or inside a
sentence's parentheses ``(robot lost in role assignment, A38)``. The check: the words right
before the label (punctuation, comment markers and line breaks skipped) must contain at
least two words of the entry's heading, with nothing but heading words and small words
(of, the, and, ...) between them and the label; plural "s" is ignored. Experiment ids are
exempt: "E5.4" is the name users type.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tomllib
from functools import cache
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
_LABEL = r"[A-Z]\d+(?:\.\d+)?"
_HEADING = re.compile(r"^#+\s+(" + _LABEL + r")\b(.*)$", re.M)
# A label standing as a word: not part of an identifier, a key=value list or a quoted colour.
_CITED = re.compile(r"(?<![\w.=,/\"'-])(" + _LABEL + r")(?:-(" + _LABEL + r"))?(?![\w-])")
# Tokens that look like labels but are not citations.
_NOT_CITATION = [
    re.compile(r"C2(?= (?:spline|cubic|reference|base|path))"),  # twice continuously differentiable
    re.compile(r"(?<=stays )C2"),
    re.compile(r"(?<=assumption )A4"),  # the dissertation's assumption A4 of Sec. 5.4
    re.compile(r"C2(?= = )|(?<=\()C2(?=, C\b)"),  # a covariance matrix in tests/unit/test_roles.py
]
_SMALL = {"a", "an", "the", "of", "and", "or", "in", "on", "at", "to", "for", "by", "with", "is", "are",
          "as", "from", "its", "it", "be", "being", "when", "what", "which", "how"}


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


def _docs() -> list[Path]:
    return sorted((ROOT / "docs").glob("*/*.md"))


@cache
def _definitions() -> dict[str, list[tuple[str, str]]]:
    """label -> [(doc relative to docs/, heading text after the label)] over every docs page."""
    out: dict[str, list[tuple[str, str]]] = {}
    for doc in _docs():
        for m in _HEADING.finditer(doc.read_text(encoding="utf-8")):
            out.setdefault(m.group(1), []).append((str(doc.relative_to(ROOT / "docs")), m.group(2)))
    return out


def _is_experiment(label: str) -> bool:
    return label.startswith("E")


def _key(label: str) -> tuple:
    return (label[0], *map(int, re.findall(r"\d+", label)))


def _span(first: str, last: str) -> list[str]:
    """The defined labels from first to last (a range "W1-W3")."""
    return [lbl for lbl in _definitions() if lbl[0] == first[0] and _key(first) <= _key(lbl) <= _key(last)]


def _stem(word: str) -> str:
    return word[:-1] if len(word) > 3 and word.endswith("s") else word


def _words(text: str) -> list[str]:
    return [_stem(w) for w in re.findall(r"[a-z0-9]+", text.lower())]


def test_no_label_is_defined_twice():
    twice = []
    for label, places in _definitions().items():
        docs = [doc for doc, _ in places]
        if _is_experiment(label):
            # An experiment has one entry in the catalogue; targets.md has a section per experiment.
            docs = [d for d in docs if d != "reference/targets.md"]
        if len(docs) > 1:
            twice.append(f"{label}: {docs}")
    assert _definitions(), "docs/ defines labelled entries"
    assert not twice, "a label is defined once across docs/:\n" + "\n".join(sorted(twice))


def _citations(text: str):
    """(label, last label of a range or None, start, end) of every label-like word that is a citation."""
    for m in _CITED.finditer(text):
        line_start = text.rfind("\n", 0, m.start()) + 1
        if re.match(r"#+\s+" + re.escape(m.group(1)) + r"\b", text[line_start:]):
            continue  # the entry's own heading
        window = text[max(0, m.start() - 20):m.end() + 20]
        offset = m.start() - max(0, m.start() - 20)
        if any(p.start() == offset for rx in _NOT_CITATION for p in rx.finditer(window)):
            continue
        yield m.group(1), m.group(2), m.start(), m.end()


def test_every_cited_doc_and_entry_exists():
    files = _tracked()
    assert (ROOT / "docs" / "README.md").is_file(), "docs/README.md indexes docs/"
    defined = _definitions()
    missing = []
    cited = 0
    for f in files:
        text = f.read_text(encoding="utf-8")
        for m in _DOC.finditer(text):
            cited += 1
            if not (ROOT / "docs" / m.group(1)).is_file():
                missing.append(f"{f.relative_to(ROOT)}: docs/{m.group(1)} does not exist")
                continue
            # "<page>, <name> (L)": the first label after the comma, up to a ';' or the end of
            # the enclosing parenthesis, is an entry of that page (an experiment id in a name,
            # "profile of E5.4 (P12)", is not, except in the pages that hold experiments).
            rest = text[m.end():m.end() + 200]
            if not re.match(r"`?\)?,\s", rest):
                continue
            depth, end = 0, len(rest)
            for i, ch in enumerate(rest):
                depth += {"(": 1, ")": -1}.get(ch, 0)
                if depth < 0 or ch == ";" or rest.startswith("docs/", i):
                    end = i
                    break
            pages_of_experiments = ("reference/experiments.md", "reference/targets.md")
            first = next((c for c in _citations(rest[:end])
                          if not _is_experiment(c[0]) or m.group(1) in pages_of_experiments), None)
            if first is None:
                continue
            for label in filter(None, first[:2]):
                if m.group(1) not in [d for d, _ in defined.get(label, [])]:
                    missing.append(f"{f.relative_to(ROOT)}: docs/{m.group(1)} has no entry {label}")
    assert cited > 0, "the code cites docs/ somewhere"
    assert not missing, "\n".join(sorted(set(missing)))


_SECTION = re.compile(r'docs/((?:[\w.-]+/)?[\w.-]+\.md)`?,?\s+"([^"]+)"')


def test_every_cited_section_exists():
    """A section cited by its title, ``docs/reference/faults.md, "Gone quiet"``, is there: a
    heading (after its label, if any), a bold lead-in, a bullet or a line starts with it."""
    missing = []
    for f in _tracked():
        text = f.read_text(encoding="utf-8")
        for m in _SECTION.finditer(text):
            doc = ROOT / "docs" / m.group(1)
            if not doc.is_file():
                continue  # test_every_cited_doc_and_entry_exists reports it
            title = re.sub(r"\s*\n\s*(?:#+|\*)?\s*", " ", m.group(2)).strip().lower()
            page = doc.read_text(encoding="utf-8").lower()
            words = r"\s+".join(re.escape(w) for w in title.split())
            if not re.search(r"(?m)(?:^#+\s+(?:[a-z]\d+ — )?|\*\*|^- |^)(?:the )?" + words, page):
                missing.append(f"{f.relative_to(ROOT)}: docs/{m.group(1)} has no section {m.group(2)!r}")
    assert not missing, "\n".join(sorted(set(missing)))


def _unnamed(text: str, label: str, last: str | None, start: int) -> str | None:
    """Why the citation of label (or the range label-last) at start lacks its name, or None."""
    labels = _span(label, last) if last else [label]
    if not labels:
        return f"{label} is not an entry of docs/"
    heading = {w for lbl in labels for _, h in _definitions()[lbl] for w in _words(h)}
    before = re.sub(r"\n\s*(?:#+|//|\*|>|-|\|)?", " ", text[max(0, start - 240):start])
    found: set[str] = set()
    for word in reversed(_words(before)):
        if word in heading:
            if not word.isdigit():
                found.add(word)
        elif word not in _SMALL:
            break
    if len(found) < 2:
        return f"{label}{'-' + last if last else ''} needs a name from its heading before it"
    return None


def test_every_label_is_cited_with_its_name():
    bad = []
    for f in _tracked():
        rel = str(f.relative_to(ROOT))
        if rel in ("docs/README.md", "tests/unit/test_standalone.py"):
            continue  # the index lists ranges (test_docs_index_lists_every_doc); this file has bad examples
        text = f.read_text(encoding="utf-8")
        for label, last, start, _ in _citations(text):
            if _is_experiment(label) or label not in _definitions():
                continue  # experiment ids are names; an undefined token is not a docs label
            why = _unnamed(text, label, last, start)
            if why:
                line = text.count("\n", 0, start) + 1
                bad.append(f"{rel}:{line}: {why}")
    assert not bad, ("cite a label as '<name from its heading> (L)':\n" + "\n".join(bad))


def test_the_name_rule_rejects_a_bare_label():
    """The check itself: a bare label and a wrong name fail, a heading's words pass."""
    label = "A38"
    assert label in _definitions(), "docs/reference/ambiguities.md has entry A38"
    text = "merges skip them (A38) and docs/reference/ambiguities.md, A38; wrong words here (A38)"
    starts = [m.start() for m in re.finditer(label, text)]
    assert all(_unnamed(text, label, None, s) for s in starts)
    named = "docs/reference/ambiguities.md, robot lost in role assignment (A38)"
    assert _unnamed(named, label, None, named.index(label)) is None


def _listed(row: str, doc: str) -> set[str]:
    """The labels an index row lists for doc: items "X1-X9" or "X1", comma-separated."""
    cell = row.rstrip().rstrip("|").rsplit("|", 1)[-1]
    out = set()
    for first, last in re.findall(r"(" + _LABEL + r")(?:-(" + _LABEL + r"))?", cell):
        defined_here = {lbl for lbl, places in _definitions().items() if doc in [d for d, _ in places]}
        if last:
            span = {lbl for lbl in defined_here if lbl[0] == first[0] and _key(first) <= _key(lbl) <= _key(last)}
            out |= span | {first, last}
        else:
            out.add(first)
    return out


def test_docs_index_lists_every_doc():
    index = (ROOT / "docs" / "README.md").read_text(encoding="utf-8")
    docs = sorted(str(p.relative_to(ROOT / "docs")) for p in _docs())
    assert docs, "docs/ holds topic files"
    unlisted = [name for name in docs if f"({name})" not in index]
    assert not unlisted, f"docs/README.md does not link {unlisted}"
    wrong = []
    for name in docs:
        rows = [line for line in index.splitlines() if line.startswith("| [") and f"({name})" in line.split("|")[1]]
        assert rows, f"docs/README.md has a table row for {name}"
        defined = {lbl for lbl, places in _definitions().items() if name in [d for d, _ in places]}
        listed = _listed(rows[0], name)
        if listed != defined:
            wrong.append(f"{name}: index lists {sorted(listed - defined, key=_key)} not defined, "
                         f"misses {sorted(defined - listed, key=_key)}")
    assert not wrong, "docs/README.md's entry ranges:\n" + "\n".join(wrong)


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


def test_architecture_names_every_folder_and_only_folders_that_exist():
    """docs/reference/architecture.md's folder table is kept true: every folder it names
    exists (``<family>`` stands for each folder of agent/controllers/), and every tracked
    folder one or two levels down is named there."""
    page = (ROOT / "docs" / "reference" / "architecture.md").read_text(encoding="utf-8")
    table = page[page.index("## Folders"):]
    named = re.findall(r"^\|\s*`([\w./<>-]+/)`\s*\|", table, re.M)
    assert named, "architecture.md has a folder table"
    missing = []
    for folder in named:
        if "<" in folder:
            parent = ROOT / folder.split("<")[0]
            if not any(p.is_dir() and (p / "__init__.py").is_file() for p in parent.iterdir()):
                missing.append(f"{folder}: no such folder under {parent.relative_to(ROOT)}")
        elif not (ROOT / folder).is_dir():
            missing.append(f"{folder} does not exist")
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    folders = set()
    for line in out.splitlines():
        parts = line.split("/")[:-1]
        if parts and not parts[0].startswith("."):
            folders.update("/".join(parts[:n]) + "/" for n in (1, 2) if len(parts) >= n)
    unnamed = sorted(f for f in folders if f not in named and (ROOT / f).is_dir())
    assert not missing, "architecture.md names folders that do not exist:\n" + "\n".join(missing)
    assert not unnamed, f"architecture.md's folder table does not name {unnamed}"
