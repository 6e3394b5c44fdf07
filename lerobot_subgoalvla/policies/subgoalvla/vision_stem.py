"""A convolutional stem for the tiny vision tower, in place of its patch embedding.

The tiny tower is a CLIP ViT learnt from scratch. Its patch embedding is one linear map of each P x P patch
(a convolution with kernel = stride = P), which at the laptop preset's 64-wide tower squeezes 1,200 pixel
values into 64 numbers in one step. An object of a few pixels inside a patch (Meta-World's puck is about 6 px
at 160 px) then has to be read from that one projection. Early convolutions (Xiao et al. 2021, "Early
Convolutions Help Transformers See Better") replace it with a few stride-2 3 x 3 convolutions and a last
convolution that finishes the downsampling, which gives a ViT the locality prior of a CNN at a cost similar
to the projection it replaces; the token grid, and so every shape after it, is unchanged.

The stem keeps ``patch_embedding``'s contract: (B, 3, I, I) pixels in, (B, D, I / P, I / P) out, and a
``weight`` whose dtype the CLIP embeddings read to cast their input.

Dimension legend (the package's, ``__init__.py``): ``B`` batch, ``I`` the vision tower's square input side,
``D`` the tower's width; ``P`` is the patch size, ``C`` a stem layer's channels and ``h, w`` its grid.
"""

from __future__ import annotations

from einops import rearrange
from torch import Tensor, nn

#: 3 x 3 stride-2 convolutions at most; the last convolution covers the rest of the patch.
MAX_HALVINGS = 3
#: Channels of the first stride-2 convolution as a fraction of the tower's width (doubled at each halving).
_FIRST_WIDTH_DIVISOR = 4


def stem_halvings(patch_size: int) -> int:
    """How many stride-2 convolutions a stem for ``patch_size`` has: the factors of 2 in P, at most 3."""
    halvings = 0
    while patch_size % 2 == 0 and halvings < MAX_HALVINGS:
        patch_size //= 2
        halvings += 1
    return halvings


class ChannelNorm(nn.Module):
    """LayerNorm over the channels at each pixel (ConvNeXt's), so a token depends on its own patch only: a
    norm over the whole map (GroupNorm) would let every pixel move every token, and batch statistics
    (BatchNorm) would differ between training batches and single-episode evaluation."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(channels)

    def forward(self, x: Tensor) -> Tensor:
        """(B, C, h, w) -> (B, C, h, w)."""
        height = x.shape[-2]
        pixels = rearrange(x, "b c h w -> b (h w) c")
        return rearrange(self.norm(pixels), "b (h w) c -> b c h w", h=height)


class ConvStem(nn.Module):
    """Stride-2 3 x 3 convolutions (ChannelNorm, GELU), then one with kernel = stride = the rest of P.

    Args:
        patch_size: P; it must be even (at least one halving).
        width: D, the vision tower's hidden size (the stem's output channels).
    """

    def __init__(self, patch_size: int, width: int) -> None:
        super().__init__()
        halvings = stem_halvings(patch_size)
        if halvings == 0:
            raise ValueError(f"a convolutional stem needs an even patch size, got {patch_size}")
        layers: list[nn.Module] = []
        channels_in = 3
        channels = max(width // _FIRST_WIDTH_DIVISOR, 8)
        for _ in range(halvings):
            layers += [
                nn.Conv2d(channels_in, channels, kernel_size=3, stride=2, padding=1, bias=False),
                ChannelNorm(channels),
                nn.GELU(),
            ]
            channels_in, channels = channels, channels * 2
        rest = patch_size // 2**halvings
        self.convolutions = nn.Sequential(*layers)
        self.projection = nn.Conv2d(channels_in, width, kernel_size=rest, stride=rest)

    @property
    def weight(self) -> Tensor:
        """The last convolution's weight: CLIP's embeddings cast their input to ``patch_embedding.weight``'s
        dtype."""
        return self.projection.weight

    def forward(self, pixel_values: Tensor) -> Tensor:
        """(B, 3, I, I) -> (B, D, I / P, I / P)."""
        return self.projection(self.convolutions(pixel_values))


def install_conv_stem(vision_tower: nn.Module, patch_size: int) -> None:
    """Replace a transformers CLIP vision tower's patch embedding by a ``ConvStem`` of the same output."""
    embeddings = vision_tower.vision_model.embeddings
    width = embeddings.patch_embedding.out_channels
    embeddings.patch_embedding = ConvStem(patch_size, width)
