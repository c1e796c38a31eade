"""Search optimizers and driver on a synthetic noisy objective with a hidden optimum."""

import functools

import numpy as np
import pytest

from goldenticket.config import SearchConfig
from goldenticket.errors import OptionError, UserError
from goldenticket.ticket_search import (
    CEM,
    Candidate,
    CEMRacing,
    EpisodeOutcome,
    Query,
    RandomSearch,
    SearchResult,
    ZerothOrder,
    make_optimizer,
    run_search,
)

SHAPE = (8, 4)
SEEDS = tuple(range(100, 125))  # M = 25 = 5 tiers x 5 seeds


class NoisyTask:
    """Hidden optimum w*, shifted per seed by a small offset; noisy returns near w* are high.

    "bernoulli": return = success ~ Bernoulli(exp(-d^2 / D)); "gaussian": return = -d^2 / D + N(0,
    0.05^2), where d is the distance to the seed's shifted optimum and D = H * A.
    """

    def __init__(self, kind: str, seed: int):
        rng = np.random.default_rng(seed)
        self.w_star = rng.standard_normal(SHAPE)
        self.offsets = 0.2 * rng.standard_normal((len(SEEDS), *SHAPE))
        self.kind, self.rng = kind, rng

    def __call__(self, queries: list[Query]) -> list[EpisodeOutcome]:
        return [self._episodes(q) for q in queries]

    def _episodes(self, query: Query) -> EpisodeOutcome:
        shifted = self.w_star + self.offsets[np.array(query.seeds) - SEEDS[0]]
        d2 = np.sum((query.ticket - shifted) ** 2, axis=(1, 2)) / query.ticket.size
        if self.kind == "bernoulli":
            returns = (self.rng.random(len(d2)) < np.exp(-d2)).astype(float)
        else:
            returns = -d2 + 0.05 * self.rng.standard_normal(len(d2))
        return EpisodeOutcome(returns, returns > -0.1)

    def closeness(self, tickets: list[np.ndarray]) -> float:
        """Mean squared distance of `tickets` to w*, relative to that of N(0, I) tickets."""
        random_mean = self.w_star.size + np.sum(self.w_star**2)
        return float(np.mean([np.sum((t - self.w_star) ** 2) for t in tickets]) / random_mean)


class Stuck:
    """Dummy optimizer that never improves: one N(0, I) ticket asked forever."""

    def __init__(self, noise_shape, seeds, rng):
        self.seeds, self.ticket = tuple(seeds), rng.standard_normal(noise_shape)

    def ask(self) -> list[Query]:
        return [Query(self.ticket, self.seeds)]

    def tell(self, queries, returns) -> None:
        pass


@functools.cache  # deterministic: the bars' baselines (RS, the stuck search) run once per objective
def closeness_after_search(method: str, kind: str, budget: int = 25_000) -> float:
    """Mean over 3 runs of the top-5 tickets' closeness (0 = at w*, 1 = like random tickets)."""
    scores = []
    for run in range(3):
        task, rng = NoisyTask(kind, seed=500 + run), np.random.default_rng(run)
        stuck = method == "stuck"
        opt = Stuck(SHAPE, SEEDS, rng) if stuck else make_optimizer(method, SHAPE, SEEDS, rng)
        result = run_search(opt, task, budget=budget)
        best = result.top(5, min_episodes=len(opt.seeds))
        scores.append(task.closeness([c.ticket for c in best]))
    return float(np.mean(scores))


# (method, objective, closeness bar); RS is the non-improving baseline for the adaptive methods.
BARS = [
    ("rs", "gaussian", 0.7),
    ("cem", "bernoulli", 0.35),
    ("cem-racing", "bernoulli", 0.35),
    ("cem", "gaussian", 0.15),
    ("zos", "gaussian", 0.15),
    ("cem-racing", "gaussian", 0.15),
    ("cma-es", "bernoulli", 0.35),
    ("cma-es", "gaussian", 0.15),
    ("tiled-then-full", "gaussian", 0.15),
    ("portfolio", "gaussian", 0.15),
    ("cem-bounds", "bernoulli", 0.35),
    ("cem-bounds", "gaussian", 0.15),
]


@pytest.mark.slow
@pytest.mark.parametrize(("method", "kind", "bar"), BARS)
def test_optimizer_finds_tickets_near_the_hidden_optimum(method, kind, bar):
    assert closeness_after_search(method, kind) < bar


@pytest.mark.slow
@pytest.mark.parametrize(("method", "kind", "bar"), BARS)
def test_bars_reject_a_search_that_never_improves(method, kind, bar):
    dummy = "stuck" if method == "rs" else "rs"
    assert closeness_after_search(dummy, kind) > bar


def record_queries(method: str, rng_seed: int) -> list[tuple[bytes, tuple[int, ...]]]:
    task = NoisyTask("bernoulli", seed=7)
    seen = []

    def evaluate(queries):
        seen.extend((q.ticket.tobytes(), q.seeds) for q in queries)
        return task(queries)

    small = {"population": 10} if method.startswith("cem") else {}
    opt = make_optimizer(method, SHAPE, SEEDS, np.random.default_rng(rng_seed), **small)
    run_search(opt, evaluate, budget=2_000)
    return seen


@pytest.mark.parametrize("method",
                         ["rs", "cem", "zos", "cem-racing", "cma-es", "cem-bounds", "tiled-then-full",
                          "portfolio"])
def test_same_rng_seed_gives_the_same_queries(method):
    first = record_queries(method, rng_seed=3)
    assert len(first) > 10
    assert first == record_queries(method, rng_seed=3)
    assert first != record_queries(method, rng_seed=4)


def test_cma_es_leaves_numpys_global_random_state_alone():
    np.random.seed(123)
    expected = np.random.random(3)
    np.random.seed(123)
    record_queries("cma-es", rng_seed=3)
    assert np.array_equal(np.random.random(3), expected)
    np.random.seed(999)  # the caller's global draws do not move the optimizer's either
    assert record_queries("cma-es", rng_seed=3) == record_queries("cma-es", rng_seed=3)


def test_cma_es_starts_from_the_mean_it_is_given():
    start = np.full(SHAPE, 3.0)
    asked = make_optimizer("cma-es", SHAPE, SEEDS, np.random.default_rng(0), mean=start, sigma_init=0.1).ask()
    tickets = np.array([q.ticket for q in asked])
    assert np.abs(tickets.mean(axis=0) - start).max() < 0.2 and tickets.std() < 0.2
    with pytest.raises(UserError, match="noise shape"):
        make_optimizer("cma-es", SHAPE, SEEDS, np.random.default_rng(0), mean=np.zeros((2, 2)))
    with pytest.raises(UserError, match="mean must be of type"):  # a start ticket has rows
        make_optimizer("cma-es", SHAPE, SEEDS, np.random.default_rng(0), mean=np.zeros(5))


def test_tiled_then_full_starts_the_full_stage_from_the_tiled_stages_best():
    opt = make_optimizer("tiled-then-full", SHAPE, SEEDS, np.random.default_rng(0), population=6,
                         tiled_generations=2, sigma_full=0.01)
    tiled = []
    for _ in range(2):
        asked = opt.ask()
        tiled += asked
        assert len(asked) == 6 and all((q.ticket == q.ticket[0]).all() for q in asked)  # tiled rows
        opt.tell(asked, returns_by_ticket(asked))
    best = max(tiled, key=lambda q: q.ticket[0, 0]).ticket
    full = np.array([q.ticket for q in opt.ask()])
    assert np.abs(full.mean(axis=0) - best).max() < 0.02 and not (full == full[:, :1]).all()
    with pytest.raises(OptionError, match="subspace full"):
        SearchConfig("metaworld/reach-v3/flow", "metaworld/reach-v3", method="tiled-then-full",
                     subspace="tiled").check()


def test_portfolio_gives_the_full_search_the_budget_only_where_its_best_ticket_clearly_wins():
    def generations(tiled: list[float], full: list[float], n: int = 5) -> list[str]:
        """Each ticket of a search succeeds on the seeds its list gives it (on 20 seeds)."""
        opt = make_optimizer("portfolio", SHAPE, tuple(range(20)), np.random.default_rng(0), population=6)
        went = []
        for _ in range(n):
            asked = opt.ask()
            kind = "tiled" if all((q.ticket == q.ticket[0]).all() for q in asked) else "full"
            assert len(asked) == 6 and all(q.ticket.shape == SHAPE for q in asked)
            opt.tell(asked, [np.asarray(tiled if kind == "tiled" else full) for _ in asked])
            went.append(kind)
        return went

    seeds = np.arange(20)
    assert generations(list(seeds < 7), list(seeds < 20)) == ["tiled", "full", "full", "full", "full"]
    # a lead of 5 seeds of 20 is no clear win (p = 0.031): the tiled search keeps the budget
    assert generations(list(seeds < 10), list(seeds < 15), 8) == ["tiled", "full", "tiled", "tiled", "tiled",
                                                                 "tiled", "full", "tiled"]  # the 5th: explore
    pair = ("metaworld/reach-v3/flow", "metaworld/reach-v3")
    with pytest.raises(OptionError, match="subspace full"):
        SearchConfig(*pair, method="portfolio", subspace="tiled").check()
    assert SearchConfig(*pair).method == "portfolio" and SearchConfig(*pair).subspace == "full"
    assert SearchConfig(*pair, method="cma-es").subspace == "tiled"


def returns_by_ticket(queries: list[Query]) -> list[np.ndarray]:
    """Deterministic returns: every episode of a ticket returns its first entry."""
    return [np.full(len(q.seeds), float(q.ticket[0, 0])) for q in queries]


def test_racing_halves_on_shared_fresh_seeds_and_refits_on_cumulative_means():
    opt = CEMRacing(SHAPE, SEEDS, np.random.default_rng(0), population=50)
    population = opt.ask()
    alive, used_seeds, episodes = population, set(), 0
    for tier in range(5):
        queries = alive if tier == 0 else opt.ask()
        best_of_alive = sorted(alive, key=lambda q: -q.ticket[0, 0])[: len(queries)]
        assert {q.ticket.tobytes() for q in queries} == {q.ticket.tobytes() for q in best_of_alive}
        assert len({q.seeds for q in queries}) == 1 and len(queries[0].seeds) == 5
        assert not used_seeds & set(queries[0].seeds)
        used_seeds |= set(queries[0].seeds)
        episodes += sum(len(q.seeds) for q in queries)
        opt.tell(queries, returns_by_ticket(queries))
        alive = queries
    assert used_seeds == set(SEEDS)
    p, m0, m = 50, 5, 25
    assert episodes == 5 * (50 + 25 + 12 + 6 + 3) <= 2 * p * m0 < p * m
    elites = sorted(population, key=lambda q: -q.ticket[0, 0])[:10]
    np.testing.assert_allclose(opt.mu, np.mean([q.ticket for q in elites], axis=0), atol=1e-6)
    nxt = opt.ask()
    assert opt.iteration == 1 and len(nxt) == 50 and nxt[0].seeds == population[0].seeds


def test_racing_drops_leftover_seeds_and_needs_one_seed_per_tier():
    assert CEMRacing(SHAPE, range(12), np.random.default_rng(0)).seeds == tuple(range(10))
    with pytest.raises(UserError, match="at least tiers=5"):
        make_optimizer("cem-racing", SHAPE, range(4), np.random.default_rng(0))


def test_cem_refits_on_elites_and_respects_sigma_floor():
    opt = CEM(SHAPE, SEEDS[:2], np.random.default_rng(0), population=10, elite_frac=0.2,
              sigma_min=0.5)
    queries = opt.ask()
    opt.tell(queries, returns_by_ticket(queries))
    elites = sorted(queries, key=lambda q: -q.ticket[0, 0])[:2]
    np.testing.assert_allclose(opt.mu, np.mean([q.ticket for q in elites], axis=0), atol=1e-6)
    assert opt.sigma.min() >= 0.5


def test_zos_evaluates_pivot_first_then_replays_the_winning_step():
    opt = ZerothOrder(SHAPE, SEEDS[:3], np.random.default_rng(0), candidates=4, radius=0.5)
    (pivot,) = opt.ask()
    opt.tell([pivot], [np.zeros(3)])
    queries = opt.ask()
    assert len(queries) == 4
    opt.tell(queries, [np.full(3, float(i == 2)) for i in range(4)])
    assert np.array_equal(opt.pivot, queries[2].ticket)
    replay = opt.ask()[0].ticket - queries[2].ticket
    step = queries[2].ticket - pivot.ticket
    np.testing.assert_allclose(replay, 0.5 * step / np.linalg.norm(step), atol=1e-5)
    opt.tell(opt.ask(), [np.zeros(3)] * 4)  # no improvement: pivot stays, no replay
    assert np.array_equal(opt.pivot, queries[2].ticket) and opt.step is None


class Spy:
    """Counts the optimizer's tells."""

    def __init__(self, opt):
        self.opt, self.seeds, self.tells = opt, opt.seeds, 0

    def ask(self):
        return self.opt.ask()

    def tell(self, queries, returns):
        self.tells += 1
        self.opt.tell(queries, returns)


def test_budget_truncates_to_whole_queries_and_tells_nothing_partial():
    spy = Spy(CEM(SHAPE, SEEDS[:3], np.random.default_rng(0), population=10))
    batches = []
    result = run_search(spy, NoisyTask("gaussian", 0), budget=100, on_batch=batches.append)
    assert result.stopped_because == "budget"
    assert batches == [30, 30, 30, 9] and result.episodes_used == 99
    assert spy.tells == 3 and len(result.candidates) == 33
    assert all(c.n == 3 for c in result.candidates)


def test_bound_racing_drops_surely_worse_tickets_and_keeps_running_the_rest():
    def evaluate(queries):  # tickets with a positive first entry always succeed, the others never
        return [EpisodeOutcome(np.full(len(q.seeds), float(q.ticket.flat[0] > 0)),
                               np.full(len(q.seeds), q.ticket.flat[0] > 0)) for q in queries]

    opt = make_optimizer("cem-bounds", SHAPE, SEEDS, np.random.default_rng(0), population=20, iterations=1)
    result = run_search(opt, evaluate, budget=10_000)
    good = [c.n for c in result.candidates if c.ticket.flat[0] > 0]
    bad = [c.n for c in result.candidates if c.ticket.flat[0] <= 0]
    # Hoeffding at delta 0.1 separates 1s from 0s after two blocks of 4 seeds; the race then ends as
    # soon as no more than the 4 elites are left, or continues with the surely good ones
    assert good and bad and max(bad) == 8 and min(good) >= 8
    assert result.episodes_used < 20 * len(SEEDS)


@pytest.mark.parametrize("method", ["rs", "cem", "zos", "cem-racing", "cem-bounds", "tiled-then-full"])
def test_driver_never_exceeds_the_budget(method):
    for budget in range(1, 1_300, 97):
        opt = make_optimizer(method, SHAPE, SEEDS, np.random.default_rng(budget))
        result = run_search(opt, NoisyTask("bernoulli", budget), budget=budget)
        assert result.episodes_used == sum(c.n for c in result.candidates) <= budget


def always_perfect(queries: list[Query]) -> list[EpisodeOutcome]:
    return [EpisodeOutcome(np.ones(len(q.seeds)), np.ones(len(q.seeds), bool)) for q in queries]


def test_early_stop_after_perfect_tickets_counts_only_fully_evaluated_ones():
    cem = CEM(SHAPE, SEEDS, np.random.default_rng(0), population=10)
    result = run_search(cem, always_perfect, budget=10_000, stop_after_perfect=3)
    assert result.stopped_because == "k perfect tickets" and result.episodes_used == 10 * 25

    racing = CEMRacing(SHAPE, SEEDS, np.random.default_rng(0), population=50)
    result = run_search(racing, always_perfect, budget=10_000, stop_after_perfect=3)
    assert result.stopped_because == "k perfect tickets" and result.episodes_used == 480
    assert sorted(c.n for c in result.candidates)[-3:] == [25, 25, 25]  # survivors accumulate
    assert set(result.top(1)[0].seeds) == set(SEEDS)


def test_ticket_cap_and_optimizer_finished():
    rs = RandomSearch(SHAPE, SEEDS[:4], np.random.default_rng(0), batch_size=10)
    result = run_search(rs, always_perfect, budget=10_000, max_tickets=25)
    assert (result.stopped_because, len(result.candidates), result.episodes_used) == \
        ("ticket cap", 25, 100)

    racing = CEMRacing(SHAPE, SEEDS, np.random.default_rng(0), population=50)
    result = run_search(racing, NoisyTask("gaussian", 0), budget=10_000, max_tickets=50)
    assert (result.stopped_because, len(result.candidates), result.episodes_used) == \
        ("ticket cap", 50, 480)

    zos = ZerothOrder(SHAPE, SEEDS[:2], np.random.default_rng(0), iterations=3)
    result = run_search(zos, NoisyTask("gaussian", 0), budget=10_000)
    assert result.stopped_because == "optimizer finished" and result.episodes_used == 2 * 31


def test_top_breaks_ties_by_episodes_then_first_seen():
    def cand(value, returns):
        return Candidate(np.full(SHAPE, value, np.float32), list(range(len(returns))), returns,
                         [r > 0 for r in returns])

    a, b, c, d = cand(0, [1.0]), cand(1, [0.0, 1.0]), cand(2, [1.0, 1.0]), cand(3, [1.0])
    result = SearchResult([a, b, c, d], episodes_used=6, stopped_because="budget")
    assert result.top(3) == [c, a, d]
    assert result.top(5, min_episodes=2) == [c, b]


def test_top_with_shrink_ranks_a_ticket_seen_on_few_seeds_by_less_than_its_mean():
    def cand(value, returns):
        return Candidate(np.full(SHAPE, value, np.float32), list(range(len(returns))), returns,
                         [r > 0 for r in returns])

    few, many, poor = cand(0, [1.0]), cand(1, [1.0] * 8 + [0.0] * 2), cand(2, [0.0] * 10)
    result = SearchResult([few, many, poor], episodes_used=21, stopped_because="budget")
    assert result.top(3) == [few, many, poor]  # by mean: 1.0, 0.8, 0.0
    # the search's mean is 9 / 21: few scores (1 + 5 * 9 / 21) / 6 = 0.52, many (8 + 5 * 9 / 21) / 15 = 0.68
    assert result.top(3, shrink=5) == [many, few, poor]


def test_bad_inputs_raise_one_line_user_errors():
    rng = np.random.default_rng(0)
    bad = [
        lambda: make_optimizer("hill-climb", SHAPE, SEEDS, rng),
        lambda: make_optimizer("cem", SHAPE, SEEDS, rng, populaton=10),
        lambda: make_optimizer("cem", SHAPE, SEEDS, rng, population=1),
        lambda: make_optimizer("cem-racing", SHAPE, SEEDS, rng, elite_frac=0.0),
        lambda: make_optimizer("zos", SHAPE, SEEDS, rng, radius=0),
        lambda: make_optimizer("rs", SHAPE, [], rng),
        lambda: run_search(RandomSearch(SHAPE, SEEDS, rng), always_perfect, budget=0),
    ]
    for call in bad:
        with pytest.raises(UserError) as err:
            call()
        assert "\n" not in str(err.value)


def test_evaluate_must_answer_every_query_and_seed():
    rs = RandomSearch(SHAPE, SEEDS[:2], np.random.default_rng(0))
    with pytest.raises(ValueError, match="outcomes"):
        run_search(rs, lambda queries: always_perfect(queries)[:-1], budget=100)


def test_query_holds_a_read_only_float32_copy():
    source = np.zeros(SHAPE)
    query = Query(source, [1, 2])
    source[0, 0] = 5.0
    assert query.ticket.dtype == np.float32 and query.ticket[0, 0] == 0.0
    assert query.seeds == (1, 2) and not query.ticket.flags.writeable


def test_perfect_means_every_episode_succeeded_whatever_the_objective():
    def discounted(queries: list[Query]) -> list[EpisodeOutcome]:  # returns < 1, all successes
        return [EpisodeOutcome(np.full(len(q.seeds), 0.9), np.ones(len(q.seeds), bool))
                for q in queries]

    cem = make_optimizer("cem", SHAPE, SEEDS, np.random.default_rng(0), population=10)
    result = run_search(cem, discounted, budget=10_000, stop_after_perfect=3)
    assert result.stopped_because == "k perfect tickets" and result.episodes_used == 10 * 25


def test_portfolios_full_search_starts_at_w_0_or_at_the_tiled_searchs_best():
    def first_full(full_start: str) -> tuple[np.ndarray, np.ndarray]:
        """The tiled generation's best ticket (its first entry the largest) and the full one's tickets."""
        opt = make_optimizer("portfolio", SHAPE, SEEDS, np.random.default_rng(0), population=6,
                             full_start=full_start)
        tiled = opt.ask()
        opt.tell(tiled, returns_by_ticket(tiled))
        return max(tiled, key=lambda q: q.ticket[0, 0]).ticket, np.array([q.ticket for q in opt.ask()])

    best, from_best = first_full("tiled")
    _, from_zero = first_full("zero")
    assert not (from_best == from_best[:, :1]).all() and np.abs(best).max() > 0.1
    assert np.abs(from_best - from_zero - best).max() < 1e-4  # the same draws, moved by the tiled best
    with pytest.raises(UserError, match="full_start must be one of"):
        make_optimizer("portfolio", SHAPE, SEEDS, np.random.default_rng(0), full_start="best")


def test_portfolios_full_search_asks_its_own_population_where_set():
    def asked(**settings) -> tuple[int, int]:
        opt = make_optimizer("portfolio", SHAPE, SEEDS, np.random.default_rng(0), population=6, **settings)
        tiled = opt.ask()
        opt.tell(tiled, returns_by_ticket(tiled))
        return len(tiled), len(opt.ask())

    assert asked() == (6, 6) and asked(full_population=3) == (6, 3)
    with pytest.raises(UserError, match="full_population must be >= 2"):
        make_optimizer("portfolio", SHAPE, SEEDS, np.random.default_rng(0), full_population=1)


def test_portfolio_asks_the_same_tickets_when_linear_algebras_last_bits_differ(monkeypatch):
    """Another CPU's kernels: every eigendecomposition CMA-ES makes moves by a few last bits."""
    shape = (8, 4)  # the full search's covariance is updated through eigendecompositions

    def queries():
        opt = make_optimizer("portfolio", shape, SEEDS, np.random.default_rng(1), population=10, alpha=0.5)
        asked = []
        for _ in range(10):
            batch = opt.ask()
            asked += [q.ticket.tobytes() for q in batch]
            opt.tell(batch, [np.full(len(q.seeds), float(np.sin(q.ticket).sum())) for q in batch])
        return asked

    mine = queries()
    eigh = np.linalg.eigh

    def another_cpus(matrix, *args, **kwargs):
        values, vectors = eigh(matrix, *args, **kwargs)
        return values * (1 + 4e-16), vectors * (1 - 2e-16)

    monkeypatch.setattr(np.linalg, "eigh", another_cpus)
    assert queries() == mine
