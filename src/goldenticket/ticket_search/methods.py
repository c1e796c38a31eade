"""Each search method's settings, registered by name: a frozen dataclass of typed options with their
defaults and help, which its optimizer (`optimizers.OPTIMIZERS[name]`) takes. Pure data and checks,
without numpy, so that config and the command line read them before anything heavy loads."""

from __future__ import annotations

from dataclasses import dataclass, fields

from goldenticket.errors import OptionError
from goldenticket.options import check_types, option

METHODS: dict[str, type] = {}  # a search method's name -> the dataclass of its settings
SELF_RACING = ("cem-racing", "cem-bounds")  # methods that race their own tickets: no race, no halving
OWN_TILING = ("portfolio", "tiled-then-full")  # methods that search tiled tickets themselves: full sub-space
FULL_STARTS = ("zero", "tiled")  # where the portfolio's full search starts


def method(name: str):
    """Register the decorated settings dataclass as search method `name`'s (the LeRobot
    `register_subclass` pattern): `--method name` and `optimizer = {...}` in a config file."""
    def register(cls):
        METHODS[name] = cls
        return cls
    return register


def method_settings(name: str, values: dict):
    """Method `name`'s settings with `values` changed; OptionError for an unknown method, setting or
    a value of the wrong type."""
    if name not in METHODS:
        raise OptionError(f"unknown method {name!r}; choose from {list(METHODS)}", "method")
    cls = METHODS[name]
    if unknown := sorted(set(values) - {f.name for f in fields(cls)}):
        raise OptionError(f"unknown optimizer setting {', '.join(unknown)} for {name}; its settings: "
                          f"{', '.join(f.name for f in fields(cls))}", "optimizer")
    check_types(cls, values)
    return cls(**values)


@method("rs")
@dataclass(frozen=True)
class RandomSearchSettings:
    """Random search (the paper's Alg. 1): i.i.d. N(0, I) tickets, each on every search seed."""

    batch_size: int = option(50, "tickets per ask")
    num_tickets: int | None = option(None, "tickets in all (default: until the budget is spent)")


@method("cem")
@dataclass(frozen=True)
class CEMSettings:
    """The cross-entropy method (Alg. 2) over a diagonal Gaussian: sample `population`, keep the top
    `elite_frac`, refit with smoothing `alpha`; sigma floored at `sigma_min`, then inflated by
    `sigma_extra`."""

    population: int = option(50, "tickets per iteration")
    elite_frac: float = option(0.2, "fraction of the population refit on")
    alpha: float = option(1.0, "smoothing of the refit (1: the elites' statistics alone)")
    sigma_init: float = option(1.0, "initial standard deviation")
    sigma_min: float = option(0.01, "floor of the standard deviation")
    sigma_extra: float = option(0.0, "noise added to the standard deviation after each refit")
    iterations: int | None = option(None, "iterations (default: until the budget is spent)")


@method("zos")
@dataclass(frozen=True)
class ZerothOrderSettings:
    """Zeroth-order search (Alg. 3): a random walk on a sphere of `radius` around a pivot."""

    candidates: int = option(10, "tickets per iteration")
    radius: float = option(0.5, "L2 radius of the steps")
    iterations: int | None = option(None, "iterations after the pivot (default: until the budget)")


@method("cem-racing")
@dataclass(frozen=True)
class CEMRacingSettings(CEMSettings):
    """CEM whose population is raced by sequential halving over `tiers` blocks of search seeds."""

    tiers: int = option(5, "blocks of search seeds; the top half survives each")


@method("cem-bounds")
@dataclass(frozen=True)
class CEMBoundsSettings(CEMSettings):
    """CEM whose population is raced with Hoeffding confidence bounds, `block` seeds at a time."""

    block: int = option(4, "search seeds per block")
    delta: float = option(0.1, "level of each confidence bound")
    value_range: float = option(1.0, "range of an episode's return")


@method("cma-es")
@dataclass(frozen=True)
class CMAESSettings:
    """CMA-ES (the `cma` package) over the flattened ticket."""

    population: int = option(20, "tickets per generation")
    sigma_init: float = option(1.0, "initial step size")
    mean: tuple[tuple[float, ...], ...] | None = option(None, "start ticket, rows of the searched shape "
                                                        "(default: w = 0)")
    iterations: int | None = option(None, "generations (default: until the budget is spent)")


@method("tiled-then-full")
@dataclass(frozen=True)
class TiledThenFullSettings:
    """CMA-ES over a tiled ticket, then CMA-ES over the full ticket from the tiled stage's best (run
    with the full sub-space)."""

    population: int = option(20, "tickets per generation, in both stages")
    sigma_init: float = option(1.0, "the tiled stage's initial step size")
    tiled_generations: int = option(2, "generations of the tiled stage")
    sigma_full: float = option(0.5, "the full stage's initial step size")


@method("portfolio")
@dataclass(frozen=True)
class PortfolioSettings:
    """Two CMA-ES searches, one over a tiled ticket (one action-sized vector repeated along the
    horizon), one over the full ticket, a generation at a time: one generation of each, then each
    generation to the tiled one unless the full one's best ticket beats its best on the search seeds
    by a paired sign test at p < `alpha`, every `explore`-th to the other one; the full one starts
    at w = 0 or at the tiled one's best (`full_start`) (run with the full sub-space)."""

    population: int = option(20, "tickets per generation, in both searches")
    full_population: int | None = option(None, "tickets per generation of the full search (default: "
                                         "population)")
    sigma_init: float = option(1.0, "both searches' initial step size")
    alpha: float = option(0.01, "level of the paired sign test by which the full search's best ticket "
                          "must beat the tiled search's best to take the next generation")
    explore: int = option(5, "every explore-th generation after the first two goes to the search the "
                          "test did not choose (0: never)")
    full_start: str = option("zero", "where the full search starts: zero (w = 0) or tiled (the tiled "
                             "search's best ticket, repeated along the horizon, when the full search "
                             "takes its first generation)")


@dataclass(frozen=True)
class ModelBasedSettings:
    """Model-based search through an Optuna sampler, each searched number in [-bound, bound] and seen
    by the sampler as its N(0, 1) quantile."""

    batch_size: int = option(4, "tickets per ask (the sampler treats the unscored ones as pending)")
    startup: int = option(10, "random tickets before the model proposes")
    bound: float = option(3.0, "each searched number lies in [-bound, bound]")
    start_at_zero: bool = option(True, "score w = 0 first")
    num_tickets: int | None = option(None, "tickets in all (default: until the budget is spent)")


@method("tpe")
@dataclass(frozen=True)
class TPESettings(ModelBasedSettings):
    """The tree-structured Parzen estimator (Optuna's multivariate TPESampler, constant liar)."""


@method("gp")
@dataclass(frozen=True)
class GPSettings(ModelBasedSettings):
    """Bayesian optimisation with a Gaussian process (Optuna's GPSampler: a Matern-5/2 kernel with
    learned noise, log expected improvement)."""

