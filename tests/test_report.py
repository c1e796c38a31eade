"""Text for people: the notes under a verdict say what is true for its number of tickets, and the
docs site shows program output such as the verdict table whole."""

import re
from pathlib import Path

import pytest

from goldenticket.evaluation import p_value_note

ROOT = Path(__file__).parents[1]


def test_the_p_value_note_says_holm_only_where_it_adjusts_something():
    one = p_value_note(1)
    assert "Holm" not in one and "1 tickets" not in one and "one ticket" in one
    assert "Holm-adjusted over the 3 tickets tested" in p_value_note(3) and "Holm" not in p_value_note(0)


def test_the_docs_site_sets_text_blocks_small_enough_for_the_verdict_table():
    config = pytest.importorskip("mkdocs.config").load_config(str(ROOT / "mkdocs.yml"))
    css = "".join((Path(config.docs_dir) / path).read_text() for path in config.extra_css)
    rule = re.search(r"\.language-text[^{]*code\s*\{[^}]*font-size:\s*([\d.]+)rem", css)
    assert rule and float(rule.group(1)) < 0.68  # material's code size: 0.85 x 0.8rem
    assert config.mdx_configs["pymdownx.highlight"]["pygments_lang_class"]  # the class the rule names
    assert re.search(r"--8<-- \[start:verdict\] -->\n```text\n", (ROOT / "README.md").read_text())
