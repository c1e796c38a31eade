"""Bundled policies, named like `metaworld/pick-place-v3/flow`, shipped inside the package."""

from __future__ import annotations

from pathlib import Path

from goldenticket.errors import UserError
from goldenticket.policies.mlp import MLPPolicy

BUNDLED_DIR = Path(__file__).parent / "bundled"


def policy_names() -> list[str]:
    return sorted(
        str(cfg.parent.relative_to(BUNDLED_DIR)) for cfg in BUNDLED_DIR.rglob("config.json")
    )


def load_policy(name: str) -> MLPPolicy:
    """A bundled policy by name, or a policy directory (config.json + model.safetensors)."""
    path = Path(name)
    if (path / "config.json").is_file():
        return MLPPolicy.load(path)
    if name not in policy_names():
        raise UserError(f"unknown policy {name!r}; bundled: {', '.join(policy_names()) or 'none'}")
    return MLPPolicy.load(BUNDLED_DIR / name)
