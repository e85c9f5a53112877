"""The uncertainty report (``hybrid_calib.report``): numbers against ``result.json``, the verdict rules,
the fleet page, the command, and the pages in a real headless browser (tests/browser.py)."""

from __future__ import annotations

import dataclasses
import io
import json
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from hybrid_calib.calib.result import CalibrationRun, Estimate, VehicleResult
from hybrid_calib.cli import main
from hybrid_calib.report import Tolerance, verdict_of, write_fleet_page, write_report
from hybrid_calib.report.verdict import VERDICTS
from tests.helpers import nominal_T_cam_radar


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A tiny simulated drive (2 vehicles x 6 frames, 200x112 images) calibrated from an R1 start."""
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.config import merge
    from hybrid_calib.sim import simulate as sim
    from hybrid_calib.sim.drive import SimConfig

    base = tmp_path_factory.mktemp("report")
    root = sim.simulate(merge(SimConfig, {"frames": 6, "vehicles": 2, "image_scale": 0.125, "seed": 5}),
                        base / "sim", overwrite=False, workers=1)
    calibrate(root, "v1.0-sim", "oracle", base / "run", {"start": "R1", "window": {"window": 4}})
    return base


class _Cells(HTMLParser):
    """Every element's data-key -> data-value, and the text of elements by id."""

    def __init__(self):
        super().__init__()
        self.values: dict[str, float] = {}
        self.ids: dict[str, str] = {}
        self.imgs: list[str] = []
        self.links: list[str] = []
        self._open: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "data-key" in a and "data-value" in a:
            self.values[a["data-key"]] = float(a["data-value"])
        if tag == "img":
            self.imgs.append(a.get("src", ""))
        if tag == "a":
            self.links.append(a.get("href", ""))
        self._open.append(a.get("id", ""))
        if a.get("id"):
            self.ids[a["id"]] = ""

    def handle_endtag(self, tag):
        if self._open:
            self._open.pop()

    def handle_data(self, data):
        for i in self._open:
            if i:
                self.ids[i] += data


def _parse(path: Path) -> _Cells:
    c = _Cells()
    c.feed(path.read_text())
    return c


def test_report_numbers_match_result_json(run_dir, tmp_path):
    result = run_dir / "run" / "result.json"
    doc = json.loads(result.read_text())
    name = sorted(doc["vehicles"])[1]
    out = write_report(result, tmp_path / "r.html", vehicle=name)
    cells = _parse(out)
    fin = doc["vehicles"][name]["final"]
    T = np.asarray(fin["T_cam_radar"])
    for i in range(4):
        for j in range(4):
            assert cells.values[f"T{i}{j}"] == T[i, j]
    rep = fin["report"]
    for k in ("roll_deg", "pitch_deg", "yaw_deg"):
        assert cells.values[k] == rep[k]
    for a, k in enumerate(("t_x_cm", "t_y_cm", "t_z_cm")):
        assert cells.values[k] == pytest.approx(100 * rep["t_m"][a], rel=1e-12)
    for k, v in fin["std_cam"].items():
        assert cells.values[k] == v, k
    # the verdict shown is the verdict of the result, and the status is spelled out
    vr = CalibrationRun.load(result).vehicles[name]
    word = cells.ids["verdict"].strip().split("\n")[0]
    assert verdict_of(vr).word in VERDICTS and cells.ids["verdict"].startswith(verdict_of(vr).word)
    assert word and fin["status"].split(":")[0] in cells.ids["status"]
    # pictures: before / after on frames across the drive (start and result), bands, residuals
    assert len(cells.imgs) >= 5 and all(s.startswith("data:image/png;base64,") for s in cells.imgs)
    assert "no network checkpoint" in out.read_text()


def test_report_rebuilds_the_runs_rows_and_start(run_dir):
    """The residual histograms and the before/after picture use the run's own rows and start: replaying
    the first frame from the rebuilt start gives the trajectory's first estimate."""
    from hybrid_calib.calib.pipeline import CalibrateConfig, calibrate_vehicle, replay_inputs
    from hybrid_calib.config import merge
    from hybrid_calib.report.evidence import run_config

    result = run_dir / "run" / "result.json"
    run = CalibrationRun.load(result)
    conf = run_config(result)
    inputs = replay_inputs(run.data, run.version, run.correspondences, conf)
    name = sorted(inputs)[0]
    vi, T0 = inputs[name]
    vi.frames = vi.frames[:1]
    again = calibrate_vehicle(vi, merge(CalibrateConfig, conf), progress=False)
    np.testing.assert_allclose(again.trajectory[0].T, run.vehicles[name].trajectory[0].T, atol=1e-9)
    assert not np.allclose(T0, run.vehicles[name].final.T, atol=1e-3)  # an R1 start, far from the result


def test_the_radar_points_on_a_page_are_drawn_through_the_frame_s_transform(run_dir):
    """Probe 86: the page drew the radar points as recorded through the mount, beside rows moved to the camera's
    timestamp; they reach the image through the mount times the frame's N (docs/conventions.md "Transforms")."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.geometry import se3_inverse, transform_points
    from hybrid_calib.report.evidence import gather

    result = run_dir / "run" / "result.json"
    run = CalibrationRun.load(result)
    name = sorted(run.vehicles)[0]
    ev = gather(run, result, name, None, None, n_frames=3)
    ds = NuScenesRadarCamera(run.data, run.version)
    assert ev.frames
    for sf in ev.frames:
        f = ds[sf.index]
        N = se3_inverse(f.extras["T_cam_radar_static"]) @ f.T_cam_radar
        uv, _ = f.camera.project(transform_points(ev.start @ N, f.radar_points))
        np.testing.assert_allclose(sf.uv_start, uv, atol=1e-6)
        off, _ = f.camera.project(transform_points(ev.start, f.radar_points))
        assert np.nanmax(np.abs(off - sf.uv_start)) > 1.0  # N is not the identity on this drive: the test can tell


def _vr(delta, std, status="ok", drift_extra=None, alarms=(), tested=False):
    """A vehicle result; ``alarms`` (frame indices) gives it a 5-frame trajectory, whose window step test computed a
    statistic at every frame when ``tested``."""
    keys = ("rot_x_deg", "rot_y_deg", "rot_z_deg", "t_x_cm", "t_y_cm", "t_z_cm")
    est = Estimate(nominal_T_cam_radar(), np.eye(6) * 1e-6, np.asarray(std, float), status)
    drift = {"delta_camera": dict(zip(keys, delta)), "statistic": 1.0, "p_value": 0.5, "drifted": False}
    drift.update(drift_extra or {})
    vr = VehicleResult("v", est, drift=drift)
    if alarms:
        from hybrid_calib.calib.result import FrameEstimate

        vr.trajectory = [FrameEstimate(k, str(k), 0, est, 1, 1, 1.0, 1.0 if tested else None, 30.0 if tested else None,
                                       k in alarms, 0.0, 0.0) for k in range(5)]
    return vr


@pytest.mark.parametrize("delta, std, status, word, names", [
    ((0.1, 0, 0, 1, 0, 0), (0.05,) * 3 + (0.5,) * 3, "ok", "within tolerance", ()),
    ((0, 1.2, 0, 0, 0, 0), (0.05,) * 3 + (0.5,) * 3, "ok", "recalibrate", ("rotation about camera y",)),
    ((0, 0, 0, 0, 12, 0), (0.05,) * 3 + (0.5, 30, 0.5), "weak: translation along camera y", "cannot tell",
     ("translation along camera y",)),
    ((0, 0, 0, 0, 0, 0), (0.05,) * 6, "degenerate: rotation about camera z is unobservable", "cannot tell",
     ("degenerate",)),
    ((0, 9, 0, 0, 0, 0), (0.05,) * 6, "ok (NOT CONVERGED: only 3 % of the frame's correspondences fit the estimate)",
     "cannot tell", ("did not converge",)),
    # probe 151: 0.45 deg inside a 0.5 deg tolerance, but its 3-sigma interval (0.15 deg) straddles it
    ((0, 0.45, 0, 0, 0, 0), (0.05,) * 3 + (0.5,) * 3, "ok", "cannot tell", ("3-sigma interval straddles",)),
    ((0, 0.6, 0, 0, 0, 0), (0.05,) * 3 + (0.5,) * 3, "ok", "cannot tell", ("0.60 deg +- 0.15",)),  # nor beyond
])
def test_verdict_rules(delta, std, status, word, names):
    v = verdict_of(_vr(delta, std, status), Tolerance(rot_deg=0.5, trans_cm=5.0))
    assert v.word == word
    assert all(n in v.why for n in names), v.why
    assert "0.5 deg" in v.tolerance and "5 cm" in v.tolerance


def test_out_of_domain_status_makes_the_verdict_inconclusive_whatever_the_drift_block_says():
    from hybrid_calib.calib.covariance import inconclusive_status

    status = inconclusive_status("only 2 of 41 frames are inside the network's training domain", "ok")
    for extra in ({}, {"verdict_kind": "within tolerance", "verdict": "within tolerance"}):
        v = verdict_of(_vr((0.01,) * 6, (0.01,) * 6, status, drift_extra=extra))
        assert v.word == "cannot tell" and "only 2 of 41 frames" in v.why and "status" in v.source


def test_verdict_from_the_result_and_steps():
    v = verdict_of(_vr((0,) * 6, (0.01,) * 6, drift_extra={"verdict": "recalibrate", "why": "knocked",
                                                           "tolerance": {"rot_deg": 0.3}}, alarms=(3,)))
    assert (v.word, v.why) == ("recalibrate", "knocked") and "rot_deg 0.3" in v.tolerance
    assert v.moved_frames == (3,) and v.moved.startswith("yes")
    assert verdict_of(_vr((0,) * 6, (0.01,) * 6)).moved_answer == "not tested"
    assert verdict_of(_vr((0,) * 6, (0.01,) * 6, alarms=(3,))).moved_answer == "yes"


def test_the_lidar_alignment_is_said_in_words():
    from hybrid_calib.report.vehicle import lidar_html, status_html

    vr = _vr((0,) * 6, (0.01,) * 6)
    assert lidar_html(vr) == "" and "LiDAR" not in status_html(vr)
    vr.lidar = {"applied": True, "dy_m": -0.089, "dy_std_m": 0.034, "rows": 377, "frames": 41}
    assert "-8.9 +- 3.4 cm" in status_html(vr)
    assert "the camera-x translation and its 1-sigma above are the LiDAR" in lidar_html(vr)
    vr.lidar = {**vr.lidar, "dx_m": -0.19, "dx_std_m": 0.099, "forward_applied": True}  # its forward reading too
    assert "the camera-x and camera-z translations and their 1-sigma above are the LiDAR" in lidar_html(vr)
    assert "widened" not in lidar_html(vr)
    # the Doppler's disagreement widened the forward 1-sigma afterwards (probe 120: 199 cm said to be the LiDAR's)
    vr.doppler = {"applied": False, "widened": "the radar's Doppler in turns puts its forward offset ..."}
    assert "are the LiDAR&#x27;s, not the network&#x27;s; the 1-sigma is then widened to cover the Doppler lever " \
        "arm&#x27;s (below)" in lidar_html(vr)
    vr.lidar = {**vr.lidar, "widened": "the LiDAR's offset lay 4 stds ..."}
    assert "widened to cover its own disagreement with the estimate and the Doppler lever arm&#x27;s" in lidar_html(vr)
    vr.doppler = None
    vr.lidar = {"applied": False, "dy_m": 0.2, "dy_std_m": 0.2, "rows": 120, "frames": 9, "note": "std 20.0 cm > 10"}
    assert "not applied: std 20.0 cm &gt; 10" in lidar_html(vr)
    vr.lidar = {"applied": False, "note": "no LiDAR in the frames"}
    assert "not run: no LiDAR in the frames" in lidar_html(vr)


def test_the_doppler_lever_arm_is_said_in_words():
    from hybrid_calib.report.vehicle import doppler_html, status_html

    vr = _vr((0,) * 6, (0.01,) * 6)
    assert doppler_html(vr) == "" and "Doppler" not in status_html(vr)
    vr.doppler = {"applied": True, "dx_m": 0.123, "dx_std_m": 0.051, "pairs": 198, "turning": 71}
    assert "+12.3 +- 5.1 cm" in status_html(vr) and "198 sweep pairs, 71 frames turning" in doppler_html(vr)
    assert "applied: the camera-z translation" in doppler_html(vr)
    vr.doppler = {"applied": False, "dx_m": 0.4, "dx_std_m": 1.2, "pairs": 199, "turning": 0,
                  "note": "0 frames in turns (need 20): the lever arm shows only while the vehicle turns"}
    assert "not applied: 0 frames in turns (need 20)" in doppler_html(vr)


def test_fleet_page_links_vehicle_reports_and_names_the_flagged(run_dir, tmp_path):
    result = run_dir / "run" / "result.json"
    run = CalibrationRun.load(result)
    # one result file per vehicle, as the fleet engine writes them
    paths = []
    for name, vr in run.vehicles.items():
        one = CalibrationRun(run.data, run.version, run.correspondences, run.mode, {name: vr})
        d = tmp_path / "vehicles" / name
        one.save(d / "result.json")
        (d / "config.json").write_text((result.parent / "config.json").read_text())
        paths.append(d / "result.json")
    names = sorted(run.vehicles)
    design = run.vehicles[names[0]].truth_T
    page = write_fleet_page(paths, tmp_path / "fleet.html", design=design, flagged=[names[1]])
    cells = _parse(page)
    text = page.read_text()
    assert f'data-vehicle="{names[1]}"' in text and "Flagged: " + names[1] in text
    for n in names:
        assert f"vehicles/{n}/report.html" in cells.links
        assert (tmp_path / "vehicles" / n / "report.html").is_file()
    assert 'class=sortable' in text and len(cells.imgs) == 1
    # a rerun keeps the pages whose result did not change, and writes again the one whose result did (probe 57: a
    # rerun that ran nothing rewrote every page, ~2 s each)
    pages = {n: tmp_path / "vehicles" / n / "report.html" for n in names}
    for p in pages.values():
        p.write_text(p.read_text().replace("</body>", "<p id=marker></p></body>"))
    paths[0].write_text(paths[0].read_text().replace('"n_frames": ', '"n_frames":  '))  # other bytes, same result
    write_fleet_page(paths, tmp_path / "fleet.html", design=design, flagged=[names[1]])
    assert "id=marker" not in pages[names[0]].read_text() and "id=marker" in pages[names[1]].read_text()
    assert 'meta name="hybrid-calib-source"' in pages[names[0]].read_text()
    cut = pages[names[1]].read_text()[:5000]  # a page cut short is written again (probe 59)
    pages[names[1]].write_text(cut)
    write_fleet_page(paths, tmp_path / "fleet.html", design=design, flagged=[names[1]])
    assert pages[names[1]].read_text().rstrip().endswith("</html>") and "id=marker" not in pages[names[1]].read_text()
    pages[names[1]].write_text(pages[names[1]].read_text().replace("</body>", "<p id=marker></p></body>"))
    # one page that cannot be written: the others and the fleet page are, listing it, and then the error says so
    # (probe 59: it stopped the fleet page and every later page)
    pages[names[0]].unlink()
    pages[names[0]].mkdir()
    paths[1].write_text(paths[1].read_text().replace('"n_frames": ', '"n_frames":  '))
    (tmp_path / "fleet.html").unlink()
    from hybrid_calib.errors import HybridCalibError

    with pytest.raises(HybridCalibError, match=rf"1 vehicle report page\(s\) could not be written \(first: {names[0]}"):
        write_fleet_page(paths, tmp_path / "fleet.html", design=design, flagged=[names[1]])
    assert "Report pages not written (1)" in (tmp_path / "fleet.html").read_text()
    assert "id=marker" not in pages[names[1]].read_text()  # its result changed: written again
    # a user's file at a page's path is never replaced (the sessions before 36 wrote the page over it): that page is
    # listed as not written, and a fleet page over a user's file is refused, naming it
    pages[names[0]].rmdir()
    pages[names[0]].write_text("my notes\n")
    with pytest.raises(HybridCalibError, match="1 vehicle report page"):
        write_fleet_page(paths, tmp_path / "fleet.html", design=design, flagged=[names[1]])
    assert pages[names[0]].read_text() == "my notes\n"
    assert "is not an HTML page, so it is not replaced" in (tmp_path / "fleet.html").read_text()
    (tmp_path / "fleet.html").write_text("fleet,notes\n")
    with pytest.raises(HybridCalibError, match="fleet.html exists and is not an HTML page"):
        write_fleet_page(paths, tmp_path / "fleet.html", design=design, flagged=[names[1]])
    assert (tmp_path / "fleet.html").read_text() == "fleet,notes\n"


def test_the_fleet_page_shows_each_vehicle_s_largest_sigmas(run_dir, tmp_path):
    """Each row's sigma cells are its result's largest, whichever camera axis holds it (probe 74: the largest
    translation sigma without camera x passed, the oracle's x never being the largest)."""
    import dataclasses
    import re

    run = CalibrationRun.load(run_dir / "run" / "result.json")
    paths, stds = [], {}
    from hybrid_calib.calib.covariance import report_basis, report_std

    for k, (name, vr) in enumerate(sorted(run.vehicles.items())):
        cam = [[0.3, 0.1, 0.2, 9.0, 1.0, 2.0], [0.1, 0.2, 0.3, 1.0, 2.0, 9.0]][k % 2]  # deg, cm in camera axes
        Bi = np.linalg.inv(report_basis(vr.final.T))
        cov = Bi @ np.diag(np.r_[np.radians(cam[:3]), np.array(cam[3:]) / 100] ** 2) @ Bi.T
        std = report_std(vr.final.T, cov)
        np.testing.assert_allclose(std, cam, rtol=1e-9)
        vr = dataclasses.replace(vr, final=dataclasses.replace(vr.final, cov=cov, std=std), error=None)
        stds[name] = std
        one = CalibrationRun(run.data, run.version, run.correspondences, run.mode, {name: vr})
        one.save(tmp_path / "vehicles" / name / "result.json")
        paths.append(tmp_path / "vehicles" / name / "result.json")
    text = write_fleet_page(paths, tmp_path / "fleet.html").read_text()
    for name, std in stds.items():
        row = re.search(rf'<tr data-vehicle="{name}">.*?</tr>', text, re.S).group(0)
        shown = {k: float(v) for k, v in re.findall(r'data-key="(\w+)" data-value="([^"]+)"', row)}
        assert shown["max_t_sigma_cm"] == max(std[3:]) and shown["max_rot_sigma_deg"] == max(std[:3]), (name, shown)


def test_the_fleet_page_says_moved_as_the_vehicle_report_does():
    """Probe 75: the fleet page read "yes (frames 15)" for alarms the vehicle's report called "not told" (an estimate
    that is not trusted), and showed the alarm's frame where the monitor had placed the change 4 frames earlier."""
    from hybrid_calib.report.fleet import moved_cell

    lost = _vr((0,) * 6, (0.05,) * 6, "inconclusive: only 12 % of the rows fit", alarms=(3,), tested=True)
    v = verdict_of(lost)
    assert v.moved_answer == "not told" and moved_cell(v, lost) == "not told (alarm at frame 3)"
    knocked = _vr((0,) * 6, (0.05,) * 6, alarms=(4,), tested=True)
    knocked.mount = {"steps": [{"at": 4, "change": 1, "step_deg": 1.0, "std_deg": 0.1}], "pairs_tested": 9}
    v = verdict_of(knocked)
    assert moved_cell(v, knocked) == "yes (alarm at frame 4; changed from about frame 1)"
    calm = _vr((0,) * 6, (0.05,) * 6, alarms=(9,), tested=True)  # 5 tested frames, no alarm among them
    assert moved_cell(verdict_of(calm), calm) == "no"


def test_report_command(run_dir, tmp_path, capsys):
    result = run_dir / "run" / "result.json"
    name = sorted(json.loads(result.read_text())["vehicles"])[0]
    out = tmp_path / "x.html"
    assert main(["report", str(result), "--vehicle", name, "--frames", "1", "--out", str(out)]) == 0
    assert out.is_file() and str(out) in capsys.readouterr().out
    assert main(["report", str(result), "--out", str(out)]) == 2  # two vehicles, none named
    assert "pass --vehicle NAME" in capsys.readouterr().err
    assert main(["report", str(result), "--vehicle", "nope", "--out", str(out)]) == 2
    assert "'nope' is not in" in capsys.readouterr().err
    assert main(["report", str(result), "--vehicle", name + "x", "--out", str(out)]) == 2  # a typo: the close name
    assert f"did you mean {name}" in capsys.readouterr().err
    empty = tmp_path / "empty" / "result.json"  # "holds 0 vehicles (): pass --vehicle NAME" (probe 38)
    empty.parent.mkdir()
    empty.write_text(json.dumps({**json.loads(result.read_text()), "vehicles": {}}))
    assert main(["report", str(empty), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "holds no vehicle result (its 'vehicles' is empty" in err and "--vehicle" not in err
    import shutil

    from hybrid_calib.hybrid.network import shipped_checkpoint

    ck = tmp_path / "ck"  # a checkpoint named on the command line whose weights are cut short: an error, not a note
    ck.mkdir()
    for f in shipped_checkpoint("R1").parent.glob("small-sim-r1.*"):
        shutil.copy(f, ck / f.name)
    (ck / "small-sim-r1.safetensors").write_bytes((ck / "small-sim-r1.safetensors").read_bytes()[:1000])
    assert main(["report", str(result), "--vehicle", name, "--checkpoint", str(ck / "small-sim-r1.json"), "--out",
                 str(tmp_path / "y.html")]) == 2
    assert "small-sim-r1.safetensors" in capsys.readouterr().err and not (tmp_path / "y.html").exists()


def test_report_without_data_says_so(run_dir, tmp_path):
    result = run_dir / "run" / "result.json"
    name = sorted(json.loads(result.read_text())["vehicles"])[0]
    with pytest.warns(UserWarning, match="no data root: .*missing.* is not there"):  # said on the terminal too
        out = write_report(result, tmp_path / "r.html", vehicle=name, data=tmp_path / "missing")
    notes = _parse(out).ids["notes"]
    assert "no data root" in notes and "--data ROOT --version V" in notes
    assert out.read_text().count("data:image/png") == 1  # only the 3-sigma bands (from result.json)


def test_a_report_on_a_moved_root_names_the_root_its_frames_came_from(run_dir, tmp_path):
    """--data at a copy of the run's root: the header named only the run's own root (probe 30: a moved root)."""
    import shutil

    result = run_dir / "run" / "result.json"
    name = sorted(json.loads(result.read_text())["vehicles"])[0]
    moved = shutil.copytree(run_dir / "sim", tmp_path / "sim-moved")
    page = write_report(result, tmp_path / "m.html", vehicle=name, data=moved).read_text()
    assert f"frames shown from {moved} (v1.0-sim)" in page and "data:image/png" in page
    assert "frames shown from" not in write_report(result, tmp_path / "o.html", vehicle=name).read_text()


def test_report_on_data_changed_since_the_result_shows_none_of_them(run_dir, tmp_path):
    """A result drawn over a root re-simulated since (the same tokens, other data) showed the new frames and rows
    beside the old numbers, without a word; export refused the same result."""
    import shutil
    import warnings

    run = tmp_path / "run"
    shutil.copytree(run_dir / "run", run)
    stamp = json.loads((run / "data_stamp.json").read_text())
    name = sorted(json.loads((run / "result.json").read_text())["vehicles"])[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the data as they were: no warning
        assert write_report(run / "result.json", tmp_path / "a.html", vehicle=name).read_text().count(
            "data:image/png") > 1
    (run / "data_stamp.json").write_text(json.dumps({**stamp, "digest": "0" * len(stamp["digest"])}))
    with pytest.warns(UserWarning, match="are not those"):
        out = write_report(run / "result.json", tmp_path / "b.html", vehicle=name)
    assert "are not those" in _parse(out).ids["notes"]
    assert out.read_text().count("data:image/png") == 1  # only the 3-sigma bands (from result.json)
    (run / "data_stamp.json").write_text('{"dig')  # damaged: it drew the other drive's pictures in silence (probe 109)
    with pytest.warns(UserWarning, match="data_stamp.json is damaged"):
        out = write_report(run / "result.json", tmp_path / "c.html", vehicle=name)
    assert out.read_text().count("data:image/png") == 1


def _variance(png: bytes) -> float:
    from PIL import Image

    return float(np.asarray(Image.open(io.BytesIO(png)).convert("L"), np.float64).var())


def test_pages_in_a_headless_browser(run_dir, tmp_path):
    """Both pages load in chromium with no console error, no request leaving the file, and are not blank;
    the same check catches a page that breaks those rules."""
    from tests.browser import chromium_or_skip, render

    exe = chromium_or_skip()
    result = run_dir / "run" / "result.json"
    name = sorted(json.loads(result.read_text())["vehicles"])[0]
    pages = [write_report(result, tmp_path / "v.html", vehicle=name),
             write_fleet_page([result], tmp_path / "fleet.html", reports={})]
    # the fleet table sorts when a header is clicked (twice on "vehicle": descending names)
    sort = ("(function(){var th=document.querySelector('#vehicles th');th.click();th.click();"
            "return Array.from(document.querySelectorAll('#vehicles tbody tr')).map(r=>r.dataset.vehicle);})()")
    for page, js in zip(pages, (None, sort)):
        r = render(page, exe, evaluate=js)
        if js:
            assert r.value == sorted(json.loads(result.read_text())["vehicles"], reverse=True)
        assert r.console_errors == [], (page, r.console_errors)
        assert r.outside(page) == [], (page, r.outside(page))
        assert _variance(r.screenshot_png) > 100, page  # not blank
        (tmp_path / (page.stem + ".png")).write_bytes(r.screenshot_png)
    bad = tmp_path / "bad.html"
    bad.write_text('<html><body><img src="http://example.invalid/a.png"><script>console.error("x")</script>'
                   "</body></html>")
    r = render(bad, exe)
    assert r.outside(bad) == ["http://example.invalid/a.png"] and "x" in r.console_errors
    blank = tmp_path / "blank.html"
    blank.write_text("<html><body></body></html>")
    assert _variance(render(blank, exe).screenshot_png) < 1


def test_missing_browser_fails_under_ci_and_skips_otherwise(monkeypatch):
    from tests import browser

    monkeypatch.setattr(browser.shutil, "which", lambda name: None)
    monkeypatch.setenv("CI", "1")
    with pytest.raises(pytest.fail.Exception, match="CI is set"):
        browser.chromium_or_skip()
    monkeypatch.delenv("CI")
    with pytest.raises(pytest.skip.Exception, match="apt-get install -y chromium"):
        browser.chromium_or_skip()


@pytest.mark.parametrize("n_total, first", [
    ((1, 2, 3, 4, 2, 3), 3),  # the window's own alarm at frame 4, restarted with frames 3-4
    ((1, 2, 3, 4, 5, 3), 3),  # the mount monitor's alarm at frame 4, its change at frame 3: frame 5 fuses 3-5
    ((1, 2, 3, 4, 1, 2), 4),  # restarted at the alarm frame alone
])
def test_a_restarted_window_splits_the_drive_into_two_estimates(n_total, first):
    """Probe 88: the pictures cut at the alarm frame drew a knock's frames between the change and the alarm with the
    pre-knock estimate ("result of frames 0-12" on frame 8 of a window restarted from frame 8)."""
    from hybrid_calib.calib.result import FrameEstimate
    from hybrid_calib.report.evidence import segment_estimates

    vr = _vr((0,) * 6, (0.01,) * 6)
    Ts = [nominal_T_cam_radar() + np.diag([0, 0, 0, 0]) for _ in range(6)]
    for k, T in enumerate(Ts):
        T[0, 3] = k  # each frame's estimate distinguishable
    vr.trajectory = [FrameEstimate(k, f"f{k}", 0, Estimate(Ts[k], np.eye(6), np.ones(6), "ok"), n_total[k],
                                   n_total[k], 1.0, None, None, k == 4, 0.0, 0.0) for k in range(6)]
    seg = segment_estimates(vr)
    final = vr.final.T[0, 3]
    assert [seg[f"f{k}"][0][0, 3] for k in range(6)] == [first - 1] * first + [final] * (6 - first)
    assert seg["f0"][1] == f"result of frames 0-{first - 1}" and seg["f5"][1] == f"result of frames {first}-5"
    assert [seg[f"f{k}"][2] for k in range(6)] == list(range(6))
    # one estimate per frame (pure) or a window that never restarted: one segment, the result
    for n in ((1,) * 6, (1, 2, 3, 4, 5, 6)):
        vr.trajectory = [dataclasses.replace(f, n_window=n[k], n_total=n[k]) for k, f in enumerate(vr.trajectory)]
        assert {seg[1] for seg in segment_estimates(vr).values()} == {"result"}


def test_a_bad_run_config_leaves_a_note_not_a_crash(run_dir, tmp_path):
    src = run_dir / "run"
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "result.json").write_text((src / "result.json").read_text())
    (tmp_path / "run" / "config.json").write_text('{"no_such_option": 1}')
    name = sorted(json.loads((src / "result.json").read_text())["vehicles"])[0]
    out = write_report(tmp_path / "run" / "result.json", tmp_path / "r.html", vehicle=name, conf={"frames": 1})
    notes = _parse(out).ids["notes"]
    assert "config.json" in notes and "no correspondences or residuals" in notes
    assert "Residuals unavailable" in out.read_text()


def test_a_mount_monitor_that_tested_nothing_does_not_say_no():
    """A hybrid result whose radar mount monitor tested no frame pair (no usable Doppler velocity) does not
    answer "did the sensor move?" with "no": the radar's yaw was not tested."""
    from hybrid_calib.calib.mount_monitor import tested_words
    from hybrid_calib.report.verdict import moved_during_drive

    vr = _vr((0.0,) * 6, (0.05,) * 6, alarms=(99,), tested=True)  # a trajectory, no alarm in it
    vr.mount = {"steps": [], "levels": [], "frames_tested": 0, "pairs_tested": 0, "threshold": 8.0}
    moved, frames = moved_during_drive(vr)
    assert moved.startswith("not told for the radar's yaw") and frames == ()
    assert moved.endswith("no step alarm from the window's windowed chi-square of the recent frames against the "
                          "long-run estimate, over the 5 frames the estimate used")
    assert tested_words(vr.mount).startswith("no frame pair tested (no pair had a usable Doppler velocity")
    skipped = {**vr.mount, "frames_skipped": 4, "skip_example": "the ego poses moved 0.00 m"}
    assert tested_words(skipped).startswith("no frame pair tested (4 frames skipped, the first because the ego poses")
    vr.mount = {**vr.mount, "frames_tested": 40, "pairs_tested": 40, "blind_frames": [10, 5]}
    said = moved_during_drive(vr)[0]
    assert said.startswith("no: no step alarm from the radar mount monitor (the radar's Doppler heading against the "
                           "vehicle's ego poses) over 40 frame pairs tested and from the window's")
    assert said.endswith("; the radar mount monitor is blind to a step in the first 10 or the last 5 frames tested")
    vr.mount = {**vr.mount, "finds_deg": 0.61, "finds_within": 20, "scatter_deg": 0.35}  # how large a turn it finds
    assert moved_during_drive(vr)[0].endswith("; by the monitor a turn of 0.61 deg or more in yaw is found within 20 "
                                              "frames (9 drives in 10; its readings scatter by 0.35 deg)")
    # a 4-frame monitor cannot alarm: with no window statistic either (pure, pure-avg, a short drive) nothing was
    # tested, which read "no: no step alarm ... over the 16 frames the estimate used" for a pure result (probe 30)
    vr = _vr((0.0,) * 6, (0.05,) * 6, alarms=(99,))
    assert moved_during_drive(vr)[0].startswith("not tested: no step test could run on this result (the window's "
                                                "step test computed no statistic over these 5 frames")
    # the window's first frames build its long-run estimate: blind there, said (probe 129: knocked at frame 6, "no")
    import dataclasses

    late = _vr((0.0,) * 6, (0.05,) * 6, alarms=(99,), tested=True)
    late.trajectory = [dataclasses.replace(f, step_statistic=None) if f.index < 3 else f for f in late.trajectory]
    assert moved_during_drive(late)[0].startswith("no: no step alarm from the window's") and \
        "blind to a step before frame 3 (the frames its long-run estimate is first built from)" in \
        moved_during_drive(late)[0]
    # the monitor alone (the hybrid's window on no rows): its "no" is of turns in yaw, and says so (probe 123: a radar
    # moved 20 cm sideways read "Did the sensor move? no")
    vr.mount = {"steps": [], "levels": [], "frames_tested": 40, "pairs_tested": 40, "blind_frames": [10, 5]}
    said = moved_during_drive(vr)[0]
    assert said.startswith("no: no step alarm from the radar mount monitor") and said.endswith(
        "; a shift of the radar without a turn in yaw, or a turn in roll or pitch alone, is looked for by no test here "
        "(the window's step test ran on no rows)"), said
    vr.mount = {"steps": [], "levels": [], "frames_tested": 4, "pairs_tested": 4, "blind_frames": [10, 5]}
    said = moved_during_drive(vr)[0]
    assert said.startswith("not tested:") and "the radar mount monitor: it could not see a step on a drive this " \
        "short: 4 frames tested" in said


def test_a_step_alarm_names_the_test_that_raised_it():
    """A radar mount monitor step credited to the window's test at the alarm frame (probe 30: "the window's step test
    ... the window restarted there" at frame 13 for a monitor step from frame 8); a window alarm stays the window's."""
    from hybrid_calib.report.verdict import alarm_words, moved_during_drive

    vr = _vr((0.0,) * 6, (0.05,) * 6, alarms=(3, 4), tested=True)
    vr.mount = {"steps": [{"at": 3, "change": 1, "step_deg": 1.48, "std_deg": 0.11, "statistic": 10.0}],
                "levels": [], "frames_tested": 5, "pairs_tested": 5}
    words = alarm_words(vr)
    assert words[0].startswith("frame 3: the radar mount monitor (its Doppler against the ego poses): the radar "
                               "turned by 1.48 +- 0.11 deg (1 sigma) to the left in yaw from about frame 1")
    assert words[1].startswith("frame 4: the window's step test")
    assert "raised at" not in words[0]
    moved, frames = moved_during_drive(vr)
    assert moved.startswith("yes: the sensor stepped during the drive; step alarm at frame 3: the radar mount") \
        and frames == (3, 4)
    # raised on frame 2, not fused (dropped out of the network's domain): applied on the next (probe 39: "step alarm
    # at frame 14" beside the monitor's "(alarm at frame 13)")
    vr.mount["steps"][0]["at"] = 2
    assert alarm_words(vr)[0].endswith("the window kept only the frames since then (raised at frame 2, applied at "
                                       "frame 3, the next one fused)")


def test_the_attention_section_finds_a_network_methods_checkpoint(tmp_path):
    """A hybrid / pure result names its checkpoint in vehicles.<v>.checkpoint; the page said 'the result names no
    network checkpoint (a run on oracle or plain correspondences)'."""
    from hybrid_calib.report.attention import attention_html
    from hybrid_calib.report.evidence import Evidence

    vr = _vr((0.0,) * 6, (0.1,) * 6)
    assert "names no network checkpoint" in attention_html(vr, Evidence(), None, "v1.0-sim", "", tmp_path)
    vr.checkpoint = "/ck/small-sim-r1.json -> /ck/small-sim-r0.json"  # a cascade: its first stage is drawn
    html = attention_html(vr, Evidence(), None, "v1.0-sim", "", tmp_path)
    assert "checkpoint /ck/small-sim-r1.json is named but no camera frame" in html


def test_the_attention_section_says_when_the_checkpoint_given_is_not_the_results(tmp_path, monkeypatch):
    """``report --checkpoint B`` on a result calibrated with A drew B's attention without a word (probe 33); the same
    file named by another path is not flagged."""
    from types import SimpleNamespace

    import hybrid_calib.report.attention as attention
    from hybrid_calib.report.evidence import Evidence

    png = tmp_path / "a.png"
    png.write_bytes(b"\x89PNG")
    asked = []
    monkeypatch.setattr(attention, "attention_figure",
                        lambda *a, **k: asked.append(a[5]) or (png, a[5] or "corrupted-truth"))
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text("{}"), b.write_text("{}")
    vr = _vr((0.0,) * 6, (0.1,) * 6)
    vr.checkpoint = str(a)
    vr.config = {"depth_effective": "lidar-densified"}  # the depth the run's network read
    ev = Evidence(frames=[SimpleNamespace(index=0, drive_index=None)])
    other = attention.attention_html(vr, ev, None, "v1.0-sim", str(b), tmp_path)
    assert f"The result was calibrated with {a}</b>" in other and "not that file" in other
    same = attention.attention_html(vr, ev, None, "v1.0-sim", str(tmp_path / "." / "a.json"), tmp_path)
    own = attention.attention_html(vr, ev, None, "v1.0-sim", "", tmp_path)
    assert "calibrated with" not in same and "calibrated with" not in own
    # probe 141: the figure chose its own depth (corrupted truth where the root has depth maps), not the run's
    assert asked == ["", "lidar-densified", "lidar-densified"]
    assert "with depth lidar-densified (as the run read it)" in own
    assert "with depth corrupted-truth (as calibrate would choose it)" in other
    # rows of an evaluate export (calibrate --correspondences): the exporting network's depth, in the network block
    vr.config, vr.network = None, {"depth": "depth-anything:/m"}
    assert "with depth depth-anything:/m (as the run read it)" in attention.attention_html(vr, ev, None, "v1.0-sim", "",
                                                                                           tmp_path)
    vr.network = {}  # a result written before the block named it
    assert "(the result does not say which depth its network read" in attention.attention_html(
        vr, ev, None, "v1.0-sim", "", tmp_path)


def test_a_pure_result_cannot_tell_against_any_tolerance_asked():
    """Probe 113: `report --set tolerance.rot_deg=0.5` (the calibration's own tolerance) turned a pure result's
    "cannot tell: one pass of the network alone ... decides nothing" into "recalibrate"."""
    from hybrid_calib.calib.drift import one_pass_verdict, reference_test
    from hybrid_calib.geometry import retract

    ref = nominal_T_cam_radar()
    est = retract(ref, np.array([0.0, 0.0, np.radians(9.4), 0.0, 0.0, 0.0]))
    cov = np.diag([np.radians(0.5) ** 2] * 3 + [0.01 ** 2] * 3)
    vr = VehicleResult("v", Estimate(est, cov, np.full(6, 0.01), "ok"), method="pure",
                       drift=one_pass_verdict(reference_test(est, cov, ref).to_dict()))
    assert verdict_of(vr).word == "cannot tell"
    for tol in (Tolerance(rot_deg=0.5, trans_cm=2), Tolerance(rot_deg=0.05), Tolerance(trans_cm=30)):
        v = verdict_of(vr, tol)
        assert v.word == "cannot tell" and "one pass of the network alone" in v.why and "it read: " in v.why, v
    vr.method = "hybrid"  # the same block of another method is redone as it reads
    assert verdict_of(vr, Tolerance(rot_deg=0.5)).word == "recalibrate"


def test_a_tolerance_asked_of_the_report_redoes_the_calibrators_test():
    """``report --set tolerance.rot_deg=0.01`` kept the calibrator's verdict against its own 0.5 deg: the asked
    tolerance was ignored whenever the result stored a verdict (every current one does)."""
    from hybrid_calib.calib.drift import reference_test
    from hybrid_calib.geometry import retract

    ref = nominal_T_cam_radar()
    est = retract(ref, np.array([0.0, 0.0, np.radians(0.2), 0.0, 0.0, 0.0]))  # 0.2 deg about the radar's z
    cov = np.diag([np.radians(0.01) ** 2] * 3 + [0.001 ** 2] * 3)
    drift = reference_test(est, cov, ref).to_dict()
    vr = VehicleResult("v", Estimate(est, cov, np.full(6, 0.01), "ok"), drift=drift)
    own = verdict_of(vr)
    assert own.word == "within tolerance" and "redone" not in own.source and "0.5 deg" in own.tolerance
    tight = verdict_of(vr, Tolerance(rot_deg=0.05))
    assert tight.word == "recalibrate" and "0.05 deg" in tight.why and "redone" in tight.source
    assert "2 cm" in tight.tolerance  # the axis not asked keeps the calibration's
    loose = reference_test(retract(ref, np.array([0.0, 0.0, 0.0, 0.0, 0.10, 0.0])), cov, ref).to_dict()
    vr_loose = VehicleResult("v", Estimate(est, cov, np.full(6, 0.01), "ok"), drift=loose)
    assert verdict_of(vr_loose).word == "recalibrate"  # 10 cm against 2 cm
    assert verdict_of(vr_loose, Tolerance(trans_cm=30)).word == "within tolerance"
    # the page's "some axis beyond the tolerance" is the test the verdict read: it said True from the stored 2 cm test
    # beside a 30 cm tolerance (probe 50)
    from hybrid_calib.report.vehicle import verdict_html

    assert "beyond the tolerance (the change itself, not weighed by its sigma): True" in verdict_html(
        verdict_of(vr_loose), vr_loose)
    assert "beyond the tolerance (the change itself, not weighed by its sigma): False" in verdict_html(
        verdict_of(vr_loose, Tolerance(trans_cm=30)), vr_loose)
    assert "C_ref = 0: the reference taken as exact, so its own error counts as a change" in verdict_html(
        verdict_of(vr_loose, Tolerance(trans_cm=30)), vr_loose)  # what the p-value beside it means (probe 54)


def test_a_real_roots_tables_are_not_called_the_truth():
    """On a real root the page's "truth" column and "Error against the ground truth" were the nuScenes tables."""
    import dataclasses

    from hybrid_calib.report.vehicle import extrinsic_html

    vr = _vr((0,) * 6, (0.01,) * 6)
    vr = dataclasses.replace(vr, truth_T=nominal_T_cam_radar(), error={"geodesic_deg": 1.3, "trans_norm_cm": 24.0,
                                                                         "nees": 6.1}, errors_against="tables")
    html = extrinsic_html(vr)
    assert "<th>tables (reference)</th>" in html and "Error against the calibration tables" in html
    assert "Error against the ground truth" not in html
    sim = extrinsic_html(dataclasses.replace(vr, errors_against="truth"))
    assert "<th>truth</th>" in sim and "Error against the ground truth" in sim


def test_a_step_the_mount_monitor_measured_is_the_calibrators_verdict_too():
    """A knocked radar: the report said "recalibrate" (the mount monitor's step) while calibrate's line and
    result.json's drift block said "cannot tell" (probe 7). The calibrator's verdict now carries the step, and the
    report does not say it twice."""
    import dataclasses

    from hybrid_calib.calib.drift import DriftConfig, reference_test, with_mount_step
    from hybrid_calib.report.verdict import verdict_of

    T = nominal_T_cam_radar()
    cov = np.diag([np.radians(1.0) ** 2] * 3 + [0.05 ** 2] * 3)  # the end cannot tell against 0.5 deg / 2 cm
    drift = reference_test(T, cov, T, DriftConfig()).to_dict()
    vr = VehicleResult("v", Estimate(T, cov, np.full(6, 1.0), "ok"), drift=drift)
    assert vr.drift["verdict_kind"] == "cannot tell"
    mount = {"steps": [{"step_deg": 1.53, "std_deg": 0.1, "change": 6}]}
    raised = with_mount_step(vr.drift, mount)
    assert raised["verdict_kind"] == "recalibrate" and raised["drifted"] and raised["at_end"]["verdict_kind"] == \
        "cannot tell" and raised["verdict"].startswith("recalibrate: The radar turned on the vehicle")
    assert with_mount_step(vr.drift, {"steps": [{"step_deg": 0.3, "std_deg": 0.1, "change": 6}]}) is vr.drift
    v = verdict_of(dataclasses.replace(vr, drift=raised, mount=mount))
    assert v.word == "recalibrate" and v.why.count("The radar turned on the vehicle") == 1
    assert "Against the reference at the drive's end: cannot tell: " in v.why  # one verdict word, not two (probe 20)
    assert "inconclusive: cannot tell" not in v.why


# ---- tests the mutation probe (probe 25) found missing: each fails under its mutant

def test_a_derived_verdict_recalibrates_beyond_three_sigma_only():
    from hybrid_calib.report.verdict import Tolerance, verdict_of
    from tests.test_report import _vr
    assert verdict_of(_vr((0, 0.62, 0, 0, 0, 0), (0.05,) * 6), Tolerance(rot_deg=0.5, trans_cm=5.0)).word == \
        "cannot tell"


def test_a_monitor_step_is_judged_against_the_calibrations_tolerance():
    from hybrid_calib.report.verdict import Tolerance, verdict_of
    from tests.test_report import _vr
    vr = _vr((0.0,) * 6, (0.01,) * 6, drift_extra={"verdict_kind": "within tolerance", "verdict": "within tolerance",
                                                   "axes": {"yaw": {"tolerance": 2.0, "unit": "deg"}}})
    vr.mount = {"steps": [{"step_deg": 1.0, "std_deg": 0.05, "change": 3}], "levels": []}
    assert verdict_of(vr).word == "within tolerance"
    assert verdict_of(vr, Tolerance(rot_deg=0.5)).word == "recalibrate"


def test_the_page_says_the_radars_own_doppler_level_beside_an_untrusted_verdict():
    """Probe 36: calibrate's "cannot tell ...; but the radar's own Doppler ... puts its yaw on the vehicle 8.93 +- 0.14
    deg ... check the radar's yaw" was not on the report page, whose untrusted verdict is built from the status."""
    from hybrid_calib.report.verdict import verdict_of

    words = "but the radar's own Doppler against the ego poses puts its yaw 8.93 +- 0.14 deg right of its tables'"
    vr = _vr((0.0,) * 6, (0.05,) * 6, status="inconclusive: only 21 of 41 frames are inside the network's domain",
             drift_extra={"verdict_kind": "cannot tell", "verdict": "cannot tell: ...",
                          "doppler_level": {"level_deg": -8.93, "std_deg": 0.14, "words": words}})
    v = verdict_of(vr)
    assert v.word == "cannot tell" and v.why.endswith("; " + words)
    vr.drift.pop("doppler_level")
    assert "Doppler" not in verdict_of(vr).why


def test_a_window_alarm_on_an_untrusted_estimate_is_not_told_as_the_mount_moving():
    """Probe 34: a rear radar paired with the front camera (no shared view, 0 of 41 frames in domain) read "step alarm
    at frame 15: the window's step test (the mount changed inside the drive ...)"; a trusted result's alarm is as
    before, and a monitor step on an untrusted one still says the radar turned."""
    from hybrid_calib.report.verdict import alarm_words, moved_during_drive

    bad = _vr((0.0,) * 6, (0.05,) * 6, status="inconclusive: out of domain", alarms=(3,), tested=True)
    assert alarm_words(bad) == ["frame 3: the window's step test, on an estimate that is not trusted (its status is "
                                "inconclusive: the network's outputs may have jumped, not the mount; the window "
                                "restarted there)"]
    moved, frames = moved_during_drive(bad)
    assert moved.startswith("not told: step alarm at frame 3: the window's step test, on an estimate that is not "
                            "trusted") and frames == (3,)
    oracle = dataclasses.replace(bad, method="oracle")  # it runs no network (probe 41)
    assert "inconclusive: its correspondence rows may have jumped, not the mount" in alarm_words(oracle)[0]
    good = _vr((0.0,) * 6, (0.05,) * 6, alarms=(3,), tested=True)
    assert moved_during_drive(good)[0].startswith("yes: the sensor stepped during the drive; step alarm at frame 3: "
                                                  "the window's step test (the mount changed")
    bad.mount = {"steps": [{"at": 3, "change": 1, "step_deg": 1.48, "std_deg": 0.11, "statistic": 10.0}],
                 "levels": [], "frames_tested": 5, "pairs_tested": 5}
    assert moved_during_drive(bad)[0].startswith("yes: the sensor stepped during the drive; step alarm at frame 3: "
                                                 "the radar mount monitor")


def test_the_step_figure_draws_the_test_that_raised_each_alarm(run_dir, tmp_path):
    """Probe 67: the hybrid's step figure drew only the window's chi-square (below its threshold at the alarm, which
    the radar mount monitor raised), its axis shrank to the frames that statistic had, and an untested drive drew an
    empty panel without a word. Now: the monitor's CUSUM against its threshold with its change point and alarm, the
    window's panel only for alarms it raised, the whole drive on the axis, and a note where nothing was tested."""
    from hybrid_calib.plots.calibration import plot_vehicle, step_panels

    run = CalibrationRun.load(run_dir / "run" / "result.json")
    vr = next(iter(run.vehicles.values()))
    n = len(vr.trajectory)
    ids = [f.frame_id for f in vr.trajectory]
    cusum = [None, None, 0.0, 3.0, 9.5, 0.0][:n]
    traj = [dataclasses.replace(f, step_alarm=(i == 4), step_statistic=None, step_threshold=None)
            for i, f in enumerate(vr.trajectory)]
    hyb = dataclasses.replace(vr, trajectory=traj, frame_rows=[
        {"frame_id": ids[i], "used": 0, "rejected": 0, "mount": {"statistic": cusum[i]}} for i in range(n)],
        mount={"threshold": 8.0, "steps": [{"at": 4, "change": 3}], "pairs_tested": 20})
    monitor, *rest = step_panels(hyb)
    assert monitor.threshold == 8.0 and monitor.alarms == (4,) and monitor.changes == (3,) and not monitor.note
    np.testing.assert_array_equal(monitor.values, [np.nan if c is None else c for c in cusum])
    assert rest == []  # the window tested no frame: no empty panel beside the monitor's
    window = dataclasses.replace(hyb, trajectory=[dataclasses.replace(f, step_statistic=1.0, step_threshold=25.9)
                                                  for f in traj])
    assert step_panels(window)[1].alarms == ()  # the monitor's alarm is not the window's
    untested = dataclasses.replace(hyb, frame_rows=[{"frame_id": i, "mount": {"statistic": None}} for i in ids])
    assert step_panels(untested)[0].note.startswith("no frame tested (20 sweep pairs read)")
    oracle = dataclasses.replace(vr, trajectory=[dataclasses.replace(f, step_statistic=None) for f in vr.trajectory])
    (only,) = step_panels(oracle)
    assert only.title.startswith("sliding window") and only.note.startswith("no frame tested")
    import matplotlib.image as mpimg

    for k, r in enumerate((hyb, window, untested, oracle)):
        _, drift = plot_vehicle(r, tmp_path / str(k))
        assert mpimg.imread(drift).shape[0] > 300


def test_the_error_curve_ends_at_the_median_of_every_trials_end(run_dir):
    """Probe 67: trials lined up by frames fused; a trial that left a frame out was shorter, so the curve's last point
    was the longer trials' median (one trial's, at worst) while compare.md's table was every trial's."""
    from hybrid_calib.plots.calibration import trajectory_errors
    from hybrid_calib.plots.compare import _series

    run = CalibrationRun.load(run_dir / "run" / "result.json")
    full = next(iter(run.vehicles.values()))
    short = dataclasses.replace(full, trajectory=full.trajectory[:-2])
    err, std = _series([full, short])
    assert err.shape == (2, len(full.trajectory), 6) and np.isfinite(err).all() and np.isfinite(std).all()
    np.testing.assert_allclose(err[1, -1], np.abs(trajectory_errors(short))[-1])
    np.testing.assert_allclose(np.median(err[:, -1], axis=0),
                               np.median([np.abs(trajectory_errors(r))[-1] for r in (full, short)], axis=0))


def test_the_fleet_figure_shows_whole_bars_one_colour_rule_and_names_its_band(run_dir, tmp_path, monkeypatch):
    """Probe 67: the axes were fitted to the offsets and cut the +-2 sigma bars; a vehicle out of tolerance that also
    stepped was orange (purple never drawn); the fleet page coloured every flagged vehicle red while fleet.png used
    its flags; the grey band was named nowhere."""
    from hybrid_calib.plots.fleet import axis_limits, vehicle_colour

    assert vehicle_colour(["out_of_tolerance", "drifted_in_drive"]) == "tab:purple"
    assert vehicle_colour(["drifted_in_drive", "fleet_outlier"]) == "tab:red" and vehicle_colour([]) == "tab:blue"
    for flag in ("out_of_tolerance", "drifted_in_drive", "fleet_outlier", "degenerate", "inconclusive",
                 "doppler_off_tables"):  # every flag of fleet.summary (probe 69: inconclusive ones were blue)
        assert vehicle_colour([flag]) not in ("tab:blue", "tab:gray"), flag  # grey is the fleet's band
    off, std = np.array([[1.0, 0, 0, 7.2, 0, 0], [-0.5, 0, 0, -0.2, 0, 0]]), np.full((2, 6), 1.0)
    std[0, 3] = 26.7
    lim = axis_limits(off, std, 2.0, (np.full(6, 0.5), np.full(6, 3.0)))
    assert lim[3] >= 7.2 + 2 * 26.7 and lim[0] >= 3.0 and lim[1] >= 3.5
    run = CalibrationRun.load(run_dir / "run" / "result.json")
    names = sorted(run.vehicles)
    paths = []
    for name, vr in run.vehicles.items():
        d = tmp_path / name
        CalibrationRun(run.data, run.version, run.correspondences, run.mode, {name: vr}).save(d / "result.json")
        paths.append(d / "result.json")
    import hybrid_calib.plots.fleet

    drawn, draw = {}, hybrid_calib.plots.fleet.draw_fleet
    monkeypatch.setattr(hybrid_calib.plots.fleet, "draw_fleet",
                        lambda names, off, std, flags, *a, **k: drawn.update(zip(names, flags)) or draw(
                            names, off, std, flags, *a, **k))
    page = write_fleet_page(paths, tmp_path / "fleet.html", flagged={names[0]: ("out_of_tolerance",), names[1]: ()},
                            reports={})
    assert drawn == {names[0]: ("out_of_tolerance",), names[1]: ()}  # as fleet.png colours them
    assert "Flagged: " + names[0] in page.read_text() and names[1] not in page.read_text().split("Flagged: ")[1][:60]
    # a drive too short for a step test is no finding: not "Flagged" beside a figure that draws it blue (probe 125)
    drawn.clear()
    page = write_fleet_page(paths, tmp_path / "fleet2.html", flagged={names[0]: ("step_not_tested",),
                                                                      names[1]: ("step_not_tested", "inconclusive")},
                            reports={})
    assert drawn == {names[0]: (), names[1]: ("inconclusive",)}
    assert "Flagged: " + names[1] + "." in page.read_text(), page.read_text().split("Flagged: ")[1][:60]


def test_the_page_names_drive_frames_and_draws_rings_only_where_it_says_so(run_dir, tmp_path):
    """Probe 67: the pictures' alt texts (and the attention's line) named the dataset's frame index beside titles
    and plots counting the drive's frames; the rings' caption stood on pages that drew no rings."""
    import re
    import shutil

    result = run_dir / "run" / "result.json"
    name = sorted(json.loads(result.read_text())["vehicles"])[1]
    text = write_report(result, tmp_path / "a.html", vehicle=name).read_text()
    alts = re.findall(r'alt="([^"]*) start and result"', text)
    assert alts and all(a.startswith("drive frame ") for a in alts), alts
    assert "rings: the correspondences' observed pixels" in text
    bare = tmp_path / "bare"
    shutil.copytree(run_dir / "run", bare)
    (bare / "config.json").unlink()  # no config: the rows are not rebuilt, no rings
    text = write_report(bare / "result.json", tmp_path / "b.html", vehicle=name, data=run_dir / "sim").read_text()
    assert "rings:" not in text and "no correspondences are drawn (see the notes below)" in text


def test_a_page_is_recognised_through_its_bom_and_comments_and_a_linked_page_is_updated(tmp_path):
    """Probe 69: pages with a byte-order mark, a browser's "saved from" comment before the doctype, or an empty
    placeholder were refused as "not an HTML page"; a symbolic link to a page was replaced by a file, the page it
    pointed to kept as it was."""
    from hybrid_calib.report.html import is_html, write_page

    pages = {"bom.html": b"\xef\xbb\xbf<!DOCTYPE html><html></html>",
             "saved.html": b"<!-- saved from url=(0014)about:internet -->\n<!DOCTYPE html>\n<html></html>",
             "empty.html": b"", "upper.html": b"  \n<HTML><body></body></HTML>"}
    for name, data in pages.items():
        (tmp_path / name).write_bytes(data)
        assert is_html(tmp_path / name), name
        assert "new page" in write_page(tmp_path / name, "new page", "b").read_text()
    for data in (b"notes", b"<!-- a comment -->\nnotes", b"<!-- unclosed"):
        (tmp_path / "x.html").write_bytes(data)
        assert not is_html(tmp_path / "x.html"), data
    store = tmp_path / "store"
    store.mkdir()
    write_page(store / "real.html", "old", "b")
    (tmp_path / "link.html").symlink_to(store / "real.html")
    assert write_page(tmp_path / "link.html", "new", "b") == store / "real.html"
    assert (tmp_path / "link.html").is_symlink() and "<title>new</title>" in (store / "real.html").read_text()


def test_a_page_replays_the_rows_of_its_own_vehicle_alone(run_dir, tmp_path, monkeypatch):
    """Probe 69: a page of one vehicle rebuilt the oracle rows of every vehicle of the result (their progress bars, and
    time growing with the vehicles of one result)."""
    import hybrid_calib.report.evidence as evidence

    asked, real = [], evidence.replay_inputs
    monkeypatch.setattr(evidence, "replay_inputs", lambda *a: asked.append(a[3].vehicles) or real(*a))
    result = run_dir / "run" / "result.json"
    name = sorted(json.loads(result.read_text())["vehicles"])[1]
    assert "Residuals" in write_report(result, tmp_path / "a.html", vehicle=name).read_text()
    assert asked == [(name,)]


def test_a_one_frame_trajectory_draws_its_estimate_and_band(monkeypatch, tmp_path):
    """Probe 88: a vehicle that stood still (one frame kept) drew six empty panels: a line and a fill of one point."""
    from hybrid_calib.calib.result import FrameEstimate
    from hybrid_calib.plots import report as plots

    vr = _vr((0,) * 6, (0.01,) * 6)
    vr.trajectory = [FrameEstimate(0, "f0", 0, vr.final, 1, 1, 1.0, None, None, False, 0.0, 0.0)]
    figs = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path, **kw: figs.append(fig) or Path(path))
    plots.plot_estimate_bands(vr, tmp_path / "bands.png")
    for ax in figs[0].axes:
        assert any(line.get_marker() == "o" and len(line.get_xdata()) == 1 for line in ax.get_lines())
        assert any(len(c.get_segments()) == 1 for c in ax.collections if hasattr(c, "get_segments"))  # 3-sigma bar


def test_a_killed_reports_figures_are_removed_by_the_next_and_never_left_in_tmp(tmp_path, monkeypatch):
    """Probe 111: a report killed with -9 left its figures in /tmp/hc-report-* for ever, and a figure that could not
    be written was named by that temporary path. The figures are drawn beside the page, in a folder the next report
    of that page removes; an error writing one names the page."""
    import errno

    from hybrid_calib.report.html import figures_folder

    page = tmp_path / "r.html"
    stale = tmp_path / ".r.html.figures-dead1234"
    stale.mkdir()
    (stale / "frame0.png").write_bytes(b"x")
    with figures_folder(page) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".r.html.figures-") and not stale.exists()
        (tmp / "a.png").write_bytes(b"y")
    assert not tmp.exists() and sorted(p.name for p in tmp_path.iterdir()) == []
    with pytest.raises(OSError) as e, figures_folder(page) as tmp:
        raise OSError(errno.EFBIG, "File too large", str(tmp / "frame0.png"))
    assert e.value.filename == str(page) and "the figures of" in str(e.value) and not list(tmp_path.iterdir())
    with pytest.raises(OSError) as e, figures_folder(page):  # another file's error: as it was
        raise OSError(errno.ENOENT, "No such file", "/data/x.jpg")
    assert e.value.filename == "/data/x.jpg"


def test_the_tolerance_reads_alike_whichever_branch_gave_the_verdict():
    """Probe 126: fleet.html's "Tolerance:" read "0.5 deg per camera axis, 2 cm per camera axis" or "0.5 deg per
    rotation axis, 2 cm per translation axis (camera axes)" by which vehicle sorted first (a stored verdict, or an
    inconclusive one)."""
    axes = {"yaw": {"unit": "deg", "tolerance": 0.5, "decision": "undecided"},
            "lateral offset": {"unit": "cm", "tolerance": 2.0, "decision": "undecided"}}
    stored = _vr((0,) * 6, (0.05,) * 6, "weak: x", {"verdict_kind": "cannot tell", "verdict": "cannot tell: x",
                                                    "axes": axes})
    untrusted = _vr((0,) * 6, (0.05,) * 6, "inconclusive: y [the estimate's own status: weak: x]",
                    {"verdict_kind": "cannot tell", "verdict": "cannot tell: x", "axes": axes})
    a, b = verdict_of(stored), verdict_of(untrusted, Tolerance(rot_deg=0.5, trans_cm=2.0))
    assert a.tolerance == b.tolerance == "0.5 deg per rotation axis, 2 cm per translation axis (camera axes)", (a, b)


def test_the_page_s_residuals_measure_heights_from_the_road_as_calibrate_did(run_dir, monkeypatch):
    """Session 50: calibrate measures the height model's reflector heights from the road as the vehicle's reference
    mount puts the radar on it; the page rebuilt the rows' residuals and inliers with the radar's own plane."""
    from hybrid_calib.report import evidence

    seen = []
    real = evidence._rows_residuals
    monkeypatch.setattr(evidence, "_rows_residuals", lambda T, c, fc, gate: seen.append(fc) or real(T, c, fc, gate))
    result = run_dir / "run" / "result.json"
    run = CalibrationRun.load(result)
    evidence.gather(run, result, sorted(run.vehicles)[0], None, None, n_frames=1)
    assert seen and all(fc.height_plane_normal is not None and fc.height_plane_normal[2] > 0.99 for fc in seen)


def test_a_library_report_keeps_out_of_a_page_another_run_writes(run_dir, tmp_path):
    """The report command locked its page, the library's write_report and write_fleet_page did not: a library call
    onto a page a command was writing removed that run's figures folder and replaced its page. Both take the page's
    lock now (re-entrant under the command's own); another writer gets OutDirBusy naming the holder."""
    import threading

    from hybrid_calib.atomic import OutDirBusy
    from hybrid_calib.report.html import page_lock

    result = run_dir / "run" / "result.json"
    page = tmp_path / "r.html"
    held, done = threading.Event(), threading.Event()

    def hold():
        with page_lock(page, "report"):
            held.set()
            done.wait(60)

    t = threading.Thread(target=hold)
    t.start()
    try:
        assert held.wait(60)
        for write in (lambda: write_report(result, page), lambda: write_fleet_page([result], page)):
            with pytest.raises(OutDirBusy) as e:
                write()
            assert "hybrid-calib report" in str(e.value) and str(page) in str(e.value)
        assert not page.exists()
    finally:
        done.set()
        t.join()
    with page_lock(page, "report"):  # the command's lock around the library call: re-entrant, the page is written
        assert write_report(result, page, "sim-veh-000") == page and page.is_file()
