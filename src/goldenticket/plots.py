"""Pictures for people: held-out success per arm with intervals, and the search's progress."""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from matplotlib import colormaps
from matplotlib.container import ErrorbarContainer
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import PercentFormatter

from goldenticket.evaluation import BASE, ZERO
from goldenticket.files import write_atomic
from goldenticket.report import gain_text, short_task
from goldenticket.stats import Rate

if TYPE_CHECKING:
    from goldenticket.evaluation import MultitaskVerdict
    from goldenticket.results import Comparison, ParetoFront, TransferStudy

COLORS = {"base": "0.45", "zero ticket": "tab:blue", "golden": "goldenrod", "ticket": "tab:green"}
ARMS = {"base": "base (Gaussian noise)", "zero ticket": "zero ticket", "golden": "golden ticket",
        "ticket": "ticket, not golden"}
SIDES = {"A": "tab:blue", "B": "0.45"}  # a comparison's arms, neither significantly better
GREENS = colormaps["Greens"]  # search scores: darker, more search seeds run
LABEL_BOX = {"boxstyle": "square,pad=0.1", "facecolor": "white", "edgecolor": "none"}  # over the base line


class Arm(Protocol):
    """What a verdict picture draws of an arm: an `evaluation.VerdictRow`, or a session's arm."""

    rate: Rate
    golden: bool


def arms_png(rows: dict[str, Arm], path: Path, title: str, what: str = "held-out success",
             unit: str = "seeds", best: str | None = None) -> Path:
    """One row per arm (base, zero ticket, tickets): held-out success with its 95% Wilson
    interval on an axis from 0% to 100%; golden tickets in gold, the base rate as a dashed line,
    the row labelled `best` (the chosen ticket) starred and in bold."""
    fig = Figure(figsize=(8.5, 1.4 + 0.45 * len(rows)))
    ax = fig.subplots()
    _arms(ax, rows, best, f"{what}, 95% Wilson interval (n = {rows['base'].rate.n} {unit})")
    ax.set_title(title)
    _legend(ax)
    return _save(fig, path)


def _arms(ax, rows: dict[str, Arm], best: str | None, xlabel: str) -> None:
    """`arms_png`'s rows drawn on `ax`."""
    for y, (label, r) in enumerate(rows.items()):
        _rate_point(ax, r.rate, y, COLORS[_kind(label, r)], ARMS[_kind(label, r)])
    ax.axvline(rows["base"].rate.success_rate, color=COLORS["base"], linestyle="--", linewidth=1,
               label="base rate")
    ax.set_yticks(range(len(rows)), list(rows))
    if best in rows:
        _star(ax, rows[best].rate.success_rate, list(rows).index(best), "chosen ticket")
        ax.get_yticklabels()[list(rows).index(best)].set_fontweight("bold")
    # the limits leave room for a marker at 0% or 100% and the first row's rate
    ax.set(xlim=(-0.04, 1.04), ylim=(len(rows) - 0.5, -0.7), xticks=[i / 5 for i in range(6)], xlabel=xlabel)
    _success_axis(ax)


def _rate_point(ax, rate: Rate, y: float, color: str, label: str | None = None) -> None:
    """A success rate at height `y`: its point, its 95% Wilson interval and its value above it."""
    x = rate.success_rate
    ax.errorbar(x, y, xerr=[[x - rate.ci_low], [rate.ci_high - x]], fmt="o", capsize=4, color=color,
                label=label)
    ax.annotate(f"{x:.1%}", (x, y), xytext=(0, 6), textcoords="offset points", fontsize="small",
                ha="left" if x < 0.1 else "right" if x > 0.9 else "center", bbox=LABEL_BOX)


def comparison_png(comparison: Comparison, path: Path, title: str) -> Path:
    """Arms A and B: success on the same seeds with 95% Wilson intervals, the better one (two-sided
    exact paired test, p < 0.05) in gold, the test's p-values under the title."""
    c = comparison
    fig = Figure(figsize=(8.5, 2.6), layout="constrained")
    ax = fig.subplots()
    for y, (side, arm) in enumerate((("A", c.a), ("B", c.b))):
        _rate_point(ax, arm.rate, y, COLORS["golden"] if c.better == side else SIDES[side])
    ax.set_yticks([0, 1], [f"A: {c.a.label}", f"B: {c.b.label}"])
    ax.set(xlim=(-0.04, 1.04), ylim=(1.5, -0.7), xticks=[i / 5 for i in range(6)],
           xlabel=f"success, 95% Wilson interval, on {c.a.rate.n} paired seeds (gold: significantly better)")
    fig.suptitle(f"{title}\nexact paired test: two-sided p = {c.p_two_sided:.3g} (p A > B "
                 f"{c.p_a_better:.3g}, p B > A {c.p_b_better:.3g})")
    _success_axis(ax)
    return _save(fig, path)


def _success_axis(ax) -> None:
    """The x axis drawn from 0% to 100% only: no frame, the bottom spine bounded there."""
    for side in ("top", "right", "left"):
        ax.spines[side].set_visible(False)
    ax.tick_params(axis="y", length=0)
    ax.spines["bottom"].set_bounds(0, 1)
    ax.xaxis.set_major_formatter(PercentFormatter(1.0))


def _kind(label: str, row: Arm) -> str:
    """The arm's colour and legend entry: base, zero ticket, golden or ticket."""
    if label in COLORS:
        return label
    return "golden" if row.golden else "ticket"


def search_png(scores: list[float], episodes: list[int], path: Path, title: str, *,
               validated: Sequence[int] = (), judged: Sequence[int] = (), chosen: int | None = None,
               heldout: tuple[dict[str, Arm], str, str] | None = None) -> Path:
    """What the search did: each ticket's search score (mean objective over the search seeds it ran)
    in the order tried, darker the more search seeds it ran (sequential halving cuts the others);
    rings mark the tickets (indices) `validated` and `judged` on held-out seeds, a star the `chosen`
    one. `heldout` (rows by label, the chosen row's label, the seeds' name) adds a panel of those
    rows' held-out success, the base's among them, on the seeds that decided."""
    fig = Figure(figsize=(14, 5) if heldout else (9, 5), layout="constrained")
    ax, *side = fig.subplots(1, 2, width_ratios=(3, 2)) if heldout else [fig.subplots()]
    full, order = max(episodes, default=0), range(1, len(scores) + 1)
    counts = sorted(set(episodes))
    for level, n in enumerate(counts):
        shown = [i for i, ran in enumerate(episodes) if ran == n]
        cut = "every search seed" if n == full else "then cut by halving"
        shade = GREENS(0.35 + 0.65 * level / max(1, len(counts) - 1))
        ax.scatter([order[i] for i in shown], [scores[i] for i in shown], s=18, color=shade,
                   label=f"ran {n} episodes, {cut}")
    for marked, size, color, label in ((validated, 90, "black", "sent to validation"),
                                       (judged, 200, "tab:purple", "judged on held-out seeds")):
        if marked:
            ax.scatter([order[i] for i in marked], [scores[i] for i in marked], s=size, facecolors="none",
                       edgecolors=color, linewidths=1.2, label=label)
    if chosen is not None:
        _star(ax, order[chosen], scores[chosen], "delivered: the best on held-out seeds" if judged else
              "delivered")
    ax.set_title(title, loc="left")
    ax.set(xlabel="tickets, in the order the search tried them", ylabel="search score (mean objective)",
           ylim=(min(0, *scores) - 0.05, max(1, *scores) + 0.05))
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncols=3, fontsize="small")
    if heldout:
        rows, best, seeds = heldout
        _arms(side[0], rows, best, "success, 95% Wilson interval")
        side[0].set_title(f"judged on {seeds}", loc="left")
    return _save(fig, path)


def _star(ax, x: float, y: float, label: str) -> None:
    ax.scatter(x, y, marker="*", s=260, color=COLORS["golden"], edgecolors="black", linewidths=0.8,
               zorder=4, label=label)


def _legend(ax) -> None:
    """The legend right of the axes, one entry per label, arms (error bars) first."""
    entries = sorted(zip(*ax.get_legend_handles_labels(), strict=True),
                     key=lambda entry: not isinstance(entry[0], ErrorbarContainer))
    unique = {label: handle for handle, label in entries}
    ax.legend(unique.values(), unique.keys(), loc="upper left", bbox_to_anchor=(1.01, 1), fontsize="small")


def front_png(study: ParetoFront, path: Path) -> Path:
    """Left: every ticket's two search scores, the Pareto front in gold. Right: the front, the
    base and the zero ticket re-judged on held-out seeds."""
    x_name, y_name = study.objectives
    fig = Figure(figsize=(10, 4.2))
    search, heldout = fig.subplots(1, 2)
    for _, scores, front in study.search:
        search.scatter(scores[x_name], scores[y_name], s=40 if front else 14,
                       color=COLORS["golden"] if front else "0.6", zorder=3 if front else 2)
    for arm, front in study.heldout.items():
        color = {BASE: COLORS["base"], ZERO: COLORS["zero ticket"]}.get(arm, COLORS["golden"])
        heldout.scatter(front.scores[x_name], front.scores[y_name], color=color, s=40, zorder=3)
        heldout.annotate(arm.key, (front.scores[x_name], front.scores[y_name]), xytext=(4, 4),
                         textcoords="offset points", fontsize="x-small")
    seeds = study.heldout_seeds
    search.set(title="search seeds: every ticket (front in gold)", xlabel=x_name, ylabel=y_name)
    heldout.set(title=f"held-out seeds {seeds[0]}..{seeds[1]}: front, base, zero", xlabel=x_name,
                ylabel=y_name)
    return _save(fig, path)


def tasks_png(verdict: MultitaskVerdict, path: Path, title: str) -> Path:
    """Per task and on average: base, zero ticket and the best ticket (the top one by average
    success when no ticket qualified), with 95% Wilson intervals; tasks it regresses on in red."""
    ticket = verdict.best or max(verdict.tickets, key=lambda t: verdict.average[t].rate.success_rate)
    rows = {short_task(name): arms for name, arms in verdict.tasks.items()}
    rows["average"] = verdict.average
    fig = Figure(figsize=(8, 1.2 + 0.75 * len(rows)))
    ax = fig.subplots()
    arms = ((BASE, BASE.label, COLORS["base"]), (ZERO, ZERO.label, COLORS["zero ticket"]),
            (ticket, ticket.label, COLORS["golden"]))
    for y, arms_of_task in enumerate(rows.values()):
        for offset, (label, legend, color) in zip((-0.22, 0, 0.22), arms, strict=True):
            r = arms_of_task[label].rate
            ax.errorbar(r.success_rate, y + offset,
                        xerr=[[r.success_rate - r.ci_low], [r.ci_high - r.success_rate]],
                        fmt="o", capsize=3, color=color, label=legend if y == 0 else None)
    regressing = {short_task(t) for t in verdict.regressions[ticket]}
    ax.set_yticks(range(len(rows)), list(rows))
    for label in ax.get_yticklabels():
        if label.get_text() in regressing:
            label.set_color("tab:red")
    ax.invert_yaxis()
    ax.set(xlim=(0, 1.02), title=title, xlabel="held-out success, 95% Wilson interval (red: the ticket "
           "is significantly worse than the base there)")
    ax.xaxis.set_major_formatter(PercentFormatter(1.0))
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1), fontsize="small")
    return _save(fig, path)


def transfer_png(study: TransferStudy, path: Path) -> Path:
    """Ticket x task heatmap of the gain over each task's base; * marks a significant gain
    (Holm-adjusted p < 0.05), a box the cover's choice for each task."""
    tickets, tasks = list(study.tickets), study.tasks
    gains = [[study.cells[t][task].gain for task in tasks] for t in tickets]
    fig = Figure(figsize=(5.5 + 0.8 * len(tasks), 2.2 + 0.45 * len(tickets)))
    ax = fig.subplots()
    limit = max(0.05, max(abs(g) for row in gains for g in row))
    image = ax.imshow(gains, cmap="RdBu", vmin=-limit, vmax=limit, aspect="auto")
    for i, ticket in enumerate(tickets):
        for j, task in enumerate(tasks):
            cell = study.cells[ticket][task]
            ax.text(j, i, gain_text(cell.gain, cell.significant), ha="center", va="center", fontsize="small",
                    color="white" if abs(cell.gain) > limit / 2 else "black")
            if study.cover.table[task][0].key == ticket:
                ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, linewidth=2, color="goldenrod"))
    ax.set_xticks(range(len(tasks)), [short_task(t) for t in tasks], rotation=40, ha="right")
    ax.set_yticks(range(len(tickets)), [f"{t} ({', '.join(map(short_task, study.tickets[t]))})"
                                        for t in tickets])
    ax.set(title="gain over base, points (* significant; box: the cover's pick)",
           xlabel="evaluated on", ylabel="ticket (found on)")
    fig.colorbar(image, ax=ax, format=PercentFormatter(1.0))
    return _save(fig, path)


def _save(fig: Figure, path: Path) -> Path:
    if fig.get_layout_engine() is None:  # a constrained layout lays itself out
        fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    return write_atomic(path, buffer.getvalue())
