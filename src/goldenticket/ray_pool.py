"""Shards of episodes on Ray actors: the cluster twin of `multiprocessing.Pool(workers,
initializer, initargs).imap(fn, shards)`. Each actor runs the initializer once (it loads the
policy and keeps its envs) and then one shard at a time; a shard whose actor dies is re-run on
a new actor, so a lost machine costs only its in-flight shard. Requires `pip install ray`."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Iterable, Iterator

from goldenticket.errors import UserError

RETRIES = 3  # new actors per shard before giving up


class _Actor:
    def __init__(self, initializer: Callable, initargs: tuple):
        initializer(*initargs)

    def run(self, fn: Callable, shard):
        return fn(shard)


class RayPool:
    """`workers` actors of one CPU each on the Ray cluster at `address` (None: a local Ray
    instance started here)."""

    def __init__(self, workers: int, initializer: Callable, initargs: tuple, address: str | None = None):
        try:
            import ray
        except ImportError:
            raise UserError("--backend ray needs Ray: pip install 'goldenticket[ray]'") from None
        self._ray = ray
        if not ray.is_initialized():
            try:
                ray.init(address=address, include_dashboard=False, log_to_driver=False,
                         logging_level=logging.ERROR, configure_logging=False)
            except (ConnectionError, ValueError, RuntimeError) as exc:
                where = address or "a new local instance"
                raise UserError(f"cannot reach a Ray cluster at {where}: {exc}") from None
        self._remote = ray.remote(num_cpus=1)(_Actor)
        self._initializer, self._initargs = initializer, initargs
        self.actors = [self._new_actor() for _ in range(workers)]

    def _new_actor(self):
        return self._remote.remote(self._initializer, self._initargs)

    def imap(self, fn: Callable, shards: Iterable) -> Iterator:
        """`fn(shard)` for every shard on the actors, yielded in shard order as they finish."""
        ray = self._ray
        todo, idle = deque(enumerate(shards)), list(self.actors)
        running, finished, tries, next_index = {}, {}, {}, 0
        while todo or running:
            while todo and idle:
                index, shard = todo.popleft()
                actor = idle.pop()
                running[actor.run.remote(fn, shard)] = (index, shard, actor)
            (ref,), _ = ray.wait(list(running), num_returns=1)
            index, shard, actor = running.pop(ref)
            try:
                finished[index] = ray.get(ref)
                idle.append(actor)
            except ray.exceptions.RayTaskError as exc:  # the shard's own error, as if run here
                raise exc.cause from None
            except ray.exceptions.RayActorError as exc:
                tries[index] = tries.get(index, 0) + 1
                if tries[index] > RETRIES:
                    first_line = (str(exc).strip().splitlines() or ["no message"])[0]
                    raise UserError(f"Ray actors died {RETRIES + 1} times running shard {index}: "
                                    f"{first_line}") from None
                self.actors[self.actors.index(actor)] = replacement = self._new_actor()
                idle.append(replacement)
                todo.appendleft((index, shard))
            while next_index in finished:
                yield finished.pop(next_index)
                next_index += 1

    def terminate(self) -> None:
        for actor in self.actors:
            self._ray.kill(actor)
        self.actors = []
