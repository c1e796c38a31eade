"""The paper is cited by title, authors and arXiv id, the same in README and CITATION.cff."""

from pathlib import Path

import yaml

ROOT = Path(__file__).parents[1]


def test_citation_file_and_readme_name_the_same_paper():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    paper = cff["references"][0]
    readme = " ".join((ROOT / "README.md").read_text().split())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert paper["title"] in readme and paper["identifiers"][0]["value"] in readme
    assert all(author["family-names"] in readme for author in paper["authors"])
    assert "shared/reference" not in readme
