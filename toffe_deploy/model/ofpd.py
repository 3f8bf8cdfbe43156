"""OFPD: the paper's two conv layers + one FC layer with pose, direction and speed heads.

Input: ``toffe_deploy.ofpd_io.prepare`` output (N, C, g, g): 2B pooled event planes of an
object-centric crop, the motion planes (ofpd.motion "time_cov": 2, "none": 0), then two
coordinate planes (cell centres in px / COORD_SCALE).

    h      = ReLU(FC(MaxPool2(ReLU(conv2(ReLU(conv1(x_events)))))))   conv1, conv2 stride 2
    P      = round(COORD_SCALE * (x[x-plane, 0, g-1] - x[x-plane, 0, 0]) / (g - 1))   (cell size, px)
    pose   = COORD_SCALE * mean(coordinate planes) + (g P / 2) * pose_head(h)   (px: a residual in cells)
    dir    = direction_head(h) / |direction_head(h)|                      (cos, sin)
    speed  = speed_head(h) + ln P            (ln px/ms: the head regresses ln cells/ms; speed_unit "px_ms")
    speed  = speed_head(h) + ln(30)          (ln m/s; speed_unit "mps", checkpoints before it)

With a fixed crop P = ofpd.pool and g P / 2 = crop_px / 2, as before the crop scaled.

The convolutions see only the event and motion planes (translation invariant features); the crop centre comes from the coordinate planes inside the graph, so the exported ONNX model
outputs full-resolution pixels and the runtime needs no side channel. Shapes are listed by
``ofpd_io.ofpd_param_shapes`` (torch-free, used to validate checkpoints).
"""
from __future__ import annotations

import math

import torch
from torch import nn
import torch.nn.functional as F

from ..config import ToffeConfig
from ..ofpd_io import COORD_SCALE, input_shape, ofpd_settings

SPEED_OFFSET = math.log(30.0)   # centre of the log-speed range, so the head starts near 0


class OFPD(nn.Module):
    def __init__(self, in_channels: int, grid: int, conv_channels=(16, 32), conv_kernels=(5, 3),
                 hidden: int = 64, speed_unit: str = "px_ms"):
        super().__init__()
        c1, c2 = conv_channels
        k1, k2 = conv_kernels
        if grid % 8:
            raise ValueError(f"OFPD grid {grid} must be a multiple of 8")
        self.n_event_planes = in_channels - 2
        self.grid = grid
        self.speed_in_cells = speed_unit == "px_ms"
        self.conv1 = nn.Conv2d(self.n_event_planes, c1, k1, stride=2, padding=k1 // 2)
        self.conv2 = nn.Conv2d(c1, c2, k2, stride=2, padding=k2 // 2)
        self.fc = nn.Linear(c2 * (grid // 8) ** 2, hidden)
        self.pose_head = nn.Linear(hidden, 2)
        self.direction_head = nn.Linear(hidden, 2)
        self.speed_head = nn.Linear(hidden, 1)
        with torch.no_grad():
            self.pose_head.weight.mul_(0.1)
            self.pose_head.bias.zero_()

    @classmethod
    def from_config(cls, config: ToffeConfig) -> "OFPD":
        s = ofpd_settings(config)
        c_in, g, _ = input_shape(config)
        return cls(c_in, g, tuple(s["conv_channels"]), tuple(s["conv_kernels"]), s["hidden"], s["speed_unit"])

    def forward(self, x: torch.Tensor):
        # Mean of each coordinate plane = mean of its first and last cell (an arithmetic
        # progression along one axis): exact, and identical in onnxruntime (a ReduceMean over
        # 64x64 cells rounds differently from torch's and cost 3e-4 px of ONNX parity).
        planes = x[:, self.n_event_planes:]
        centre = 0.5 * (planes[:, :, 0, 0] + planes[:, :, -1, -1]) * COORD_SCALE    # (N, 2) px
        # cell size from the x plane's spacing: an integer, rounded so float32 noise cannot reach it
        pool = torch.round((planes[:, 0, 0, -1:] - planes[:, 0, 0, :1]) * (COORD_SCALE / (self.grid - 1)))   # (N, 1)
        h = F.relu(self.conv1(x[:, :self.n_event_planes]))
        h = F.relu(self.conv2(h))
        h = F.max_pool2d(h, 2)
        h = F.relu(self.fc(h.flatten(1)))
        pose = centre + (0.5 * self.grid) * pool * self.pose_head(h)
        d = self.direction_head(h)
        direction = d / torch.sqrt((d * d).sum(dim=1, keepdim=True) + 1e-12)
        speed = self.speed_head(h) + (torch.log(pool) if self.speed_in_cells else SPEED_OFFSET)
        return pose, direction, speed
