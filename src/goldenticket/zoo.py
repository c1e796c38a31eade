"""The policies and tickets shipped inside the package, and policies on the Hugging Face Hub, found by
name without loading a model (a misspelt name is one line in a fraction of a second).

A policy name may end in `@N` to run with N denoising steps instead of the trained default, e.g.
`metaworld/pick-place-v3/ddim@2`; the weights are the same, only inference changes.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from goldenticket.errors import UserError
from goldenticket.factories import is_import_string

BUNDLED_DIR = Path(__file__).parent / "policies" / "bundled"
HUB_ID = re.compile(r"[A-Za-z0-9][\w.-]{0,95}/[A-Za-z0-9][\w.-]{0,95}")  # `owner/name`, as the Hub spells one


def policy_names() -> list[str]:
    """The bundled policies' names; a hidden folder (a policy being built) is none."""
    names = (cfg.parent.relative_to(BUNDLED_DIR) for cfg in BUNDLED_DIR.rglob("config.json"))
    return sorted(str(name) for name in names if not any(part.startswith(".") for part in name.parts))


def bundled_tickets() -> list[Path]:
    """Golden tickets shipped beside the bundled policies (`<policy>/tickets/<id>.safetensors`)."""
    return sorted(BUNDLED_DIR.rglob("tickets/*.safetensors"))


def find_ticket(ref: str) -> Path:
    """A ticket file path, or the id of a bundled ticket (as `goldenticket tickets list` shows)."""
    path = Path(ref)
    if path.is_file():
        return path
    matches = [p for p in bundled_tickets() if p.stem == ref]
    if not matches:
        raise UserError(f"{ref}: no such ticket file or bundled ticket id (see `goldenticket tickets list`)")
    if len(matches) > 1:
        raise UserError(f"ticket id {ref} is ambiguous; name one file: "
                        + ", ".join(str(p) for p in matches))
    return matches[0]


def split_steps(name: str) -> tuple[str, int | None]:
    """`"a/b/ddim@2"` -> `("a/b/ddim", 2)`; a name without `@N` -> `(name, None)`."""
    base, at, steps = name.rpartition("@")
    if not at:
        return name, None
    if not steps.isdigit() or int(steps) < 1:
        raise UserError(f"policy {name!r}: the part after '@' must be a step count >= 1")
    return base, int(steps)


def bundled(base: str) -> Path:
    """A bundled policy's folder; UserError naming an unknown one."""
    if base not in policy_names():
        raise UserError(f"unknown policy {base!r}; run `goldenticket policies` to list them")
    return BUNDLED_DIR / base


def is_hub_id(base: str) -> bool:
    """Whether a policy name (without `@N`) is a Hugging Face Hub repo id, as `lerobot-eval
    --policy.path=lerobot/smolvla_libero` takes one: `owner/name`, neither a path here nor in a folder of
    bundled policies (`metaworld/reach-v3` is a bundled name cut short)."""
    families = {name.partition("/")[0] for name in policy_names()}
    return (HUB_ID.fullmatch(base) is not None and ".." not in base and not Path(base).exists()
            and base.partition("/")[0] not in families)


def check_name(name: object) -> None:
    """UserError for a policy name that is neither an import string, a path, a Hub repo id in the cache
    or downloadable (`hub_snapshot`, which loads no model library) nor a bundled policy's name (a
    policy object passes)."""
    if isinstance(name, str) and not is_import_string(name):
        base, _ = split_steps(name)
        if is_hub_id(base):
            hub_snapshot(base)
        elif not Path(base).exists():
            bundled(base)


def hub_snapshot(repo_id: str) -> Path:
    """The folder of Hugging Face Hub repo `repo_id` as LeRobot reads `--policy.path=<repo id>`:
    huggingface_hub's `snapshot_download`, from its cache (HF_HOME, HF_HUB_CACHE; with HF_HUB_OFFLINE=1
    the cache alone), downloading where a network is; one line naming `hf download` where neither
    has it."""
    try:
        from huggingface_hub import constants, snapshot_download
    except ImportError:
        raise UserError(f"policy {repo_id!r} names a Hugging Face Hub repo, and huggingface_hub is not "
                        "installed here (LeRobot's venv has it)") from None
    try:
        return Path(snapshot_download(repo_id))
    except (OSError, ValueError) as error:
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise UserError(f"policy {repo_id!r} is no bundled policy (`goldenticket policies` lists them) nor "
                        "folder here, and the Hugging Face Hub repo of that id is not in the cache "
                        f"({constants.HF_HUB_CACHE}) nor downloadable ({reason}); download it where a "
                        f"network is: `hf download {repo_id}`, or name its folder") from None


def bundled_task(name: str) -> str | None:
    """The task a bundled single-task policy was trained on, the folder its name lies in
    (`metaworld/pick-place-v3/flow@2` -> `metaworld/pick-place-v3`); None for a multi-task one and for
    any other policy (an import string, a path: a folder or a checkpoint file, or a Hub repo id);
    UserError for an unknown name."""
    if is_import_string(name):
        return None
    base, _ = split_steps(name)
    if Path(base).exists() or is_hub_id(base):
        return None
    if json.loads((bundled(base) / "config.json").read_text()).get("tasks"):
        return None
    return base.rpartition("/")[0]
