"""Seed sets: every integer seed names one initial state and belongs to exactly one set."""

from __future__ import annotations

from collections.abc import Sequence

from goldenticket.errors import UserError

# Disjoint by construction: a seed names one initial state and belongs to exactly one set.
SEED_SETS: dict[str, range] = {
    "search": range(0, 1_000_000),
    "heldout": range(1_000_000, 2_000_000),
    "train": range(2_000_000, 3_000_000),
    "validation": range(3_000_000, 4_000_000),  # selection among search tickets (--validation-seeds)
}


def seeds_in(seed_set: str, n: int) -> list[int]:
    """The first `n` seeds of a seed set."""
    if seed_set not in SEED_SETS:
        raise UserError(f"unknown seed set {seed_set!r}; choose from {sorted(SEED_SETS)}")
    block = SEED_SETS[seed_set]
    if not 0 <= n <= len(block):
        raise UserError(f"seed set {seed_set!r} has {len(block)} seeds; asked for {n}")
    return list(block[:n])


def require_unseen(seeds: Sequence[int], used: range, what: str) -> None:
    """UserError unless `seeds` avoid `used`: numbers on seen states would not be held-out."""
    if min(seeds) < used.stop and used.start <= max(seeds):
        raise UserError(f"seeds {min(seeds)}:{max(seeds) + 1} overlap the {what} "
                        f"({used.start}:{used.stop}); held-out seeds must be new")


def require_heldout(seeds: Sequence[int]) -> None:
    """UserError unless every seed is a held-out seed: verdicts need states nothing was fit on."""
    block = SEED_SETS["heldout"]
    if min(seeds) < block.start or max(seeds) >= block.stop:
        raise UserError(f"seeds {min(seeds)}:{max(seeds) + 1} are not all held-out seeds "
                        f"({block.start}:{block.stop}); a verdict needs states no search or training used")


def seed_set_of(seed: int) -> str:
    """Name of the set a seed belongs to."""
    for name, block in SEED_SETS.items():
        if seed in block:
            return name
    raise UserError(f"seed {seed} is outside every seed set")
