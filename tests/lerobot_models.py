"""Untrained LeRobot checkpoints for the tests, built offline and written as a user's would be; no
simulator needed."""

from pathlib import Path


def save(policy, cfg, folder: Path) -> Path:
    """The policy and its processors, written by LeRobot's save_pretrained, with dataset stats of unit
    scale for its state and action."""
    import torch
    from lerobot.policies.factory import make_pre_post_processors

    def unit(n: int) -> dict:
        return {"mean": torch.zeros(n), "std": torch.full((n,), 0.5), "min": -torch.ones(n),
                "max": torch.ones(n),
                "q01": -torch.ones(n), "q99": torch.ones(n)}

    features = {**cfg.input_features, **cfg.output_features}
    stats = {key: unit(features[key].shape[0]) for key in ("observation.state", "action") if key in features}
    policy.save_pretrained(folder)
    for pipeline in make_pre_post_processors(cfg, dataset_stats=stats):
        pipeline.save_pretrained(folder)
    return folder


def tiny_smolvla(folder: Path, backbone: Path, inputs: dict, outputs: dict, **settings) -> Path:
    """An untrained SmolVLA with these input and output features, on the tiny offline backbone."""
    import torch
    from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

    settings = {"chunk_size": 10, "n_action_steps": 5, "num_steps": 3, "resize_imgs_with_padding": (64, 64),
                "num_vlm_layers": 2} | settings
    cfg = SmolVLAConfig(input_features=inputs, output_features=outputs, vlm_model_name=str(backbone),
                        load_vlm_weights=False, device="cpu", push_to_hub=False, **settings)
    torch.manual_seed(0)
    return save(SmolVLAPolicy(cfg), cfg, folder)


def in_hub_cache(cache: Path, repo_id: str, folder: Path) -> Path:
    """`folder`'s files laid out in the Hugging Face Hub cache `cache` as `hf download repo_id` leaves
    them: models--owner--name/snapshots/<revision>/..., and refs/main naming the revision."""
    import shutil

    repo = cache / ("models--" + repo_id.replace("/", "--"))
    revision = "0123456789abcdef0123456789abcdef01234567"
    shutil.copytree(folder, repo / "snapshots" / revision)
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text(revision)
    return repo / "snapshots" / revision
