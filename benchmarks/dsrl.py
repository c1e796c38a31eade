"""DSRL-SAC and DSRL-NA against CEM and CMA-ES: held-out success against wall time and env steps.

    pip install -e ".[dsrl]" && python benchmarks/dsrl.py [--minutes 60] [--na-minutes M] [--pairs TASK ...]
    robomimic-venv/bin/python benchmarks/dsrl.py --na-minutes 0 --pairs robomimic/lift  # robomimic's

DSRL (diffusion steering by RL) trains SAC whose action is the frozen policy's initial noise,
chosen per observation; goldenticket searches one constant noise. Both get the same bundled
policies, tasks, search seeds (SAC's training episodes cycle through them) and the same held-out
seeds (`Family.heldout`), and the same cores: SAC on `--workers` torch threads, the searches on `--workers`
workers (default 1: one core each, so two pairs can run side by side as two processes).

- DSRL-SAC (stable-baselines3, the DSRL authors' settings): actor and critic lr 3e-4, batch
  256, tau 0.005, gamma 0.99, 20 gradient steps per environment step (UTD 20), actions in
  [-1, 1] scaled to noise in [-1.5, 1.5]; one SAC step is one policy call (a chunk of actions),
  reward 1 on success. Trained for `--minutes` of wall time per pair; every `Family.checkpoint`
  steps the deterministic actor is judged on the held-out seeds (judging and saving time not counted).
- DSRL-NA (noise aliasing, `dsrl_na.py`): the same SAC settings and budget, but the noise critic
  is distilled from an action-space critic that learns by TD over the executed chunks (NA); it
  trains `--na-minutes` (default: `--minutes`; 0: not run).
- CEM and CMA-ES (goldenticket, paper defaults), at the family's budgets, each search timed from
  scratch; its top ticket judged on the same held-out seeds. On Meta-World every ticket runs on
  every search seed; on robomimic the searches halve as the defaults do, so CMA-ES at 1100 episodes
  is the default search before the portfolio.

Resumable: each pair's folder `--runs`/<task> keeps, per DSRL variant (a sub-folder), its model
and replay buffer, the env's counters and the curve so far (rewritten after every checkpoint),
and the base's success and every search point. A rerun continues until each variant has trained
its minutes in total, or only reports if they have. A resumed run is not bit-identical to an
uninterrupted one (SB3 reseeds its random generators on load and the episode in progress starts
over), but its curve continues.

The report says whether each DSRL curve has plateaued (`plateaued`) and, against CEM and CMA-ES,
how long each side takes to first reach the other's best held-out success, with an interval
from 95% Wilson bounds (`race`).

Writes benchmarks/results/dsrl.{md,json,png}, robomimic's pairs dsrl_robomimic.{md,json,png}
(`--no-write`: only prints the table). SAC trains in float32 torch: its numbers repeat on the
same kind of CPU only (the searches' on any).
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from results_files import write_results

from goldenticket import kernels
from goldenticket.config import EngineOptions, SearchConfig
from goldenticket.errors import UserError
from goldenticket.evaluation import Evaluator
from goldenticket.files import write_atomic
from goldenticket.job import search_only
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import load_policy
from goldenticket.rollout import Engine, Episode
from goldenticket.stats import wilson_interval
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in

# the flow policies with the lowest base: Meta-World's (the task's name) and robomimic's (robosuite's venv)
PAIRS = ("pick-place-v3", "reach-v3", "drawer-open-v3", "robomimic/lift", "robomimic/can")
VARIANTS = {"dsrl_sac": "DSRL-SAC", "dsrl_na": "DSRL-NA"}
SEARCHES = ("cem", "cma-es")
RUNS = Path(__file__).parent / "runs" / "dsrl"
NOISE_MAGNITUDE = 1.5
# buffer_size: room for every transition of a run of hours (one per policy call), saved at each checkpoint
SAC = dict(learning_rate=3e-4, batch_size=256, tau=0.005, gamma=0.99, train_freq=1, gradient_steps=20,
           learning_starts=100, buffer_size=100_000)
# DSRL-NA: one distillation step of the noise critic per two TD steps (10 per env step at UTD 20, as
# the DSRL authors' configuration)
NA = dict(distill_every=2)
SEARCH_SEEDS = 20


@dataclass(frozen=True)
class Family:
    """What differs per simulator."""

    checkpoint: int  # SAC steps between held-out judgements
    heldout: int  # held-out seeds each judgement runs
    budgets: tuple[int, ...]  # the searches' budgets, in episodes
    halving: bool | None  # the searches' (None: the default rule, halved up to 1100 episodes)
    results: str  # the results files' name
    python: str  # the interpreter in the regenerating command


# a robomimic episode is up to 400 steps, seconds on one core: its judgements are 100 episodes, its
# searches two budgets, following the defaults' halving (CMA-ES at 1100: the default before the portfolio)
FAMILIES = {"metaworld": Family(400, 200, (100, 300, 1000, 3000), False, "dsrl", "python"),
            "robomimic": Family(1000, 100, (100, 1100), None, "dsrl_robomimic", "robomimic-venv/bin/python")}


def family(pair: str) -> Family:
    return FAMILIES["robomimic" if pair.startswith("robomimic/") else "metaworld"]


def names(pair: str) -> tuple[str, str]:
    """A pair's flow policy and its task."""
    task = pair if pair.startswith("robomimic/") else f"metaworld/{pair}"
    return f"{task}/flow", task


def loaded(pair: str):
    """A pair's flow policy, loaded, and its task."""
    policy, task = names(pair)
    return load_policy(policy), get_task(task)


class NoiseSpaceEnv(gym.Env):
    """The task seen through the frozen policy: observation in, noise out (scaled from [-1, 1]);
    one step executes the chunk the policy makes from that noise; reward 1 on success."""

    def __init__(self, policy, task, seeds: list[int], magnitude: float = NOISE_MAGNITUDE):
        self.policy, self.task, self.seeds, self.magnitude = policy, task, seeds, magnitude
        self.env, self.episodes, self.env_steps = task.make_env(), 0, 0
        horizon, action_dim = policy.noise_shape
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (task.obs_dim,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (horizon * action_dim,), np.float32)

    def reset(self, *, seed=None, options=None):
        self.obs, self.t = self.env.reset(self.seeds[self.episodes % len(self.seeds)]), 0
        self.episodes += 1
        return self.obs, {}

    @property
    def chunk_dim(self) -> int:
        return self.policy.n_exec * self.policy.noise_shape[1]

    def chunks(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The chunks [B, n_exec * A] the policy makes from observations [B, ...] and actions [B, H * A]."""
        noise = (self.magnitude * np.asarray(actions, np.float32)).reshape(len(obs), *self.policy.noise_shape)
        return self.policy.act(obs, noise).reshape(len(obs), -1)

    def step(self, action):
        chunk = self.chunks(self.obs[None], np.asarray(action)[None])[0]
        success = done = False
        for a in chunk.reshape(self.policy.n_exec, -1):
            self.obs, success, done = self.env.step(a)
            self.t, self.env_steps = self.t + 1, self.env_steps + 1
            if success or done or self.t >= self.task.max_steps:
                break
        truncated = not success and (done or self.t >= self.task.max_steps)
        return self.obs, float(success), success, truncated, {"chunk": chunk}


class ActorNoise:
    """A NoisePolicy: the frozen policy driven by the SAC actor's deterministic noise (the noise
    the engine offers is ignored)."""

    def __init__(self, policy, model, magnitude: float = NOISE_MAGNITUDE):
        self.policy, self.model, self.magnitude = policy, model, magnitude
        self.noise_shape, self.n_exec = policy.noise_shape, policy.n_exec

    def act(self, obs: np.ndarray, noise: np.ndarray) -> np.ndarray:
        action, _ = self.model.predict(obs, deterministic=True)
        steered = (self.magnitude * action).reshape(len(obs), *self.noise_shape).astype(np.float32)
        return self.policy.act(obs, steered)


def heldout_success(policy, task, n: int) -> float:
    """Success on `n` held-out seeds, in the engine's shards (one env per episode of a shard)."""
    with Engine(policy, task, loaded=policy) as engine:
        results = engine.evaluate([Episode(Gaussian(0), s) for s in seeds_in("heldout", n)])
    return float(np.mean([r.success for r in results]))


def settings(workers: int, fam: Family) -> dict:
    """What a pair's folder is computed with (as JSON reads it back)."""
    return json.loads(json.dumps({"sac": SAC, "na": NA, "noise_magnitude": NOISE_MAGNITUDE,
                                  "checkpoint": fam.checkpoint, "search_seeds": SEARCH_SEEDS,
                                  "heldout": fam.heldout, "workers": workers}))


def check_settings(folder: Path, workers: int, fam: Family) -> None:
    """Record the settings in `folder`, or raise UserError if it holds a run made with others."""
    path, mine = folder / "settings.json", settings(workers, fam)
    if path.exists() and json.loads(path.read_text()) != mine:
        raise UserError(f"{folder} holds a run made with other settings (--workers included); name another "
                        "--runs folder or remove it")
    write_atomic(path, json.dumps(mine, indent=2) + "\n")


def cached(path: Path, compute: Callable):
    """`compute()`, or what it returned when first run, kept as JSON at `path`."""
    if path.exists():
        return json.loads(path.read_text())
    value = compute()
    write_atomic(path, json.dumps(value, indent=2) + "\n")
    return value


def save_checkpoint(folder: Path, model, curve: list[dict]) -> None:
    """SAC's model and replay buffer under names of their step count, then dsrl.json naming them
    with the curve so far (the checkpoint's commit), then the older files removed."""
    steps = curve[-1]["sac_steps"]
    files = {"model": f"sac-{steps}.zip", "replay_buffer": f"replay-{steps}.pkl"}
    for save, name in ((model.save, files["model"]), (model.save_replay_buffer, files["replay_buffer"])):
        data = io.BytesIO()
        save(data)
        write_atomic(folder / name, data.getvalue())
    write_atomic(folder / "dsrl.json", json.dumps(files | {"curve": curve}, indent=2) + "\n")
    kept = {folder / name for name in files.values()}
    for stale in {*folder.glob("sac-*.zip"), *folder.glob("replay-*.pkl")} - kept:
        stale.unlink()


def dsrl_model(variant: str, env: NoiseSpaceEnv, path: Path | None):
    """A DSRL variant's model on `env`: loaded from `path`, or new (seed 0) if None."""
    if variant == "dsrl_sac":
        from stable_baselines3 import SAC as algorithm
        attached, built = {}, {}
    else:
        from dsrl_na import NoiseAliasingSAC as algorithm
        attached = {"chunk_of": env.chunks}
        built = NA | {"chunk_dim": env.chunk_dim, "noise_magnitude": NOISE_MAGNITUDE}
    from stable_baselines3.common.logger import Logger

    if path is not None:
        model = algorithm.load(path, env=env, device="cpu", **attached)
    else:
        model = algorithm("MlpPolicy", env, seed=0, device="cpu", **SAC, **attached, **built)
    model.set_logger(Logger(None, []))  # SB3's own logs nowhere (its default makes a folder in /tmp)
    return model


def dsrl_curve(pair: str, variant: str, minutes: float, folder: Path) -> list[dict]:
    """A DSRL variant trained until `minutes` of wall time in total, resumed from `folder`'s last
    checkpoint (if any) and checkpointed there: (seconds, SAC steps, episodes, env steps, held-out
    success)."""
    policy, task = loaded(pair)
    env, saved = NoiseSpaceEnv(policy, task, seeds_in("search", SEARCH_SEEDS)), folder / "dsrl.json"
    if saved.exists():
        state = json.loads(saved.read_text())
        model = dsrl_model(variant, env, folder / state["model"])
        model.load_replay_buffer(folder / state["replay_buffer"])
        curve = state["curve"]
        env.episodes, env.env_steps = curve[-1]["episodes"], curve[-1]["env_steps"]
    else:
        folder.mkdir(parents=True, exist_ok=True)
        model, curve = dsrl_model(variant, env, None), []
    trained = curve[-1]["seconds"] if curve else 0.0
    while trained < 60 * minutes:
        start = time.perf_counter()
        model.learn(family(pair).checkpoint, reset_num_timesteps=False)
        trained += time.perf_counter() - start
        curve.append({"seconds": trained, "sac_steps": int(model.num_timesteps), "episodes": env.episodes,
                      "env_steps": env.env_steps,
                      "success": heldout_success(ActorNoise(policy, model), task, family(pair).heldout)})
        save_checkpoint(folder, model, curve)
        print(f"{VARIANTS[variant]} {pair}: {curve[-1]}", flush=True)
    return curve


def search_point(pair: str, method: str, budget: int, workers: int) -> dict:
    """One search of `budget` episodes timed from scratch; its top ticket judged on the held-out seeds."""
    policy_name = names(pair)[0]
    policy, task = loaded(pair)
    with tempfile.TemporaryDirectory() as tmp, RunStore(Path(tmp) / "run.sqlite") as store, \
            Evaluator.open(policy_name, task, EngineOptions(workers=workers), store,
                           loaded=policy) as evaluator:
        start = time.perf_counter()
        cfg = SearchConfig(policy_name, task.name, method, budget, seed=0, search_seeds=SEARCH_SEEDS,
                           subspace="full", stop_after_perfect=None, halving=family(pair).halving)
        result = search_only(cfg, evaluator, policy)
        seconds = time.perf_counter() - start
        env_steps = sum(row.length for row in store.episodes())
        top = (result.top(1, min_episodes=SEARCH_SEEDS) or result.top(1))[0]
        judged = evaluator.run([("top", Constant(top.ticket), seeds_in("heldout", family(pair).heldout))])[0]
    point = {"budget": budget, "seconds": seconds, "env_steps": env_steps,
             "success": float(np.mean([r.success for r in judged]))}
    print(f"{method} {pair}: {point}", flush=True)
    return point


def search_curve(pair: str, method: str, workers: int, folder: Path) -> list[dict]:
    """The search at every budget, each point kept in `folder` once judged."""
    return [cached(folder / f"{method}-{budget}.json", lambda budget=budget: search_point(pair, method,
                                                                                           budget, workers))
            for budget in family(pair).budgets]


def plateaued(curve: list[dict], n: int) -> bool:
    """Whether the curve has plateaued: it has 3 checkpoints or more and its best held-out success
    (of `n` seeds) before the last third of them is inside the 95% Wilson interval of its overall
    best, so the last third of training gained nothing beyond sampling noise."""
    best = max(p["success"] for p in curve)
    earlier = curve[:len(curve) * 2 // 3]
    return len(curve) >= 3 and max(p["success"] for p in earlier) >= wilson_interval(round(best * n), n)[0]


def reach_times(curve: list[dict], target: float, n: int) -> list[float | None]:
    """Seconds until `curve` first reaches held-out success `target` (of `n` seeds) by its 95% Wilson
    upper bound (optimistic), its estimate and its lower bound (pessimistic); None where never."""
    def bounds(p):
        low, high = wilson_interval(round(p["success"] * n), n)
        return high, p["success"], low
    return [next((p["seconds"] for p in curve if bounds(p)[i] >= target), None) for i in range(3)]


def ratio(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a / b


def race(dsrl: list[dict], search: list[dict], n: int) -> list[dict]:
    """For DSRL's best held-out success, then the search's: each side's seconds to first reach it
    (the owner's: its best checkpoint's; the other's: `reach_times`) and the speed-up, DSRL seconds
    over search seconds, as (low, estimate, high); None where a bound is never reached."""
    rows = []
    for owner in (dsrl, search):
        best = max(owner, key=lambda p: p["success"])
        d, s = ([best["seconds"]] * 3 if curve is owner else reach_times(curve, best["success"], n)
                for curve in (dsrl, search))
        rows.append({"target": best["success"], "dsrl_seconds": d, "search_seconds": s,
                     "speedup": [ratio(d[0], s[2]), ratio(d[1], s[1]), ratio(d[2], s[0])]})
    return rows


def trained(minutes: dict[str, float]) -> list[str]:
    """The DSRL variants given any minutes."""
    return [variant for variant in VARIANTS if minutes[variant] > 0]


def run_pair(pair: str, minutes: dict[str, float], folder: Path, workers: int) -> dict:
    """One pair's base, DSRL and search curves (resumed from and kept in `folder`) and verdicts;
    `minutes`: each DSRL variant's training time (0: not run)."""
    fam = family(pair)
    check_settings(folder, workers, fam)
    base = cached(folder / "base.json", lambda: heldout_success(*loaded(pair), fam.heldout))
    variants = trained(minutes)
    result = {"base": base} | {variant: dsrl_curve(pair, variant, minutes[variant], folder / variant)
                               for variant in variants}
    result |= {method: search_curve(pair, method, workers, folder) for method in SEARCHES}
    return result | {"plateaued": {variant: plateaued(result[variant], fam.heldout) for variant in variants},
                     "race": {variant: {method: race(result[variant], result[method], fam.heldout)
                                        for method in SEARCHES} for variant in variants}}


def span(values: list[float | None], form: str) -> str:
    """(low, estimate, high) as 'estimate (low to high)', one value if all equal; None: 'not reached'."""
    low, estimate, high = ("not reached" if v is None else form.format(v) for v in values)
    return estimate if low == estimate == high else f"{estimate} ({low} to {high})"


def markdown(results: dict, minutes: dict[str, float]) -> str:
    """The pairs' table (one family's) and their races."""
    fam, variants = family(next(iter(results))), {v: VARIANTS[v] for v in trained(minutes)}

    def cells(curve):
        return "<br>".join(f"{p['budget']}: {p['seconds']:.0f} s, {p['env_steps']}, {p['success']:.0%}"
                           for p in curve)

    def best(curve):
        top = max(curve, key=lambda p: p["success"])
        return f"{top['success']:.0%} ({top['seconds']:.0f} s, {top['sac_steps']} steps, {top['env_steps']})"

    na = "" if minutes["dsrl_na"] == minutes["dsrl_sac"] else f" --na-minutes {minutes['dsrl_na']:g}"
    lines = [f"Regenerate: `{fam.python} benchmarks/dsrl.py --minutes {minutes['dsrl_sac']:g}{na} --pairs "
             f"{' '.join(results)}` (resumes from benchmarks/runs/dsrl/).", "",
             "| task (flow policy) | base | " + " | ".join(
                 f"{name} best (at s, SAC steps, env steps) | plateaued" for name in variants.values())
             + " | " + " | ".join(f"{m.upper()}: budget, s, env steps, success" for m in SEARCHES) + " |",
             "|---|---|" + "---|---|" * len(variants) + "---|" * len(SEARCHES)]
    for task, r in results.items():
        lines.append(f"| {task} | {r['base']:.0%} | " + " | ".join(
            f"{best(r[v])} | {'yes' if r['plateaued'][v] else 'no'}" for v in variants)
            + " | " + " | ".join(cells(r[m]) for m in SEARCHES) + " |")
    lines += ["", "| task | DSRL | search | target: best held-out success of | DSRL, s | search, s | "
              "speed-up (DSRL s / search s) |", "|---|---|---|---|---|---|---|"]
    for task, r in results.items():
        for variant, name in variants.items():
            for method, rows in r["race"][variant].items():
                for owner, row in zip((name, method.upper()), rows, strict=True):
                    seconds = (span(row[side], "{:.0f} s") for side in ("dsrl_seconds", "search_seconds"))
                    lines.append(f"| {task} | {name} | {method.upper()} | {owner}, {row['target']:.0%} | "
                                 + " | ".join(seconds) + f" | {span(row['speedup'], '{:.2g}x')} |")
    spent = " and ".join(f"{name} {minutes[variant]:g} min" for variant, name in variants.items())
    halved = " (halved up to 1100 episodes, as the defaults)" if fam.halving is None else ""
    lines += ["", f"Held-out success on {fam.heldout} held-out seeds; trained per pair: {spent}, judged "
              f"every {fam.checkpoint} SAC steps; each search{halved} timed from scratch at each "
              "budget. Plateaued: with 3 checkpoints or more, the best success before the last third of them "
              "is inside the 95% Wilson interval of the overall best (the last third gained nothing beyond "
              "sampling noise). Seconds to a target: the owner's are those of its best checkpoint or budget; "
              "the other side's are its first to reach the target, by the estimate (from the 95% Wilson "
              "upper bound, optimistic, to the lower bound, pessimistic)."]
    return "\n".join(lines) + "\n"


def plot(results: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5 * len(results), 4))
    styles = dict(zip((*VARIANTS, *SEARCHES), ("-o", "-D", "-s", "--^"), strict=True))
    labels = VARIANTS | {method: method.upper() for method in SEARCHES}
    for ax, (task, r) in zip(np.atleast_1d(fig.subplots(1, len(results))), results.items(), strict=True):
        for name in (name for name in labels if name in r):  # a DSRL variant not trained is absent
            ax.plot([p["seconds"] for p in r[name]], [p["success"] for p in r[name]], styles[name],
                    label=labels[name])
        ax.axhline(r["base"], color="0.45", linestyle="--", label="base")
        ax.set(xscale="log", title=f"{task} (flow)", xlabel="wall time, s", ylim=(0, 1),
               ylabel=f"held-out success ({family(task).heldout})")
        ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0,
                        help="each DSRL variant's training time per pair, in total over resumed runs")
    parser.add_argument("--na-minutes", type=float,
                        help="DSRL-NA's training time per pair instead (default: --minutes; 0: not run)")
    parser.add_argument("--pairs", nargs="+", choices=PAIRS, default=PAIRS[:2], metavar="TASK",
                        help=f"tasks to run, of one simulator: {', '.join(PAIRS)} (default: the first two)")
    parser.add_argument("--runs", type=Path, default=RUNS, help="folder of the pairs' resumable runs")
    parser.add_argument("--workers", type=int, default=1,
                        help="SAC's torch threads and the searches' workers (default: 1)")
    parser.add_argument("--no-write", action="store_true", help="print the table, write no results files")
    args = parser.parse_args()
    na = args.minutes if args.na_minutes is None else args.na_minutes
    minutes = {"dsrl_sac": args.minutes, "dsrl_na": na}
    if args.minutes <= 0 or na < 0 or args.workers < 1:
        parser.error("--minutes must be > 0, --na-minutes >= 0 and --workers >= 1")
    families = {family(pair) for pair in args.pairs}
    if len(families) > 1:
        parser.error("--pairs: Meta-World's and robomimic's run in venvs of their own; give one simulator's")
    fam = families.pop()
    torch.set_num_threads(args.workers)
    try:
        results = {task: run_pair(task, minutes, args.runs / task, args.workers) for task in args.pairs}
    except UserError as exc:
        parser.error(str(exc))
    text = markdown(results, minutes)
    if args.no_write:
        print(text)
        return
    record = {"settings": settings(args.workers, fam) | {"budgets": fam.budgets, "halving": fam.halving,
                                                         "minutes": minutes}, "results": results}
    write_results(fam.results, record, text, lambda path: plot(results, path))


if __name__ == "__main__":
    kernels.restart_pinned(sys.argv)  # robomimic's pairs: as the CLI pins, before any work
    main()
