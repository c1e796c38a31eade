"""A SmolVLM backbone folder for SmolVLA, built offline: config, tokenizer and processor, no weights.

SmolVLA reads its backbone's config and processor from `vlm_model_name` (a hub id, or a local
folder) even when it loads its own weights (`load_vlm_weights=False`), so a SmolVLA checkpoint
needs that folder on disk. `write_backbone(folder, size)` writes one: a SmolVLM config of the
given size, a word-level tokenizer built with the `tokenizers` library (with SmolVLM's special
image tokens) and a SmolVLM processor beside it. Random weights come from SmolVLA itself.

    SIZES["tiny"]     a few thousand parameters a layer: tests
    SIZES["small"]    the shipped example (examples/smolvla_train.py)
    SIZES["smolvla"]  the sizes of SmolVLA's own backbone, SmolVLM2-500M (benchmarks)

Run in LeRobot's venv: `python examples/smolvla_backbone.py DIR [tiny|smolvla]`.
"""

from __future__ import annotations

import string
import sys
from pathlib import Path

SPECIAL = {"pad_token": "<pad>", "unk_token": "<unk>", "bos_token": "<|im_start|>",
           "eos_token": "<end_of_utterance>"}
IMAGE_TOKENS = {"image_token": "<image>", "fake_image_token": "<fake_token_around_image>",
                "global_image_token": "<global-img>", "end_of_utterance_token": "<end_of_utterance>"}
ROWS = [f"<row_{r}_col_{c}>" for r in range(1, 7) for c in range(1, 7)]  # SmolVLM's image tiles

SIZES = {
    "tiny": {"text": {"hidden_size": 64, "intermediate_size": 128, "num_hidden_layers": 2,
                      "num_attention_heads": 4, "num_key_value_heads": 2, "head_dim": 16},
             "vision": {"hidden_size": 32, "intermediate_size": 64, "num_hidden_layers": 1,
                        "num_attention_heads": 2, "patch_size": 16},
             "image_size": 64},
    "small": {"text": {"hidden_size": 128, "intermediate_size": 256, "num_hidden_layers": 4,
                       "num_attention_heads": 4, "num_key_value_heads": 2, "head_dim": 32},
              "vision": {"hidden_size": 64, "intermediate_size": 128, "num_hidden_layers": 2,
                         "num_attention_heads": 2, "patch_size": 8},
              "image_size": 64},
    "smolvla": {"text": {"hidden_size": 960, "intermediate_size": 2560, "num_hidden_layers": 32,
                         "num_attention_heads": 15, "num_key_value_heads": 5, "head_dim": 64},
                "vision": {"hidden_size": 768, "intermediate_size": 3072, "num_hidden_layers": 12,
                           "num_attention_heads": 12, "patch_size": 16},
                "image_size": 512},
}


def characters() -> list[str]:
    """The tokenizer's vocabulary past its special tokens: one token a character (others are <unk>)."""
    return sorted(set(string.ascii_letters + string.digits + string.punctuation + " \n"))


def write_backbone(folder: str | Path, size: str = "tiny") -> Path:
    """Writes config.json, the tokenizer and the processor of a SmolVLM backbone into `folder`."""
    from tokenizers import Tokenizer, models, pre_tokenizers
    from transformers import (
        PreTrainedTokenizerFast,
        SmolVLMConfig,
        SmolVLMImageProcessor,
        SmolVLMProcessor,
        SmolVLMVideoProcessor,
    )

    folder, dims = Path(folder), SIZES[size]
    folder.mkdir(parents=True, exist_ok=True)
    tokens = [*SPECIAL.values(), *dict.fromkeys(IMAGE_TOKENS.values()), *ROWS, *characters()]
    vocab = {token: i for i, token in enumerate(dict.fromkeys(tokens))}
    core = Tokenizer(models.WordLevel(vocab, unk_token=SPECIAL["unk_token"]))
    core.pre_tokenizer = pre_tokenizers.Split("", "isolated")  # one token a character
    specials = [*dict.fromkeys(IMAGE_TOKENS.values()), *ROWS]
    tokenizer = PreTrainedTokenizerFast(tokenizer_object=core, **SPECIAL, extra_special_tokens=IMAGE_TOKENS,
                                        additional_special_tokens=specials)
    images = SmolVLMImageProcessor(do_resize=False, do_image_splitting=False,
                                   max_image_size={"longest_edge": dims["image_size"]})
    tokens_per_image = (dims["image_size"] // dims["vision"]["patch_size"] // 2) ** 2
    processor = SmolVLMProcessor(image_processor=images, tokenizer=tokenizer,
                                 video_processor=SmolVLMVideoProcessor(), image_seq_len=tokens_per_image)
    config = SmolVLMConfig(
        text_config={"model_type": "llama", "vocab_size": len(vocab), "pad_token_id": 0,
                     "max_position_embeddings": 2048, **dims["text"]},
        vision_config={"image_size": dims["image_size"], **dims["vision"]},
        image_token_id=vocab[IMAGE_TOKENS["image_token"]], pad_token_id=0, scale_factor=2)
    config.save_pretrained(folder)
    processor.save_pretrained(folder)
    return folder


if __name__ == "__main__":
    print(write_backbone(sys.argv[1], *sys.argv[2:3]))
