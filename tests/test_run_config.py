"""What a run store holds of a search's config: the options that change results, so that a rerun with
another engine option resumes, one with another result option is refused, and every run stored so far
resumes."""

import sqlite3
from dataclasses import dataclass
from types import SimpleNamespace

import pytest

from goldenticket.config import SearchConfig, make, option
from goldenticket.errors import UserError
from goldenticket.job.folder import open_store
from goldenticket.job.plan import Names

NAMES = Names("metaworld/pick-place-v3/flow", "metaworld/pick-place-v3", "018bd7c659905392@10")
GIVEN = {"policy": NAMES.policy, "task": NAMES.task, "method": "cma-es"}  # the default before the portfolio
STORED = (  # what `goldenticket demo` stored before the portfolio: a rerun of such a folder resumes
    '{"address": null, "backend": null, "budget": 1100, "device": "cpu", "front_objective": null, '
    '"halving": true, "heldout": 200, "max_steps": null, "max_tickets": null, "method": "cma-es", '
    '"no_regression": false, "objective": "success", "policy": "metaworld/pick-place-v3/flow", '
    '"policy_fingerprint": "018bd7c659905392@10", "race": null, "search_seeds": 20, "seed": 0, '
    '"stop_after_perfect": 3, "subspace": "tiled", "success": null, "task": "metaworld/pick-place-v3", '
    '"tickets": [], "top_k": 3, "validation_seeds": null, "workers": null}')


@dataclass(frozen=True)
class WithPoolSize(SearchConfig):
    """A search config with one more option that does not change results."""

    pool_size: int = option(4, "threads per worker", changes_results=False)


def _claim(out, cfg) -> str:
    """The config the run store in `out` holds once `cfg` opened it."""
    with open_store(out, SimpleNamespace(cfg=cfg, names=NAMES)):
        pass
    with sqlite3.connect(out / "run.sqlite") as con:
        return con.execute("SELECT value FROM config").fetchone()[0]


def test_a_run_stored_so_far_holds_the_config_claimed_now(tmp_path):
    assert _claim(tmp_path, make(SearchConfig, GIVEN)) == STORED


def test_an_option_that_does_not_change_results_is_not_claimed(tmp_path):
    _claim(tmp_path, make(SearchConfig, GIVEN))
    rerun = WithPoolSize(**GIVEN, pool_size=9, workers=1, backend="ray", address="ray://head:10001",
                         max_nonfinite=0.5, step_timeout=3.0, log=("tensorboard",))
    assert _claim(tmp_path, rerun) == STORED


def test_an_engine_option_that_changes_results_is_another_run(tmp_path):
    _claim(tmp_path, make(SearchConfig, GIVEN))
    with pytest.raises(UserError, match="holds a different run"):
        _claim(tmp_path, make(SearchConfig, GIVEN | {"device": "cuda"}))
