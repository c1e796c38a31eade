"""A search method's settings are config: typed, defaulted once, given in TOML or as flags, and
written back to config.toml."""

import dataclasses
import inspect
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from goldenticket.cli import main
from goldenticket.config import METHODS, SearchConfig, make, read_toml, to_toml
from goldenticket.errors import OptionError
from goldenticket.ticket_search import OPTIMIZERS, make_optimizer

HERE = Path(__file__).parent
SMALL = ["--policy", "byo_example:make_policy", "--task", "byo_example:make_env", "--search-seeds", "2",
         "--heldout", "4", "--top-k", "1", "--validation-seeds", "0", "--max-steps", "10", "--workers", "1"]


def test_the_methods_settings_import_from_ticket_search_without_config_or_numpy():
    """Search sits below config: config (and the command line) reads each method's settings from it,
    before anything heavy loads."""
    code = ("import sys\nfrom goldenticket.ticket_search import METHODS, CEMSettings\n"
            "assert METHODS['cem'] is CEMSettings\n"
            "print(sorted({'goldenticket.config', 'numpy'} & set(sys.modules)))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.stdout == "[]\n", done.stderr


def test_every_method_has_its_settings_and_no_optimizer_repeats_a_default():
    assert set(METHODS) == set(OPTIMIZERS)
    for method, klass in OPTIMIZERS.items():
        parameters = inspect.signature(klass.__init__).parameters.values()
        keywords = [p for p in parameters if p.default is not p.empty]
        assert [p.name for p in keywords] == ["settings"], method  # defaults live in config.METHODS only
        assert make_optimizer(method, (4, 2), range(10), np.random.default_rng(0)).ask()


@pytest.mark.parametrize("values, says", [
    ({"method": "cma-es", "optimizer": {"popsize": 4}}, "unknown optimizer setting popsize for cma-es"),
    ({"method": "cem", "optimizer": {"population": "4"}}, "population must be of type int"),
    ({"method": "cma-es", "optimizer": {"mean": [1, 2]}}, "mean must be of type"),
])
def test_a_bad_setting_is_one_line_naming_it(values, says):
    cfg = make(SearchConfig, {"policy": "p", "task": "t"} | values)
    with pytest.raises(OptionError, match=says):
        cfg.check()


def test_settings_round_trip_through_config_toml(tmp_path):
    cfg = make(SearchConfig, {"policy": "p", "task": "t", "optimizer": {"population": 4, "sigma_init": 0.5}})
    path = tmp_path / "run.toml"
    path.write_text(to_toml(cfg))
    assert "optimizer = {population = 4, sigma_init = 0.5}" in path.read_text()
    assert make(SearchConfig, read_toml(path)).settings() == dataclasses.replace(
        METHODS["portfolio"](), population=4, sigma_init=0.5)  # the default method's
    assert "optimizer" not in to_toml(make(SearchConfig, {"policy": "p", "task": "t"}))  # defaults: unsaid


@pytest.mark.slow
def test_flags_set_the_methods_settings_for_the_search(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    out = tmp_path / "run"
    assert main(["search", *SMALL, "--budget", "16", "--optimizer", "population=4",
                 "--optimizer", "sigma_init=0.5", "--out", str(out)]) == 0
    with sqlite3.connect(out / "run.sqlite") as db:
        tickets = db.execute("SELECT COUNT(DISTINCT ticket_id) FROM episodes WHERE seed_set = 'search'"
                             ).fetchone()
    assert tickets == (8,)  # two generations of 4 (the portfolio's tiled, then full) on 2 seeds: 16 episodes
    assert "optimizer = {population = 4, sigma_init = 0.5}" in (out / "config.toml").read_text()
    assert main(["search", *SMALL, "--budget", "16", "--out", str(out)]) == 2  # other settings: another run
