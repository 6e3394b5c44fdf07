"""The backbone's tokenizer: the checkpoint's own, or for the tiny backbone an offline word-level one whose
words come from the training data (``BackboneConfig.vocabulary``, filled from the dataset's tasks).

A word-level tokenizer needs no download and gives every training word its own id; an instruction with words
outside the vocabulary reads them as ``<unk>`` (the preprocessor names them in one warning,
``unknown_words``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from tokenizers import Tokenizer, models, normalizers, pre_tokenizers
from transformers import AutoTokenizer, PreTrainedTokenizerBase, PreTrainedTokenizerFast

from lerobot_subgoalvla.policies.subgoalvla.config_components import TinyLlavaDims

PAD_TOKEN, UNK_TOKEN, IMAGE_TOKEN = "<pad>", "<unk>", "<image>"
SPECIAL_TOKENS = (PAD_TOKEN, UNK_TOKEN, IMAGE_TOKEN)


def vocabulary_words(instructions: Iterable[str]) -> tuple[str, ...]:
    """The sorted distinct words of ``instructions`` as the tiny tokenizer splits them (lower-cased,
    whitespace and punctuation): the vocabulary a tiny backbone is built with (``BackboneConfig.vocabulary``).
    """
    splitter = pre_tokenizers.Whitespace()
    words: set[str] = set()
    for text in instructions:
        words.update(word for word, _ in splitter.pre_tokenize_str(text.lower()))
    return tuple(sorted(words - set(SPECIAL_TOKENS)))


def unknown_words(instructions: Iterable[str], vocabulary: Iterable[str]) -> list[str]:
    """The words of ``instructions`` the tiny tokenizer would map to ``<unk>``, sorted."""
    return sorted(set(vocabulary_words(instructions)) - set(vocabulary))


def tiny_vocabulary(words: Sequence[str]) -> list[str]:
    """The tiny tokenizer's tokens: the specials, then ``words`` (deterministic: a saved pipeline rebuilds the
    identical tokenizer from the words stored in its config)."""
    return [*SPECIAL_TOKENS, *words]


def build_tiny_tokenizer(words: Sequence[str]) -> PreTrainedTokenizerFast:
    """Offline word-level tokenizer (lower-cased, whitespace/punctuation split) over
    ``tiny_vocabulary(words)``."""
    vocab = {word: index for index, word in enumerate(tiny_vocabulary(words))}
    backend = Tokenizer(models.WordLevel(vocab=vocab, unk_token=UNK_TOKEN))
    backend.normalizer = normalizers.Lowercase()
    backend.pre_tokenizer = pre_tokenizers.Whitespace()
    return PreTrainedTokenizerFast(
        tokenizer_object=backend,
        pad_token=PAD_TOKEN,
        unk_token=UNK_TOKEN,
        extra_special_tokens={"image_token": IMAGE_TOKEN},
        padding_side="right",
    )


def load_tokenizer(name_or_path: str | None, tiny: TinyLlavaDims | None = None) -> PreTrainedTokenizerBase:
    """The backbone's tokenizer: the checkpoint's own, or the tiny offline one (over ``tiny.vocabulary``) when
    ``name_or_path`` is None."""
    if name_or_path is None:
        if tiny is None:
            raise ValueError("a tiny backbone (name_or_path=None) needs its TinyLlavaDims for its vocabulary")
        return build_tiny_tokenizer(tiny.vocabulary)
    tokenizer = AutoTokenizer.from_pretrained(name_or_path)
    tokenizer.padding_side = "right"
    return tokenizer
