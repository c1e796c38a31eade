"""The paper's robomimic table beside ours, from results already measured (it runs no episode):

    python benchmarks/robomimic_paper.py

Per task: the paper's DPPO checkpoint (base and golden ticket after random search over 5000 tickets
x 100 episodes, as "You've Got a Golden Ticket: Improving Generative Robot Policies With A Single
Noise Vector", Patil et al., arXiv 2603.15757, reports them), then ours: the zoo's policies (the
robomimic existence table) and the DPPO-format checkpoints trained here by DPPO's recipe (the
untuned bench's rows), each on the two fresh ranges of 200 held-out seeds that no search or choice
saw; a policy not searched yet shows its base and zero ticket on the held-out seeds it was measured
on. Results: benchmarks/results/robomimic_paper.{md,json}.
"""

from __future__ import annotations

import json
from importlib import resources

from results_files import RESULTS, write_results

TASKS = ("lift", "can", "square", "transport")
ZOO_KINDS = ("flow", "ddim")
HEADER = ("| task | policy | base | zero ticket | searched ticket | search |\n"
          "|---|---|---|---|---|---|\n")


def read(name: str) -> dict | None:
    path = RESULTS / name
    return json.loads(path.read_text()) if path.is_file() else None


def rates(row: dict, arm: str) -> str:
    """`arm`'s success on the two fresh ranges, 'a% / b%'."""
    return " / ".join(f"{(r if arm == 'ticket' else r[arm])['success_rate']:.1%}"
                      for r in (row["fresh"], row["fresh_2"]))


def searched_row(task: str, policy: str, row: dict) -> str:
    ticket = "w = 0 (the zero ticket)" if row["zero_ticket"] else row["ticket"]
    return (f"| {task} | {policy} | {rates(row, 'base')} | {rates(row, 'zero')} | "
            f"{rates(row, 'ticket')}: {ticket} | {row['search']} |")


def unsearched_row(task: str, policy: str, base: dict, zero: dict | None) -> str:
    zero_text = f"{zero['success_rate']:.1%}" if zero else "-"
    return (f"| {task} | {policy} | {base['success_rate']:.1%} (held-out, {base['n']} seeds) | "
            f"{zero_text} | - | not searched yet |")


def zoo_card(task: str, kind: str) -> dict | None:
    card = resources.files("goldenticket") / "policies" / "bundled" / "robomimic" / task / kind / "card.json"
    return json.loads(card.read_text()) if card.is_file() else None


def task_rows(task: str, existence: dict) -> list[str]:
    base, golden = existence["paper"][task]
    best = "golden" if golden > base else "its best, below the base: no golden ticket"
    rows = [f"| {task} | DPPO's checkpoint (the paper) | {base:.1%} | - | {golden:.1%} ({best}) | "
            "random search, 5000 tickets x 100 episodes |"]
    searched = {p["policy"]: p for p in existence["pairs"] if p["task"] == f"robomimic/{task}"}
    for policy, row in searched.items():
        rows.append(searched_row(task, f"zoo {policy}", row))
    for kind in ZOO_KINDS:
        card = zoo_card(task, kind)
        if card and not any(p.split("@")[0] == kind for p in searched):
            rows.append(unsearched_row(task, f"zoo {kind}", card["base"], card.get("zero")))
    if bench := read(f"untuned_bench/portfolio/dppo-{task}.json"):
        rows.append(searched_row(task, "DPPO-format, trained here", bench))
    elif trained := read(f"dppo_{task}.json"):
        rows.append(unsearched_row(task, "DPPO-format, trained here", trained["base"], trained.get("zero")))
    if len(rows) == 1:
        rows.append(f"| {task} | - | no bundled or DPPO-format policy yet | | | |")
    return rows


def main() -> None:
    existence = read("robomimic_existence.json")
    rows = {task: task_rows(task, existence) for task in TASKS}
    markdown = HEADER + "\n".join(line for task in TASKS for line in rows[task]) + "\n"
    write_results("robomimic_paper", {"paper": existence["paper"], "rows": rows}, markdown)


if __name__ == "__main__":
    main()
