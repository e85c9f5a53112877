"""learned.export: correspondences and per-frame covariance for the hybrid."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from factors.correspondences import Correspondences
from learned import lie
from learned.export import (
    ExportConfig,
    calibrate_cov_scale,
    export_correspondences,
    extrinsics_per_iteration,
    frame_covariance,
    refine_matches,
)
from tests.test_learned_model import make_batch, tiny_model


def test_export_shapes_and_finite_values():
    model = tiny_model().eval()
    batch = make_batch(2, seed=4)
    batch["frame_id"] = ["tokA", "tokB"]
    with torch.no_grad():
        out = model(batch)
    corr, cov = export_correspondences(model, out, batch, ExportConfig(min_confidence=0.0))
    assert len(corr) == 2 and cov.shape == (2, 6, 6)
    assert corr[0].frame_id == "tokA"
    for c in corr:
        assert isinstance(c, Correspondences) and len(c) > 10
        assert np.isfinite(c.pixels).all() and (c.sigma_px > 0).all()
        assert ((c.confidence >= 0) & (c.confidence <= 1)).all()
        np.testing.assert_allclose(c.K, batch["K"][0].numpy())
        assert (c.points_radar[:, 2] == 0).all()  # raw radar points
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert extrinsics_per_iteration(out).shape == (2, 3, 4, 4)
    spread = frame_covariance(out, "spread")
    assert spread.shape == (2, 6, 6) and np.all(np.diag(spread[0]) >= 1e-6 - 1e-12)
    # min_confidence filters rows
    corr_hi, _ = export_correspondences(model, out, batch, ExportConfig(min_confidence=2.0))
    assert all(len(c) == 0 for c in corr_hi)


@pytest.mark.parametrize("ablation", [{"use_ems": False}, {"views": "bev"}])
def test_ablated_models_export_the_covariance_without_rows(ablation):
    model = tiny_model(**ablation).eval()
    batch = make_batch(2, seed=4)
    batch["frame_id"] = ["tokA", "tokB"]
    with torch.no_grad():
        out = model(batch)
    corr, cov = export_correspondences(model, out, batch)
    assert [len(c) for c in corr] == [0, 0] and [c.frame_id for c in corr] == ["tokA", "tokB"]
    assert cov.shape == (2, 6, 6) and np.all(np.linalg.eigvalsh(cov) > 0)
    scaled = frame_covariance(out, "learned", cov_scale=(1, 2, 3, 4, 5, 6))
    np.testing.assert_allclose(np.diagonal(scaled, axis1=1, axis2=2), np.diagonal(cov, axis1=1, axis2=2)
                               * np.arange(1, 7), rtol=1e-12)


def test_forced_true_assignment_exports_true_pixels():
    model = tiny_model().eval()
    batch = make_batch(2, seed=6, rot_deg=3.0, trans_m=0.2)
    with torch.no_grad():
        out = model(batch)
    M, _, _ = model.match_targets(out, batch)[-1]["fv"]
    # force the FV assignment of the last iteration to the ground truth
    out["match"][-1]["fv"]["log_P"] = torch.log(M * 0.98 + 1e-6)
    corr, _ = export_correspondences(model, out, batch, ExportConfig(min_confidence=0.5))
    K = batch["K"][0].double().numpy()
    errs = []
    for b, c in enumerate(corr):
        assert len(c) >= 5
        T_gt = batch["T_gt"][b].double().numpy()
        pc = c.points_radar @ T_gt[:3, :3].T + T_gt[:3, 3]
        uv = (pc @ K.T)[:, :2] / pc[:, 2:3]
        err = np.abs(c.pixels - uv)
        errs.append(err)
        assert (c.confidence > 0.9).all()
        np.testing.assert_allclose(c.sigma_px, 8 / np.sqrt(12), rtol=1e-3)
    err = np.concatenate(errs)
    # matched cell + the point's own in-cell offset: within one cell per axis, about a third of it on average
    assert err.max() <= 8.0 + 1e-6, err.max()
    assert err.mean() < 4.0, err.mean()


def test_refine_matches_soft_argmax_is_sub_cell():
    # one radar cell whose column puts equal mass on two neighbouring image cells -> centre halfway
    log_P = torch.full((1, 8, 2), -30.0)
    log_P[0, 1, 0] = np.log(0.45)
    log_P[0, 2, 0] = np.log(0.45)
    ref = refine_matches(log_P, (2, 4), torch.tensor([[0, -1]]), window=1)
    torch.testing.assert_close(ref["centre"][0, 0], torch.tensor([15.5, 3.5]))
    assert ref["mass"][0, 0] == pytest.approx(0.9, abs=1e-4)
    assert ref["var"][0, 0] == pytest.approx(16.0 / 2, abs=1e-3)  # (+-4 px)^2 over two axes


def test_learned_covariance_tracks_error_after_variance_training():
    """The variance head learns error magnitudes: NEES scale calibrates to ~1 on its own training data."""
    model = tiny_model()
    batch = make_batch(2, seed=7)
    opt = torch.optim.Adam(model.head.log_var.parameters(), lr=5e-2)
    model.eval()
    with torch.no_grad():
        out = model(batch)
    for _ in range(200):
        from learned.losses import variance_nll

        lv = [model.head.log_var(torch.zeros(2, model.cfg.lstm_hidden))] * 3  # a constant-input head
        loss = variance_nll(lv, out["T_iters"], batch["T_gt"])
        opt.zero_grad()
        loss.backward()
        opt.step()
    lv = model.head.log_var(torch.zeros(2, model.cfg.lstm_hidden)).detach()
    errs = torch.cat([lie.local(T, batch["T_gt"]) for T in out["T_iters"]])
    np.testing.assert_allclose(lv.exp()[0].numpy(), (errs ** 2).mean(0).numpy(), rtol=0.05)
    covs = np.stack([np.diag(v) for v in lv.exp().repeat(3, 1).double().numpy()])
    assert calibrate_cov_scale(errs.double().numpy(), covs) == pytest.approx(1.0, rel=0.05)


def test_per_axis_cov_scale_makes_each_axis_honest():
    g = np.random.default_rng(3)
    true_sd = np.array([0.01, 0.02, 0.005, 0.1, 0.05, 0.2])
    errors = g.normal(size=(4000, 6)) * true_sd
    reported = np.tile(np.diag((true_sd * np.array([0.5, 1, 2, 1, 1, 3])) ** 2), (4000, 1, 1))
    s = calibrate_cov_scale(errors, reported, per_axis=True)
    np.testing.assert_allclose(s, [4, 1, 0.25, 1, 1, 1 / 9], rtol=0.1)
    fixed = reported * np.array(s)[None, :, None] * np.eye(6)
    assert calibrate_cov_scale(errors, fixed) == pytest.approx(1.0, rel=0.02)


def test_plot_frame_writes_png(tmp_path):
    from hybrid_calib.plots.network import attention_numpy, plot_frame

    model = tiny_model().eval()
    batch = make_batch(1, seed=8)
    with torch.no_grad():
        out = model(batch)
    path = plot_frame(out, batch, 0, tmp_path / "frame.png")
    assert path.is_file() and path.stat().st_size > 10_000
    maps = attention_numpy(out)
    assert maps["attn_I_from_R"].shape == (1, 8, 16)
    no_mca = tiny_model(use_mca=False, views="fv").eval()
    with torch.no_grad():
        out2 = no_mca(batch)
    assert plot_frame(out2, batch, 0, tmp_path / "f2.png").is_file()
    with pytest.raises(ValueError, match="no attention"):
        attention_numpy(out2)


def test_an_export_scale_written_as_text_is_refused():
    """A checkpoint's export.sigma_scale "1" (text) was read as the number (probe 109); numbers of any numpy type
    still are."""
    import numpy as np

    from learned.export import scale_problem

    assert scale_problem(1.0, "1").startswith("sigma_scale='1'")
    assert scale_problem(["2"] * 6, 1.0).startswith("cov_scale=")
    assert scale_problem([np.float32(2.0)] * 6, np.float64(1.1)) == ""
    assert scale_problem(np.full(6, 2.0), 1) == ""
