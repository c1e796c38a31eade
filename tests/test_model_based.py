"""Model-based search (TPE and a Gaussian process, through Optuna's samplers) on a small noisy
objective: the ask/tell contract, seeds, bounds, budgets and that the model finds the optimum."""

import numpy as np
import pytest
import torch

from goldenticket.errors import UserError
from goldenticket.ticket_search import EpisodeOutcome, Query, make_optimizer, run_search

SHAPE = (1, 4)  # a tiled ticket of a 4-dim action
SEEDS = tuple(range(100, 120))
METHODS = ("tpe", "gp")


class HiddenOptimum:
    """Success ~ Bernoulli(exp(-|w - w*|^2 / 2)), w* drawn from `seed`."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)
        self.w_star = self.rng.uniform(-1.5, 1.5, SHAPE)

    def __call__(self, queries: list[Query]) -> list[EpisodeOutcome]:
        outcomes = []
        for q in queries:
            p = np.exp(-np.sum((q.ticket - self.w_star) ** 2) / 2)
            successes = self.rng.random(len(q.seeds)) < p
            outcomes.append(EpisodeOutcome(successes.astype(float), successes))
        return outcomes

SLOW_GP = [pytest.param(m, marks=pytest.mark.slow) if m == "gp" else m for m in METHODS]  # GP: seconds

def asked(method: str, rng_seed: int, budget: int = 200, **changed) -> list[Query]:
    seen = []

    def evaluate(queries):
        seen.extend(queries)
        return HiddenOptimum(7)(queries)

    settings = {"startup": 4} | changed
    run_search(make_optimizer(method, SHAPE, SEEDS, np.random.default_rng(rng_seed), **settings), evaluate,
               budget=budget)
    return seen


@pytest.mark.parametrize("method", SLOW_GP)
def test_the_same_rng_seed_gives_the_same_queries_and_leaves_global_random_states_alone(method):
    np.random.seed(123)
    torch.manual_seed(123)
    expected = np.random.random(3), torch.rand(3)
    np.random.seed(123)
    torch.manual_seed(123)
    first = [(q.ticket.tobytes(), q.seeds) for q in asked(method, 3)]
    assert np.array_equal(np.random.random(3), expected[0]) and torch.equal(torch.rand(3), expected[1])
    assert len(first) == 200 // len(SEEDS)
    assert first == [(q.ticket.tobytes(), q.seeds) for q in asked(method, 3)]
    assert first != [(q.ticket.tobytes(), q.seeds) for q in asked(method, 4)]


def test_a_search_says_no_line_per_ticket_and_leaves_optunas_log_level_as_it_was(caplog):
    import optuna

    optuna.logging.set_verbosity(optuna.logging.INFO)
    optuna.logging.enable_propagation()
    try:
        with caplog.at_level("INFO", logger="optuna"):
            asked("tpe", 3)
            assert optuna.logging.get_verbosity() == optuna.logging.INFO  # (caplog restores it on exit)
    finally:
        optuna.logging.disable_propagation()
        optuna.logging.set_verbosity(optuna.logging.WARNING)
    assert not [r for r in caplog.records if r.name.startswith("optuna")]


@pytest.mark.parametrize("method", SLOW_GP)
def test_w_0_first_then_tickets_within_the_bound_on_every_search_seed(method):
    queries = asked(method, 0, bound=0.5)
    assert not queries[0].ticket.any() and all(q.seeds == SEEDS for q in queries)
    assert all(np.abs(q.ticket).max() <= 0.5 for q in queries)
    assert len({q.ticket.tobytes() for q in queries}) == len(queries)
    assert asked(method, 0, start_at_zero=False)[0].ticket.any()


@pytest.mark.parametrize("method", METHODS)
def test_random_tickets_are_draws_of_the_policys_own_noise(method):
    """Before the model proposes, each number is N(0, 1) truncated to the bound: mean |w| near
    0.80, where uniform draws in [-3, 3] would give 1.5."""
    opt = make_optimizer(method, SHAPE, SEEDS, np.random.default_rng(0), startup=200, batch_size=50,
                         start_at_zero=False)
    tickets = np.concatenate([[q.ticket for q in opt.ask()] for _ in range(2)])
    assert tickets.shape == (100, *SHAPE) and 0.72 < np.abs(tickets).mean() < 0.88


@pytest.mark.parametrize("method", METHODS)
def test_batches_num_tickets_and_the_budget(method):
    opt = make_optimizer(method, SHAPE, SEEDS, np.random.default_rng(0), batch_size=3, num_tickets=5)
    first = opt.ask()
    opt.tell(first, [np.zeros(len(SEEDS))] * 3)
    assert len(first) == 3 and len(opt.ask()) == 2 and opt.ask() == []
    for budget in (1, 19, 20, 61, 250):
        result = run_search(make_optimizer(method, SHAPE, SEEDS, np.random.default_rng(budget)),
                            HiddenOptimum(budget), budget=budget)
        assert result.episodes_used == sum(c.n for c in result.candidates) <= budget


@pytest.mark.parametrize("value", [{"batch_size": 0}, {"startup": 0}, {"bound": 0.0}, {"num_tickets": 0}])
def test_bad_settings_are_one_line(value):
    with pytest.raises(UserError) as err:
        make_optimizer("gp", SHAPE, SEEDS, np.random.default_rng(0), **value)
    assert "\n" not in str(err.value) and next(iter(value)) in str(err.value)


def distance_of_best(method: str, run: int, budget: int) -> float:
    """Distance to w* of the search's best ticket (by mean return over all search seeds)."""
    task = HiddenOptimum(500 + run)
    result = run_search(make_optimizer(method, SHAPE, SEEDS, np.random.default_rng(run)), task, budget=budget)
    return float(np.linalg.norm(result.top(1, min_episodes=len(SEEDS))[0].ticket - task.w_star))


@pytest.mark.slow
@pytest.mark.parametrize(("method", "budget"), [("tpe", 1_000), ("gp", 600)])  # the GP's asks take seconds
def test_the_model_gets_closer_to_the_optimum_than_random_search(method, budget):
    runs = range(3)
    mine = np.mean([distance_of_best(method, run, budget) for run in runs])
    assert mine < 0.75 * np.mean([distance_of_best("rs", run, budget) for run in runs])
