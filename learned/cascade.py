"""Coarse-to-fine cascade: networks trained for wide starts hand their estimate to networks trained for
narrow ones (LCCNet-style multi-range refinement), e.g. the R2 checkpoint, then the R1 checkpoint.

``Cascade(models)`` behaves like one ``RCAutoCalib``: ``forward(batch)`` runs every stage with the
previous stage's final estimate as its ``T_init`` and returns the stages' per-iteration lists
concatenated in order (``T_iters``, ``T_deltas``, ``T_inputs``, ``log_var``, ``match``, ``attention``,
``render``, ``fusion_weights``: N_1 + N_2 + ... entries), ``image_hw`` and ``pseudo_bev`` of the last
stage. ``cfg`` is the last stage's config, so ``learned.export`` reads the last stage's matching
(iteration -1) and covariance; ``iteration=0`` still means the first stage against the true start.
Every stage must take the same input size.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import nn

LIST_KEYS = ("T_iters", "T_deltas", "T_inputs", "log_var", "match", "attention", "render", "fusion_weights")


class Cascade(nn.Module):
    def __init__(self, models: Sequence[nn.Module]):
        super().__init__()
        if not models:
            raise ValueError("a cascade needs at least one model")
        sizes = {tuple(int(v) for v in m.cfg.input_hw) for m in models}
        if len(sizes) > 1:
            raise ValueError(f"cascade stages take different input sizes {sorted(sizes)}; use one preset")
        self.stages = nn.ModuleList(models)

    @property
    def cfg(self):
        return self.stages[-1].cfg

    def forward(self, batch: Mapping, iterations: int | None = None) -> dict:
        out: dict = {k: [] for k in LIST_KEYS}
        T = batch["T_init"]
        for stage in self.stages:
            o = stage({**batch, "T_init": T}, iterations)
            for k in LIST_KEYS:
                out[k].extend(o[k])
            out["image_hw"], out["pseudo_bev"] = o["image_hw"], o["pseudo_bev"]
            T = o["T_iters"][-1].detach()
        return out

    @torch.no_grad()
    def stage_boundaries(self) -> list[int]:
        """Index in ``T_iters`` where each stage starts."""
        starts, n = [], 0
        for stage in self.stages:
            starts.append(n)
            n += int(stage.cfg.iterations)
        return starts
