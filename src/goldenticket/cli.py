"""goldenticket: find one constant noise (a golden ticket) that makes a frozen diffusion or
flow-matching policy succeed more often, and prove it on held-out initial states."""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import json
import os
import signal
import sys
import time
import tomllib
import traceback
import typing
from dataclasses import MISSING, fields
from pathlib import Path

from goldenticket import __version__, kernels
from goldenticket.config import (
    CheckConfig,
    CompareConfig,
    EvaluateConfig,
    SearchConfig,
    ServeConfig,
    SessionConfig,
    TrainConfig,
    TransferOptions,
    cli_fields,
    make,
    read_toml,
    seed_range,
    spelled_flags,
)
from goldenticket.errors import OptionError, UserError, flag, flags_in
from goldenticket.files import check_target
from goldenticket.options import field_types
from goldenticket.zoo import bundled_task, check_name, find_ticket

DEMO_POLICY, DEMO_TASK = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3"
PENDING = "(the policy's own task)"  # stands in for a task found later, while the other options are checked
RESUME = dict.fromkeys(("demo", "search", "transfer"),
                       " (finished episodes are kept in --out: rerun the same command to resume)")


class Interrupted(BaseException):
    """Ctrl-C or SIGTERM: stop, keep what is recorded, exit 128 + signal number."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _seed_range(text: str) -> range:
    try:
        return seed_range(text)
    except UserError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("seeds: ")) from None


class _HelpFormatter(argparse.HelpFormatter):
    """Each option's help ends with "(required)", or with its default where it has one worth saying
    (the generated flags' help has it already: their argparse default is SUPPRESS)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        required = action.required and bool(action.option_strings)  # not a positional argument
        return _with_default(action.help or "", action.default, required)


class _Parser(argparse.ArgumentParser):
    def __init__(self, **kwargs):
        super().__init__(formatter_class=_HelpFormatter, **kwargs)

    def error(self, message: str):  # one clear line, exit 2
        if message.startswith("argument --seed: invalid int value") and ":" in message.partition("value:")[2]:
            message += "; --seed is the run's random seed, a range of seeds A:B is --seeds"
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _config_flags(p: argparse.ArgumentParser, cls, skip: tuple[str, ...] = (),
                  config_file: bool = True) -> None:
    """A flag per field of the config `cls` (`search_seeds` -> `--search-seeds`), with the field's
    help and default; values not given stay unset, so a --config file can supply them."""
    if config_file:
        p.add_argument("--config", type=Path, default=None,
                       help="a TOML file of options (keys are the options' names with _, e.g. search_seeds); "
                            "flags override it. Every search writes the one it ran with to --out/config.toml")
    named = [g.name for g in cli_fields(cls) if "_" in g.name]  # plain words stay
    spelled = spelled_flags(cls)
    for f in cli_fields(cls, skip):
        cli = dict(f.metadata["cli"])
        name = cli.pop("flag", flag(f.name))
        help_text = _with_default(f.metadata["help"], f.default, f.default is MISSING)
        kwargs = {"dest": f.name, "default": argparse.SUPPRESS,
                  "help": flags_in(help_text, named, spelled).replace("%", "%%")}
        if cli.pop("seed_range", False):
            kwargs["type"] = _seed_range
        if cli.pop("key_values", False):
            cli["action"] = _KeyValues
        if cli.get("action") is None:
            kwargs |= {"action": _Once, "type": kwargs.get("type", _parse_type(field_types(cls)[f.name]))}
        p.add_argument(name, **kwargs | cli)


class _KeyValues(argparse.Action):
    """KEY=VALUE flags into one dict, each value read as TOML (40, 0.5, [[0, 1]]) or else a string."""

    def __call__(self, parser, namespace, values, option_string=None):
        key, equals, text = values.partition("=")
        if not (key and equals):
            parser.error(f"{option_string} takes KEY=VALUE, got {values!r}")
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text
        setattr(namespace, self.dest, getattr(namespace, self.dest, {}) | {key: value})


class _Once(argparse.Action):
    """A flag that takes one value: given twice, an error, not the last one silently."""

    def __call__(self, parser, namespace, values, option_string=None):
        if hasattr(namespace, self.dest):
            parser.error(f"{option_string} given twice; give it once")
        setattr(namespace, self.dest, values)


def _with_default(text: str, default, required: bool) -> str:
    """`text` ending in "(required)", or in `default` unless it is none, false or empty; as it is where
    it says its default already."""
    if "(default" in text:
        return text
    if required:
        return f"{text} (required)"
    if any(default is v for v in (None, False, argparse.SUPPRESS)) or default in ((), []):
        return text
    shown = f"{default.start}:{default.stop}" if isinstance(default, range) else default
    return f"{text} (default: {shown})"


def _parse_type(hint):
    """The command-line type of a field of type `hint`: int or float where the hint is one (alone or
    with None), else str."""
    kinds = typing.get_args(hint) or (hint,)
    return next((kind for kind in (int, float) if kind in kinds), str)


def _folder(name: str) -> Path:
    """An output folder's name as typed (Path("") would be the current folder)."""
    if not name:
        raise argparse.ArgumentTypeError("empty; name a folder")
    return Path(name)


def _out_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=_folder, required=True,
                   help="output folder: run.sqlite (every episode; rerun to resume), summary.json, "
                        "tickets/, verdict.png, search.png, config.toml, log.csv")


def _options(args, cls, skip: tuple[str, ...] = ()) -> dict:
    """The config's values: the --config file's, then the flags given (but those of `skip`)."""
    values = read_toml(args.config) if getattr(args, "config", None) else {}
    return values | {f.name: getattr(args, f.name) for f in cli_fields(cls, skip) if hasattr(args, f.name)}


def _transfer_parser(sub) -> None:
    tr = sub.add_parser("transfer", help="one ticket per task of a multi-task policy, each judged on every "
                                         "task: the transfer matrix and the smallest set that covers them")
    _config_flags(tr, TransferOptions)
    own = tuple(f.name for f in fields(TransferOptions))
    _config_flags(tr, SearchConfig, skip=TRANSFER_SKIPS + own, config_file=False)
    _out_arg(tr)


TRANSFER_SKIPS = ("tickets", "top_k", "objective", "front_objective", "stop_after_perfect", "max_tickets",
                  "success", "subspace", "no_regression", "max_nonfinite")
DEMO_OPTIONS = ("seed", "workers", "backend", "address")  # the demo's flags; the policy and task are its own


def _search_parser(sub) -> None:
    search = sub.add_parser("search", help="search golden tickets for a policy on a task")
    _config_flags(search, SearchConfig)
    _out_arg(search)


def _evaluate_parser(sub) -> None:
    ev = sub.add_parser("evaluate", help="judge tickets against the base policy on held-out seeds")
    _config_flags(ev, EvaluateConfig)
    _plot_and_json_args(ev)


def _compare_parser(sub) -> None:
    cmp = sub.add_parser("compare", help="policy A against policy B (or one policy with and without a "
                                         "ticket) on the same held-out seeds: a paired A/B test")
    _config_flags(cmp, CompareConfig)
    cmp.add_argument("--out", type=_folder, default=None,
                     help="folder for the run store (run.sqlite: every episode; rerun the same command to "
                          "resume, or with more seeds to add them) (default: none, nothing written)")
    _plot_and_json_args(cmp)


def _plot_and_json_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--plot", type=Path, default=None,
                   help="write a PNG of success with intervals per arm to this file (default: none)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")


def _check_plot(path: Path | None) -> None:
    """UserError, before any episode, unless --plot names a new or regular file in a folder one can
    write to."""
    if path is not None:
        check_target(path)
        if not path.parent.is_dir() or not os.access(path.parent, os.W_OK):
            raise UserError(f"--plot {path}: name a new file in a folder you can write to")


def _train_parser(sub) -> None:
    tr = sub.add_parser("train", help="train a policy on imperfect scripted-expert demonstrations")
    tr.add_argument("--out", type=_folder, required=True, help="new policy folder to write")
    _config_flags(tr, TrainConfig)


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="goldenticket", description=__doc__)
    parser.add_argument("--version", action="version", version=f"goldenticket {__version__}")
    parser.add_argument("--verbose", action="store_true",
                        help="on an error, also print its full traceback (an error in your own policy, "
                             "env or success predicate is otherwise one line naming its file and line)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    demo = sub.add_parser("demo", help=f"search and judge a golden ticket for the bundled {DEMO_POLICY}")
    skip = tuple(f.name for f in fields(SearchConfig) if f.name not in DEMO_OPTIONS)
    _config_flags(demo, SearchConfig, skip=skip, config_file=False)
    _out_arg(demo)
    _search_parser(sub)
    _transfer_parser(sub)
    _evaluate_parser(sub)
    _compare_parser(sub)
    _train_parser(sub)
    _config_flags(sub.add_parser("check", help="check a policy on a task before a search: the checks every "
                                               "search runs, one line each"), CheckConfig, config_file=False)
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
    _config_flags(new, SessionConfig, config_file=False)
    new.add_argument("--out", type=_folder, required=True, help="session folder")
    serve = session_sub.add_parser("serve", help="the operator page and the robot's HTTP API")
    serve.add_argument("folder", type=Path)
    _config_flags(serve, ServeConfig, config_file=False)
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
    _trace_crashes()
    try:
        kernels.pin(_names(args))
        return COMMANDS[args.command](args)
    except UserError as exc:
        if args.verbose:
            traceback.print_exception(exc)
        spelled = spelled_flags(*CONFIGS.get(args.command, ()))
        return _fail(exc.as_flags(spelled) if isinstance(exc, OptionError) else str(exc))
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


def _names(args) -> list:
    """The policy and tasks a command names (its flags, then its --config file's), before any runs."""
    given = read_toml(args.config) if getattr(args, "config", None) else {}
    given |= {key: getattr(args, key) for key in ("policy", "against", "task") if hasattr(args, key)}
    task = given.get("task")
    return [given.get("policy"), *(task if isinstance(task, list | tuple) else [task])]


def _trace_crashes() -> None:
    """A crash in C code (a segfault in an env's simulator, say) prints the Python traceback of the call
    it happened in (as each local worker does before the one line saying how it ended)."""
    if not faulthandler.is_enabled():
        with contextlib.suppress(AttributeError, OSError, RuntimeError, ValueError):  # stderr is no file
            faulthandler.enable()


def _raise_interrupted(signum: int, frame) -> None:
    for s in (signal.SIGINT, signal.SIGTERM):  # a second signal must not interrupt the clean-up
        signal.signal(s, signal.SIG_IGN)
    raise Interrupted(signum)


def _fail(message: str) -> int:
    print(f"goldenticket: error: {message}", file=sys.stderr)
    return 2


def _demo(args) -> int:
    options = {"policy": DEMO_POLICY, "task": DEMO_TASK} | _options(args, SearchConfig)
    return _run_search(make(SearchConfig, options), args.out)


def _search(args) -> int:
    options = _options(args, SearchConfig)
    make(SearchConfig, {"task": PENDING} | options).check()  # a bad option answers before anything loads
    _check_names(options)
    return _run_search(make(SearchConfig, _with_bundled_task(options)), args.out)


def _check_names(options: dict) -> None:
    """A misspelt policy or task name, or an env option the task does not take, answers before any
    model or simulator loads."""
    check_name(options.get("policy"))
    tasks = options.get("task")
    if tasks is not None:
        from goldenticket.tasks.registry import check_task

        for task in tasks if isinstance(tasks, list | tuple) else [tasks]:
            check_task(task, options.get("env_option"))


def _with_bundled_task(options: dict) -> dict:
    """The options, with the task a bundled single-task policy was trained on where none is given."""
    if "task" in options or not isinstance(options.get("policy"), str):
        return options
    task = bundled_task(options["policy"])
    return options if task is None else options | {"task": task}


def _transfer(args) -> int:
    options = _options(args, SearchConfig, skip=("tickets",))
    own = make(TransferOptions, {"budget": options.get("budget"), "tickets": getattr(args, "tickets", ())})
    own.check()
    cfg = make(SearchConfig, options)
    if len(cfg.tasks) < 2:
        raise UserError("transfer needs at least two --task")
    cfg.check()

    from goldenticket.multitask import transfer
    from goldenticket.report import transfer_text

    start = time.perf_counter()
    print(transfer_text(transfer(cfg, args.out, list(own.tickets))))
    print(f"Wrote {args.out / 'transfer.json'}, transfer.csv and transfer.png in "
          f"{time.perf_counter() - start:.0f} s.")
    return 0


def _run_search(cfg, out: Path) -> int:
    cfg.check()
    from goldenticket.job import find_golden_tickets
    from goldenticket.report import multitask_text, verdict_text

    start = time.perf_counter()
    s = find_golden_tickets(cfg, out)
    if len(cfg.tasks) > 1:
        print(multitask_text(s))
        print(f"Tickets saved in {out / 'tickets'}. Wrote {out / 'summary.json'}, verdict.png and search.png "
              f"in {time.perf_counter() - start:.0f} s.")
        return 0
    print(verdict_text(s.table(), s.best.heldout, s.best.name, s.p_value_note))
    if s.front is not None:
        print(f"Pareto front ({cfg.objective} vs {cfg.front_objective}): {len(s.front.tickets)} tickets "
              f"({', '.join(s.front.tickets)}), judged on the held-out seeds in {out / 'front.json'} and "
              f"front.png; their files are in {out / 'tickets'}.")
    print(f"Best ticket saved to {s.best.path}. Wrote {out / 'summary.json'}, "
          f"verdict.png and search.png in {time.perf_counter() - start:.0f} s.")
    return 0


def _evaluate(args) -> int:
    cfg = make(EvaluateConfig, _options(args, EvaluateConfig))
    cfg.check()  # a bad option, policy or task name or ticket answers before anything loads
    _check_names({"policy": cfg.policy, "task": cfg.task, "env_option": cfg.env_option})
    paths = [find_ticket(ref) for ref in cfg.tickets]
    _check_plot(args.plot)
    from goldenticket.evaluation import BASE, MIXTURE, ZERO, Kind, p_value_note, to_dicts
    from goldenticket.job.evaluate import evaluate_tickets, found_under
    from goldenticket.plots import arms_png
    from goldenticket.report import verdict_text
    from goldenticket.results import VerdictTable
    from goldenticket.tickets import Ticket

    rows = evaluate_tickets(cfg)
    tickets = {arm: r for arm, r in rows.items() if arm.kind is Kind.TICKET}
    shown = {arm.label: r for arm, r in tickets.items()}
    if cfg.mixture:
        epsilon = f", eps {cfg.epsilon:g}" if cfg.epsilon else ""
        shown[f"mixture of {len(tickets)}{epsilon}"] = rows[MIXTURE]
    table = VerdictTable(rows[BASE], rows[ZERO], shown)
    candidates = tickets or {ZERO: rows[ZERO]}
    best = max(candidates, key=lambda t: (candidates[t].rate.success_rate, -candidates[t].p_vs_base))
    if args.plot is not None:
        task = cfg.task or found_under([Ticket.load(p) for p in paths], {"task": None})["task"]
        title = f"{cfg.policy} on {task}, seeds {min(cfg.seeds)}:{max(cfg.seeds) + 1}"
        arms_png(table.rows(), args.plot, title, best=best.label)
    if args.json:
        print(json.dumps(to_dicts(rows), indent=2))
    else:
        name = "w = 0, the zero ticket" if best == ZERO else best.key
        print(verdict_text(table, candidates[best], name, p_value_note(table.adjusted_over)))
        if cfg.mixture:
            spread = ", ".join(f"{label} {r.diversity:.3f}" for label, r in table.rows().items())
            print("diversity (RMS spread of executed actions across 5 noise streams from each of the first "
                  f"10 seeds): {spread}")
        if args.plot is not None:
            print(f"Wrote {args.plot}.")
    return 0


def _compare(args) -> int:
    cfg = make(CompareConfig, _options(args, CompareConfig))
    cfg.check()  # a bad option, policy or task name or ticket answers before anything loads
    _check_names({"policy": cfg.policy, "task": cfg.task, "env_option": cfg.env_option})
    check_name(cfg.against)
    for ref in (cfg.ticket, cfg.against_ticket):
        if ref is not None:
            find_ticket(ref)
    _check_plot(args.plot)
    from goldenticket.job.compare import compare_policies
    from goldenticket.plots import comparison_png
    from goldenticket.report import comparison_text

    comparison = compare_policies(cfg, args.out)
    if args.plot is not None:
        first, last = comparison.seeds
        comparison_png(comparison, args.plot, f"{comparison.task}, seeds {first}:{last + 1}")
    if args.json:
        print(json.dumps(comparison.to_dict(), indent=2))
        return 0
    print(comparison_text(comparison))
    if args.out is not None:
        print(f"Every episode is kept in {args.out / 'run.sqlite'}: rerun the command to resume.")
    if args.plot is not None:
        print(f"Wrote {args.plot}.")
    return 0


def _train(args) -> int:
    cfg = make(TrainConfig, _options(args, TrainConfig))
    cfg.check()
    from goldenticket.train import build_policy

    build_policy(cfg, args.out)
    print(f"Wrote {args.out} (config.json, model.safetensors, MODEL_CARD.md).")
    return 0


def _check(args) -> int:
    options = _options(args, CheckConfig)
    make(CheckConfig, {"task": PENDING} | options).check()
    cfg = make(CheckConfig, _with_bundled_task(options))
    cfg.check()
    from goldenticket.checks import results
    from goldenticket.policies import load_policy
    from goldenticket.tasks import get_task

    policy = load_policy(cfg.policy, cfg.device, **cfg.policy_settings())
    task = get_task(cfg.task, success=cfg.success, env_options=cfg.env_option)
    ran = []
    for result in results(task, policy):
        print(result, flush=True)
        ran.append(result)
    if failed := [r.name for r in ran if not r.passed]:
        raise UserError(f"{len(failed)} of {len(ran)} checks failed: {'; '.join(failed)}")
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

        cfg = make(SessionConfig, _options(args, SessionConfig))
        cfg.check()
        policy = load_policy(cfg.policy)
        plan = Plan(policy_label(cfg.policy), identity(policy), tuple(policy.noise_shape), cfg.tickets,
                    cfg.episodes_per_ticket, cfg.confirm_episodes(), cfg.seed, cfg.stopping, cfg.alpha)
        status = Session.new(args.out, plan).status()
        print(f"Planned {status['planned']} search episodes in {args.out} ({status['stage']}); at most "
              f"{plan.episodes} episodes in all ({cfg.stopping} stopping). "
              f"Next: goldenticket session serve {args.out}")
        return 0
    if args.session_command == "serve":
        from goldenticket.session.server import serve

        cfg = make(ServeConfig, _options(args, ServeConfig))
        serve(args.folder, cfg.host, cfg.port, cfg.token)
        return 0
    from goldenticket.session.terminal import score_in_terminal

    return score_in_terminal(Session(args.folder))


CONFIGS = {"demo": (SearchConfig,), "search": (SearchConfig,), "transfer": (TransferOptions, SearchConfig),
           "evaluate": (EvaluateConfig,), "compare": (CompareConfig,), "train": (TrainConfig,),
           "check": (CheckConfig,), "session": (SessionConfig, ServeConfig)}
COMMANDS = {"demo": _demo, "search": _search, "transfer": _transfer, "evaluate": _evaluate,
            "compare": _compare, "train": _train, "check": _check, "policies": _policies, "tickets": _tickets,
            "session": _session}

if __name__ == "__main__":
    sys.exit(main())
