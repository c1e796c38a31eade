"""Plain-text tables for people."""

from __future__ import annotations


def verdict_table(rows: dict[str, dict], title: str = "noise") -> str:
    """One line per noise source: success rate, 95% Wilson interval, p-values, verdict."""
    width = max(len(label) for label in [*rows, title])
    lines = [f"{title:<{width}} {'success':>8} {'95% Wilson CI':>16} {'n':>5} {'p vs base':>10} "
             f"{'p vs zero':>10}  verdict"]
    for label, r in rows.items():
        p_base, p_zero = (f"{r[key]:.3g}" if key in r else "-" for key in ("p_value", "p_vs_zero"))
        ci = f"[{r['ci_low']:.1%}, {r['ci_high']:.1%}]"
        lines.append(f"{label:<{width}} {r['success_rate']:>8.1%} {ci:>16} {r['n']:>5} {p_base:>10} "
                     f"{p_zero:>10}  {r.get('verdict', '')}".rstrip())
    return "\n".join(lines)


def verdict_text(rows: dict[str, dict], best: dict, note: str) -> str:
    """The verdict table (rows from `workflow.arm_rows`), a one-line plain verdict on the best
    ticket, and how to read the p-values."""
    base = rows["base"]["success_rate"]
    if best["golden"]:
        line = (f"Golden ticket {best['ticket_id']}: {best['success_rate']:.1%} vs base {base:.1%} on "
                f"{best['n']} held-out seeds (p = {best['p_value']:.3g})")
    else:
        line = (f"No golden ticket: the best ticket ({best['ticket_id']}, {best['success_rate']:.1%}) "
                f"is not significantly better than the base ({base:.1%}); p = {best['p_value']:.3g} >= 0.05")
    return f"{verdict_table(rows)}\n\n{line}\n{note}"


def _columns(header: tuple[str, ...], rows: list[tuple[str, ...]]) -> str:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
                     for r in [header, *rows])


def rate_text(r: dict, width: int = 0) -> str:
    """`56.5% [50%, 63%]`: a success rate with its 95% Wilson interval."""
    return f"{r['success_rate']:{width}.1%} [{r['ci_low']:.0%}, {r['ci_high']:.0%}]"


def policy_table(cards: list[dict]) -> str:
    """One line per bundled policy: its base and zero-ticket held-out success."""
    rows = [(c["policy"], str(c["demos"]), rate_text(c["base"], 6), rate_text(c["zero"], 6),
             str(c["base"]["n"])) for c in cards]
    return _columns(("policy", "demos", "base", "zero ticket", "n"), rows)


def ticket_table(tickets: list) -> str:
    """One line per shipped ticket: policy, id, search score, held-out success and its seeds, and
    success on fresh held-out seeds where measured."""
    rows = []
    for t in tickets:
        held = t.metadata["heldout"]
        fresh = t.metadata.get("fresh")
        rows.append((t.metadata["policy"], t.id, f"{t.metadata['search_score']:.0%}", rate_text(held, 6),
                     f"{held['p_value']:.2g}", f"{held['seeds'][0]}:{held['seeds'][1] + 1}",
                     rate_text(fresh, 6) if fresh else "-"))
    return _columns(("policy", "ticket", "search", "held-out success", "p vs base", "seeds",
                     "fresh seeds"), rows)
