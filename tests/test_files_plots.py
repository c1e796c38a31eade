"""Outputs replace only regular files, `evaluate` draws only where asked, and the pictures say
what they show."""

import json
import os
import socket
import stat
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from goldenticket import plots
from goldenticket.cli import main
from goldenticket.config import SearchConfig
from goldenticket.errors import UserError
from goldenticket.files import write_atomic
from goldenticket.job import find_golden_tickets
from goldenticket.stats import Rate

HERE = Path(__file__).parent
BYO = ["--policy", "byo_example:make_policy", "--task", "byo_example:make_env", "--max-steps", "10"]


def _socket(path: Path) -> None:
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(path))


def _link_to_file(path: Path) -> None:
    (path.parent / "real.txt").write_text("kept")
    path.symlink_to(path.parent / "real.txt")


def _link_to_fifo(path: Path) -> None:  # stands for a link to a device
    os.mkfifo(path.parent / "fifo")
    path.symlink_to(path.parent / "fifo")


@pytest.mark.parametrize("make", [os.mkfifo, os.mkdir, _socket, _link_to_file, _link_to_fifo],
                         ids=["fifo", "folder", "socket", "link-to-file", "link-to-fifo"])
def test_write_atomic_refuses_what_is_not_a_regular_file(tmp_path, make):
    target = tmp_path / "out.png"
    make(target)
    before = {p.name: (p.lstat().st_mode, p.is_symlink()) for p in tmp_path.iterdir()}
    with pytest.raises(UserError, match=str(target)):
        write_atomic(target, b"picture")
    assert {p.name: (p.lstat().st_mode, p.is_symlink()) for p in tmp_path.iterdir()} == before
    if (tmp_path / "real.txt").exists():
        assert (tmp_path / "real.txt").read_text() == "kept"


def test_write_atomic_replaces_a_regular_file(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    write_atomic(target, "new")
    assert target.read_text() == "new" and stat.S_ISREG(target.lstat().st_mode)
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


KILLED_WRITER = """
import os, sys, time
from goldenticket.files import write_atomic
os.fsync = lambda fd: (print("writing", flush=True), time.sleep(60))
write_atomic(sys.argv[1], b"half")
"""


def test_a_file_half_written_by_a_killed_process_is_removed_on_the_next_write(tmp_path):
    target = tmp_path / "tickets" / "abc.safetensors"
    writer = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(target)], stdout=subprocess.PIPE,
                              text=True)
    assert writer.stdout.readline() == "writing\n"
    writer.kill()
    writer.wait()
    assert len(list(target.parent.glob(".*.partial"))) == 1
    running = target.with_name(f".{target.name}.{os.getpid()}-0000.partial")  # a live writer's
    running.write_bytes(b"")
    write_atomic(target, b"whole")
    assert target.read_bytes() == b"whole"
    assert list(target.parent.glob(".*.partial")) == [running]


def test_evaluate_refuses_a_fifo_as_plot_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    fifo = tmp_path / "e.png"
    os.mkfifo(fifo)
    code = main(["evaluate", *BYO, "--seeds", "1000000:1000003", "--workers", "1", "--plot", str(fifo)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and str(fifo) in err
    assert stat.S_ISFIFO(fifo.lstat().st_mode)


@pytest.mark.slow
def test_evaluate_draws_no_picture_unless_asked(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    monkeypatch.chdir(tmp_path)
    assert main(["evaluate", *BYO, "--seeds", "1000000:1000003", "--workers", "1"]) == 0
    assert list(tmp_path.iterdir()) == [] and "Wrote" not in capsys.readouterr().out
    assert main(["evaluate", *BYO, "--seeds", "1000000:1000003", "--workers", "1", "--plot", "v.png"]) == 0
    assert (tmp_path / "v.png").read_bytes().startswith(b"\x89PNG")


@pytest.fixture
def drawn(monkeypatch) -> list:
    """Every figure the plots module saves, in order (nothing is written)."""
    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or path)
    return figures


def _rate(p: float, p_vs_base: float | None = None, golden: bool = False, low: float = 0.1,
          high: float = 0.1) -> SimpleNamespace:
    """An arm as arms_png reads it: a rate and whether it is golden."""
    return SimpleNamespace(rate=Rate(0, 20, p, max(p - low, 0), min(p + high, 1)), golden=golden)


def _legend(ax) -> list[str]:
    return [t.get_text() for t in ax.get_legend().get_texts()]


def _points(ax, label: str) -> list[tuple]:
    return [tuple(p) for c in ax.collections if c.get_label() == label for p in c.get_offsets()]


def test_verdict_legend_names_every_arm_and_the_base_line_and_stars_the_chosen_ticket(tmp_path, drawn):
    rows = {"base": _rate(0.5), "zero ticket": _rate(0.55, p_vs_base=0.4, golden=False),
            "ticket aaa": _rate(0.8, p_vs_base=0.01, golden=True),
            "ticket bbb": _rate(0.6, p_vs_base=0.3, golden=False)}
    plots.arms_png(rows, tmp_path / "v.png", "title", best="ticket bbb")
    ax = drawn[0].axes[0]
    assert _legend(ax) == ["base (Gaussian noise)", "zero ticket", "golden ticket", "ticket, not golden",
                           "base rate", "chosen ticket"]
    assert [t.get_text() for t in ax.get_yticklabels() if t.get_fontweight() == "bold"] == ["ticket bbb"]
    assert _points(ax, "chosen ticket") == [(0.6, 3)]


def test_verdict_without_zero_ticket_or_best_draws_what_it_has(tmp_path):
    rows = {"base": _rate(0.5), "ab12": _rate(0.7, p_vs_base=0.02, golden=True)}
    assert plots.arms_png(rows, tmp_path / "v.png", "session").read_bytes().startswith(b"\x89PNG")


def test_search_picture_marks_validated_judged_and_chosen_tickets_beside_the_heldout_rows(tmp_path, drawn):
    scores = [0.2, 0.9, 0.5, 0.7, 0.6, 0.8]
    rows = {"base": _rate(0.4), "zero ticket": _rate(0.5),
            "ticket ab12": _rate(0.7, p_vs_base=0.02, golden=True)}
    plots.search_png(scores, [5] * 6, tmp_path / "s.png", "title", validated=[1, 3, 5], judged=[3, 1],
                     chosen=3, heldout=(rows, "ticket ab12", "held-out seeds 1000000:1000010"))
    ax, side = drawn[0].axes
    assert ax.get_ylabel().startswith("search score")
    delivered = "delivered: the best on held-out seeds"
    assert _legend(ax) == ["ran 5 episodes, every search seed", "sent to validation",
                           "judged on held-out seeds", delivered]
    assert _points(ax, "sent to validation") == [(2, 0.9), (4, 0.7), (6, 0.8)]
    assert _points(ax, "judged on held-out seeds") == [(4, 0.7), (2, 0.9)]
    assert _points(ax, delivered) == [(4, 0.7)]
    assert side.get_title(loc="left") == "judged on held-out seeds 1000000:1000010"  # the base among them
    assert [t.get_text() for t in side.get_yticklabels()] == list(rows)
    assert [t.get_text() for t in side.get_yticklabels() if t.get_fontweight() == "bold"] == ["ticket ab12"]


def test_search_picture_shows_how_many_seeds_halving_let_each_ticket_run(tmp_path, drawn):
    plots.search_png([0.9, 0.3, 0.5, 0.6], [2, 4, 2, 8], tmp_path / "s.png", "title")
    ax = drawn[0].axes[0]
    assert len(drawn[0].axes) == 1 and not ax.lines  # no held-out panel yet, no line across tickets
    assert _legend(ax) == ["ran 2 episodes, then cut by halving", "ran 4 episodes, then cut by halving",
                           "ran 8 episodes, every search seed"]
    assert _points(ax, "ran 2 episodes, then cut by halving") == [(1, 0.9), (3, 0.5)]
    shades = [collection.get_facecolor()[0][1] for collection in ax.collections]
    assert shades == sorted(shades, reverse=True)  # darker green, more seeds run


@pytest.mark.slow
def test_search_marks_the_tickets_the_run_validated_and_judged(tmp_path, drawn, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    cfg = SearchConfig("byo_example:make_policy", "byo_example:make_env", method="rs", budget=30,
                       search_seeds=3, validation_seeds=3, heldout=5, top_k=2, workers=1, max_steps=10)
    summary = find_golden_tickets(cfg, tmp_path)
    verdict, search = (figure.axes[0] for figure in drawn)
    assert search.figure.axes[1].get_yticklabels()[0].get_text() == "base"
    best = summary.best
    assert [t.get_text() for t in verdict.get_yticklabels() if t.get_fontweight() == "bold"] == [best.label]
    assert len(_points(search, "sent to validation")) == 3 * cfg.top_k
    assert [y for _, y in _points(search, "judged on held-out seeds")] == [
        t.search_score for t in summary.tickets if t.source != "zero ticket"]  # the zero ticket: no search
    chosen = [] if best.source == "zero ticket" else [best.search_score]  # the zero ticket: not searched
    assert [y for _, y in _points(search, "delivered: the best on held-out seeds")] == chosen


def test_existence_figure_titles_fit_in_the_picture(monkeypatch):
    monkeypatch.syspath_prepend(str(HERE.parent / "benchmarks"))
    import existence

    record = json.loads((HERE.parent / "benchmarks" / "results" / "existence.json").read_text())
    fig = existence.figure(record["pairs"])
    fig.draw_without_rendering()
    for ax in fig.axes:
        box = ax.title.get_window_extent()
        assert box.x0 >= 0 and box.x1 <= fig.bbox.x1, ax.get_title()


def test_verdict_draws_the_zero_ticket_once_where_it_was_judged_as_a_ticket(tmp_path, drawn):
    from goldenticket.evaluation import VerdictRow
    from goldenticket.results import FoundTicket, SearchRun, Summary
    from goldenticket.tickets import ZERO_SOURCE

    def row(k, p=None):
        return VerdictRow(Rate.counted(k, 20), p_vs_base=p)

    tickets = (FoundTicket("81be", "z", None, row(12, 0.4), source=ZERO_SOURCE),
               FoundTicket("aaa", "a", 0.5, row(11, 0.6)))
    summary = Summary("task", SearchRun("p", "rs", 0, 8, "budget", (0, 19)), row(10), row(12, 0.2), tickets)
    plots.arms_png(summary.table().rows(), tmp_path / "v.png", "title", best=summary.best.label)
    ax = drawn[0].axes[0]
    assert [t.get_text() for t in ax.get_yticklabels()] == ["base", "zero ticket", "ticket aaa"]
    assert len(ax.containers) == 3 and _points(ax, "chosen ticket") == [(0.6, 1)]


def test_verdict_success_axis_stays_within_0_and_100_percent(tmp_path, drawn):
    rows = {"base": _rate(0.0), "ticket aaa": _rate(1.0, golden=True)}
    plots.arms_png(rows, tmp_path / "v.png", "title")
    ax = drawn[0].axes[0]
    assert ax.spines["bottom"].get_bounds() == (0, 1) and not ax.spines["top"].get_visible()
    assert all(0 <= tick <= 1 for tick in ax.get_xticks())
    assert -0.05 < ax.get_xlim()[0] < 0 and 1 < ax.get_xlim()[1] < 1.05  # room for a marker's radius only
