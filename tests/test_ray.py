"""The Ray backend: the same shards on Ray actors give the same episodes as local processes,
even when an actor dies mid-run, from the engine and from the CLI."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from goldenticket.cli import main
from goldenticket.noise import Constant, Gaussian
from goldenticket.rollout import Engine, Episode
from goldenticket.tasks import get_task, seeds_in

ray = pytest.importorskip("ray")
pytestmark = [pytest.mark.ray, pytest.mark.xdist_group("ray")]
HERE = Path(__file__).parent


@pytest.fixture(scope="module", autouse=True)
def local_ray():
    """One local Ray instance for the module, started by the first run on Ray as a user's run
    starts it; byo_example is importable here and on its workers."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("PYTHONPATH", os.pathsep.join(filter(None, (str(HERE), os.environ.get("PYTHONPATH")))))
        patch.syspath_prepend(str(HERE))
        yield
        ray.shutdown()


def _key(results):
    return [(r.seed, r.success, r.length, r.ret) for r in results]


def test_ray_actors_give_the_local_episodes_even_when_one_dies():
    task = get_task("metaworld/reach-v3", max_steps=60)
    sources = (Gaussian(0), Constant(np.full((8, 4), 0.3, np.float32)))
    episodes = [Episode(source, s) for s in seeds_in("heldout", 12) for source in sources]  # 8 shards
    with Engine("metaworld/reach-v3/flow", task, shard_size=3) as engine:  # in this process
        local = engine.evaluate(episodes)
    killed = []
    with Engine("metaworld/reach-v3/flow", task, workers=2, shard_size=3, backend="ray") as engine:
        first_actor = engine._pool.actors[0]

        def kill_once(start, results):
            if not killed:
                ray.kill(first_actor)
                killed.append(start)

        remote = engine.evaluate(episodes, kill_once)
        assert first_actor not in engine._pool.actors  # replaced, and its shard re-run
    assert killed and _key(remote) == _key(local)
    assert 0 < sum(r.success for r in local) < len(local)


def test_search_from_the_cli_on_ray_matches_local(tmp_path):
    argv = ["search", "--policy", "byo_example:make_policy", "--task", "byo_example:make_env",
            "--max-steps", "30", "--budget", "120", "--search-seeds", "20", "--heldout", "30", "--top-k", "2",
            "--validation-seeds", "10"]
    runs = {}
    for backend in (["local", "--workers", "1"], ["ray"]):  # Ray: two actors
        assert main([*argv, "--backend", *backend, "--out", str(tmp_path / backend[0])]) == 0
        runs[backend[0]] = json.loads((tmp_path / backend[0] / "summary.json").read_text())
    strip = [{k: v for k, v in t.items() if k != "ticket_path"} for t in runs["ray"]["tickets"]]
    assert strip == [{k: v for k, v in t.items() if k != "ticket_path"} for t in runs["local"]["tickets"]]
    assert runs["ray"]["base"] == runs["local"]["base"]


def test_address_without_ray_is_one_line(capsys):
    argv = ["evaluate", "--policy", "metaworld/reach-v3/flow", "--task", "metaworld/reach-v3",
            "--seeds", "1000000:1000002", "--address", "ray://head:10001"]
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == "goldenticket: error: --address needs --backend ray"


def test_an_error_on_an_actor_is_one_line(tmp_path, capsys):
    argv = ["evaluate", "--policy", "byo_example:make_nan_policy", "--task", "byo_example:make_env",
            "--seeds", "1000000:1000004", "--max-steps", "30", "--backend", "ray",
            "--plot", str(tmp_path / "e.png")]
    code, stderr = main(argv), capsys.readouterr().err
    errors = [line for line in stderr.splitlines() if "error" in line]
    assert code == 2 and "Traceback" not in stderr, stderr
    assert len(errors) == 1 and errors[0].startswith(
        "goldenticket: error: policy 'biased-controller' returned NaN or infinite actions in 4 of the 4 ")
