"""The Ray backend on several nodes: Ray's own test cluster runs a head and two worker nodes
(raylets) on this machine, one CPU each. A search on it gives the episodes of local processes,
and a node lost mid-run costs only the shard it was running: another node re-runs it and the
numbers are unchanged, although the cluster has no room left for a new actor."""

import sys
import threading
import time
from functools import partial
from pathlib import Path

import pytest

import goldenticket
from goldenticket import rollout
from goldenticket.noise import Gaussian
from goldenticket.rollout import Engine, Episode
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in

ray = pytest.importorskip("ray")
from ray.cluster_utils import Cluster  # noqa: E402

pytestmark = [pytest.mark.ray, pytest.mark.xdist_group("ray")]

POLICY, TASK = "metaworld/reach-v3/flow", "metaworld/reach-v3"
NODES = 3


@pytest.fixture(scope="module")
def cluster():
    """A head and NODES - 1 worker nodes of one CPU each; the driver connects to the head."""
    ray.shutdown()
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # actors run _logged below
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    for _ in range(NODES - 1):
        cluster.add_node(num_cpus=1)
    yield cluster
    ray.shutdown()
    cluster.shutdown()
    ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def _episodes(results) -> list[tuple]:
    return [(r.seed, r.success, r.ret, r.length) for r in results]


def test_a_search_over_three_nodes_gives_the_episodes_of_local_processes(cluster, tmp_path):
    options = dict(budget=48, search_seeds=8, heldout=16, top_k=1, validation_seeds=4, max_steps=60)
    runs = {"local": {"workers": 1}, "ray": {"workers": NODES, "backend": "ray", "address": cluster.address}}
    summaries, stored = {}, {}
    for name, backend in runs.items():
        summary = goldenticket.search(POLICY, TASK, tmp_path / name, **options, **backend).to_dict()
        summaries[name] = {k: v for k, v in summary.items() if k not in ("best", "tickets")}
        summaries[name]["tickets"] = [{k: v for k, v in t.items() if k != "ticket_path"}
                                      for t in summary["tickets"]]
        with RunStore(tmp_path / name / "run.sqlite") as store:
            stored[name] = [(r.ticket_id, r.seed_set, r.seed, r.success, r.ret, r.length, r.cause)
                            for r in store.episodes()]
    assert stored["ray"] == stored["local"] and summaries["ray"] == summaries["local"]
    searched = [t for t in summaries["local"]["tickets"] if t.get("source") != "zero ticket"]
    assert len(stored["local"]) >= 2 * 16 + 48 and len(searched) == 1


def _logged(log: Path, shard):
    """The engine's own `_run_shard(shard)` (on an actor, this module's patch is not there), with a
    line on `log` as it starts and ends: event, first seed, node."""
    node, first_seed = ray.get_runtime_context().get_node_id(), shard[1][0].seed
    with open(log, "a") as f:
        f.write(f"start {first_seed} {node}\n")
    results = rollout._run_shard(shard)
    with open(log, "a") as f:
        f.write(f"end {first_seed} {node}\n")
    return results


def _lines(log: Path) -> list[list[str]]:
    return [line.split() for line in log.read_text().splitlines()] if log.exists() else []


def _remove_a_node_mid_shard(cluster, log: Path, running: threading.Thread) -> str | None:
    """Once every node has started a shard, removes the worker node of the next shard to start, at
    once (the shard is still running there); returns its id, or None if the run ended first."""
    workers, seen = {node.node_id: node for node in cluster.worker_nodes}, 0
    while running.is_alive():
        lines = _lines(log)
        fresh = [node for event, _, node in lines[seen:] if event == "start" and node in workers]
        if seen and fresh:
            cluster.remove_node(workers[fresh[0]])
            return fresh[0]
        if len({node for _, _, node in lines}) == NODES:
            seen = len(lines)
        time.sleep(0.01)
    return None


def test_a_node_lost_mid_run_costs_only_its_shard(cluster, tmp_path, monkeypatch):
    task, log = get_task(TASK), tmp_path / "shards.log"
    episodes = [Episode(Gaussian(0), seed) for seed in seeds_in("heldout", 48)]
    with Engine(POLICY, task, shard_size=4) as engine:
        local = engine.evaluate(episodes)
    monkeypatch.setattr(rollout, "_run_shard", partial(_logged, log))
    results = []
    with Engine(POLICY, task, workers=NODES, shard_size=4, backend="ray", address=cluster.address) as engine:
        ray.get([actor.ready.remote() for actor in engine._pool.actors])  # one actor up on each node
        running = threading.Thread(target=lambda: results.append(engine.evaluate(episodes)), daemon=True)
        running.start()
        removed = _remove_a_node_mid_shard(cluster, log, running)
        running.join(timeout=120)
    assert removed is not None and results, "no node removed mid-run, or the run did not finish without it"
    assert _episodes(results[0]) == _episodes(local)
    assert 0 < sum(r.success for r in local) < len(local)
    lines = _lines(log)
    assert len({node for _, _, node in lines}) == NODES
    runs = {}  # first seed of a shard -> the nodes that started it, in order
    for event, seed, node in lines:
        if event == "start":
            runs.setdefault(int(seed), []).append(node)
    lost = [seed for seed, nodes in runs.items() if nodes[0] == removed][-1]
    assert {seed: len(nodes) for seed, nodes in runs.items()} == {e.seed: 1 + (e.seed == lost)
                                                                  for e in episodes[::4]}
    ended = [(int(seed), node) for event, seed, node in lines if event == "end"]
    assert sorted(ended) == sorted((seed, nodes[-1]) for seed, nodes in runs.items())
