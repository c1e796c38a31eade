"""goldenticket: find one constant noise (a golden ticket) that makes a frozen diffusion or
flow-matching policy succeed more often, and prove it on held-out initial states."""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
import traceback
from pathlib import Path

from goldenticket import __version__
from goldenticket.errors import UserError
from goldenticket.ticket_search.optimizers import OPTIMIZERS

DEMO_POLICY, DEMO_TASK = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3"
POLICY_HELP = "bundled policy name (see `goldenticket policies`) or a folder written by `train` " \
              "(append @N to run N denoising steps), or package.module:factory returning a NoisePolicy"
TASK_HELP = "task name, e.g. metaworld/pick-place-v3, or package.module:factory returning a gymnasium.Env"
WORKERS_HELP = "worker processes (results do not depend on it)"
MAX_STEPS_HELP = "episode step limit (default: the task's, 150 for Meta-World)"
SUCCESS_HELP = "Gymnasium tasks: package.module:function(obs, info) -> bool deciding success " \
               "(default: info['success'] or info['is_success'])"
RESUME = dict.fromkeys(("demo", "search", "transfer"),
                       " (finished episodes are kept in --out: rerun the same command to resume)")


class Interrupted(BaseException):
    """Ctrl-C or SIGTERM: stop, keep what is recorded, exit 128 + signal number."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _seed(text: str) -> int:
    try:
        seed = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if seed < 0:
        raise argparse.ArgumentTypeError(f"seed must be >= 0, got {seed}")
    return seed


def _seed_range(text: str) -> range:
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected A:B (integers), got {text!r}") from None
    if not 0 <= a < b:
        raise argparse.ArgumentTypeError(f"seed range {text!r} must satisfy 0 <= A < B")
    return range(a, b)


class _HelpFormatter(argparse.HelpFormatter):
    """Each option's help ends with its default, where it has one worth saying."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        unsaid = action.default is False or action.default in (None, [], argparse.SUPPRESS)
        if action.required or unsaid or "default" in text:
            return text
        return f"{text} (default: {action.default})"


class _Parser(argparse.ArgumentParser):
    def __init__(self, **kwargs):
        super().__init__(formatter_class=_HelpFormatter, **kwargs)

    def error(self, message: str):  # one clear line, exit 2
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True,
                   help="output folder: run.sqlite (every episode; rerun to resume), summary.json, "
                        "tickets/, verdict.png, search.png")
    p.add_argument("--seed", type=_seed, default=0, help="seed of every random draw")
    _engine_args(p)


def _engine_args(p: argparse.ArgumentParser) -> None:
    """Where episodes run; results do not depend on it."""
    p.add_argument("--workers", type=int, default=2, help=WORKERS_HELP)
    p.add_argument("--backend", choices=["local", "ray"], default="local",
                   help="where episodes run: local processes, or Ray actors (results do not depend on it)")
    p.add_argument("--address", default=None,
                   help="Ray cluster address, e.g. ray://head:10001 (default: start a local Ray instance)")


def _max_nonfinite_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--max-nonfinite", type=float, default=0.1,
                   help="an episode whose policy call returns NaN or infinite actions ends as a failure; "
                        "stop when more than this fraction of an arm's held-out episodes end so")


def _search_options(p: argparse.ArgumentParser, per_task_budget: bool = False) -> None:
    p.add_argument("--method", default="cma-es", choices=list(OPTIMIZERS),
                   help="random search, CEM, zeroth-order search, CEM raced by halving "
                        "(cem-racing) or by confidence bounds (cem-bounds), CMA-ES")
    p.add_argument("--budget", type=int, default=None,
                   help="search episodes per task (needed unless --ticket)" if per_task_budget
                   else "search episodes to spend (default: 2000)")
    p.add_argument("--search-seeds", type=int, default=20, help="initial states to search on (per task)")
    p.add_argument("--heldout", type=int, default=200,
                   help="held-out initial states (per task) to judge base, zero ticket and tickets on")


def _transfer_parser(sub) -> None:
    tr = sub.add_parser("transfer", help="one ticket per task of a multi-task policy, each judged on every "
                                         "task: the transfer matrix and the smallest set that covers them")
    tr.add_argument("--policy", required=True, help=POLICY_HELP)
    tr.add_argument("--task", required=True, action="append", help="task name; repeat (at least two)")
    tr.add_argument("--ticket", action="append", default=[],
                    help="take these tickets (files or bundled ids) instead of searching one per task")
    _search_options(tr, per_task_budget=True)
    tr.add_argument("--max-steps", type=int, default=None, help=MAX_STEPS_HELP)
    _run_args(tr)


def _search_parser(sub) -> None:
    search = sub.add_parser("search", help="search golden tickets for a policy on a task")
    search.add_argument("--policy", required=True, help=POLICY_HELP)
    search.add_argument("--task", required=True, action="append",
                        help=TASK_HELP + "; repeat for one ticket over several tasks of a multi-task "
                                         "policy (task-averaged success, judged per task)")
    _search_options(search)
    search.add_argument("--no-regression", action="store_true",
                        help="several --task: never pick a ticket significantly worse than the base on "
                             "a task")
    search.add_argument("--top-k", type=int, default=3, help="best search tickets judged on held-out states")
    search.add_argument("--validation-seeds", type=int, default=None,
                        help="run the 3 x top-k best search tickets on this many validation states and "
                             "judge the top-k of those on held-out states (default: 100 for one task; "
                             "0: judge the search's top-k)")
    search.add_argument("--max-tickets", type=int, default=None,
                        help="stop after this many distinct tickets (default: no cap)")
    search.add_argument("--stop-after-perfect", type=int, default=3,
                        help="stop once this many tickets succeed on every search seed (0: never)")
    search.add_argument("--objective", action="append", default=None,
                        choices=["success", "success-progress", "discounted-success", "length", "speed"],
                        help="episode return the search maximises (default success); give a second one "
                             "to also find the Pareto front between them (front.json, front.png); "
                             "speed: short successful episodes; success-progress: success, ties broken by "
                             "how far failed episodes got (Meta-World's shaped reward at their end)")
    search.add_argument("--subspace", default="full",
                        help="what the search varies: full (every entry), tiled (one action-sized vector "
                             "repeated over the horizon), channels:I,J (those action channels; the others 0)")
    search.add_argument("--max-steps", type=int, default=None, help=MAX_STEPS_HELP)
    search.add_argument("--success", default=None, help=SUCCESS_HELP)
    _max_nonfinite_arg(search)
    _run_args(search)


def _evaluate_parser(sub) -> None:
    ev = sub.add_parser("evaluate", help="judge tickets against the base policy on held-out seeds")
    ev.add_argument("--policy", required=True, help=POLICY_HELP)
    ev.add_argument("--task", default=None,
                    help=TASK_HELP + " (default: the task the tickets were found on)")
    ev.add_argument("--ticket", action="append", default=[],
                    help="ticket file or bundled ticket id; repeat for several; without it, only "
                         "the base and the zero ticket run")
    ev.add_argument("--seeds", type=_seed_range, required=True,
                    help="held-out seed range A:B (seeds 1000000:2000000 name held-out states)")
    ev.add_argument("--seed", type=_seed, default=0, help="seed of the base policy's Gaussian noise")
    ev.add_argument("--max-steps", type=int, default=None,
                    help="episode step limit (default: the tickets' own, else the task's)")
    ev.add_argument("--success", default=None,
                    help=SUCCESS_HELP.replace("(default: ", "(default: the tickets' own, else "))
    _engine_args(ev)
    _max_nonfinite_arg(ev)
    ev.add_argument("--allow-transfer", action="store_true",
                    help="run tickets found for another policy or task, or under another --max-steps or "
                         "--success (transfer studies)")
    ev.add_argument("--mixture", action="store_true",
                    help="add an arm that draws one of the tickets at every policy call, and report "
                         "each arm's diversity (spread of executed actions from one initial state)")
    ev.add_argument("--epsilon", type=float, default=0.0,
                    help="with --mixture: fresh Gaussian noise instead of a ticket with this probability")
    ev.add_argument("--plot", type=Path, default=None,
                    help="write a PNG of success with intervals per arm to this file (default: none)")
    ev.add_argument("--json", action="store_true", help="print one JSON object instead of the table")


def _train_parser(sub) -> None:
    tr = sub.add_parser("train", help="train a policy on imperfect scripted-expert demonstrations")
    tr.add_argument("--task", required=True, help=TASK_HELP)
    tr.add_argument("--kind", choices=["flow", "ddim"], default="flow",
                    help="flow matching (Euler steps) or DDIM (eta = 0)")
    tr.add_argument("--out", type=Path, required=True, help="new policy folder to write")
    tr.add_argument("--demos", type=int, default=20, help="successful demonstrations to train on")
    tr.add_argument("--grasp-offset", type=float, default=0.0,
                    help="each demonstrator aims at the object shifted by U(+-this) m in x and y")
    tr.add_argument("--goal-offset", type=float, default=0.0,
                    help="each demonstrator aims at the goal shifted by U(+-this) m in x and y")
    tr.add_argument("--action-noise", type=float, default=0.0,
                    help="std of Gaussian noise added to the demonstrators' actions")
    tr.add_argument("--steps", type=int, default=20_000, help="gradient steps")
    tr.add_argument("--denoise-steps", type=int, default=10, help="Euler / DDIM steps at inference")
    tr.add_argument("--horizon", type=int, default=8, help="actions predicted per call (H)")
    tr.add_argument("--n-exec", type=int, default=4, help="actions executed before replanning")
    tr.add_argument("--heldout", type=int, default=200,
                    help="held-out initial states the model card's base and zero-ticket success use")
    tr.add_argument("--seed", type=_seed, default=0, help="seed of demonstrations and training")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="goldenticket", description=__doc__)
    parser.add_argument("--version", action="version", version=f"goldenticket {__version__}")
    parser.add_argument("--verbose", action="store_true",
                        help="on an error, also print its full traceback (an error in your own policy, "
                             "env or success predicate is otherwise one line naming its file and line)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    demo = sub.add_parser("demo", help=f"search and judge a golden ticket for the bundled {DEMO_POLICY}")
    _run_args(demo)
    _search_parser(sub)
    _transfer_parser(sub)
    _evaluate_parser(sub)
    _train_parser(sub)
    sub.add_parser("policies", help="list bundled policies with their measured success").add_argument(
        "--json", action="store_true", help="print the model cards as one JSON list")
    tickets = sub.add_parser("tickets", help="inspect ticket files and the bundled golden tickets")
    tickets_sub = tickets.add_subparsers(dest="tickets_command", required=True, parser_class=_Parser)
    tickets_sub.add_parser("show", help="print a ticket's id, shape and metadata").add_argument(
        "ticket", help="ticket file or bundled ticket id")
    tickets_sub.add_parser("list", help="the golden tickets shipped with the bundled policies").add_argument(
        "--json", action="store_true", help="print one JSON list")
    _session_parser(sub)
    return parser


def _session_parser(sub) -> None:
    session = sub.add_parser("session", help="search on a real robot: a person scores each episode")
    session_sub = session.add_subparsers(dest="session_command", required=True, parser_class=_Parser)
    new = session_sub.add_parser("new", help="plan a session: N random tickets raced (or K episodes each), "
                                             "then the finalists and the base; at most 100000 episodes")
    new.add_argument("--policy", required=True,
                     help="the policy the robot runs (name, folder or import string)")
    new.add_argument("--out", type=Path, required=True, help="session folder")
    new.add_argument("--tickets", type=int, default=6, help="candidate tickets (N, at least 2)")
    new.add_argument("--episodes-per-ticket", type=int, default=25,
                     help="search episodes per ticket (K); sequential: the race spends at most N x K in all")
    new.add_argument("--stopping", choices=["sequential", "fixed"], default="sequential",
                     help="sequential (default): a race runs the tickets in rounds and drops each one that "
                          "clearly trails the leader, until one is left or N x K search episodes are spent; "
                          "then it and the base run in pairs until a sequential test decides (at most "
                          "--confirm pairs). In simulation, 6 x 25 with one ticket 20 to 40 points better "
                          "than the base: 31-63%% fewer operator episodes than fixed, at equal or higher "
                          "power; false golden below --alpha (benchmarks/results/session_sequential.md). "
                          "fixed: the paper's protocol, N x K episodes, then the top 2 and the base on M "
                          "each")
    new.add_argument("--alpha", type=float, default=0.05,
                     help="type-I error: the chance of calling a ticket golden when it is no better")
    new.add_argument("--confirm", type=int, default=None,
                     help="confirm episodes per arm (M): fixed, each finalist and the base run M (default "
                          "50); sequential, at most M pairs of the finalist and the base (default 70, so "
                          "never more episodes than fixed); N x K + 3 x M (fixed) or + 2 x M is at most "
                          "100000")
    new.add_argument("--seed", type=_seed, default=0,
                     help="seed of the tickets, the order and the base noise")
    serve = session_sub.add_parser("serve", help="the operator page and the robot's HTTP API")
    serve.add_argument("folder", type=Path)
    serve.add_argument("--host", default="127.0.0.1", help="interface; other than local needs --token")
    serve.add_argument("--port", type=int, default=8765)
    serve.add_argument("--token", default=None, help="required from every client when set")
    session_sub.add_parser("score", help="score the session's episodes in this terminal").add_argument(
        "folder", type=Path)


def _joined_seed_ranges(argv: list[str]) -> list[str]:
    """`--seeds -5:3` -> `--seeds=-5:3`, so a negative range gets the range check, not argparse's
    'expected one argument'."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1] == "--seeds" and arg.startswith("-") and ":" in arg:
            out[-1] = f"--seeds={arg}"
        else:
            out.append(arg)
    return out


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(_joined_seed_ranges(sys.argv[1:] if argv is None else argv))
    previous = {s: signal.signal(s, _raise_interrupted) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return COMMANDS[args.command](args)
    except UserError as exc:
        if args.verbose:
            traceback.print_exception(exc)
        return _fail(str(exc))
    except BrokenPipeError:  # `goldenticket tickets list | head`: the reader has gone; say nothing
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as exc:  # a full disk, a read-only folder, ...: what was recorded stays
        where = f"{exc.filename}: " if exc.filename else ""
        return _fail(f"{where}{exc.strerror or exc}{RESUME.get(args.command, '')}")
    except (Interrupted, KeyboardInterrupt) as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"goldenticket: stopped by {signal.Signals(signum).name}{RESUME.get(args.command, '')}",
              file=sys.stderr)
        return 128 + signum
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _raise_interrupted(signum: int, frame) -> None:
    for s in (signal.SIGINT, signal.SIGTERM):  # a second signal must not interrupt the clean-up
        signal.signal(s, signal.SIG_IGN)
    raise Interrupted(signum)


def _fail(message: str) -> int:
    print(f"goldenticket: error: {message}", file=sys.stderr)
    return 2


def _demo(args) -> int:
    from goldenticket.workflow import SearchConfig

    return _run_search(SearchConfig(DEMO_POLICY, DEMO_TASK, seed=args.seed, workers=args.workers,
                                    backend=args.backend, address=args.address),
                       args.out)


def _search(args) -> int:
    from goldenticket.workflow import SearchConfig

    objectives = args.objective or ["success"]
    if len(objectives) > 2:
        raise UserError(f"--objective given {len(objectives)} times; a Pareto front takes two")
    budget = SearchConfig.budget if args.budget is None else args.budget
    cfg = SearchConfig(args.policy, _tasks(args.task), args.method, budget, args.seed,
                       args.search_seeds, args.heldout, args.top_k, objectives[0],
                       args.stop_after_perfect or None, args.max_tickets, args.workers, args.max_steps,
                       args.success, args.backend, args.address, args.subspace,
                       objectives[1] if len(objectives) == 2 else None, args.validation_seeds,
                       args.no_regression, max_nonfinite=args.max_nonfinite)
    if isinstance(cfg.task, tuple):
        return _run_multitask_search(cfg, args.out)
    return _run_search(cfg, args.out)


def _tasks(names: list[str]) -> str | tuple[str, ...]:
    """One --task: its name; several: the tuple of names (a multi-task run)."""
    return names[0] if len(names) == 1 else tuple(names)


def _run_multitask_search(cfg, out: Path) -> int:
    from goldenticket.multitask import find_multitask_tickets
    from goldenticket.report import multitask_text

    start = time.perf_counter()
    summary = find_multitask_tickets(cfg, out)
    print(multitask_text(summary))
    print(f"Tickets saved in {out / 'tickets'}. Wrote {out / 'summary.json'} and verdict.png in "
          f"{time.perf_counter() - start:.0f} s.")
    return 0


def _transfer(args) -> int:
    from goldenticket.multitask import transfer
    from goldenticket.report import transfer_text
    from goldenticket.workflow import SearchConfig

    tasks = _tasks(args.task)
    if not isinstance(tasks, tuple):
        raise UserError("transfer needs at least two --task")
    if args.budget is None and not args.ticket:
        raise UserError("transfer needs --budget (search episodes per task) or --ticket")
    start = time.perf_counter()
    cfg = SearchConfig(args.policy, tasks, args.method, args.budget, args.seed, args.search_seeds,
                       args.heldout, workers=args.workers, max_steps=args.max_steps, backend=args.backend,
                       address=args.address)
    print(transfer_text(transfer(cfg, args.out, args.ticket)))
    print(f"Wrote {args.out / 'transfer.json'}, transfer.csv and transfer.png in "
          f"{time.perf_counter() - start:.0f} s.")
    return 0


def _run_search(cfg, out: Path) -> int:
    from goldenticket.report import verdict_text
    from goldenticket.workflow import arm_rows, find_golden_tickets

    start = time.perf_counter()
    s = find_golden_tickets(cfg, out)
    print(verdict_text(arm_rows(s["base"], s["zero"], s["tickets"]), s["best"], s["p_value_note"]))
    if "front" in s:
        print(f"Pareto front ({cfg.objective} vs {cfg.front_objective}): {len(s['front'])} tickets "
              f"({', '.join(s['front'])}), judged on the held-out seeds in {out / 'front.json'} and "
              f"front.png; their files are in {out / 'tickets'}.")
    print(f"Best ticket saved to {s['best']['ticket_path']}. Wrote {out / 'summary.json'}, "
          f"verdict.png and search.png in {time.perf_counter() - start:.0f} s.")
    return 0


def _evaluate(args) -> int:
    from goldenticket.evaluation import p_value_note
    from goldenticket.files import check_target
    from goldenticket.plots import arms_png
    from goldenticket.policies import find_ticket
    from goldenticket.report import verdict_text
    from goldenticket.tickets import Ticket
    from goldenticket.workflow import arm_rows, evaluate_tickets, found_under

    paths = [find_ticket(ref) for ref in args.ticket]
    if args.plot is not None:
        check_target(args.plot)
        if not args.plot.parent.is_dir() or not os.access(args.plot.parent, os.W_OK):
            raise UserError(f"--plot {args.plot}: name a new file in a folder you can write to")
    rows = evaluate_tickets(args.policy, args.task, paths, list(args.seeds), args.seed, args.workers,
                            args.allow_transfer, args.max_steps, args.success, args.backend, args.address,
                            args.mixture, args.epsilon, args.max_nonfinite)
    tickets = [r | {"ticket_id": label} for label, r in rows.items()
               if label not in ("base", "zero", "mixture")]
    arms = arm_rows(rows["base"], rows["zero"], tickets)
    if args.mixture:
        epsilon = f", eps {args.epsilon:g}" if args.epsilon else ""
        arms[f"mixture of {len(tickets)}{epsilon}"] = rows["mixture"]
    best = max(tickets or [rows["zero"] | {"ticket_id": "zero"}],
               key=lambda r: (r["success_rate"], -r["p_value"]))
    if args.plot is not None:
        task = args.task or found_under([Ticket.load(p) for p in paths], {"task": None})["task"]
        arms_png(arms, args.plot, f"{args.policy} on {task}, seeds {args.seeds.start}:{args.seeds.stop}",
                 best=f"ticket {best['ticket_id']}")
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        print(verdict_text(arms, best, p_value_note(len(arms) - 2)))
        if args.mixture:
            print("diversity (RMS spread of executed actions across 5 noise streams from each of the first "
                  "10 seeds): " + ", ".join(f"{label} {r['diversity']:.3f}" for label, r in arms.items()))
        if args.plot is not None:
            print(f"Wrote {args.plot}.")
    return 0


def _train(args) -> int:
    from goldenticket.train import DemoStyle, build_policy

    style = DemoStyle(args.grasp_offset, args.action_noise, args.goal_offset)
    build_policy(args.task, args.kind, args.out, n_demos=args.demos, style=style,
                 steps=args.steps, denoise_steps=args.denoise_steps, horizon=args.horizon,
                 n_exec=args.n_exec, seed=args.seed, heldout=args.heldout)
    print(f"Wrote {args.out} (config.json, model.safetensors, MODEL_CARD.md).")
    return 0


def _policies(args) -> int:
    from goldenticket.policies import BUNDLED_DIR, policy_names
    from goldenticket.report import policy_table

    cards = [json.loads((BUNDLED_DIR / name / "card.json").read_text()) for name in policy_names()]
    if args.json:
        print(json.dumps(cards, indent=2))
        return 0
    print(policy_table(cards))
    print(f"Held-out success (95% Wilson interval) on the first {cards[0]['base']['n']} held-out seeds, "
          f"from the model cards in {BUNDLED_DIR}. DDIM policies run with another step count as NAME@N.")
    return 0


def _tickets(args) -> int:
    import numpy as np

    from goldenticket.policies import find_ticket
    from goldenticket.tickets import Ticket

    if args.tickets_command == "list":
        return _tickets_list(args.json)
    ticket = Ticket.load(find_ticket(args.ticket))
    print(f"ticket {ticket.id}  shape {tuple(ticket.noise.shape)}  "
          f"norm {np.linalg.norm(ticket.noise.astype(np.float64)):.4g}")
    print(json.dumps(ticket.metadata, indent=2))
    return 0


def _tickets_list(as_json: bool) -> int:
    from goldenticket.policies import bundled_tickets
    from goldenticket.report import ticket_table
    from goldenticket.tickets import Ticket

    paths = bundled_tickets()
    tickets = [Ticket.load(p) for p in paths]
    if as_json:
        print(json.dumps([{"id": t.id, "path": str(p)} | t.metadata
                          for t, p in zip(tickets, paths, strict=True)], indent=2))
        return 0
    print(ticket_table(tickets) if tickets else "No bundled tickets.")
    print("search: success on the search seeds; p vs base: Holm-adjusted over the tickets judged "
          "with it; fresh seeds: the 200 held-out seeds after those shown.\n"
          "Reproduce one: goldenticket evaluate --policy POLICY --task TASK --ticket ID --seeds A:B "
          "(the seeds shown give the recorded success; other held-out seeds give fresh numbers).")
    return 0


def _session(args) -> int:
    from goldenticket.session import Plan, Session

    if args.session_command == "new":
        from goldenticket.policies import load_policy, policy_label
        from goldenticket.policies.registry import identity
        from goldenticket.session.protocol import DEFAULT_CONFIRM

        policy = load_policy(args.policy)
        label = policy_label(args.policy)
        confirm = DEFAULT_CONFIRM[args.stopping] if args.confirm is None else args.confirm
        plan = Plan(label, identity(policy), tuple(policy.noise_shape), args.tickets,
                    args.episodes_per_ticket, confirm, args.seed, args.stopping, args.alpha)
        status = Session.new(args.out, plan).status()
        print(f"Planned {status['planned']} search episodes in {args.out} ({status['stage']}); at most "
              f"{plan.episodes} episodes in all ({args.stopping} stopping). "
              f"Next: goldenticket session serve {args.out}")
        return 0
    if args.session_command == "serve":
        from goldenticket.session.server import serve

        serve(args.folder, args.host, args.port, args.token)
        return 0
    from goldenticket.session.terminal import score_in_terminal

    return score_in_terminal(Session(args.folder))


COMMANDS = {"demo": _demo, "search": _search, "transfer": _transfer, "evaluate": _evaluate, "train": _train,
            "policies": _policies, "tickets": _tickets, "session": _session}

if __name__ == "__main__":
    sys.exit(main())
