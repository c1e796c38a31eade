"""MkDocs hooks, run when the site builds: the command-line reference from goldenticket's own
argparse parsers, the output of listing commands where a page asks for it, and the benchmark
figures served from benchmarks/results/ (no copies under docs/)."""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import re
import shlex
from collections.abc import Iterator
from pathlib import Path

RESULTS = Path(__file__).parents[1] / "benchmarks" / "results"
CLI_MARKER = "<!-- the command-line reference, generated from goldenticket.cli -->"
OUTPUT = re.compile(r"<!-- output of: goldenticket (.+?) -->")
WIDTH = 100  # help text wrapped as on a terminal this wide, whatever the terminal building the site


def commands(parser: argparse.ArgumentParser, words: tuple[str, ...] = (), summary: str = "",
             ) -> Iterator[tuple[tuple[str, ...], str, argparse.ArgumentParser]]:
    """Every command line under `parser`, depth first: its words, one-line summary and parser."""
    yield words, summary, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help for choice in action._choices_actions}
            for name, sub in action.choices.items():
                yield from commands(sub, (*words, name), helps.get(name) or "")


def cli_reference() -> str:
    """One section per command: its summary and its `--help`, as the installed CLI prints it."""
    from goldenticket.cli import _parser

    sections = []
    for words, summary, parser in commands(_parser()):
        parser.formatter_class = functools.partial(parser.formatter_class, width=WIDTH)
        title = " ".join(("goldenticket", *words))
        said = f"{summary}\n\n" if summary else ""
        sections.append(f"## {title}\n\n{said}```text\n{parser.format_help().rstrip()}\n```\n")
    return "\n".join(sections)


def output_of(match: re.Match) -> str:
    """What `goldenticket ARGS` prints (a listing: it runs no episode), as a text block."""
    from goldenticket.cli import main

    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(shlex.split(match.group(1)))
    if code != 0:
        raise RuntimeError(f"goldenticket {match.group(1)} exited with {code}")
    return f"```text\n{printed.getvalue().rstrip()}\n```"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if CLI_MARKER in markdown:
        markdown = markdown.replace(CLI_MARKER, cli_reference())
    return OUTPUT.sub(output_of, markdown)


def on_files(files, config):
    """benchmarks/results/*.png as results/img/<name>.png, for the results pages."""
    from mkdocs.structure.files import File

    for png in sorted(RESULTS.glob("*.png")):
        files.append(File.generated(config, f"results/img/{png.name}", abs_src_path=str(png)))
    return files
