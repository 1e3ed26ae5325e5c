"""ResNet-18 backbones (torchvision) for the visual and tactile branches and the tactile classifier.

``pretrained=True`` loads torchvision's ImageNet weights only when the weight file is already in the local torch hub
cache (``torch.hub.get_dir()/checkpoints/<basename of ResNet18_Weights.IMAGENET1K_V1.url>``); otherwise the network
keeps its random initialisation and one ``logging.warning`` line says so. Nothing is ever downloaded.
"""

from __future__ import annotations

import logging
import os

import torch
from torch import Tensor, nn
from torchvision.models import ResNet18_Weights, resnet18

from tvrecon.utils.shape_check import check_shape

__all__ = ["RESNET18_CHANNELS", "ResNet18Backbone", "cached_resnet18_weights_path", "load_resnet18", "widen_conv"]

log = logging.getLogger(__name__)

RESNET18_CHANNELS: tuple[int, int, int, int] = (64, 128, 256, 512)
_warned_missing = False


def cached_resnet18_weights_path() -> str:
    """Path where torchvision's hub cache keeps the ImageNet ResNet-18 weights (it may not exist)."""
    name = os.path.basename(ResNet18_Weights.IMAGENET1K_V1.url)
    return os.path.join(torch.hub.get_dir(), "checkpoints", name)


def load_resnet18(pretrained: bool = False) -> tuple[nn.Module, bool]:
    """Build a torchvision ResNet-18, with cached ImageNet weights when asked and available.

    Args:
        pretrained: load ``IMAGENET1K_V1`` weights if the file is in the local torch hub cache.

    Returns:
        (model, loaded): a ``torchvision.models.ResNet`` and whether ImageNet weights were loaded.
    """
    model = resnet18(weights=None)
    if not pretrained:
        return model, False
    path = cached_resnet18_weights_path()
    if os.path.isfile(path):
        state = torch.load(path, map_location="cpu", weights_only=True)
        model.load_state_dict(state)
        log.info("Loaded ImageNet ResNet-18 weights from %s", path)
        return model, True
    global _warned_missing
    report = log.info if _warned_missing else log.warning  # one warning per process, not one per backbone
    _warned_missing = True
    report(
        "ImageNet ResNet-18 weights not found at %s; using random initialisation (no download is attempted). "
        "Place the torchvision file there to use pretrained weights.",
        path,
    )
    return model, False


class ResNet18Backbone(nn.Module):
    """ResNet-18 trunk returning the four stage feature maps (strides 4, 8, 16, 32).

    The stem and the four stages are exposed so the reconstructor can fuse tactile features into visual stage ``j``
    before stage ``j + 1`` runs (``stem`` then ``stage(j, x)``).

    Args:
        pretrained: load cached ImageNet weights (see module docstring).
        in_channels: input channels; 3 for RGB and tactile images. Other values replace the first conv (the RGB
            kernel is replicated and scaled by ``3 / in_channels`` when pretrained weights were loaded, a fresh
            randomly initialised conv otherwise).
    """

    channels: tuple[int, int, int, int] = RESNET18_CHANNELS

    def __init__(self, pretrained: bool = False, in_channels: int = 3) -> None:
        super().__init__()
        if in_channels < 1:
            raise ValueError(f"in_channels must be >= 1, got {in_channels}")
        net, loaded = load_resnet18(pretrained)
        if in_channels != 3:
            net.conv1 = widen_conv(net.conv1, in_channels, copy_weights=loaded)
        self.in_channels = in_channels
        self.pretrained_loaded = loaded
        self.stem = nn.Sequential(net.conv1, net.bn1, net.relu, net.maxpool)
        self.stages = nn.ModuleList([net.layer1, net.layer2, net.layer3, net.layer4])

    def stage(self, index: int, x: Tensor) -> Tensor:
        """Run stage ``index`` (0..3) on the previous stage's output (or the stem's for index 0)."""
        return self.stages[index](x)

    def forward(self, x: Tensor) -> list[Tensor]:
        """Extract the four stage feature maps.

        Args:
            x: (B, C_in, H, W) float image.

        Returns:
            list of 4 float tensors (B, 64, H/4, W/4), (B, 128, H/8, W/8), (B, 256, H/16, W/16), (B, 512, H/32, W/32)
            (sizes rounded up by the strided convolutions).
        """
        check_shape(x, f"(B, {self.in_channels}, H, W)", "x")
        feats = []
        x = self.stem(x)
        for layer in self.stages:
            x = layer(x)
            feats.append(x)
        return feats

    def forward_touches(self, tactile: Tensor) -> list[Tensor]:
        """Run the shared-weight tactile branch on touches folded into the batch.

        Args:
            tactile: (B, T, C_in, h, w) float tactile images.

        Returns:
            list of 4 float tensors (B, T, C_i, h_i, w_i).
        """
        check_shape(tactile, "(B, T, C, h, w)", "tactile")
        B, T = tactile.shape[:2]
        feats = self(tactile.flatten(0, 1))  # (B*T, C, h, w) each
        return [f.unflatten(0, (B, T)) for f in feats]


def widen_conv(conv: nn.Conv2d, in_channels: int, copy_weights: bool = True) -> nn.Conv2d:
    """Copy of ``conv`` taking ``in_channels`` inputs.

    With ``copy_weights`` the new weight is the original RGB kernel tiled over the new input channels and scaled by
    ``3 / in_channels`` (so a stack of N identical RGB images gives the original response, i.e. weights / N for 3N
    channels); without it the new conv keeps PyTorch's default random initialisation.

    Args:
        conv: a conv with 3 input channels (ResNet ``conv1``).
        in_channels: new input channel count.
        copy_weights: replicate the (pretrained) RGB kernel.

    Returns:
        A new ``nn.Conv2d`` with the same kernel size, stride, padding and bias setting.
    """
    if conv.in_channels != 3:
        raise ValueError(f"widen_conv expects a 3-channel conv, got {conv.in_channels} input channels")
    new = nn.Conv2d(
        in_channels,
        conv.out_channels,
        kernel_size=conv.kernel_size,
        stride=conv.stride,
        padding=conv.padding,
        bias=conv.bias is not None,
    )
    if not copy_weights:
        return new
    with torch.no_grad():
        reps = -(-in_channels // 3)
        w = conv.weight.repeat(1, reps, 1, 1)[:, :in_channels] * (3.0 / in_channels)
        new.weight.copy_(w)
        if conv.bias is not None:
            new.bias.copy_(conv.bias)
    return new
