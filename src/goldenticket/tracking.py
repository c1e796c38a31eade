"""A search's numbers as it runs: `log.csv` in its folder always, TensorBoard and Weights & Biases
(offline) when asked for, and `search.png` redrawn every few seconds. It only observes: nothing here
changes a recorded number (docs/logging.md)."""

from __future__ import annotations

import csv
import time
import tomllib
from collections.abc import Callable
from dataclasses import astuple, dataclass
from pathlib import Path

import numpy as np

from goldenticket.config import SearchConfig, to_toml
from goldenticket.evaluation import BASE, ZERO, to_dicts
from goldenticket.files import check_target
from goldenticket.plots import search_png
from goldenticket.results import MultitaskSummary, Summary
from goldenticket.ticket_search import Candidate, EpisodeOutcome, Query
from goldenticket.tickets import Ticket, ticket_id

REDRAW_SECONDS = 10.0  # search.png at most this often while the search runs (a drawing takes ~0.3 s)


@dataclass(frozen=True)
class Row:
    """One number: its stage (search, validation, verdict), the search's generation and episodes so
    far, the arm (a ticket id, base, zero, or best), what is measured, and, in a multi-task run's
    per-task verdict, the task."""

    stage: str
    step: int
    episodes: int
    task: str
    arm: str
    metric: str
    value: float

    @property
    def tag(self) -> str:
        """Its name in TensorBoard and W&B: stage/task/arm/metric."""
        return "/".join(part for part in (self.stage, self.task, self.arm, self.metric) if part)


COLUMNS = tuple(Row.__dataclass_fields__)


class CsvSink:
    """log.csv: one row per number, flushed as written, so `tail -f` follows a search. Always a new
    file (a rerun replays the run from its store: a new log), never one written through a hard link
    to another file."""

    def __init__(self, path: Path):
        check_target(path)
        path.unlink(missing_ok=True)
        self.file = path.open("x", newline="")
        self.writer = csv.writer(self.file)
        self.writer.writerow(COLUMNS)

    def write(self, rows: list[Row]) -> None:
        self.writer.writerows(map(astuple, rows))
        self.file.flush()

    def close(self, failed: bool = False) -> None:
        self.file.close()


def _split(rows: list[Row]) -> tuple[dict[str, float], list[float]]:
    """Scalars by tag, but a search generation's ticket scores as one list (a histogram there)."""
    def per_ticket(row: Row) -> bool:
        return row.stage == "search" and row.arm != "best"
    scalars = {r.tag: r.value for r in rows if not per_ticket(r)}
    return scalars, [r.value for r in rows if per_ticket(r) and r.metric == "score"]


class TensorBoardSink:
    """Event files in --out/tensorboard, step = search episodes; a rerun supersedes the last run."""

    def __init__(self, out: Path, cfg: SearchConfig):
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(str(out / "tensorboard"), purge_step=0)

    def write(self, rows: list[Row]) -> None:
        scalars, scores = _split(rows)
        for tag, value in scalars.items():
            self.writer.add_scalar(tag, value, rows[0].episodes)
        if scores:
            self.writer.add_histogram("search/scores", np.asarray(scores), rows[0].episodes)
        self.writer.flush()

    def close(self, failed: bool = False) -> None:
        self.writer.close()


class WandbSink:
    """An offline W&B run in --out/wandb (never the network; `wandb sync` uploads it), step =
    search episodes, the run's config as its config; a run of the user's own is left alone."""

    def __init__(self, out: Path, cfg: SearchConfig):
        import wandb

        self.wandb = wandb
        settings = wandb.Settings(mode="offline", silent=True, console="off", x_disable_stats=True,
                                  disable_git=True, save_code=False, disable_job_creation=True)
        self.run = wandb.init(dir=out, project="goldenticket", name=out.resolve().name, reinit="create_new",
                              config=tomllib.loads(to_toml(cfg)), settings=settings)

    def write(self, rows: list[Row]) -> None:
        scalars, scores = _split(rows)
        histogram = {"search/scores": self.wandb.Histogram(scores)} if scores else {}
        self.run.log(scalars | histogram, step=rows[0].episodes)

    def close(self, failed: bool = False) -> None:
        self.run.finish(exit_code=int(failed))


OPEN = {"tensorboard": TensorBoardSink, "wandb": WandbSink}  # config.SINKS: the packages they need


class Tracker:
    """What a search job reports as it goes: each generation of the search (`watch`), the validation
    scores (`validated`) and the verdict (`finish`, which closes the sinks); as a context manager it
    closes them if the job fails."""

    def __init__(self, cfg: SearchConfig, out: Path, title: str):
        self.out, self.title = out, title
        self.sinks = [CsvSink(out / "log.csv")] + [OPEN[name](out, cfg) for name in cfg.log]
        self.found: dict[bytes, Candidate] = {}
        self.step = self.episodes = 0
        self.drawn = time.monotonic()

    def __enter__(self) -> Tracker:
        return self

    def __exit__(self, kind, error, traceback) -> None:
        if error is not None:
            self._close(failed=True)

    def watch(self, evaluate: Callable[[list[Query]], list[EpisodeOutcome]], expand: Callable,
              fingerprint: str) -> Callable[[list[Query]], list[EpisodeOutcome]]:
        """The search driver's `evaluate`, logging each generation (one evaluated ask) as it ends;
        a ticket is named by its id: `expand` makes the ticket of a searched array, for the policy
        `fingerprint`."""
        def name(searched: np.ndarray) -> str:
            return ticket_id(expand(searched), fingerprint)

        def watched(queries: list[Query]) -> list[EpisodeOutcome]:
            outcomes = evaluate(queries)
            self._generation(queries, outcomes, name)
            return outcomes
        return watched

    def _generation(self, queries: list[Query], outcomes: list[EpisodeOutcome], name: Callable) -> None:
        """Each ticket of the generation: its search score (mean return over all its search episodes,
        as the driver counts them) and episodes so far; and the best score among the tickets with the
        most episodes (search.png's best so far). Redraws search.png when it is due."""
        self.step += 1
        tried = {}
        for query, outcome in zip(queries, outcomes, strict=True):
            key = query.ticket.tobytes()
            tried[key] = self.found.setdefault(key, Candidate(query.ticket))
            tried[key].returns += [float(r) for r in outcome.returns]
            self.episodes += len(query.seeds)
        full = max(c.n for c in self.found.values())
        best = max(c.mean_return for c in self.found.values() if c.n == full)
        self._write(self._rows("search", [(name(c.ticket), metric, value) for c in tried.values()
                                          for metric, value in (("score", c.mean_return), ("episodes", c.n))]
                               + [("best", "score", best)]))
        if time.monotonic() - self.drawn >= REDRAW_SECONDS:
            self._draw()

    def _draw(self) -> None:
        candidates = list(self.found.values())
        search_png([c.mean_return for c in candidates], [c.n for c in candidates], self.out / "search.png",
                   self.title)
        self.drawn = time.monotonic()

    def validated(self, tickets: list[Ticket]) -> None:
        """The validation score of each ticket that ran on the validation seeds."""
        self._write(self._rows("validation", [(t.id, "score", t.record.validation_score)
                                              for t in tickets if t.record.validation_score is not None]))

    def finish(self, summary: Summary | MultitaskSummary) -> None:
        """Every number of the verdict (as summary.json has it), per arm; then close the sinks."""
        if isinstance(summary, MultitaskSummary):  # the task average, then each task's own
            verdict = summary.verdict
            rows = self._rows("verdict", _numbers(to_dicts(verdict.average))) + [
                row for task, arms in verdict.tasks.items() 
                for row in self._rows("verdict", _numbers(to_dicts(arms)), task)]
        else:
            arms = {BASE.key: summary.base.to_dict(), ZERO.key: summary.zero.to_dict()}
            rows = self._rows("verdict", _numbers(arms | {t.id: t.to_dict() for t in summary.tickets}))
        self._write(rows)
        self._close()

    def _rows(self, stage: str, numbers: list[tuple[str, str, float]], task: str = "") -> list[Row]:
        """(arm, metric, value) `numbers` as rows of `stage` at the search's generation and episodes."""
        return [Row(stage, self.step, self.episodes, task, *number) for number in numbers]

    def _write(self, rows: list[Row]) -> None:
        for sink in self.sinks if rows else ():
            sink.write(rows)

    def _close(self, failed: bool = False) -> None:
        for sink in self.sinks:
            sink.close(failed)
        self.sinks = []


def _numbers(arms: dict[str, dict]) -> list[tuple[str, str, float]]:
    """Every number of each arm's verdict (a flag as 0 or 1), as (arm, metric, value)."""
    return [(arm, metric, int(value) if isinstance(value, bool) else value)
            for arm, row in arms.items() for metric, value in row.items()
            if isinstance(value, int | float)]
