"""goldenticket: golden-ticket search for frozen diffusion and flow-matching robot policies.

`search` and `evaluate` are the Python twins of `goldenticket search` and `goldenticket
evaluate`: same optimizers, statistics, run store, resume and worker pool.

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


def search(policy, task, out: str | Path, **options) -> dict:
    """Search tickets and judge the best on held-out seeds into `out` (resumable); returns the
    summary (`summary.json`). `task` may be several task names (a tuple): one ticket for a
    multi-task policy. `options`: the fields of `workflow.SearchConfig` (method, budget, seed,
    search_seeds, heldout, top_k, objective, stop_after_perfect, max_tickets, workers, max_steps,
    success, backend, address, subspace, front_objective, validation_seeds, no_regression)."""
    from goldenticket.workflow import SearchConfig, find_golden_tickets

    options = _known(options, SearchConfig, ("policy", "task"))
    if isinstance(task, tuple | list):
        from goldenticket.multitask import find_multitask_tickets

        return find_multitask_tickets(SearchConfig(policy, tuple(task), **options), Path(out))
    return find_golden_tickets(SearchConfig(policy, task, **options), Path(out))


def evaluate(policy, task=None, tickets: Sequence[str | Path] = (),
             seeds: Iterable[int] = range(1_000_000, 1_000_200), **options) -> dict[str, dict]:
    """Base, zero ticket and each ticket file on held-out `seeds`, with Wilson intervals and
    Holm-adjusted paired p-values. `task`, `max_steps` and `success` default to those the tickets
    were found under. `options`: seed, workers, allow_transfer, max_steps, success, backend
    ("local" or "ray"), address (a Ray cluster), mixture, epsilon."""
    from goldenticket.workflow import evaluate_tickets

    options = _known(options, evaluate_tickets, ("policy_ref", "task_ref", "ticket_paths", "seeds"))
    return evaluate_tickets(policy, task, [Path(t) for t in tickets], list(seeds), **options)


def _known(options: dict, target, taken: tuple[str, ...]) -> dict:
    """`options` if `target` (a dataclass or function) takes each of them as a keyword besides the
    parameters `taken`; else a one-line UserError naming the unknown ones."""
    import inspect

    from goldenticket.errors import UserError

    accepted = set(inspect.signature(target).parameters) - set(taken)
    if unknown := sorted(set(options) - accepted):
        raise UserError(f"unknown option {', '.join(unknown)}; options are: {', '.join(sorted(accepted))}")
    return options
