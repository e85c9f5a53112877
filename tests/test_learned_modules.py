"""Shapes and hand-checked behaviour of the RC-AutoCalib building blocks."""

from __future__ import annotations

import math

import pytest
import torch
from safetensors.torch import save_file

from learned.attention import MultiModalCrossAttention
from learned.backbone import ImageFVEncoder, ResNetStem3, TwoConvBranch, load_resnet18_weights
from learned.config import ConfigError, model_config
from learned.fusion import make_fusion
from learned.matching import MatchingHead, ResidualConvBlock
from learned.nr_matcher import match_ground_truth, match_matrix, nr_boxes, nr_reliable
from learned.regression import LSTMRegressionHead

H, W = 64, 128
CFG = model_config("small", {"input_hw": (H, W), "bev_hw": (64, 64), "bev_res_m": 0.5})





def test_backbone_shapes():
    x = torch.rand(2, 1, H, W)
    assert ResNetStem3(1, (16, 16, 32))(x).shape == (2, 32, H // 8, W // 8)
    assert TwoConvBranch(24, 8)(x).shape == (2, 24, H // 8, W // 8)
    enc = ImageFVEncoder(24, (16, 16, 32), 8)
    assert enc(torch.rand(2, 3, H, W), x).shape == (2, 24, H // 8, W // 8)


def test_load_resnet18_weights_roundtrip(tmp_path):
    src = ResNetStem3(3, (64, 64, 128))
    state = {k: v.clone() for k, v in src.state_dict().items()}
    state["layer3.0.conv1.weight"] = torch.zeros(256, 128, 3, 3)  # extra ResNet-18 keys are ignored
    state["fc.weight"] = torch.zeros(1000, 512)
    save_file(state, str(tmp_path / "r18.safetensors"))
    torch.save(state, tmp_path / "r18.pth")
    for name in ("r18.safetensors", "r18.pth"):
        dst = ResNetStem3(3, (64, 64, 128))
        loaded = load_resnet18_weights(dst, tmp_path / name)
        assert "layer2.1.bn2.running_var" in loaded
        for k, v in src.state_dict().items():
            assert torch.equal(dst.state_dict()[k], v), k
    with pytest.raises(ValueError, match="context_widths"):
        load_resnet18_weights(ResNetStem3(3, (32, 32, 64)), tmp_path / "r18.pth")


def test_mca_shapes_residual_and_attention_maps():
    torch.manual_seed(0)
    mca = MultiModalCrossAttention(32, heads=2)
    F_I, F_R = torch.rand(2, 32, 4, 6), torch.rand(2, 32, 3, 5)
    FI, FR, maps = mca(F_I, F_R)
    assert FI.shape == F_I.shape and FR.shape == F_R.shape
    assert maps["attn_I_from_R"].shape == (2, 1, 4, 6) and maps["attn_R_from_I"].shape == (2, 1, 3, 5)
    # max of a softmax row over m_R entries lies in [1/m_R, 1]
    a = maps["attn_I_from_R"]
    assert (a >= 1 / 15 - 1e-6).all() and (a <= 1).all()
    # residual: with Theta's last Linear zeroed the features pass unchanged
    for theta in (mca.theta_I, mca.theta_R):
        torch.nn.init.zeros_(theta.net[-1].weight)
        torch.nn.init.zeros_(theta.net[-1].bias)
    FI, FR, _ = mca(F_I, F_R)
    assert torch.equal(FI, F_I) and torch.equal(FR, F_R)


def test_matching_head_assignment_is_a_partial_assignment():
    torch.manual_seed(0)
    head = MatchingHead(16, 8)
    out = head(torch.rand(2, 16, 4, 4), torch.rand(2, 16, 4, 4))
    P = out["log_P"].exp()
    assert P.shape == (2, 16, 16) and out["logit_I"].shape == (2, 16)
    assert (P.sum(2) <= 1 + 1e-5).all() and (P.sum(1) <= 1 + 1e-5).all()
    # P = sigma_I sigma_R softmax_i(S) softmax_j(S)
    S = out["S"]
    ref = (torch.sigmoid(out["logit_I"])[:, :, None] * torch.sigmoid(out["logit_R"])[:, None, :]
           * S.softmax(1) * S.softmax(2))
    torch.testing.assert_close(P, ref)


def test_residual_conv_block_any_input_size():
    phi = ResidualConvBlock(16, 8, (3, 6), 32)
    assert phi(torch.rand(2, 16, 8, 16), torch.rand(2, 16, 8, 16)).shape == (2, 32)
    assert phi(torch.rand(2, 16, 12, 25), torch.rand(2, 16, 12, 25)).shape == (2, 32)


@pytest.mark.parametrize("kind,views,out_dim", [("selective", "both", 40), ("add", "both", 40),
                                                ("concat", "both", 80), ("selective", "fv", 40)])
def test_fusion(kind, views, out_dim):
    fus = make_fusion(kind, views, 40, 4, 8)
    a, b = torch.rand(3, 40), torch.rand(3, 40)
    y, w = fus(a, b) if views == "both" else fus(a, None)
    assert y.shape == (3, out_dim) and fus.out_dim == out_dim
    if views != "both":
        assert w is None and torch.equal(y, a)
    elif kind == "selective":
        torch.testing.assert_close(w.sum(1), torch.ones(3, 40))
        assert ((y - torch.minimum(a, b)) >= -1e-6).all() and ((torch.maximum(a, b) - y) >= -1e-6).all()
        fus.train()
        assert fus(a[:1], b[:1])[0].shape == (1, 40)  # one-sample batch does not fail


def test_regression_head_starts_near_identity():
    head = LSTMRegressionHead(20, 16)
    out, state = head(torch.rand(2, 20))
    assert out["T_delta"].shape == (2, 4, 4) and out["log_var"].shape == (2, 6)
    assert (out["T_delta"][:, :3, :3] - torch.eye(3)).abs().max() < 0.05
    out2, _ = head(torch.rand(2, 20), state)
    assert out2["rot"].shape == (2, 3)


def test_config_presets_and_errors():
    assert model_config("paper").input_hw == (192, 400)
    assert model_config("small").feat_dim == 64
    with pytest.raises(ConfigError):
        model_config("small", {"no_such_key": 1})
    with pytest.raises(ConfigError):
        model_config("small", {"fusion": "mean"})
    with pytest.raises(ConfigError):
        model_config("small", {"input_hw": (60, 128)})
    assert not model_config("small", {"variant": "lidar"}).nr_active


# ---------------------------------------------------------------------------------------------
# ground-truth matches and the noise-resistant matcher


def _K():
    return torch.tensor([[[100.0, 0, 63.5], [0, 100.0, 31.5], [0, 0, 1]]])


def test_match_ground_truth_hand_made():
    # T_gt = identity (radar frame = camera frame); the current estimate is shifted 0.8 m along x.
    T_gt = torch.eye(4)[None]
    T_cur = torch.eye(4)[None].clone()
    T_cur[0, 0, 3] = 0.8
    pts = torch.tensor([[
        [0.0, 0.0, 10.0],    # A: true pixel (63.5, 31.5) -> cell (4, 8) = 72; current (71.5, 31.5) -> cell 73
        [50.0, 0.0, 10.0],   # B: outside the image under both
        [-2.0, 1.0, 10.0],   # C: true col 44 (cell 5), current col 52 (cell 6), row 42 (cell 5)
        [-1.9, 1.0, 10.0],   # E: true col 45 (cell 5), current col 53 (cell 6)
        [-6.0, 4.0, 40.0],   # D: true col 49 (cell 6), current col 51 (cell 6): conflicts with C/E, loses 1:2
    ]])
    mask = torch.ones(1, 5, dtype=torch.bool)
    M, N_I, N_R = match_ground_truth(pts, mask, T_cur, T_gt, _K(), CFG, "fv")
    assert M.shape == (1, 128, 128)
    assert M.sum() == 2
    assert M[0, 72, 73] == 1 and M[0, 85, 86] == 1 and M[0, 86, 86] == 0
    assert N_I[0, 72] == 0 and N_I[0, 85] == 0 and N_I[0, 86] == 1
    assert N_R[0, 73] == 0 and N_R[0, 86] == 0 and N_R.sum() == 126
    # masking A out removes its match
    M2, _, _ = match_ground_truth(pts, torch.tensor([[False, True, True, True, True]]), T_cur, T_gt, _K(), CFG, "fv")
    assert M2.sum() == 1 and M2[0, 72, 73] == 0
    # BEV: A at X = 0, Z = 10 -> true col 32 (cell 4), current X = 0.8 -> col 33.1 -> 33 (cell 4): same cell
    Mb, _, _ = match_ground_truth(pts[:, :1], mask[:, :1], T_cur, T_gt, _K(), CFG, "bev")
    row = int((32.0 - 10.0) / 0.5 - 0.5 + 0.5) // 8
    cell = row * 8 + 4
    assert Mb.shape == (1, 64, 64) and Mb[0, cell, cell] == 1 and Mb.sum() == 1


def test_match_matrix_is_one_to_one():
    cell_I = torch.tensor([[0, 0, 1, 2, -1]])
    cell_R = torch.tensor([[3, 4, 3, 3, 1]])
    M, N_I, N_R = match_matrix(cell_I, cell_R, 4, 5)
    assert (M.sum(1) <= 1).all() and (M.sum(2) <= 1).all()
    assert ((N_I == 0) | (N_I == 1)).all() and ((N_R == 0) | (N_R == 1)).all()
    # greedy: radar cell 3 keeps image cell 0 (ties -> first), radar cell 4 also wants image cell 0,
    # and image cell 0 keeps radar cell 3 (first); so one match survives
    assert M.sum() == 1 and M[0, 0, 3] == 1


def test_nr_boxes_hand_computed():
    origin = torch.zeros(1, 3)
    pts = torch.tensor([[[3.0, 1.0, 4.0], [-3.0, 0.5, 4.0], [0.5, 0.0, 0.5]]])
    centre, size = nr_boxes(pts, origin, delta=1.0, delta_s=0.5)
    cos_phi = math.sqrt(1 - (1.0 / 5.0) ** 2)
    dx, dz = 3 * (1 - cos_phi), 4 * (1 - cos_phi)
    torch.testing.assert_close(size[0, 0], torch.tensor([dx + 1.0, 3.0, dz + 1.0]))
    torch.testing.assert_close(centre[0, 0], torch.tensor([3 - dx / 2, 1.0, 4 - dz / 2]))
    # left of the radar: positive width, centre shifted toward the radar (X increases)
    torch.testing.assert_close(size[0, 1], torch.tensor([dx + 1.0, 3.0, dz + 1.0]))
    torch.testing.assert_close(centre[0, 1], torch.tensor([-3 + dx / 2, 0.5, 4 - dz / 2]))
    # closer than delta: cos(phi) clamps to 0, the box spans back to the radar
    torch.testing.assert_close(size[0, 2], torch.tensor([0.5 + 1.0, 3.0, 0.5 + 1.0]))
    # the radar origin matters: shifted origin -> same offsets
    c2, s2 = nr_boxes(pts + torch.tensor([0.0, 1.0, 1.7]), torch.tensor([[0.0, 1.0, 1.7]]), 1.0, 0.5)
    torch.testing.assert_close(s2, size)


def test_nr_reliable_keeps_supported_points():
    origin = torch.zeros(1, 3)
    radar = torch.tensor([[[0.0, 1.0, 10.0], [5.0, 1.0, 10.0], [-5.0, 1.0, 10.0], [0.0, 0.0, 30.0]]])
    mask = torch.tensor([[True, True, True, False]])
    lidar = torch.tensor([[
        [0.2, 1.5, 9.8], [-0.3, 0.0, 10.2], [0.1, 2.2, 9.9],  # 3 inside box of point 0 (h_B = 3 -> |dy| <= 1.5)
        [0.0, 3.0, 10.0],                                     # outside (|dy| = 2 > 1.5)
        [5.2, 1.0, 10.0], [4.8, 1.3, 9.9],                     # only 2 near point 1
        [0.0, 0.0, 30.0], [0.1, 0.0, 30.0], [0.2, 0.0, 30.0],  # near the masked point 3
    ]])
    keep, counts = nr_reliable(radar, mask, origin, lidar, torch.ones(1, 9, dtype=torch.bool), tau=3)
    assert counts[0].tolist() == [3, 2, 0, 3]
    assert keep[0].tolist() == [True, False, False, False]
    keep2, _ = nr_reliable(radar, mask, origin, lidar, torch.ones(1, 9, dtype=torch.bool), tau=3, chunk=1)
    assert torch.equal(keep, keep2)
    # a sample that kept half of its sweep's points needs half the paper's tau in a box (the same density):
    # point 1's 2 kept points stand for ~4 of the sweep's (probe 132: subsampling tightened the matcher)
    half, _ = nr_reliable(radar, mask, origin, lidar, torch.ones(1, 9, dtype=torch.bool), tau=3,
                          lidar_fraction=torch.tensor([0.5]))
    assert half[0].tolist() == [True, True, False, False]
    whole, _ = nr_reliable(radar, mask, origin, lidar, torch.ones(1, 9, dtype=torch.bool), tau=3,
                           lidar_fraction=torch.tensor([1.0]))
    assert torch.equal(whole, keep)
