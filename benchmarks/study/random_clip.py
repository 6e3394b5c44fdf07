"""A randomly initialised CLIP saved to a folder, so LeRobot's ``multi_task_dit`` builds without a download.

``multi_task_dit`` loads its vision and text towers with ``CLIPVisionModel.from_pretrained`` /
``CLIPTextModel.from_pretrained`` and its tokenizer with ``AutoTokenizer.from_pretrained`` from one name, and
insists that the name contains ``clip``. The study has no Hub access and SubgoalVLA's ``laptop`` preset starts
its own CLIP tower from random weights too, so the baseline gets a random CLIP of the same size as that tower
(64 wide, 3 layers, 80 px in patches of 10) and a text tower of the size of ``laptop``'s LLM (64 wide, 4
layers). OpenAI's ViT-B/16 at 224 px would cost about a minute per update of 32 samples on 2 CPU cores and
would be random here anyway.

The tokenizer is word-level over the words of the instructions it is given (by default every CALVIN
training and evaluation instruction; ``--tasks-from`` takes a LeRobotDataset's task strings instead, e.g.
Meta-World's) with an end-of-text token appended: CLIP's text pooler reads the hidden state at the first
``eos_token_id``, so every instruction must end with one.

Usage::

    python benchmarks/study/random_clip.py outputs/study/random_clip
    python benchmarks/study/random_clip.py outputs/metaworld/random_clip --tasks-from outputs/metaworld/raw
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from pathlib import Path

END_OF_TEXT = "<|endoftext|>"
#: The towers' sizes: SubgoalVLA ``laptop``'s vision tower and LLM (config_components.PRESET_VALUES).
VISION = {"hidden_size": 64, "num_hidden_layers": 3, "num_attention_heads": 4, "intermediate_size": 256,
          "image_size": 80, "patch_size": 10}  # fmt: skip
TEXT = {"hidden_size": 64, "num_hidden_layers": 4, "num_attention_heads": 4, "intermediate_size": 256,
        "max_position_embeddings": 77}  # fmt: skip


def dataset_tasks(root: Path) -> list[str]:
    """The task strings of the LeRobotDataset at ``root`` (its ``meta/tasks.parquet``)."""
    import pandas as pd

    path = root / "meta" / "tasks.parquet"
    if not path.is_file():
        raise SystemExit(
            f"--tasks-from {root}: no meta/tasks.parquet there; pass a LeRobotDataset's root folder"
        )
    return list(pd.read_parquet(path).index)


def build_tokenizer(instructions: Iterable[str] | None = None):
    """Word-level tokenizer over the words of ``instructions`` (default: CALVIN's) whose every encoding ends
    with ``END_OF_TEXT``."""
    from tokenizers import Tokenizer, models, normalizers, pre_tokenizers, processors
    from transformers import PreTrainedTokenizerFast

    from lerobot_subgoalvla.policies.subgoalvla.tokenizer import (
        IMAGE_TOKEN,
        PAD_TOKEN,
        UNK_TOKEN,
        vocabulary_words,
    )

    if instructions is None:
        from lerobot_subgoalvla.calvin_vocab import ALL_INSTRUCTIONS

        instructions = ALL_INSTRUCTIONS
    words = [IMAGE_TOKEN, *vocabulary_words(instructions)]  # the tiny tokenizer's words
    vocab = {word: index for index, word in enumerate((PAD_TOKEN, UNK_TOKEN, END_OF_TEXT, *words))}
    backend = Tokenizer(models.WordLevel(vocab=vocab, unk_token=UNK_TOKEN))
    backend.normalizer = normalizers.Lowercase()
    backend.pre_tokenizer = pre_tokenizers.Whitespace()
    backend.post_processor = processors.TemplateProcessing(
        single=f"$A {END_OF_TEXT}", special_tokens=[(END_OF_TEXT, vocab[END_OF_TEXT])]
    )
    return PreTrainedTokenizerFast(
        tokenizer_object=backend, pad_token=PAD_TOKEN, unk_token=UNK_TOKEN, eos_token=END_OF_TEXT
    )


def save_random_clip(directory: Path, instructions: Iterable[str] | None = None, seed: int = 0) -> Path:
    """Write a random CLIP (weights, config, tokenizer) to ``directory`` unless it is there; returns it.

    The folder name must contain ``clip`` (``multi_task_dit`` checks the name).
    """
    if "clip" not in directory.name.lower():
        raise ValueError(f"{directory}: multi_task_dit requires 'clip' in the model name; rename the folder")
    if (directory / "config.json").is_file():
        return directory
    import torch
    from transformers import CLIPConfig, CLIPModel

    tokenizer = build_tokenizer(instructions)
    ids = {"pad_token_id": tokenizer.pad_token_id, "eos_token_id": tokenizer.eos_token_id,
           "bos_token_id": tokenizer.eos_token_id}  # fmt: skip
    config = CLIPConfig(text_config={**TEXT, **ids, "vocab_size": len(tokenizer)}, vision_config=VISION)
    torch.manual_seed(seed)
    partial = directory.with_name(directory.name + ".partial")
    CLIPModel(config).save_pretrained(partial)
    tokenizer.save_pretrained(partial)
    partial.replace(directory)
    return directory


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", type=Path, help="folder to write (its name must contain 'clip')")
    parser.add_argument(
        "--tasks-from",
        type=Path,
        default=None,
        metavar="DATASET_ROOT",
        help="build the tokenizer from this LeRobotDataset's task strings instead of CALVIN's instructions",
    )
    args = parser.parse_args()
    instructions = None if args.tasks_from is None else dataset_tasks(args.tasks_from)
    print(save_random_clip(args.directory, instructions))


if __name__ == "__main__":
    main()
