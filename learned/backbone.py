"""Feature extraction (paper Sec. 3.2 and supplement A), without torchvision.

- ``ResNetStem3``: the first three ResNet blocks (stem conv7x7/2 + max-pool/2, layer1, layer2/2), output
  at 1/8. Used for both radar maps (trained from scratch, 1 input channel) and, with RGB input and
  ResNet-18 widths, as the image context network. Parameter names follow torchvision's ResNet
  (``conv1``, ``bn1``, ``layer1.0.conv1`` ...), so a ResNet-18 state dict loads key for key.
- ``TwoConvBranch``: the two convolutions of the estimated-depth and pseudo-BEV branches (1/4 then 1/8).
- ``ImageFVEncoder``: depth-branch features integrated with the context features (concat + 1x1 conv).
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class BasicBlock(nn.Module):
    """ResNet BasicBlock: two 3x3 convs with BN and a (projected) identity shortcut."""

    def __init__(self, cin: int, cout: int, stride: int = 1):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.downsample = None
        if stride != 1 or cin != cout:
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        idt = x if self.downsample is None else self.downsample(x)
        y = self.relu(self.bn1(self.conv1(x)))
        return self.relu(self.bn2(self.conv2(y)) + idt)


class ResNetStem3(nn.Module):
    """First three ResNet blocks. (B, cin, H, W) -> (B, widths[2], H/8, W/8)."""

    def __init__(self, cin: int, widths: tuple = (64, 64, 128)):
        super().__init__()
        w0, w1, w2 = widths
        self.conv1 = nn.Conv2d(cin, w0, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(w0)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        self.layer1 = nn.Sequential(BasicBlock(w0, w1), BasicBlock(w1, w1))
        self.layer2 = nn.Sequential(BasicBlock(w1, w2, 2), BasicBlock(w2, w2))
        self.out_channels = w2

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        return self.layer2(self.layer1(x))


def conv_bn_lrelu(cin: int, cout: int, k: int, stride: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, k, stride, k // 2, bias=False), nn.BatchNorm2d(cout),
                         nn.LeakyReLU(0.1, inplace=True))


class TwoConvBranch(nn.Module):
    """Two convolutions (7x7/4 then 3x3/2): (B, 1, H, W) -> (B, cout, H/8, W/8)."""

    def __init__(self, cout: int, mid: int):
        super().__init__()
        self.net = nn.Sequential(conv_bn_lrelu(1, mid, 7, 4), conv_bn_lrelu(mid, cout, 3, 2))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class ImageFVEncoder(nn.Module):
    """F_I^FV: estimated-depth features integrated with ResNet-18 context features of the RGB image.

    image: (B, 3, H, W) RGB in [0, 1]; depth_n: (B, 1, H, W) normalised depth. -> (B, C, H/8, W/8).
    """

    def __init__(self, feat_dim: int, context_widths: tuple, depth_mid: int):
        super().__init__()
        self.context = ResNetStem3(3, context_widths)
        self.depth = TwoConvBranch(feat_dim, depth_mid)
        self.merge = nn.Sequential(nn.Conv2d(feat_dim + context_widths[2], feat_dim, 1), nn.LeakyReLU(0.1, True))
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def forward(self, image: torch.Tensor, depth_n: torch.Tensor) -> torch.Tensor:
        ctx = self.context((image - self.mean) / self.std)
        return self.merge(torch.cat([self.depth(depth_n), ctx], 1))


def load_resnet18_weights(module: ResNetStem3, path: str | Path) -> list[str]:
    """Load ImageNet ResNet-18 weights (torchvision key names) into ``module`` from a local file.

    path: a ``.safetensors`` file or a ``torch.save`` state dict (loaded with ``weights_only=True``).
    Keys of layer3/layer4/fc are ignored. Returns the names of the loaded tensors. Raises ValueError
    naming the file if a needed key is missing or a shape differs (e.g. non-ResNet-18 widths).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ResNet-18 weights {path}: no such file")
    if path.suffix == ".safetensors":
        from safetensors.torch import load_file

        state = load_file(str(path))
    else:
        state = torch.load(path, map_location="cpu", weights_only=True)
        if isinstance(state, dict) and "state_dict" in state:
            state = state["state_dict"]
    own = module.state_dict()
    loaded = {}
    for key, tensor in own.items():
        if key not in state:
            raise ValueError(f"{path}: key {key!r} missing; expected a torchvision-style ResNet-18 state dict")
        if state[key].shape != tensor.shape:
            raise ValueError(f"{path}: {key} has shape {tuple(state[key].shape)}, the model needs "
                             f"{tuple(tensor.shape)} (pretrained weights need context_widths=(64, 64, 128))")
        loaded[key] = state[key]
    module.load_state_dict(loaded)
    return sorted(loaded)
