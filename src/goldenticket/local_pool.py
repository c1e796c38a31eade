"""A pool of spawned worker processes, each running an initializer once and then one shard at a
time: the local twin of `ray_pool.RayPool`. A worker that cannot start, or dies, ends the run with
one line instead of being replaced (a replaced worker would lose its shard)."""

from __future__ import annotations

import faulthandler
import itertools
import multiprocessing as mp
import multiprocessing.connection
import pickle
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from multiprocessing.pool import ExceptionWithTraceback

from goldenticket.errors import UserError
from goldenticket.factories import spawnable


class WorkerDied(UserError):
    """A worker process ended while the main process waited for shards; `finished`: the results (by shard
    index) that had come back but were not yet handed on."""

    def __init__(self, exitcode: int, finished: dict[int, list]):
        super().__init__(f"worker process died ({_ended(exitcode)})")
        self.finished = finished


class LocalPool:
    """`workers` spawned processes, each running the initializer once and then one shard at a time: the
    local twin of RayPool. A worker that cannot start, or dies, ends the run with a one-line UserError
    instead of being replaced."""

    def __init__(self, workers: int, initializer: Callable, initargs: tuple):
        spawnable("worker processes")
        ctx, payload = mp.get_context("spawn"), pickle.dumps((initializer, initargs))
        self._conns, self._processes, self._ready = [], [], set()
        self._busy: dict[int, int] = {}  # worker -> the number of the shard it runs
        self._numbers = itertools.count()
        for i in range(workers):
            conn, theirs = ctx.Pipe()
            process = ctx.Process(target=_serve, args=(theirs, payload), name=f"SpawnPoolWorker-{i + 1}",
                                  daemon=True)
            process.start()
            theirs.close()
            self._conns.append(conn)
            self._processes.append(process)

    def imap(self, fn: Callable, shards: Iterable) -> Iterator:
        """`fn(shard)` for every shard, yielded in shard order (a shard's exception raised in its place);
        the next shard goes to whichever worker is free."""
        todo, finished, next_index = deque(enumerate(shards)), {}, 0
        total, mine = len(todo), {}  # shard number -> shard index, for this call's shards
        self._dispatch(fn, todo, mine)
        while next_index < total:
            mp.connection.wait(self._conns + [process.sentinel for process in self._processes])
            for number, answer in self._answers():
                if number in mine:  # else a shard of an earlier call that was given up
                    finished[mine.pop(number)] = answer
            self._check_alive(finished)
            self._dispatch(fn, todo, mine)  # before the shards are handed on: no worker waits for that
            while next_index in finished:
                result, error = finished.pop(next_index)
                if error is not None:
                    raise error
                yield result
                next_index += 1

    def _dispatch(self, fn: Callable, todo: deque, mine: dict[int, int]) -> None:
        """The next shards to the workers that are free."""
        for worker in sorted(self._ready - set(self._busy))[: len(todo)]:
            index, shard = todo.popleft()
            self._busy[worker] = number = next(self._numbers)
            mine[number] = index
            self._conns[worker].send((fn, shard))

    def _answers(self) -> list[tuple[int, tuple]]:
        """(shard number, (result, error)) for each shard that came back; marks the workers that started."""
        answers = []
        for worker, conn in enumerate(self._conns):
            try:
                if not conn.poll():
                    continue
                result, error = conn.recv()
            except EOFError:  # the worker ended: _check_alive says how
                continue
            if worker in self._ready:
                answers.append((self._busy.pop(worker), (result, error)))
            elif error is not None:
                raise UserError(f"a worker process could not start: {_first_line(error)}")
            else:
                self._ready.add(worker)
        return answers

    def _check_alive(self, finished: dict[int, tuple]) -> None:
        for worker, process in enumerate(self._processes):
            if process.is_alive():
                continue
            process.join()
            if worker not in self._ready:
                raise UserError(f"a worker process could not start ({_ended(process.exitcode)}); its error, "
                                "if it printed one, is above (a worker re-runs the main script: does a "
                                "script that calls goldenticket guard its entry point with "
                                "`if __name__ == '__main__':`?)")
            raise WorkerDied(process.exitcode, {i: r for i, (r, e) in finished.items() if e is None})

    def terminate(self) -> None:
        for process in self._processes:
            process.kill()
            process.join()
        for conn in self._conns:
            conn.close()
        self._conns, self._processes = [], []


def _ended(exitcode: int) -> str:
    return f"exit code {exitcode}" if exitcode >= 0 else f"killed by signal {-exitcode}"


def _first_line(exc: BaseException) -> str:
    """An error in one line: a UserError's message, else its type and the first line of its text."""
    text = (str(exc).strip().splitlines() or [""])[0]
    if isinstance(exc, UserError):
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _serve(conn, payload: bytes) -> None:
    """A worker process: the initializer (sent pickled, so that failing to rebuild it is an answer, not a
    crash), then `fn(shard)` for each (fn, shard) received. Every answer is (result, error). A crash in C
    code prints the traceback of the call it happened in."""
    faulthandler.enable()
    try:
        initializer, initargs = pickle.loads(payload)
        initializer(*initargs)
    except Exception as exc:
        _answer(conn, None, exc)
        return
    _answer(conn, None, None)
    while True:
        try:
            fn, shard = conn.recv()
        except EOFError:  # the main process has gone
            return
        try:
            result, error = fn(shard), None
        except Exception as exc:
            result, error = None, ExceptionWithTraceback(exc, exc.__traceback__)
        _answer(conn, result, error)


def _answer(conn, result, error: BaseException | None) -> None:
    try:
        conn.send((result, error))
    except (BrokenPipeError, ConnectionResetError):  # the main process has gone: nobody to tell
        return
    except Exception as exc:  # what fn returned or raised cannot be pickled
        conn.send((None, UserError(f"a worker process could not send back its answer: {_first_line(exc)}")))
