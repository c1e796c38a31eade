"""Plain-text tables for people."""

from __future__ import annotations

from typing import TYPE_CHECKING

from goldenticket.evaluation import ALPHA, BASE, ZERO
from goldenticket.results import PAIRED_TEST, to_run

if TYPE_CHECKING:
    from goldenticket.evaluation import VerdictRow
    from goldenticket.results import Comparison, MultitaskSummary, TransferStudy, VerdictTable


def p_vs_base(row: dict) -> float | None:
    """A verdict row's p-value against the base. Files written before it was named `p_vs_base`
    (older summary.json files, the bundled tickets' metadata) call it `p_value`."""
    return row.get("p_vs_base", row.get("p_value"))


def verdict_table(rows: dict[str, dict], title: str = "noise") -> str:
    """One line per noise source: success rate, 95% Wilson interval, p-values (p vs zero only
    when some source has one), verdict; and, when any episode ended in a NaN or infinite action,
    how many did per source."""
    width = max(len(label) for label in [*rows, title])
    nonfinite = any(r.get("nonfinite_episodes") for r in rows.values())
    extra = f" {'non-finite':>10}" if nonfinite else ""
    zero = any("p_vs_zero" in r for r in rows.values())  # none in a session: it has no zero-ticket arm
    lines = [f"{title:<{width}} {'success':>8} {'95% Wilson CI':>16} {'n':>5}{extra} {'p vs base':>10}"
             + f" {'p vs zero':>10}" * zero + "  verdict"]
    for label, r in rows.items():
        p_base, p_zero = (f"{r[key]:.3g}" if key in r else "-" for key in ("p_vs_base", "p_vs_zero"))
        ci = f"[{r['ci_low']:.1%}, {r['ci_high']:.1%}]"
        extra = f" {r.get('nonfinite_episodes', 0):>10}" if nonfinite else ""
        lines.append((f"{label:<{width}} {r['success_rate']:>8.1%} {ci:>16} {r['n']:>5}{extra} {p_base:>10}"
                      + f" {p_zero:>10}" * zero + f"  {r.get('verdict', '')}").rstrip())
    return "\n".join(lines)


def verdict_text(table: VerdictTable, best: VerdictRow, name: str, note: str) -> str:
    """The verdict table, each arm once (under it, where the zero ticket was judged as one of the
    tickets, which one it was and what Holm's adjustment made of its p vs base), a one-line plain
    verdict on the best ticket (`best`, called `name`) saying what to run (`results.to_run`), and
    how to read the p-values (and the non-finite column, when shown)."""
    base = table.base.rate.success_rate
    if best.golden:
        line = (f"Golden ticket {name}: {best.rate.success_rate:.1%} vs base {base:.1%} on "
                f"{best.rate.n} held-out seeds (p = {best.p_vs_base:.3g})")
    else:
        line = (f"No golden ticket: the best ticket ({name}, {best.rate.success_rate:.1%}) is not "
                f"significantly better than the base ({base:.1%}); p = {best.p_vs_base:.3g} >= 0.05. "
                + instead(table, best))
    rows = table.rows()
    if any(r.nonfinite for r in rows.values()):
        note += (" non-finite: episodes the policy ended with a NaN or infinite action, counted as "
                 "failures.")
    shown = verdict_table({label: r.to_dict() for label, r in rows.items()})
    if table.zero_judged_as is not None:
        shown += (f"\n{ZERO.label} = ticket {table.zero_judged_as}, judged as one of the "
                  f"{table.adjusted_over} tickets: its p vs base is Holm-adjusted over them "
                  f"({table.zero_unadjusted:.3g} unadjusted)")
    return f"{shown}\n\n{line}\n{note}"


def instead(table: VerdictTable, best: VerdictRow) -> str:
    """What to run when the best ticket (`best`) is not golden (`results.to_run`): the zero ticket
    where it is golden (never where it was judged as one of the tickets: then the best is at least
    as good), an arm ahead of the base though not proven better, or the base."""
    zero, unsure = table.zero, " though not proven better (more held-out seeds would tell)."
    run = to_run(best.rate.success_rate, zero.rate.success_rate, table.base.rate.success_rate, best.golden)
    if run == "zero" and zero.golden:
        return (f"The zero ticket (w = 0) is: {zero.rate.success_rate:.1%}, p = {zero.p_vs_base:.3g}; "
                "deploy it (a ticket of zeros) rather than these tickets.")
    if run == "zero":
        return (f"The zero ticket (w = 0, {zero.rate.success_rate:.1%}) is ahead of the base on these "
                "seeds: run it rather than the base," + unsure)
    if run == "best":
        return "It is ahead of the base on these seeds: run it rather than the base," + unsure
    return "Keep the base policy (fresh Gaussian noise) rather than these tickets."


def _columns(header: tuple[str, ...], rows: list[tuple[str, ...]]) -> str:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
                     for r in [header, *rows])


def rate_text(r: dict, width: int = 0) -> str:
    """`56.5% [50%, 63%]`: a success rate with its 95% Wilson interval (a row as JSON holds it)."""
    return _interval(r["success_rate"], r["ci_low"], r["ci_high"], width)


def row_text(row: VerdictRow, width: int = 0) -> str:
    """`rate_text` of a verdict row."""
    return _interval(row.rate.success_rate, row.rate.ci_low, row.rate.ci_high, width)


def _interval(rate: float, low: float, high: float, width: int) -> str:
    return f"{rate:{width}.1%} [{low:.0%}, {high:.0%}]"


def policy_table(cards: list[dict]) -> str:
    """One line per bundled policy (a multi-task one: per task, then over all tasks): its base
    and zero-ticket held-out success."""
    rows = []
    for c in cards:
        for task, entry in c.get("tasks", {}).items():
            rows.append((f"{c['policy']} on {short_task(task)}", str(entry["demos"]),
                         rate_text(entry["base"], 6), rate_text(entry["zero"], 6), str(entry["base"]["n"])))
        label = f"{c['policy']} (all {len(c['tasks'])} tasks)" if "tasks" in c else c["policy"]
        rows.append((label, str(c["demos"]), rate_text(c["base"], 6), rate_text(c["zero"], 6),
                     str(c["base"]["n"])))
    return _columns(("policy", "demos", "base", "zero ticket", "n"), rows)


def ticket_table(tickets: list) -> str:
    """One line per shipped ticket: policy, id, search score (- for a ticket the search did not
    score, such as the zero ticket), held-out success and its seeds, and success on fresh held-out
    seeds where measured."""
    rows = []
    for t in tickets:
        held, score = t.record.heldout, t.record.search_score
        fresh = t.record.extra.get("fresh")  # measured by benchmarks/existence.py
        rows.append((t.record.policy, t.id, "-" if score is None else f"{score:.0%}", rate_text(held, 6),
                     f"{p_vs_base(held):.2g}", f"{held['seeds'][0]}:{held['seeds'][1] + 1}",
                     rate_text(fresh, 6) if fresh else "-"))
    return _columns(("policy", "ticket", "search", "held-out success", "p vs base", "seeds",
                     "fresh seeds"), rows)


def short_task(name: str) -> str:
    """`metaworld/pick-place-v3` -> `pick-place-v3`."""
    return name.rsplit("/", 1)[-1]


def multitask_text(summary: MultitaskSummary) -> str:
    """Per task and on average: base, zero ticket and the best ticket (p-values vs base and zero),
    each task the ticket regresses on flagged; then every ticket's average and regressions."""
    verdict = summary.verdict
    best, average = verdict.best, verdict.average
    shown = best or verdict.tickets[0]
    rows = []
    for task, arms in [*verdict.tasks.items(), ("average", average)]:
        t = arms[shown]
        flag = "REGRESSES" if task in verdict.regressions[shown] else ""
        rows.append((short_task(task), row_text(arms[BASE], 6), row_text(arms[ZERO], 6),
                     row_text(t, 6), f"{t.p_vs_base:.3g}", f"{t.p_vs_zero:.3g}", flag))
    table = _columns(("task", BASE.label, ZERO.label, shown.label, "p vs base", "p vs zero", ""), rows)
    lines = [table, ""]
    if best is None:
        lines.append("No ticket qualifies: with --no-regression, every ticket is significantly worse than "
                     "the base on some task.")
    else:
        said = "golden on average" if average[best].golden else "not significantly better on average"
        lines.append(f"Best ticket {best.key}: {average[best].rate.success_rate:.1%} averaged over "
                     f"{len(verdict.tasks)} tasks vs base {average[BASE].rate.success_rate:.1%} "
                     f"(p = {average[best].p_vs_base:.3g}, {said}).")
    for ticket in verdict.tickets:
        worse = ", ".join(short_task(t) for t in verdict.regressions[ticket]) or "none"
        lines.append(f"  {ticket.label}: average {average[ticket].rate.success_rate:.1%}; "
                     f"significantly worse than base on: {worse}")
    return "\n".join(lines + [summary.p_value_note + " Regression: one-sided exact paired test, base "
                              "better than the ticket on that task, p < 0.05 (not adjusted)."])


def gain_text(gain: float, significant: bool) -> str:
    """A transfer-matrix cell: the gain over the base in points, * when significant."""
    return f"{100 * gain:+.0f}{'*' if significant else ''}"


def transfer_text(study: TransferStudy) -> str:
    """The transfer matrix (gain over base in points, * significant) and the cover's switching table."""
    tasks = study.tasks
    header = ("ticket (found on)", *[short_task(t) for t in tasks])
    rows = [(f"{ticket} ({', '.join(short_task(t) for t in found)})",
             *[gain_text(study.cells[ticket][t].gain, study.cells[ticket][t].significant) for t in tasks])
            for ticket, found in study.tickets.items()]
    cover = study.cover
    switching = [(short_task(task), use.key, f"{cell.success_rate:.1%}",
                  f"{study.baselines[task][BASE].rate.success_rate:.1%}",
                  "significant" if cell.significant else "")
                 for task, (use, cell) in cover.table.items()]
    covered = sum(cell.significant for _, cell in cover.table.values())
    return "\n".join([
        "Gain over each task's base (points) on the held-out seeds; * Holm-adjusted p < 0.05:",
        _columns(header, rows), "",
        f"Greedy cover: {len(cover.tickets)} ticket(s) ({', '.join(cover.tickets) or 'none'}) "
        f"significantly better than the base on {covered} of {len(tasks)} tasks; every other task uses "
        "the ticket with its best success if that beats the base "
        f"({', '.join(cover.fallbacks) or 'none'}), else the base. The switching table:",
        _columns(("task", "use", "success", "base", ""), switching)])


def comparison_text(comparison: Comparison) -> str:
    """Arms A and B, a line each (policy, ticket, success with its 95% Wilson interval, n; the
    episodes a NaN or infinite action ended, where any did), the discordant seeds, the paired tests
    both ways and two-sided, a one-line verdict, and what the test is."""
    c, arms = comparison, {"A": comparison.a, "B": comparison.b}
    nonfinite = any(arm.nonfinite for arm in arms.values())
    header = ("arm", "policy", "ticket", "success", "95% Wilson CI", "n") + ("non-finite",) * nonfinite
    rows = [(side, arm.policy, arm.ticket or "-", f"{arm.rate.success_rate:.1%}",
             f"[{arm.rate.ci_low:.1%}, {arm.rate.ci_high:.1%}]", str(arm.rate.n))
            + (str(arm.nonfinite),) * nonfinite for side, arm in arms.items()]
    lines = [_columns(header, rows), "",
             f"discordant seeds: {c.a_only + c.b_only} of {c.a.rate.n} (A succeeded where B failed on "
             f"{c.a_only}, B where A failed on {c.b_only})",
             f"p A > B = {c.p_a_better:.3g}, p B > A = {c.p_b_better:.3g}, two-sided p = {c.p_two_sided:.3g}",
             "", comparison_verdict(c),
             f"Test: {PAIRED_TEST} (seeds {c.seeds[0]}:{c.seeds[1] + 1}, task {c.task})."]
    if nonfinite:
        lines.append("non-finite: episodes the policy ended with a NaN or infinite action, counted as "
                     "failures.")
    return "\n".join(lines)


def comparison_verdict(c: Comparison) -> str:
    """One line: which arm is better on these seeds (the two-sided test), or no significant difference."""
    rates = f"{c.a.rate.success_rate:.1%} vs {c.b.rate.success_rate:.1%} on {c.a.rate.n} held-out seeds"
    if c.better is None:
        return (f"No significant difference between A and B on these seeds: {rates} (two-sided p = "
                f"{c.p_two_sided:.3g} >= {ALPHA}).")
    worse = "B" if c.better == "A" else "A"
    return f"{c.better} is better than {worse} on these seeds: {rates} (two-sided p = {c.p_two_sided:.3g})."
