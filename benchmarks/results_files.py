"""Where every benchmark leaves its results: benchmarks/results/<name>.{json,md,png}."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from goldenticket.files import write_atomic

RESULTS = Path(__file__).parent / "results"


def write_results(name: str, record: dict, markdown: str, plot: Callable[[Path], None] | None = None) -> None:
    """The run's record as JSON, its table as Markdown, its figure as PNG (if it has a `plot`); the
    table printed."""
    write_atomic(RESULTS / f"{name}.json", json.dumps(record, indent=2) + "\n")
    write_atomic(RESULTS / f"{name}.md", markdown)
    if plot is not None:
        plot(RESULTS / f"{name}.png")
    print(markdown)
