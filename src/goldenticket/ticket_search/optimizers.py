"""Ask/tell black-box optimizers over one constant noise ticket (paper appendix "Search Methods").

Every optimizer is pure: it proposes `Query`s and learns from their per-seed returns, with no
I/O, no environment and no global random state (the ask/tell protocol: `protocol.py`). All
randomness and tie-breaking is driven by the `rng` it was built with, so the same rng seed and the
same returns give the same queries. Each method's settings, with their defaults, are its dataclass
in `methods.METHODS`; an optimizer takes that dataclass, or its fields as keywords.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterable, Sequence
from statistics import NormalDist

import numpy as np

from goldenticket.errors import UserError
from goldenticket.stats import sign_test
from goldenticket.ticket_search.methods import (
    FULL_STARTS,
    CEMBoundsSettings,
    CEMRacingSettings,
    CEMSettings,
    CMAESSettings,
    GPSettings,
    ModelBasedSettings,
    PortfolioSettings,
    RandomSearchSettings,
    TiledThenFullSettings,
    TPESettings,
    ZerothOrderSettings,
    method_settings,
)
from goldenticket.ticket_search.protocol import Optimizer, Query
from goldenticket.ticket_search.racing import Race, TicketRace, better_half, in_blocks


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise UserError(message)


def _top_indices(scores: np.ndarray, k: int) -> np.ndarray:
    """Indices of the k highest scores, best first; ties go to the lower index."""
    return np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")[:k]


def _settings(cls, settings, params: dict):
    """`settings`, or `cls(**params)`: an optimizer is given its dataclass or its fields."""
    if settings is not None:
        return settings
    try:
        return cls(**params)
    except TypeError as exc:
        raise UserError(f"{cls.__name__}: {exc}") from None


def _check_iterations(iterations: int | None) -> None:
    _require(iterations is None or iterations >= 1, f"iterations must be >= 1, got {iterations}")


class _Base:
    """Shared constructor checks and query building."""

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator):
        _require(len(noise_shape) == 2 and min(noise_shape) >= 1,
                 f"noise_shape must be (H, A) with H, A >= 1, got {noise_shape}")
        self.noise_shape = (int(noise_shape[0]), int(noise_shape[1]))
        self.seeds = tuple(int(s) for s in seeds)
        _require(len(self.seeds) >= 1, "need at least one search seed")
        _require(len(set(self.seeds)) == len(self.seeds), "search seeds must be distinct")
        self.rng = rng

    def _queries(self, tickets: Iterable[np.ndarray],
                 seeds: tuple[int, ...] | None = None) -> list[Query]:
        return [Query(t, self.seeds if seeds is None else seeds) for t in tickets]


class RandomSearch(_Base):
    """RS (paper Alg. 1): i.i.d. N(0, I) tickets, `batch_size` per ask, each on every search seed.

    Runs until `num_tickets` have been asked for (None: until the driver stops it).
    """

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator,
                 settings: RandomSearchSettings | None = None, **params):
        super().__init__(noise_shape, seeds, rng)
        s = _settings(RandomSearchSettings, settings, params)
        batch_size, num_tickets = s.batch_size, s.num_tickets
        _require(batch_size >= 1, f"batch_size must be >= 1, got {batch_size}")
        _require(num_tickets is None or num_tickets >= 1, f"num_tickets must be >= 1, got {num_tickets}")
        self.batch_size, self.num_tickets, self.asked = batch_size, num_tickets, 0

    def ask(self) -> list[Query]:
        left = self.batch_size if self.num_tickets is None else self.num_tickets - self.asked
        n = min(self.batch_size, left)
        self.asked += n
        return self._queries(self.rng.standard_normal((n, *self.noise_shape)))

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        """RS does not adapt; the driver keeps the scores."""


class CEM(_Base):
    """Cross-entropy method (paper Alg. 2) over a diagonal Gaussian N(mu, sigma^2).

    Each iteration samples `population` tickets, keeps the top max(1, floor(elite_frac * P)) by
    mean return, and refits mu and sigma to them with smoothing `alpha`; sigma is floored at
    `sigma_min` and then inflated to sqrt(sigma^2 + sigma_extra^2). Runs `iterations` times
    (None: until the driver stops it).
    """

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator,
                 settings: CEMSettings | None = None, **params):
        super().__init__(noise_shape, seeds, rng)
        s = _settings(CEMSettings, settings, params)
        population, elite_frac, alpha, iterations = s.population, s.elite_frac, s.alpha, s.iterations
        sigma_init, sigma_min, sigma_extra = s.sigma_init, s.sigma_min, s.sigma_extra
        _require(population >= 2, f"population must be >= 2, got {population}")
        _require(0 < elite_frac <= 1, f"elite_frac must be in (0, 1], got {elite_frac}")
        _require(0 < alpha <= 1, f"alpha must be in (0, 1], got {alpha}")
        _require(sigma_init > 0, f"sigma_init must be > 0, got {sigma_init}")
        _require(sigma_min >= 0 and sigma_extra >= 0, "sigma_min and sigma_extra must be >= 0")
        _check_iterations(iterations)
        self.population, self.alpha, self.iterations = population, alpha, iterations
        self.sigma_min, self.sigma_extra = sigma_min, sigma_extra
        self.n_elite = max(1, math.floor(elite_frac * population))
        self.mu = np.zeros(self.noise_shape)
        self.sigma = np.full(self.noise_shape, float(sigma_init))
        self.iteration = 0

    def ask(self) -> list[Query]:
        return [] if self._finished() else self._queries(self._sample())

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        self._refit(np.stack([q.ticket for q in queries]), np.array([np.mean(r) for r in returns]))

    def _finished(self) -> bool:
        return self.iterations is not None and self.iteration >= self.iterations

    def _sample(self) -> np.ndarray:
        z = self.rng.standard_normal((self.population, *self.noise_shape))
        return (self.mu + self.sigma * z).astype(np.float32)

    def _refit(self, tickets: np.ndarray, scores: np.ndarray) -> None:
        elites = tickets[_top_indices(scores, self.n_elite)].astype(np.float64)
        a = self.alpha
        self.mu = a * elites.mean(axis=0) + (1 - a) * self.mu
        sigma = np.maximum(a * elites.std(axis=0) + (1 - a) * self.sigma, self.sigma_min)
        self.sigma = np.sqrt(sigma**2 + self.sigma_extra**2)  # no-op when sigma_extra == 0
        self.iteration += 1


class ZerothOrder(_Base):
    """ZOS (paper Alg. 3): random walk on an L2 sphere of `radius` around a pivot.

    The first ask evaluates the N(0, I) pivot alone. Each later ask proposes `candidates` tickets:
    the replayed winning step (pivot + d) if the last iteration moved, then random sphere points.
    The pivot moves to the best candidate if it beats the pivot's score. Runs `iterations`
    iterations after the pivot (None: until the driver stops it).
    """

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator,
                 settings: ZerothOrderSettings | None = None, **params):
        super().__init__(noise_shape, seeds, rng)
        s = _settings(ZerothOrderSettings, settings, params)
        candidates, radius, iterations = s.candidates, s.radius, s.iterations
        _require(candidates >= 1, f"candidates must be >= 1, got {candidates}")
        _require(radius > 0, f"radius must be > 0, got {radius}")
        _check_iterations(iterations)
        self.candidates, self.radius, self.iterations = candidates, radius, iterations
        self.pivot = rng.standard_normal(self.noise_shape).astype(np.float32)
        self.pivot_score: float | None = None  # None until the pivot itself is evaluated
        self.step: np.ndarray | None = None
        self.iteration = 0

    def ask(self) -> list[Query]:
        if self.pivot_score is None:
            return self._queries([self.pivot])
        if self.iterations is not None and self.iteration >= self.iterations:
            return []
        tickets = [] if self.step is None else [self.pivot + self.step]
        while len(tickets) < self.candidates:
            u = self.rng.standard_normal(self.noise_shape)
            tickets.append(self.pivot + self.radius * u / np.linalg.norm(u))
        return self._queries(tickets)

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        scores = [float(np.mean(r)) for r in returns]
        if self.pivot_score is None:
            self.pivot_score = scores[0]
            return
        best = int(np.argmax(scores))  # ties go to the earlier candidate
        self.step = None
        if scores[best] > self.pivot_score:
            move = queries[best].ticket.astype(np.float64) - self.pivot
            self.step = self.radius * move / np.linalg.norm(move)
            self.pivot, self.pivot_score = queries[best].ticket, scores[best]
        self.iteration += 1


class _RacedCEM(CEM):
    """CEM whose population is raced (`racing.TicketRace`) on blocks of `block` search seeds; `_cut`
    says who races on after each block, and once the race is over CEM refits on every candidate's
    mean over the episodes it ran, its returns summed block by block (`_block_sums_mean`)."""

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator,
                 block: int, settings: CEMSettings):
        super().__init__(noise_shape, seeds, rng, settings)
        self.blocks = in_blocks(self.seeds, block)
        self._race: TicketRace | None = None

    def ask(self) -> list[Query]:
        if self._race is None or self._race.over:
            if self._finished():
                return []
            self._race = TicketRace(self._sample(), self.blocks, self._cut, _block_sums_mean)
        return self._race.queries()

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        self._race.record(returns)
        if self._race.over:
            self._refit(self._race.tickets, np.array([self._race.score(i) for i in range(self.population)]))

    def _cut(self, race: Race) -> list[int]:
        raise NotImplementedError


def _block_sums_mean(blocks: list[np.ndarray]) -> float:
    """The mean return over the episodes of `blocks`, summed block by block as CEM's races always
    have (summed in another order, the last bit can differ)."""
    return sum(np.sum(returns) for returns in blocks) / sum(len(returns) for returns in blocks)


class CEMRacing(_RacedCEM):
    """CEM whose population is raced by sequential halving (paper "Sequential Halving").

    The search seeds are split into `tiers` disjoint blocks of M0 = M // tiers seeds (left-over
    seeds are dropped from `self.seeds`). The first ask of an iteration rolls all P candidates out
    on block 1, each next ask rolls the survivors out on the next block; after each tier the top
    half (at least one) by cumulative mean return survives. After the last tier CEM refits on
    every candidate's cumulative mean. Its other settings are CEM's.
    """

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator,
                 settings: CEMRacingSettings | None = None, **params):
        s = _settings(CEMRacingSettings, settings, params)
        seeds, tiers = tuple(seeds), s.tiers
        _require(tiers >= 1, f"tiers must be >= 1, got {tiers}")
        _require(len(seeds) >= tiers, f"cem-racing needs at least tiers={tiers} search seeds, "
                                      f"got {len(seeds)}")
        m0 = len(seeds) // tiers
        super().__init__(noise_shape, seeds[: tiers * m0], rng, m0, s)

    def _cut(self, race: Race) -> list[int]:
        return better_half(race)


class CEMBounds(_RacedCEM):
    """CEM whose population is raced with confidence bounds: episode counts decided by the data.

    Each iteration rolls the P candidates out block by block (`block` search seeds at a time).
    After each block a candidate leaves the race when its upper confidence bound falls below the
    n_elite-th best lower bound (Hoeffding, each at level `delta`, for returns spanning
    `value_range`): it is then surely not an elite. The race ends when only n_elite remain or the
    seeds run out; CEM refits on every candidate's mean over the episodes it ran.
    """

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator,
                 settings: CEMBoundsSettings | None = None, **params):
        s = _settings(CEMBoundsSettings, settings, params)
        block, delta, value_range = s.block, s.delta, s.value_range
        _require(1 <= block <= len(seeds), f"block must be in 1..{len(seeds)} search seeds, got {block}")
        _require(0 < delta < 1 and value_range > 0, "delta must be in (0, 1) and value_range > 0")
        super().__init__(noise_shape, seeds, rng, block, s)
        self.delta, self.value_range = delta, value_range

    def _cut(self, race: Race) -> list[int]:
        alive = np.array(race.alive)
        means = np.array([race.score(i) for i in race.alive])
        runs = sum(len(returns) for returns in race.results[race.alive[0]])  # the same for all still in
        half = self.value_range * np.sqrt(np.log(2 / self.delta) / (2 * runs))
        bar = np.sort(means - half)[-min(self.n_elite, len(alive))]
        alive = alive[means + half >= bar]
        return alive.tolist() if len(alive) > self.n_elite else []


GRID = 2.0**-16  # GriddedCMAES's tickets are multiples of it: CPUs' last-bit differences round away


class CMAES(_Base):
    """CMA-ES (the `cma` package) over the flattened ticket, from `mean` (default w = 0, a ticket of
    the noise shape otherwise) and step size `sigma_init`; `population` tickets per ask, each on
    every search seed, scored by mean return.

    `cma` draws from numpy's global random state. Each call into it runs with this optimizer's
    own state (seeded from `rng`) swapped in, and the caller's global state swapped back after,
    so runs stay reproducible and nobody else's draws move. `cma`'s own stopping rules are off
    (binary success makes flat fitness common): it runs `iterations` times (None: until the
    driver stops it).
    """

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator,
                 settings: CMAESSettings | None = None, **params):
        import cma

        super().__init__(noise_shape, seeds, rng)
        s = _settings(CMAESSettings, settings, params)
        population, sigma_init, mean, iterations = s.population, s.sigma_init, s.mean, s.iterations
        _require(population >= 2, f"population must be >= 2, got {population}")
        _require(sigma_init > 0, f"sigma_init must be > 0, got {sigma_init}")
        start = np.zeros(self.noise_shape) if mean is None else np.asarray(mean, dtype=np.float64)
        _require(start.shape == self.noise_shape, f"mean must have the noise shape {self.noise_shape}, "
                                                  f"got {start.shape}")
        _check_iterations(iterations)
        self.iterations, self.iteration = iterations, 0
        self._numpy_state = np.random.RandomState(int(rng.integers(2**32))).get_state()
        options = {"popsize": population, "seed": int(rng.integers(1, 2**31)), "verbose": -9,
                   "tolflatfitness": math.inf, "tolfun": 0, "tolfunhist": 0, "tolx": 0,
                   "tolstagnation": math.inf}
        self._es = self._own_numpy(lambda: cma.CMAEvolutionStrategy(
            start.ravel(), sigma_init, options))
        self._asked: list[np.ndarray] = []

    def ask(self) -> list[Query]:
        if self.iterations is not None and self.iteration >= self.iterations:
            return []
        self._asked = self._solutions()
        return self._queries(x.reshape(self.noise_shape) for x in self._asked)

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        losses = [-float(np.mean(r)) for r in returns]  # cma minimises
        self._own_numpy(lambda: self._es.tell(self._asked, losses))
        self.iteration += 1

    def _solutions(self) -> list[np.ndarray]:
        """The next generation, flat."""
        return self._own_numpy(self._es.ask)

    def _own_numpy(self, call):
        """`call()` with this optimizer's numpy global random state in place."""
        theirs = np.random.get_state()
        np.random.set_state(self._numpy_state)
        try:
            return call()
        finally:
            self._numpy_state = np.random.get_state()
            np.random.set_state(theirs)


class GriddedCMAES(CMAES):
    """CMA-ES whose tickets are multiples of `GRID`, and told so. CMA-ES updates its covariance
    through numpy's linear algebra, whose last bits differ between CPUs' kernels; on the grid, the
    same run asks the same tickets on every CPU (the portfolio's searches; `cma-es` keeps the
    tickets it has always asked)."""

    def _solutions(self) -> list[np.ndarray]:
        return [np.round(x / GRID) * GRID for x in super()._solutions()]


class TiledThenFull(_Base):
    """A tiled stage that starts a full one: CMA-ES over one action-sized vector repeated along the
    horizon for `tiled_generations` generations, then CMA-ES over the full (H, A) ticket from the
    tiled stage's best ticket (by mean return), with step size `sigma_full`, until the driver stops
    it. Both stages score each ticket on every search seed."""

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator,
                 settings: TiledThenFullSettings | None = None, **params):
        super().__init__(noise_shape, seeds, rng)
        s = _settings(TiledThenFullSettings, settings, params)
        _require(s.tiled_generations >= 1, f"tiled_generations must be >= 1, got {s.tiled_generations}")
        _require(s.sigma_full > 0, f"sigma_full must be > 0, got {s.sigma_full}")
        self.settings = s
        self._tiled = CMAES((1, self.noise_shape[1]), seeds, rng, population=s.population,
                            sigma_init=s.sigma_init, iterations=s.tiled_generations)
        self._full: CMAES | None = None
        self._asked: list[Query] = []
        self._best, self._best_score = np.zeros((1, self.noise_shape[1])), -math.inf

    def ask(self) -> list[Query]:
        if self._full is None:
            self._asked = self._tiled.ask()
            if self._asked:
                return self._queries(np.repeat(q.ticket, self.noise_shape[0], axis=0) for q in self._asked)
            start = np.repeat(self._best, self.noise_shape[0], axis=0)
            self._full = CMAES(self.noise_shape, self.seeds, self.rng, population=self.settings.population,
                               sigma_init=self.settings.sigma_full, mean=start)
        return self._full.ask()

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        if self._full is not None:
            self._full.tell(queries, returns)
            return
        for query, r in zip(self._asked, returns, strict=True):
            if np.mean(r) > self._best_score:
                self._best, self._best_score = query.ticket, float(np.mean(r))
        self._tiled.tell(self._asked, returns)


class Portfolio(_Base):
    """A tiled and a full CMA-ES search sharing one budget: a generation of the tiled one, a
    generation of the full one (of `full_population` tickets where set), then each generation to
    the tiled one unless the full one's best ticket (by mean return on every search seed) beats the
    tiled one's best on those seeds by a one-sided sign test at p < `alpha`, and every `explore`-th
    generation after the first two to the one the test did not choose, so that a long search tries
    both. A tiled ticket (few numbers) buys the most per episode where noise helps as a constant
    push; a full one can vary along the chunk. Random full tickets often look better than random
    tiled ones at first and the tiled search overtakes them, so the full one takes the budget only
    on clear evidence. Asks full (H, A) tickets: tiled ones come repeated along the horizon, both
    searches' on a grid (`GriddedCMAES`). The full search starts at w = 0, or (`full_start` "tiled")
    at the tiled search's best ticket when it takes its first generation, so that it goes on from
    where the tiled one got to."""

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator,
                 settings: PortfolioSettings | None = None, **params):
        super().__init__(noise_shape, seeds, rng)
        s = _settings(PortfolioSettings, settings, params)
        _require(0 < s.alpha < 1, f"alpha must be in (0, 1), got {s.alpha}")
        _require(s.explore >= 0, f"explore must be >= 0, got {s.explore}")
        _require(s.full_population is None or s.full_population >= 2,
                 f"full_population must be >= 2, got {s.full_population}")
        _require(s.full_start in FULL_STARTS, f"full_start must be one of {FULL_STARTS}, "
                                              f"got {s.full_start!r}")
        self.settings, self.generations = s, []  # the search each generation went to
        self.searches = {"tiled": self._search((1, self.noise_shape[1]), s.population)}  # full: at 1st ask
        self.best = {name: np.full(len(self.seeds), -math.inf) for name in ("tiled", "full")}  # by seed
        self.best_ticket = np.zeros(self.noise_shape)  # the tiled search's best, along the horizon

    def _search(self, shape: tuple[int, int], population: int, mean: np.ndarray | None = None):
        return GriddedCMAES(shape, self.seeds, self.rng, population=population,
                            sigma_init=self.settings.sigma_init, mean=mean)

    def ask(self) -> list[Query]:
        self.generations.append(name := self._next())
        if name not in self.searches:
            s = self.settings
            start = self.best_ticket if s.full_start == "tiled" else None
            self.searches[name] = self._search(self.noise_shape, s.full_population or s.population, start)
        asked = self.searches[name].ask()
        return self._queries(np.broadcast_to(q.ticket, (self.noise_shape[0], q.ticket.shape[1]))
                             for q in asked)

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        name = self.generations[-1]
        for query, r in zip(queries, returns, strict=True):
            if len(r) == len(self.seeds) and np.mean(r) > np.mean(self.best[name]):
                self.best[name] = np.asarray(r, dtype=np.float64)
                if name == "tiled":
                    self.best_ticket = np.array(np.broadcast_to(query.ticket, self.noise_shape))
        self.searches[name].tell(queries, returns)

    def _next(self) -> str:
        """The search the next generation goes to."""
        done = len(self.generations)
        if done < 2:
            return ("tiled", "full")[done]
        full, tiled = self.best["full"], self.best["tiled"]
        chosen = "full" if sign_test(int(np.sum(full > tiled)), int(np.sum(tiled > full))) < \
            self.settings.alpha else "tiled"
        explore = self.settings.explore and (done - 1) % self.settings.explore == 0
        return {"full": "tiled", "tiled": "full"}[chosen] if explore else chosen


class _ModelBased(_Base):
    """Model-based search through an Optuna sampler over the searched array: `batch_size` tickets
    per ask, each on every search seed, scored by mean return; the first ticket is w = 0 if
    `start_at_zero`. The sampler sees each number as its quantile under N(0, 1), truncated to
    [-bound, bound], so that a uniform draw there is a draw of the policy's own noise. The study
    lives in memory and its sampler is seeded from `rng` (Optuna's samplers keep their own random
    state). Runs until `num_tickets` have been asked for (None: until the driver stops it)."""

    settings_class: type[ModelBasedSettings]

    def __init__(self, noise_shape: tuple[int, int], seeds: Sequence[int], rng: np.random.Generator,
                 settings: ModelBasedSettings | None = None, **params):
        import optuna

        super().__init__(noise_shape, seeds, rng)
        s = _settings(self.settings_class, settings, params)
        _require(s.batch_size >= 1, f"batch_size must be >= 1, got {s.batch_size}")
        _require(s.startup >= 1, f"startup must be >= 1, got {s.startup}")
        _require(s.bound > 0, f"bound must be > 0, got {s.bound}")
        _require(s.num_tickets is None or s.num_tickets >= 1,
                 f"num_tickets must be >= 1, got {s.num_tickets}")
        self.settings, self.asked, self._trials = s, 0, []
        self._names = [f"w{i}" for i in range(math.prod(self.noise_shape))]
        low = NormalDist().cdf(-s.bound)
        self._space = dict.fromkeys(self._names, optuna.distributions.FloatDistribution(low, 1 - low))
        sampler = self._sampler(optuna, int(rng.integers(2**31)))
        with quiet_optuna():
            self._study = optuna.create_study(direction="maximize", sampler=sampler)
        if s.start_at_zero:
            self._study.enqueue_trial(dict.fromkeys(self._names, 0.5))

    def _sampler(self, optuna, seed: int):
        raise NotImplementedError

    def ask(self) -> list[Query]:
        num, n = self.settings.num_tickets, self.settings.batch_size
        n = n if num is None else min(n, num - self.asked)
        self.asked += n
        self._trials = [self._study.ask(self._space) for _ in range(n)]
        quantile = NormalDist().inv_cdf
        return self._queries(np.reshape([quantile(t.params[name]) for name in self._names], self.noise_shape)
                             for t in self._trials)

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        with quiet_optuna():
            for trial, r in zip(self._trials, returns, strict=True):
                self._study.tell(trial, float(np.mean(r)))


@contextlib.contextmanager
def quiet_optuna():
    """Optuna's log at WARNING inside (no line per scored ticket); the caller's level after."""
    import optuna

    level = optuna.logging.get_verbosity()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        yield
    finally:
        optuna.logging.set_verbosity(level)


class TPE(_ModelBased):
    """The tree-structured Parzen estimator: Optuna's multivariate TPESampler, whose pending tickets
    count as the worst score so far (constant liar)."""

    settings_class = TPESettings

    def _sampler(self, optuna, seed: int):
        return optuna.samplers.TPESampler(seed=seed, n_startup_trials=self.settings.startup,
                                          multivariate=True, constant_liar=True)


class GaussianProcess(_ModelBased):
    """Bayesian optimisation with a Gaussian process: Optuna's GPSampler."""

    settings_class = GPSettings

    def _sampler(self, optuna, seed: int):
        return optuna.samplers.GPSampler(seed=seed, n_startup_trials=self.settings.startup)


OPTIMIZERS: dict[str, type] = {
    "rs": RandomSearch,
    "cem": CEM,
    "zos": ZerothOrder,
    "cem-racing": CEMRacing,
    "cem-bounds": CEMBounds,
    "cma-es": CMAES,
    "tiled-then-full": TiledThenFull,
    "portfolio": Portfolio,
    "tpe": TPE,
    "gp": GaussianProcess,
}


def make_optimizer(method: str, noise_shape: tuple[int, int], seeds: Sequence[int],
                   rng: np.random.Generator, **changed) -> Optimizer:
    """The optimizer named `method` with its settings' defaults (`methods.METHODS`) but the `changed`
    ones (an array, such as a start ticket, as nested lists)."""
    changed = {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in changed.items()}
    settings = method_settings(method, changed)
    return OPTIMIZERS[method](noise_shape, seeds, rng, settings)
