"""Pictures for people: held-out success per arm with intervals, and the search's progress."""

from __future__ import annotations

import io
from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import PercentFormatter

from goldenticket.files import write_atomic
from goldenticket.report import gain_text, short_task

COLORS = {"base": "0.45", "zero ticket": "tab:blue", "golden": "goldenrod", "ticket": "tab:green"}


def arms_png(rows: dict[str, dict], path: Path, title: str, what: str = "held-out success",
             unit: str = "seeds") -> Path:
    """One row per arm (base, zero ticket, tickets): held-out success with its 95% Wilson
    interval; golden tickets in gold, the base rate as a dashed line."""
    fig = Figure(figsize=(7.5, 1.4 + 0.45 * len(rows)))
    ax = fig.subplots()
    for y, (label, r) in enumerate(rows.items()):
        kind = label if label in COLORS else ("golden" if r.get("golden") else "ticket")
        rate = r["success_rate"]
        ax.errorbar(rate, y, xerr=[[rate - r["ci_low"]], [r["ci_high"] - rate]], fmt="o", capsize=4,
                    color=COLORS[kind], label=kind if kind in ("golden", "ticket") else None)
        ax.annotate(f"{rate:.1%}", (r["ci_high"], y), xytext=(6, -4), textcoords="offset points")
    ax.axvline(rows["base"]["success_rate"], color=COLORS["base"], linestyle="--", linewidth=1)
    ax.set_yticks(range(len(rows)), list(rows))
    ax.invert_yaxis()
    n = rows["base"]["n"]
    ax.set(xlim=(0, 1.08), title=title, xlabel=f"{what}, 95% Wilson interval (n = {n} {unit})")
    ax.xaxis.set_major_formatter(PercentFormatter(1.0))
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        unique = dict(zip(labels, handles, strict=True))
        ax.legend(unique.values(), unique.keys(), loc="upper left", bbox_to_anchor=(1.01, 1),
                  fontsize="small")
    return _save(fig, path)


def search_png(scores: list[float], episodes: list[int], path: Path, title: str) -> Path:
    """Each ticket's mean search return in the order the search first tried it (marker area by
    its episodes), with the best so far among tickets scored on the most episodes."""
    fig = Figure(figsize=(7.5, 4))
    ax = fig.subplots()
    full = max(episodes, default=0)
    ax.scatter(range(1, len(scores) + 1), scores, s=[8 + 40 * n / max(full, 1) for n in episodes],
               alpha=0.5, color="tab:green", label="ticket (area: episodes)")
    best, running = [], float("-inf")
    for score, n in zip(scores, episodes, strict=True):
        running = max(running, score) if n == full else running
        best.append(running if running > float("-inf") else None)
    ax.step(range(1, len(best) + 1), [float("nan") if b is None else b for b in best], where="post",
            color="goldenrod", label=f"best so far ({full} episodes)")
    ax.set(title=title, xlabel="tickets, in the order tried", ylabel="mean search return",
           ylim=(min(0, *scores) - 0.05, max(1, *scores) + 0.05))
    ax.legend(loc="lower right", fontsize="small")
    return _save(fig, path)


def front_png(study: dict, path: Path) -> Path:
    """Left: every ticket's two search scores, the Pareto front in gold. Right: the front, the
    base and the zero ticket re-judged on held-out seeds."""
    x_name, y_name = study["objectives"]
    fig = Figure(figsize=(10, 4.2))
    search, heldout = fig.subplots(1, 2)
    for entry in study["search"]:
        front = entry["front"]
        search.scatter(entry["scores"][x_name], entry["scores"][y_name], s=40 if front else 14,
                       color=COLORS["golden"] if front else "0.6", zorder=3 if front else 2)
    for label, row in study["heldout"].items():
        kind = label if label in ("base", "zero") else "front"
        color = {"base": COLORS["base"], "zero": COLORS["zero ticket"], "front": COLORS["golden"]}[kind]
        heldout.scatter(row["scores"][x_name], row["scores"][y_name], color=color, s=40, zorder=3)
        heldout.annotate(label, (row["scores"][x_name], row["scores"][y_name]), xytext=(4, 4),
                         textcoords="offset points", fontsize="x-small")
    seeds = study["heldout_seeds"]
    search.set(title="search seeds: every ticket (front in gold)", xlabel=x_name, ylabel=y_name)
    heldout.set(title=f"held-out seeds {seeds[0]}..{seeds[1]}: front, base, zero", xlabel=x_name,
                ylabel=y_name)
    return _save(fig, path)


def tasks_png(summary: dict, path: Path, title: str) -> Path:
    """Per task and on average: base, zero ticket and the best ticket (the top one by average
    success when no ticket qualified), with 95% Wilson intervals; tasks it regresses on in red."""
    ticket = summary["best"] or max(summary["tickets"], key=lambda t: summary["average"][t]["success_rate"])
    rows = {short_task(name): arms for name, arms in summary["tasks"].items()}
    rows["average"] = summary["average"]
    fig = Figure(figsize=(8, 1.2 + 0.75 * len(rows)))
    ax = fig.subplots()
    arms = (("base", "base", COLORS["base"]), ("zero", "zero ticket", COLORS["zero ticket"]),
            (ticket, f"ticket {ticket}", COLORS["golden"]))
    for y, arms_of_task in enumerate(rows.values()):
        for offset, (label, legend, color) in zip((-0.22, 0, 0.22), arms, strict=True):
            r = arms_of_task[label]
            ax.errorbar(r["success_rate"], y + offset, xerr=[[r["success_rate"] - r["ci_low"]],
                                                             [r["ci_high"] - r["success_rate"]]],
                        fmt="o", capsize=3, color=color, label=legend if y == 0 else None)
    regressing = {short_task(t) for t in summary["regressions"][ticket]}
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


def transfer_png(study: dict, path: Path) -> Path:
    """Ticket x task heatmap of the gain over each task's base; * marks a significant gain
    (Holm-adjusted p < 0.05), a box the cover's choice for each task."""
    tickets, tasks = list(study["tickets"]), study["tasks"]
    gains = [[study["cells"][t][task]["gain"] for task in tasks] for t in tickets]
    fig = Figure(figsize=(5.5 + 0.8 * len(tasks), 2.2 + 0.45 * len(tickets)))
    ax = fig.subplots()
    limit = max(0.05, max(abs(g) for row in gains for g in row))
    image = ax.imshow(gains, cmap="RdBu", vmin=-limit, vmax=limit, aspect="auto")
    for i, ticket in enumerate(tickets):
        for j, task in enumerate(tasks):
            cell = study["cells"][ticket][task]
            ax.text(j, i, gain_text(cell), ha="center",
                    va="center", fontsize="small",
                    color="white" if abs(cell["gain"]) > limit / 2 else "black")
            if study["cover"]["table"][task]["use"] == ticket:
                ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, linewidth=2, color="goldenrod"))
    ax.set_xticks(range(len(tasks)), [short_task(t) for t in tasks], rotation=40, ha="right")
    ax.set_yticks(range(len(tickets)), [f"{t} ({', '.join(map(short_task, study['tickets'][t]))})"
                                        for t in tickets])
    ax.set(title="gain over base, points (* significant; box: the cover's pick)",
           xlabel="evaluated on", ylabel="ticket (found on)")
    fig.colorbar(image, ax=ax, format=PercentFormatter(1.0))
    return _save(fig, path)


def _save(fig: Figure, path: Path) -> Path:
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    return write_atomic(path, buffer.getvalue())
