"""One policy in the main process answering the act() calls of worker processes: on a GPU, the env
workers share one model on the device instead of loading a copy each. Each call is the batch the
worker would have given its own copy (a shard's live episodes), answered one at a time, so the
results are those of workers that each hold the policy."""

from __future__ import annotations

import dataclasses
import os
import threading
from multiprocessing.connection import Client, Listener

from goldenticket.errors import UserError
from goldenticket.factories import call_users
from goldenticket.policies import NoisePolicy, policy_label


class PolicyServer:
    """Serves `policy.act` on a local socket, one call at a time, for the policies `client()` gives."""

    def __init__(self, policy: NoisePolicy):
        self.policy, self._label = policy, policy_label(policy)
        if getattr(policy, "tasks", None):  # its clients would act unconditioned
            raise UserError(f"policy {self._label!r} is conditioned on its tasks; workers cannot share it")
        self._authkey = os.urandom(16)
        self._listener = Listener(family="AF_UNIX", authkey=self._authkey)
        self._lock = threading.Lock()  # one model call at a time
        threading.Thread(target=self._accept, daemon=True).start()

    def client(self) -> ServedPolicy:
        """A picklable stand-in for the policy that worker processes act through."""
        kind = ServedLanguagePolicy if callable(getattr(self.policy, "instructed", None)) else ServedPolicy
        p = self.policy
        return kind(str(self._listener.address), self._authkey, self._label, tuple(p.noise_shape), p.n_exec,
                    getattr(p, "action_dim", p.noise_shape[1]), getattr(p, "n_obs_steps", 1))

    def _accept(self) -> None:
        while True:
            try:
                conn = self._listener.accept()
            except OSError:  # closed
                return
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn) -> None:
        while True:
            try:
                instruction, obs, noise = conn.recv()
            except (EOFError, OSError):  # the worker has gone
                return
            try:
                with self._lock:
                    actions = call_users(self._act, f"policy {self._label!r}: act()", instruction, obs, noise)
                answer = actions, None
            except UserError as error:  # any failure, in one line
                answer = None, error
            conn.send(answer)

    def _act(self, instruction: str | None, obs, noise):
        policy = self.policy.instructed(instruction) if instruction is not None else self.policy
        return policy.act(obs, noise)

    def close(self) -> None:
        self._listener.close()


@dataclasses.dataclass
class ServedPolicy:
    """A NoisePolicy whose act() is the served policy's, in the process that serves it."""

    address: str
    authkey: bytes
    name: str
    noise_shape: tuple[int, int]
    n_exec: int
    action_dim: int
    n_obs_steps: int
    instruction: str | None = None
    _conn: object = dataclasses.field(default=None, repr=False, compare=False)

    def act(self, obs, noise):
        if self._conn is None:
            self._conn = Client(self.address, family="AF_UNIX", authkey=self.authkey)
        self._conn.send((self.instruction, obs, noise))
        actions, error = self._conn.recv()
        if error is not None:
            raise error
        return actions

    def __getstate__(self) -> dict:  # a connection stays in its process
        return {**self.__dict__, "_conn": None}


class ServedLanguagePolicy(ServedPolicy):
    """A served policy that reads a language instruction."""

    def instructed(self, instruction: str) -> ServedLanguagePolicy:
        return dataclasses.replace(self, instruction=instruction)  # the same connection
