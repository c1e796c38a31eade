"""Noise-injectable policies and the bundled policy zoo."""

from goldenticket.policies.base import NoisePolicy, TicketedPolicy
from goldenticket.policies.mlp import MLPPolicy, PolicyConfig
from goldenticket.policies.registry import (
    BUNDLED_DIR,
    bundled_tickets,
    deploy,
    find_ticket,
    fingerprint,
    for_task,
    identity,
    load_policy,
    policy_label,
    policy_names,
)

__all__ = ["BUNDLED_DIR", "MLPPolicy", "NoisePolicy", "PolicyConfig", "TicketedPolicy",
           "bundled_tickets", "deploy", "find_ticket", "fingerprint", "for_task", "identity",
           "load_policy", "policy_label", "policy_names"]
