"""The `goldenticket` command line."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from goldenticket.errors import UserError

DEMO_POLICY, DEMO_TASK = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3"


def _seed_range(text: str) -> range:
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected A:B (integers), got {text!r}") from None
    if not 0 <= a < b:
        raise argparse.ArgumentTypeError(f"seed range {text!r} must satisfy 0 <= A < B")
    return range(a, b)


def _search_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, help="output folder (resumable)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")
    p.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one clear line, exit 2
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="goldenticket", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help=f"search a golden ticket for the bundled {DEMO_POLICY}")
    _search_args(demo)

    search = sub.add_parser("search", help="search golden tickets for a policy on a task")
    search.add_argument("--policy", required=True,
                        help="bundled name or policy folder; append @N for N denoising steps")
    search.add_argument("--task", required=True, help="e.g. metaworld/pick-place-v3")
    search.add_argument("--method", default="cem-racing", choices=["rs", "cem", "zos", "cem-racing"])
    search.add_argument("--budget", type=int, required=True, help="search episodes")
    search.add_argument("--search-seeds", type=int, default=20, help="search initial states")
    search.add_argument("--heldout", type=int, default=200, help="held-out initial states")
    search.add_argument("--top-k", type=int, default=5, help="tickets judged on held-out states")
    search.add_argument("--max-tickets", type=int, default=None, help="cap on distinct tickets")
    search.add_argument("--stop-after-perfect", type=int, default=3,
                        help="stop once this many tickets succeed on every search seed (0: never)")
    search.add_argument("--objective", default="success",
                        choices=["success", "discounted-success", "length"])
    _search_args(search)

    ev = sub.add_parser("evaluate", help="judge tickets against the base policy on given seeds")
    ev.add_argument("--policy", required=True)
    ev.add_argument("--task", required=True)
    ev.add_argument("--ticket", action="append", default=[],
                    help="ticket file or bundled ticket id (repeatable)")
    ev.add_argument("--seeds", type=_seed_range, required=True, help="seed range A:B")
    ev.add_argument("--seed", type=int, default=0, help="seed of the base policy's noise")
    ev.add_argument("--workers", type=int, default=2)
    ev.add_argument("--json", action="store_true", help="print one JSON object")

    tr = sub.add_parser("train", help="train a policy on scripted-expert demonstrations")
    tr.add_argument("--task", required=True)
    tr.add_argument("--kind", choices=["flow", "ddim"], default="flow")
    tr.add_argument("--out", type=Path, required=True, help="policy folder to write")
    tr.add_argument("--demos", type=int, default=20)
    tr.add_argument("--grasp-offset", type=float, default=0.0)
    tr.add_argument("--goal-offset", type=float, default=0.0)
    tr.add_argument("--action-noise", type=float, default=0.0)
    tr.add_argument("--steps", type=int, default=20_000, help="gradient steps")
    tr.add_argument("--denoise-steps", type=int, default=10, help="Euler / DDIM steps at inference")
    tr.add_argument("--horizon", type=int, default=8, help="actions predicted per call (H)")
    tr.add_argument("--n-exec", type=int, default=4, help="actions executed before replanning")
    tr.add_argument("--seed", type=int, default=0)

    sub.add_parser("policies", help="list bundled policies with their measured success")

    tickets = sub.add_parser("tickets", help="inspect ticket files")
    tickets_sub = tickets.add_subparsers(dest="tickets_command", required=True)
    tickets_sub.add_parser("show", help="print a ticket's id, shape and metadata").add_argument(
        "ticket", help="ticket file or bundled ticket id")
    tickets_sub.add_parser("list", help="the golden tickets shipped with the bundled policies")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except UserError as exc:
        print(f"goldenticket: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("goldenticket: interrupted (demo and search keep finished episodes in --out: "
              "rerun the same command to resume)", file=sys.stderr)
        return 130


def _demo(args) -> int:
    from goldenticket.workflow import SearchConfig

    return _run_search(SearchConfig(DEMO_POLICY, DEMO_TASK, seed=args.seed, workers=args.workers),
                       args.out)


def _search(args) -> int:
    from goldenticket.workflow import SearchConfig

    cfg = SearchConfig(args.policy, args.task, args.method, args.budget, args.seed,
                       args.search_seeds, args.heldout, args.top_k, args.objective,
                       args.stop_after_perfect or None, args.max_tickets, args.workers)
    return _run_search(cfg, args.out)


def _run_search(cfg, out: Path) -> int:
    from goldenticket.report import summary_text
    from goldenticket.workflow import find_golden_tickets

    start = time.perf_counter()
    summary = find_golden_tickets(cfg, out)
    print(summary_text(summary))
    print(f"Wrote {out / 'summary.json'} in {time.perf_counter() - start:.0f} s.")
    return 0


def _evaluate(args) -> int:
    from goldenticket.policies import find_ticket
    from goldenticket.workflow import evaluate_tickets

    paths = [find_ticket(ref) for ref in args.ticket]
    rows = evaluate_tickets(args.policy, args.task, paths, list(args.seeds), args.seed, args.workers)
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        from goldenticket.report import verdict_table

        print(verdict_table(rows))
    return 0


def _train(args) -> int:
    from goldenticket.train import DemoStyle, build_policy

    style = DemoStyle(args.grasp_offset, args.action_noise, args.goal_offset)
    build_policy(args.task, args.kind, args.out, n_demos=args.demos, style=style,
                 steps=args.steps, denoise_steps=args.denoise_steps, horizon=args.horizon,
                 n_exec=args.n_exec, seed=args.seed)
    print(f"Wrote {args.out} (config.json, model.safetensors, MODEL_CARD.md).")
    return 0


def _policies(args) -> int:
    from goldenticket.policies import BUNDLED_DIR, policy_names
    from goldenticket.report import policy_table

    cards = [json.loads((BUNDLED_DIR / name / "card.json").read_text()) for name in policy_names()]
    print(policy_table(cards))
    print(f"Held-out success (95% Wilson interval) measured when each policy was trained; model "
          f"cards in {BUNDLED_DIR}. DDIM policies run with another step count as NAME@N.")
    return 0


def _tickets(args) -> int:
    from goldenticket.policies import find_ticket
    from goldenticket.tickets import Ticket

    if args.tickets_command == "list":
        return _tickets_list()
    ticket = Ticket.load(find_ticket(args.ticket))
    print(f"ticket {ticket.id}  shape {tuple(ticket.noise.shape)}  "
          f"norm {float((ticket.noise ** 2).sum() ** 0.5):.3f}")
    print(json.dumps(ticket.metadata, indent=2))
    return 0


def _tickets_list() -> int:
    from goldenticket.policies import bundled_tickets
    from goldenticket.report import ticket_table
    from goldenticket.tickets import Ticket

    paths = bundled_tickets()
    print(ticket_table([Ticket.load(p) for p in paths]) if paths else "No bundled tickets.")
    print("search: success on the search seeds; p vs base: Holm-adjusted over the tickets judged "
          "with it; fresh seeds: the 200 held-out seeds after those shown.\n"
          "Reproduce one: goldenticket evaluate --policy POLICY --task TASK --ticket ID --seeds A:B "
          "(the seeds shown give the recorded success; other held-out seeds give fresh numbers).")
    return 0


COMMANDS = {"demo": _demo, "search": _search, "evaluate": _evaluate, "train": _train,
            "policies": _policies, "tickets": _tickets}

if __name__ == "__main__":
    sys.exit(main())
