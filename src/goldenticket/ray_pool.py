"""Shards of episodes on Ray actors: the cluster twin of `multiprocessing.Pool(workers,
initializer, initargs).imap(fn, shards)`. Each actor runs the initializer once (it loads the
policy and keeps its envs) and then one shard at a time; a shard whose actor dies is re-run on
another actor, so a lost machine costs only its in-flight shards. Requires `pip install ray`."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Iterable, Iterator

from goldenticket.errors import OptionError, UserError

RETRIES = 3  # new actors per shard before giving up


class _Actor:
    def __init__(self, initializer: Callable, initargs: tuple):
        initializer(*initargs)

    def ready(self) -> None:
        """Returns once the actor has a CPU and its initializer has run."""

    def run(self, fn: Callable, shard):
        return fn(shard)


class RayPool:
    """`workers` actors of one CPU each on the Ray cluster at `address` (None: a local Ray
    instance started here)."""

    def __init__(self, workers: int, initializer: Callable, initargs: tuple, address: str | None = None):
        try:
            import ray
        except ImportError:
            raise OptionError("backend ray needs Ray: pip install 'goldenticket[ray]'", "backend") from None
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
        self._started: set = set()  # actors whose initializer has run

    def _new_actor(self):
        return self._remote.remote(self._initializer, self._initargs)

    def imap(self, fn: Callable, shards: Iterable) -> Iterator:
        """`fn(shard)` for every shard on the actors, yielded in shard order as they finish. An
        actor takes shards once it has started, so one the cluster has no room for (a dead actor's
        replacement once its node is gone, say) holds up nothing: the others run its shards."""
        ray, todo = self._ray, deque(enumerate(shards))
        total, idle = len(todo), [actor for actor in self.actors if actor in self._started]
        # call -> (shard index, shard, actor); a start-up check has no shard and, for a replacement,
        # the index of the shard its predecessor died on
        calls = {actor.ready.remote(): (None, None, actor) for actor in set(self.actors) - self._started}
        finished, tries, next_index = {}, {}, 0
        while next_index < total:
            while todo and idle:
                index, shard = todo.popleft()
                actor = idle.pop()
                calls[actor.run.remote(fn, shard)] = (index, shard, actor)
            (ref,), _ = ray.wait(list(calls), num_returns=1)
            index, shard, actor = calls.pop(ref)
            try:
                result = ray.get(ref)
            except ray.exceptions.RayTaskError as exc:  # the shard's own error, as if run here
                raise exc.cause from None
            except ray.exceptions.RayActorError as exc:
                replacement = self._replace(actor, index, exc, tries)
                calls[replacement.ready.remote()] = (index, None, replacement)
                if shard is not None:
                    todo.appendleft((index, shard))
                continue
            self._started.add(actor)
            idle.append(actor)
            if shard is not None:
                finished[index] = result
            while next_index in finished:
                yield finished.pop(next_index)
                next_index += 1

    def _replace(self, actor, index: int | None, exc: Exception, tries: dict):
        """A new actor in place of `actor`, which died running (or, index None, starting) shard `index`."""
        tries[index] = tries.get(index, 0) + 1
        if tries[index] > RETRIES:
            doing = "starting" if index is None else f"running shard {index}"
            first_line = (str(exc).strip().splitlines() or ["no message"])[0]
            raise UserError(f"Ray actors died {RETRIES + 1} times {doing}: {first_line}") from None
        self._started.discard(actor)
        self.actors[self.actors.index(actor)] = replacement = self._new_actor()
        return replacement

    def terminate(self) -> None:
        for actor in self.actors:
            self._ray.kill(actor)
        self.actors, self._started = [], set()
