"""The paper is cited by title, authors and arXiv id, the same in README, the docs' BibTeX and
CITATION.cff."""

import re
from pathlib import Path

import yaml

ROOT = Path(__file__).parents[1]
CFF = yaml.safe_load((ROOT / "CITATION.cff").read_text())
PAPER = CFF["references"][0]


def test_citation_file_and_readme_name_the_same_paper():
    readme = " ".join((ROOT / "README.md").read_text().split())
    assert CFF["cff-version"] == "1.2.0" and CFF["type"] == "software"
    assert PAPER["title"] in readme and PAPER["identifiers"][0]["value"] in readme
    assert all(author["family-names"] in readme for author in PAPER["authors"])
    assert "shared/reference" not in readme


def _bibtex(kind: str) -> dict[str, str]:
    """The fields of the docs' BibTeX entry of this kind (`misc`: the paper; `software`)."""
    page = (ROOT / "docs" / "citing.md").read_text()
    entry = re.search(rf"```bibtex\n@{kind}\{{.*?\n\}}\n```", page, re.S).group(0)
    return dict(re.findall(r"^\s+(\w+)\s+= \{(.*)\},?$", entry, re.M))


def test_the_docs_bibtex_is_citation_cffs_paper_and_software():
    paper = _bibtex("misc")
    authors = " and ".join(f"{a['family-names']}, {a['given-names']}" for a in PAPER["authors"])
    assert paper["title"] == PAPER["title"] and paper["author"] == authors
    assert paper["year"] == str(PAPER["year"]) and paper["url"] == PAPER["url"]
    assert f"{paper['archivePrefix']}:{paper['eprint']}" == PAPER["identifiers"][0]["value"]
    software = _bibtex("software")
    assert software["title"] == CFF["title"] and software["version"] == CFF["version"]
