"""goldenticket: golden-ticket search for frozen diffusion and flow-matching robot policies.

`search`, `evaluate` and `compare` are the Python twins of `goldenticket search`, `goldenticket
evaluate` and `goldenticket compare`: same optimizers, statistics, run store, resume and worker pool.

- `policy`: a NoisePolicy object (`goldenticket.policies.NoisePolicy`: `noise_shape`, `n_exec`,
  `act(obs, noise)`), a bundled policy name, a policy folder, or an import string
  `package.module:factory` whose factory returns a NoisePolicy.
- `task`: a built-in task name (`metaworld/pick-place-v3`), or a function returning a
  `gymnasium.Env` whose `reset(seed=s)` fixes the initial state, or its import string.
  `success=`: a predicate `(obs, info) -> bool` (or its import string) when the env's info
  has no `success` / `is_success`.

With `workers` > 1, worker processes receive objects pickled: define factories and predicates
at module level (and guard a script's entry point with `if __name__ == "__main__":`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

__version__ = "0.1.0"


def search(policy, task, out: str | Path, **options):
    """Search tickets and judge the best on held-out seeds into `out` (resumable); returns a
    `results.Summary` (`summary.best.heldout.golden`, `summary.best.path`; `.to_dict()` is
    summary.json), or a `results.MultitaskSummary` when `task` is several task names (a tuple):
    one ticket for a multi-task policy. `options`: the fields
    of `config.SearchConfig` (method, budget, seed, search_seeds, heldout, top_k, objective,
    front_objective, stop_after_perfect, max_tickets, race, halving, max_steps, success, subspace,
    validation_seeds, no_regression, tickets, log, optimizer, workers, backend, address,
    max_nonfinite, device, step_timeout)."""
    from goldenticket.config import SearchConfig, make
    from goldenticket.job import find_golden_tickets

    cfg = make(SearchConfig, {"policy": policy, "task": task} | options)
    return find_golden_tickets(cfg, out)


def evaluate(policy, task=None, tickets: Sequence[str | Path] = (),
             seeds: Iterable[int] = range(1_000_000, 1_000_200), **options):
    """Base, zero ticket and each ticket file on held-out `seeds`: an `evaluation.VerdictRow` per arm
    ("base", "zero", ticket ids), with its Wilson interval, Holm-adjusted paired p-values and each
    seed's success (`row.to_dict()` is what `evaluate --json` prints). `task`, `max_steps` and
    `success` default to those the tickets were found under (a task or predicate that is code, an
    import string, only when given here: a ticket never runs code it names). `options`: the other
    fields of `config.EvaluateConfig` (seed, max_steps, success, allow_transfer, mixture, epsilon,
    workers, backend, address, max_nonfinite, device, step_timeout)."""
    from goldenticket.config import EvaluateConfig, make
    from goldenticket.job.evaluate import evaluate_tickets

    seeds = seeds if isinstance(seeds, range) else list(seeds)
    cfg = make(EvaluateConfig, {"policy": policy, "task": task, "tickets": tickets,
                                "seeds": seeds} | options)
    return {arm.key: row for arm, row in evaluate_tickets(cfg).items()}


def compare(policy, against, task=None, seeds: Iterable[int] = range(1_000_000, 1_000_200),
            out: str | Path | None = None, **options):
    """Policy A (`policy`, with `ticket=` if given) against policy B (`against`, with
    `against_ticket=`; the same policy to compare it with and without a ticket) on the same held-out
    `seeds`, each seed one initial state both start from: a `results.Comparison`. Its typed rows
    `a` and `b` (`results.ComparedArm`) hold each arm's success with its Wilson interval (`rate`)
    and each seed's success (`successes`); it gives the discordant seeds (`a_only`, `b_only`), the
    exact paired one-sided p-values both ways (`p_a_better`, `p_b_better`), the two-sided one
    (`p_two_sided`) and the arm it finds better (`better`: "A", "B" or None); `to_dict()` is what
    `compare --json` prints. `out`: a folder whose run store keeps every episode, so a rerun
    resumes. `task`, `max_steps` and `success` default to those the tickets were found under, the
    task else to the one the bundled policies were trained on. `options`: the other fields of
    `config.CompareConfig` (ticket, against_ticket, seed, max_steps, success, allow_transfer,
    rename_map, policy_override, env_option, workers, backend, address, max_nonfinite, device,
    step_timeout)."""
    from goldenticket.config import CompareConfig, make
    from goldenticket.job.compare import compare_policies

    seeds = seeds if isinstance(seeds, range) else list(seeds)
    cfg = make(CompareConfig, {"policy": policy, "against": against, "task": task, "seeds": seeds} | options)
    return compare_policies(cfg, out)
