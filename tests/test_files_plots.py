"""Outputs replace only regular files, `evaluate` draws only where asked, and the pictures say
what they show."""

import json
import os
import socket
import stat
from pathlib import Path
from types import SimpleNamespace

import numpy as np
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


def test_search_picture_marks_validated_judged_and_chosen_tickets_and_the_base(tmp_path, drawn):
    scores = [0.2, 0.9, 0.5, 0.7, 0.6, 0.8]
    plots.search_png(scores, [5] * 6, tmp_path / "s.png", "title", validated=[1, 3, 5], judged=[3, 1],
                     chosen=3, base=(0.4, "held-out seeds 1000000:1000010"))
    ax = drawn[0].axes[0]
    assert ax.get_ylabel().startswith("search score")
    delivered = "delivered (chosen on validation seeds,\nthen best held-out success)"
    assert _legend(ax) == ["ticket, 5 episodes", "best so far (5 episodes)",
                           "base policy on held-out seeds 1000000:1000010", "sent to validation",
                           "judged on held-out seeds", delivered]
    assert _points(ax, "sent to validation") == [(2, 0.9), (4, 0.7), (6, 0.8)]
    assert _points(ax, "judged on held-out seeds") == [(4, 0.7), (2, 0.9)]
    assert _points(ax, delivered) == [(4, 0.7)]


def test_search_picture_tells_tickets_with_fewer_episodes_apart(tmp_path, drawn):
    plots.search_png([0.9, 0.3, 0.5], [2, 4, 4], tmp_path / "s.png", "title")
    ax = drawn[0].axes[0]
    assert _legend(ax) == ["ticket, 4 episodes", "ticket, fewer episodes", "best so far (4 episodes)"]
    assert _points(ax, "ticket, fewer episodes") == [(1, 0.9)]
    assert np.array_equal(ax.lines[0].get_ydata(), [np.nan, 0.3, 0.5], equal_nan=True)


@pytest.mark.slow
def test_search_marks_the_tickets_the_run_validated_and_judged(tmp_path, drawn, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    cfg = SearchConfig("byo_example:make_policy", "byo_example:make_env", method="rs", budget=30,
                       search_seeds=3, validation_seeds=3, heldout=5, top_k=2, workers=1, max_steps=10)
    summary = find_golden_tickets(cfg, tmp_path)
    verdict, search = (figure.axes[0] for figure in drawn)
    best = summary.best
    assert [t.get_text() for t in verdict.get_yticklabels() if t.get_fontweight() == "bold"] == [
        f"ticket {best.label}"]
    assert len(_points(search, "sent to validation")) == 3 * cfg.top_k
    assert [y for _, y in _points(search, "judged on held-out seeds")] == [
        t.search_score for t in summary.tickets if t.source != "zero ticket"]  # the zero ticket: no search
    chosen = [] if best.source == "zero ticket" else [best.search_score]  # the zero ticket: not searched
    delivered = "delivered (chosen on validation seeds,\nthen best held-out success)"
    assert [y for _, y in _points(search, delivered)] == chosen
    base_line = next(line for line in search.lines if line.get_label().startswith("base policy"))
    assert base_line.get_ydata()[0] == summary.base.rate.success_rate  # objective "success"


def test_existence_figure_titles_fit_in_the_picture(monkeypatch):
    monkeypatch.syspath_prepend(str(HERE.parent / "benchmarks"))
    import existence

    record = json.loads((HERE.parent / "benchmarks" / "results" / "existence.json").read_text())
    fig = existence.figure(record["pairs"])
    fig.draw_without_rendering()
    for ax in fig.axes:
        box = ax.title.get_window_extent()
        assert box.x0 >= 0 and box.x1 <= fig.bbox.x1, ax.get_title()


def test_search_picture_sets_the_base_apart_from_the_search_scores(tmp_path, drawn):
    plots.search_png([0.2, 0.9, 0.5], [5] * 3, tmp_path / "s.png", "title",
                     base=(0.4, "held-out seeds 1000000:1000010"))
    ax = drawn[0].axes[0]
    base = next(line for line in ax.lines if line.get_label().startswith("base"))
    assert base.get_label() == "base policy on held-out seeds 1000000:1000010"
    assert list(base.get_xdata()) == [1.0] and base.get_linestyle() == "None"  # at the right margin
    assert base.get_transform().contains_branch_seperately(ax.transData) == (False, True)  # x: axes


@pytest.mark.parametrize(("validated", "said"), [([1, 2], "chosen on validation seeds"), ([], "held-out")])
def test_search_picture_says_how_the_delivered_ticket_was_chosen(tmp_path, drawn, validated, said):
    plots.search_png([0.2, 0.9, 0.5], [5] * 3, tmp_path / "s.png", "title", validated=validated, judged=[2],
                     chosen=2)
    star = next(label for label in _legend(drawn[0].axes[0]) if label.startswith("delivered"))
    assert said in star and ("validation" in star) == bool(validated)


def test_verdict_draws_the_zero_ticket_once(tmp_path, drawn):
    rows = {"base": _rate(0.5), "zero ticket": _rate(0.55, p_vs_base=0.2, golden=False),
            "ticket aaa": _rate(0.6, p_vs_base=0.3, golden=False),
            "ticket 81be (w = 0)": _rate(0.55, p_vs_base=0.4, golden=False)}
    plots.arms_png(rows, tmp_path / "v.png", "title", best="ticket 81be (w = 0)")
    ax = drawn[0].axes[0]
    assert [t.get_text() for t in ax.get_yticklabels()] == ["base", "ticket aaa", "ticket 81be (w = 0)"]
    assert len(ax.containers) == 3 and _points(ax, "chosen ticket") == [(0.55, 2)]
    assert "zero ticket" in _legend(ax)  # drawn in the zero ticket's colour


def test_verdict_success_axis_stays_within_0_and_100_percent(tmp_path, drawn):
    rows = {"base": _rate(0.0), "ticket aaa": _rate(1.0, golden=True)}
    plots.arms_png(rows, tmp_path / "v.png", "title")
    ax = drawn[0].axes[0]
    assert ax.spines["bottom"].get_bounds() == (0, 1) and not ax.spines["top"].get_visible()
    assert all(0 <= tick <= 1 for tick in ax.get_xticks())
    assert -0.05 < ax.get_xlim()[0] < 0 and 1 < ax.get_xlim()[1] < 1.05  # room for a marker's radius only
