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
from goldenticket.config import (
    EngineOptions,
    EvaluateConfig,
    SearchConfig,
    TrainConfig,
    cli_fields,
    make,
    read_toml,
    seed_range,
    spelled_flags,
)
from goldenticket.errors import OptionError, UserError, flag, flags_in

DEMO_POLICY, DEMO_TASK = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3"
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
        return seed_range(text)
    except UserError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("seeds: ")) from None


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


def _config_flags(p: argparse.ArgumentParser, cls, skip: tuple[str, ...] = (),
                  config_file: bool = True) -> None:
    """A flag per field of the config `cls` (`search_seeds` -> `--search-seeds`), with the field's
    help and default; values not given stay unset, so a --config file can supply them."""
    if config_file:
        p.add_argument("--config", type=Path, default=None,
                       help="a TOML file of options (keys are the options' names with _, e.g. search_seeds); "
                            "flags override it. Every search writes the one it ran with to --out/config.toml")
    named, spelled = [g.name for g in cli_fields(cls) if "_" in g.name], spelled_flags()  # plain words stay
    for f in cli_fields(cls, skip):
        cli = dict(f.metadata["cli"])
        name, required = cli.pop("flag", flag(f.name)), cli.pop("required", False)
        help_text = flags_in(_help(f, required), named, spelled)
        kwargs = {"dest": f.name, "default": argparse.SUPPRESS, "help": help_text}
        if cli.pop("seed_range", False):
            kwargs["type"] = _seed_range
        if cli.get("action") is None:
            kwargs |= {"action": _Once, "type": kwargs.get("type", _parse_type(f.type))}
        p.add_argument(name, **kwargs | cli)


class _Once(argparse.Action):
    """A flag that takes one value: given twice, an error, not the last one silently."""

    def __call__(self, parser, namespace, values, option_string=None):
        if hasattr(namespace, self.dest):
            parser.error(f"{option_string} given twice; give it once")
        setattr(namespace, self.dest, values)


def _help(f, required: bool) -> str:
    unsaid = required or any(f.default is v for v in (None, False)) or f.default == () \
        or "default" in f.metadata["help"]
    return f.metadata["help"] + ("" if unsaid else f" (default: {f.default})")


def _parse_type(annotation: str):
    """The command-line type of a field annotated `annotation` (a string: postponed annotations)."""
    return int if "int" in annotation.split(" | ") else float if annotation == "float" else str


def _out_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True,
                   help="output folder: run.sqlite (every episode; rerun to resume), summary.json, "
                        "tickets/, verdict.png, search.png, config.toml, log.csv")


def _options(args, cls) -> dict:
    """The config's values: the --config file's, then the flags given."""
    values = read_toml(args.config) if getattr(args, "config", None) else {}
    return values | {f.name: getattr(args, f.name) for f in cli_fields(cls) if hasattr(args, f.name)}


def _transfer_parser(sub) -> None:
    tr = sub.add_parser("transfer", help="one ticket per task of a multi-task policy, each judged on every "
                                         "task: the transfer matrix and the smallest set that covers them")
    tr.add_argument("--ticket", action="append", default=[],
                    help="take these tickets (files or bundled ids) instead of searching one per task")
    _config_flags(tr, SearchConfig, skip=TRANSFER_SKIPS)
    _out_arg(tr)


TRANSFER_SKIPS = ("tickets", "top_k", "objective", "front_objective", "stop_after_perfect", "max_tickets",
                  "success", "subspace", "no_regression", "max_nonfinite")


def _search_parser(sub) -> None:
    search = sub.add_parser("search", help="search golden tickets for a policy on a task")
    _config_flags(search, SearchConfig)
    _out_arg(search)


def _evaluate_parser(sub) -> None:
    ev = sub.add_parser("evaluate", help="judge tickets against the base policy on held-out seeds")
    _config_flags(ev, EvaluateConfig)
    ev.add_argument("--plot", type=Path, default=None,
                    help="write a PNG of success with intervals per arm to this file (default: none)")
    ev.add_argument("--json", action="store_true", help="print one JSON object instead of the table")


def _train_parser(sub) -> None:
    tr = sub.add_parser("train", help="train a policy on imperfect scripted-expert demonstrations")
    tr.add_argument("--out", type=Path, required=True, help="new policy folder to write")
    _config_flags(tr, TrainConfig)


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="goldenticket", description=__doc__)
    parser.add_argument("--version", action="version", version=f"goldenticket {__version__}")
    parser.add_argument("--verbose", action="store_true",
                        help="on an error, also print its full traceback (an error in your own policy, "
                             "env or success predicate is otherwise one line naming its file and line)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    demo = sub.add_parser("demo", help=f"search and judge a golden ticket for the bundled {DEMO_POLICY}")
    _config_flags(demo, EngineOptions, skip=("max_nonfinite",), config_file=False)
    demo.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    _out_arg(demo)
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
        return _fail(exc.as_flags(spelled_flags()) if isinstance(exc, OptionError) else str(exc))
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
    options = _options(args, EngineOptions) | {"seed": args.seed}
    return _run_search(make(SearchConfig, {"policy": DEMO_POLICY, "task": DEMO_TASK} | options), args.out)


def _search(args) -> int:
    return _run_search(make(SearchConfig, _options(args, SearchConfig)), args.out)


def _transfer(args) -> int:
    from goldenticket.multitask import transfer
    from goldenticket.report import transfer_text

    options = _options(args, SearchConfig)
    if "budget" not in options and not args.ticket:
        raise UserError("transfer needs --budget (search episodes per task) or --ticket")
    cfg = make(SearchConfig, options)
    if len(cfg.tasks) < 2:
        raise UserError("transfer needs at least two --task")
    start = time.perf_counter()
    print(transfer_text(transfer(cfg, args.out, args.ticket)))
    print(f"Wrote {args.out / 'transfer.json'}, transfer.csv and transfer.png in "
          f"{time.perf_counter() - start:.0f} s.")
    return 0


def _run_search(cfg, out: Path) -> int:
    from goldenticket.report import multitask_text, verdict_text
    from goldenticket.workflow import find_golden_tickets

    start = time.perf_counter()
    s = find_golden_tickets(cfg, out)
    if len(cfg.tasks) > 1:
        print(multitask_text(s))
        print(f"Tickets saved in {out / 'tickets'}. Wrote {out / 'summary.json'}, verdict.png and search.png "
              f"in {time.perf_counter() - start:.0f} s.")
        return 0
    print(verdict_text(s.rows(), s.best.heldout, s.best.name, s.p_value_note))
    if s.front is not None:
        print(f"Pareto front ({cfg.objective} vs {cfg.front_objective}): {len(s.front.tickets)} tickets "
              f"({', '.join(s.front.tickets)}), judged on the held-out seeds in {out / 'front.json'} and "
              f"front.png; their files are in {out / 'tickets'}.")
    print(f"Best ticket saved to {s.best.path}. Wrote {out / 'summary.json'}, "
          f"verdict.png and search.png in {time.perf_counter() - start:.0f} s.")
    return 0


def _evaluate(args) -> int:
    from goldenticket.evaluation import p_value_note, to_dicts
    from goldenticket.files import check_target
    from goldenticket.plots import arms_png
    from goldenticket.policies import find_ticket
    from goldenticket.report import verdict_text
    from goldenticket.results import arm_rows
    from goldenticket.tickets import Ticket
    from goldenticket.workflow import evaluate_tickets, found_under

    cfg = make(EvaluateConfig, _options(args, EvaluateConfig))
    paths = [find_ticket(ref) for ref in cfg.tickets]
    if args.plot is not None:
        check_target(args.plot)
        if not args.plot.parent.is_dir() or not os.access(args.plot.parent, os.W_OK):
            raise UserError(f"--plot {args.plot}: name a new file in a folder you can write to")
    rows = evaluate_tickets(cfg)
    tickets = {label: r for label, r in rows.items() if label not in ("base", "zero", "mixture")}
    arms = arm_rows(rows["base"], rows["zero"], tickets)
    if cfg.mixture:
        epsilon = f", eps {cfg.epsilon:g}" if cfg.epsilon else ""
        arms[f"mixture of {len(tickets)}{epsilon}"] = rows["mixture"]
    candidates = tickets or {"zero": rows["zero"]}
    best = max(candidates, key=lambda t: (candidates[t].rate.success_rate, -candidates[t].p_vs_base))
    if args.plot is not None:
        task = cfg.task or found_under([Ticket.load(p) for p in paths], {"task": None})["task"]
        title = f"{cfg.policy} on {task}, seeds {cfg.seeds.start}:{cfg.seeds.stop}"
        arms_png(to_dicts(arms), args.plot, title, best=f"ticket {best}")
    if args.json:
        print(json.dumps(to_dicts(rows), indent=2))
    else:
        print(verdict_text(arms, candidates[best], best, p_value_note(len(arms) - 2)))
        if cfg.mixture:
            print("diversity (RMS spread of executed actions across 5 noise streams from each of the first "
                  "10 seeds): " + ", ".join(f"{label} {r.diversity:.3f}" for label, r in arms.items()))
        if args.plot is not None:
            print(f"Wrote {args.plot}.")
    return 0


def _train(args) -> int:
    from goldenticket.train import build_policy

    build_policy(make(TrainConfig, _options(args, TrainConfig)), args.out)
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
