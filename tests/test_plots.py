"""The projection pictures (``hybrid_calib.plots.projection``) and the shared atomic save."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from hybrid_calib.plots.projection import draw_projection


def test_draw_projection_writes_a_png_with_the_points(tmp_path):
    img = np.full((90, 160, 3), 128, np.uint8)
    uv = np.array([[20.0, 30.0], [100.0, 60.0], [-5.0, 10.0], [np.nan, 3.0]])
    depth = np.array([5.0, 40.0, 10.0, 10.0])
    out = draw_projection(img, uv, depth, tmp_path / "a" / "proj.png", title="t",
                          extra={"uv": uv + 3, "label": "estimate", "color": "r", "lines_to_first": True})
    assert out.is_file() and not list(out.parent.glob("*tmp*"))
    pic = cv2.imread(str(out))
    assert pic.shape[1] == 160 and pic.shape[0] >= 90
    plain = draw_projection(img, uv[:0], depth[:0], tmp_path / "plain.png")
    # the points change the picture, the plain one stays grey
    grey = cv2.imread(str(plain))
    assert np.abs(grey.astype(int) - 128).max() <= 2
    assert np.abs(pic[-90:].astype(int) - 128).max() > 50


def test_draw_projection_checks_inputs(tmp_path):
    with pytest.raises(ValueError, match="depth"):
        draw_projection(np.zeros((4, 4, 3), np.uint8), np.zeros((2, 2)), np.zeros(3), tmp_path / "x.png")
    with pytest.raises(ValueError, match="image_rgb"):
        draw_projection(np.zeros((4, 4), np.uint8), np.zeros((2, 2)), np.zeros(2), tmp_path / "x.png")


def _frame(tmp_path):
    from hybrid_calib.data.frame import RadarCameraFrame
    from hybrid_calib.geometry import R_AXES_CAM_FROM_RADAR, make_T
    from hybrid_calib.sensors.camera import PinholeCamera

    img_path = tmp_path / "img.jpg"
    cv2.imwrite(str(img_path), np.full((90, 160, 3), 128, np.uint8))
    cam = PinholeCamera(100.0, 100.0, 79.5, 44.5, 160, 90)
    pts = np.array([[10.0, 0.0, 0.0], [20.0, 2.0, 0.0], [15.0, -3.0, 0.0]])
    T = make_T(R_AXES_CAM_FROM_RADAR, np.array([0.0, 0.5, 0.0]))
    return RadarCameraFrame(
        index=0, sample_token="s", scene_name="scene", vehicle="veh", log_token="l", camera_channel="CAM_FRONT",
        radar_channel="RADAR_FRONT", camera_token="c", radar_token="r", timestamp_camera_us=0, timestamp_radar_us=0,
        image_path=img_path, camera=cam, radar_points=pts, radar_fields={}, T_cam_radar=T)


def test_draw_radar_on_frame(tmp_path):
    from hybrid_calib.geometry import make_T
    from hybrid_calib.plots.projection import draw_radar_on_frame

    frame = _frame(tmp_path)
    out = draw_radar_on_frame(frame, tmp_path / "o.png",
                              compare_T_cam_radar=make_T(np.eye(3), np.zeros(3)) @ frame.T_cam_radar)
    pic = cv2.imread(str(out))
    assert pic is not None and pic.shape[1] == 160
    assert np.abs(pic[-90:].astype(int) - 128).max() > 50


def test_draw_radar_truth_and_overlay(tmp_path):
    from hybrid_calib.plots.projection import draw_radar_truth, render_overlay

    frame = _frame(tmp_path)
    with_truth = draw_radar_truth(frame, frame.radar_points + [0.0, 0.0, 1.0], tmp_path / "t.png")
    without = draw_radar_truth(frame, None, tmp_path / "n.png")
    a, b = cv2.imread(str(with_truth)), cv2.imread(str(without))
    assert a.shape == b.shape and np.abs(a.astype(int) - b.astype(int)).max() > 50  # the cyan rings
    assert cv2.imread(str(render_overlay(frame, tmp_path / "sub" / "overlay.png"))) is not None
    assert not list(tmp_path.rglob("*tmp*"))


def test_a_name_in_another_script_is_drawn_without_a_warning_per_glyph(tmp_path):
    import warnings

    from hybrid_calib.plots.figure import pyplot, save_figure

    fig, ax = pyplot().subplots()
    ax.set_title("车辆-1")  # a vehicle named in a script the default font lacks
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = save_figure(fig, tmp_path / "v.png")
    assert out.is_file() and not [w for w in caught if "Glyph" in str(w.message)]
    fig, ax = pyplot().subplots()  # and while it is laid out, before any save (probe 88)
    ax.set_title("车辆-2")
    with warnings.catch_warnings(record=True) as caught:
        fig.tight_layout()
        fig.canvas.draw()
    pyplot().close(fig)
    assert not [w for w in caught if "Glyph" in str(w.message)]


@pytest.mark.parametrize("backend", ["module://matplotlib_inline.backend_inline", "inline", "Qt5"])
def test_figures_are_drawn_whatever_mplbackend_says(tmp_path, backend):
    """Probe 84: a notebook kernel's ``MPLBACKEND`` (a value matplotlib refuses while importing) made every command
    with plots end in "internal error"; the figures are drawn headless whatever it says."""
    import os
    import subprocess
    import sys

    png = str(tmp_path / "p.png")
    code = ("import numpy as np; from hybrid_calib.plots.projection import draw_projection; "
            f"draw_projection(np.zeros((9, 16, 3), np.uint8), np.zeros((0, 2)), np.zeros(0), {png!r})")
    p = subprocess.run([sys.executable, "-c", code], env={**os.environ, "MPLBACKEND": backend}, capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 0 and (tmp_path / "p.png").is_file(), p.stderr[-2000:]


def test_a_long_vehicle_name_is_shortened_where_a_figure_draws_it(monkeypatch, tmp_path):
    """Probe 88: one 226-character vehicle name as a tick label squeezed the fleet figure's six panels into a 15 px
    strip."""
    from hybrid_calib.plots import fleet
    from hybrid_calib.plots.figure import NAME_CHARS, short_name

    long = "L" + "ong-name-" * 25 + "007"
    assert short_name("sim-veh-000") == "sim-veh-000" and short_name("a\nb") == "a b"
    s = short_name(long)
    assert len(s) == NAME_CHARS and s.startswith("Long-name-") and s.endswith("-007") and "\u2026" in s
    figs = []
    monkeypatch.setattr(fleet, "save_figure", lambda fig, path, **kw: figs.append(fig) or path)
    fleet.draw_fleet([long, "sim-veh-001"], np.zeros((2, 6)), np.ones((2, 6)), [[], []], tmp_path / "f.png", "t")
    labels = [t.get_text() for t in figs[0].axes[0].get_yticklabels()]
    assert labels == [s, "sim-veh-001"]
    figs[0].canvas.draw()
    widths = [ax.get_position().width for ax in figs[0].axes]
    assert min(widths) > 0.08  # six panels share the width (with the whole name: ~0.01)
