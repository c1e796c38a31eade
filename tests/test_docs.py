"""The documentation site's sources: a CLI reference generated from the parsers, every benchmark
result on a results page, README sections the pages include, and no tracker talk anywhere.
CI builds the site itself with `mkdocs build --strict` (broken links, anchors, pages left out)."""

import argparse
import importlib.util
import re
from pathlib import Path

from goldenticket.cli import _parser

ROOT = Path(__file__).parents[1]
DOCS = ROOT / "docs"


def _hooks():
    spec = importlib.util.spec_from_file_location("docs_hooks", DOCS / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    return hooks


def test_the_cli_reference_has_every_command_and_option_the_parsers_have():
    hooks = _hooks()
    page = hooks.on_page_markdown((DOCS / "reference" / "cli.md").read_text(), None, None, None)
    assert hooks.CLI_MARKER not in page
    for words, _, parser in hooks.commands(_parser()):
        section = page.split(f"## {' '.join(('goldenticket', *words))}\n")[1].split("\n## ")[0]
        options = [s for a in parser._actions if not isinstance(a, argparse._SubParsersAction)
                   for s in a.option_strings]
        assert all(option in section for option in options), words
    assert "## goldenticket session new\n" in page and "--validation-seeds" in page


def test_listing_commands_are_printed_into_their_pages():
    page = _hooks().on_page_markdown("<!-- output of: goldenticket tickets list -->", None, None, None)
    assert page.startswith("```text\npolicy ") and "ac7033f127b8" in page and "1000000:1000200" in page


def test_every_benchmark_result_is_on_a_results_page():
    pages = "\n".join(p.read_text() for p in (DOCS / "results").glob("*.md"))
    for result in (ROOT / "benchmarks" / "results").glob("*.md"):
        assert f'--8<-- "{result.name}"' in pages, result.name
    for figure in (ROOT / "benchmarks" / "results").glob("*.png"):
        assert f"(img/{figure.name})" in pages, figure.name


def test_every_readme_section_a_page_includes_is_marked_in_readme():
    readme = (ROOT / "README.md").read_text()
    included = {name for page in DOCS.rglob("*.md")
                for name in re.findall(r'^--8<-- "README\.md:([\w-]+)"$', page.read_text(), re.M)}
    assert included
    for name in included:
        start, end = f"<!-- --8<-- [start:{name}] -->", f"<!-- --8<-- [end:{name}] -->"
        assert readme.count(start) == readme.count(end) == 1 and readme.index(start) < readme.index(end)
        assert "](" not in readme.split(start)[1].split(end)[0], f"{name}: a link would not resolve in docs/"


def test_no_tracker_numbers_in_the_repositorys_text():
    folders = ("src", "tests", "benchmarks", "examples", "docs")
    texts = [ROOT / "README.md", *DOCS.rglob("*.md"), *(ROOT / "benchmarks").rglob("*.md"),
             *(p for folder in folders for p in (ROOT / folder).rglob("*.py"))]
    tracker = re.compile(r"\b(issues?|PR|pull request|bug|ticket)\s*#\s*\d+|\bissue\s+\d+"
                         r"|(?<![\w&#\"'])#\d{1,5}\b", re.I)
    found = [f"{p.relative_to(ROOT)}: {m.group(0)}" for p in texts for m in tracker.finditer(p.read_text())]
    assert not found


def test_the_concepts_page_lists_every_search_methods_settings_with_their_defaults():
    from dataclasses import fields

    from goldenticket.config import METHODS

    page = (ROOT / "docs" / "concepts.md").read_text()
    for name, cls in METHODS.items():
        for f in fields(cls):
            default = "-" if f.default is None else f.default
            own = f"| `{name}` | `{f.name}` | {default} |"
            inherited = [base for base in METHODS if f"| `{name}` | and every `{base}` setting" in page]
            assert own in page or any(f"| `{base}` | `{f.name}` | {default} |" in page for base in inherited)
