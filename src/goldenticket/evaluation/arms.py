"""The arms a verdict judges: the base policy, the zero ticket, tickets and a mixture of tickets; and,
in a comparison of two policies, another policy with its own noise."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class Kind(Enum):
    BASE = "base"  # the policy as it is: fresh Gaussian noise at every call
    ZERO = "zero"  # the zero ticket, w = 0
    TICKET = "ticket"  # one constant noise: a ticket, by its id (or a role a study gives it)
    MIXTURE = "mixture"  # one of several tickets drawn at every call
    POLICY = "policy"  # another policy, by its name: fresh Gaussian noise, or a ticket of its own


@dataclass(frozen=True)
class Arm:
    """One arm of a verdict. `key` spells it as the run store, summary.json, front.json,
    transfer.json, `evaluate --json` and ticket metadata do: "base", "zero", "mixture", or the
    ticket's id; another policy as "policy:NAME", or "ID@policy:NAME" with ticket ID (a ticket's id
    holds no ":", so every key spells one arm)."""

    kind: Kind
    ticket_id: str | None = None
    policy: str | None = None  # the other policy's name (Kind.POLICY only)

    def __post_init__(self):
        ticket_ok = self.kind is Kind.POLICY or (self.kind is Kind.TICKET) == (self.ticket_id is not None)
        policy_ok = (self.kind is Kind.POLICY) == (isinstance(self.policy, str) and self.policy != "")
        if not (ticket_ok and policy_ok) or self.ticket_id in FIXED or ":" in (self.ticket_id or ""):
            raise ValueError(f"not an arm: {self.kind.value} {self.ticket_id!r} {self.policy!r}")

    @classmethod
    def ticket(cls, ticket_id: str) -> Arm:
        return cls(Kind.TICKET, ticket_id)

    @classmethod
    def other(cls, policy: str, ticket_id: str | None = None) -> Arm:
        """Another policy, named `policy`, with fresh Gaussian noise or with ticket `ticket_id`."""
        return cls(Kind.POLICY, ticket_id, policy)

    @classmethod
    def of(cls, key: str) -> Arm:
        """The arm that `key` spells."""
        head, colon, policy = key.partition(":")
        if colon:
            ticket_id, _, kind = head.rpartition("@")
            if kind != Kind.POLICY.value:
                raise ValueError(f"not an arm: {key!r}")
            return cls.other(policy, ticket_id or None)
        return cls(Kind(key)) if key in FIXED else cls.ticket(key)

    @property
    def key(self) -> str:
        if self.kind is Kind.POLICY:
            with_ticket = "" if self.ticket_id is None else f"{self.ticket_id}@"
            return f"{with_ticket}policy:{self.policy}"
        return self.ticket_id if self.kind is Kind.TICKET else self.kind.value

    @property
    def label(self) -> str:
        """Its row's label in a verdict table: base, zero ticket, ticket <id>, mixture; policy <name>
        (+ ticket <id>)."""
        if self.kind is Kind.POLICY:
            with_ticket = "" if self.ticket_id is None else f" + ticket {self.ticket_id}"
            return f"policy {self.policy}{with_ticket}"
        labels = {Kind.ZERO: "zero ticket", Kind.TICKET: f"ticket {self.ticket_id}"}
        return labels.get(self.kind, self.kind.value)

    @property
    def candidate(self) -> bool:
        """Whether it is one of the candidates (tickets, a mixture) a verdict tests on the same seeds and
        Holm-adjusts over; the base and the zero ticket are what they are tested against."""
        return self.kind in (Kind.TICKET, Kind.MIXTURE)


FIXED = {kind.value for kind in Kind} - {Kind.TICKET.value, Kind.POLICY.value}  # keys naming no ticket
BASE, ZERO, MIXTURE = Arm(Kind.BASE), Arm(Kind.ZERO), Arm(Kind.MIXTURE)
