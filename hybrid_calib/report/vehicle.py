"""One vehicle's report page: verdict first, then the extrinsic with its 1-sigma, the directions the
data could not pin, the pictures (before / after on frames across the drive, estimate with its
3-sigma band, residual histograms, the network's attention) and where everything came from."""

from __future__ import annotations

import functools
import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hybrid_calib.calib.lever_arm import describe as describe_doppler
from hybrid_calib.calib.lidar_alignment import describe as describe_lidar
from hybrid_calib.calib.result import CalibrationRun, VehicleResult, extrinsic_report, failed_vehicles_message
from hybrid_calib.config import merge, to_dict
from hybrid_calib.errors import HybridCalibError, check_api_out
from hybrid_calib.report.evidence import Evidence, frame_words, gather, reference_name
from hybrid_calib.report.html import (
    esc,
    figures_folder,
    img_tag,
    num,
    page_lock,
    verdict_class,
    write_page,
    written_from,
)
from hybrid_calib.report.verdict import AXIS_NAMES, Tolerance, Verdict, verdict_of
from hybrid_calib.words import did_you_mean, n_frames, some_of

STD_KEYS = ("rot_x_cam_deg", "rot_y_cam_deg", "rot_z_cam_deg", "t_x_cam_cm", "t_y_cam_cm", "t_z_cam_cm")


@dataclass(frozen=True)
class ReportConfig:
    tolerance: Tolerance = Tolerance()  # the verdict's tolerance (unset: the one the calibration's test used)
    frames: int = 3  # camera frames shown before / after, spread over the drive
    checkpoint: str = ""  # network checkpoint for the attention figure ("" = the one the result names, if any)

    def __post_init__(self):
        if isinstance(self.frames, bool) or not isinstance(self.frames, int) or not 0 <= self.frames <= 100:
            raise ValueError(f"frames must be an integer in 0..100 (camera frames shown), got {self.frames!r}")


def pick_vehicle(run: CalibrationRun, vehicle: str | None, source: str) -> str:
    """The vehicle to report: ``vehicle`` or the run's only one; ``HybridCalibError`` otherwise."""
    names = sorted(run.vehicles)
    failed = run.vehicles_failed
    if vehicle in failed:
        raise HybridCalibError(f"vehicle {vehicle!r} failed in the run of {source}, so it has no result to report: "
                               f"{failed[vehicle]}; fix its data and rerun calibrate")
    if vehicle is None and not names and failed:
        raise HybridCalibError(f"every vehicle failed in the run of {source}, so there is no result to report: "
                               f"{failed_vehicles_message(failed)}")
    if not names and not failed:  # "holds 0 vehicles (): pass --vehicle NAME" (probe 38): no name could help
        raise HybridCalibError(f"{source} holds no vehicle result (its 'vehicles' is empty: an edited or incomplete "
                               "file); rerun calibrate with --overwrite")
    if vehicle is None:
        if len(names) != 1:
            raise HybridCalibError(f"{source} holds {len(names)} vehicles ({some_of(names)}): pass --vehicle NAME")
        return names[0]
    if vehicle not in run.vehicles:
        also = f"; failed: {', '.join(sorted(failed))}" if failed else ""
        close, mean = did_you_mean(vehicle, names)
        raise HybridCalibError(f"vehicle {vehicle!r} is not in {source}{mean} (vehicles: {some_of(names, close)}"
                               f"{also})")
    return vehicle


def _conventions_link() -> str:
    """Where the conventions are, in words: a file:// link into this checkout broke once the page was sent on."""
    return "<code>docs/conventions.md</code> of hybrid-calib"


def verdict_html(v: Verdict, vr: VehicleResult) -> str:
    d = v.test if v.test is not None else vr.drift or {}  # the test redone against the tolerance asked for: its
    # "beyond the tolerance" read the stored 0.5 deg / 2 cm one beside a 3 deg / 60 cm tolerance (probe 50)
    test = ""
    if "statistic" in d:
        test = (f"<div class=\"meta\">Reference test (chi-square, dof {d.get('dof', 6)}): statistic "
                f"{d['statistic']:.1f}, p-value {d['p_value']:.2g}, change "
                f"{d.get('rot_change_deg', float('nan')):.2f} deg / {d.get('trans_change_cm', float('nan')):.1f} cm; "
                f"significant: {d.get('significant')}; some axis beyond the tolerance (the change itself, not "
                f"weighed by its sigma): {d.get('exceeds_margin')}. The chi-square flags any significant change, also "
                "along a direction the data could not pin; the verdict above weighs each axis's change and its "
                f"sigma against the tolerance. {esc(str(d.get('test', '')).partition('dof 6, ')[2])}</div>")
    return (f'<div class="verdict {verdict_class(v.word)}" id="verdict"><div class="word">{esc(v.word)}</div>'
            f"<p>{esc(v.why)}</p><p><b>Tolerance:</b> {esc(v.tolerance)}. <span class=\"meta\">({esc(v.source)})"
            f"</span></p><p><b>Checked against:</b> <span id=\"reference\">{esc(_reference_line(vr))}</span></p>"
            f"<p><b>Did the sensor move during the drive?</b> <span id=\"moved\">{esc(v.moved)}</span></p>"
            f"{test}</div>")


def _reference_line(vr: VehicleResult) -> str:
    """What the verdict compared with, in words: the tables, or the earlier export the run was given
    (``--reference``: its path and the root it was exported from)."""
    src = (vr.drift or {}).get("reference")
    if isinstance(src, dict) and src.get("kind") == "export":
        return f"{reference_name(vr)} (from {src.get('from')})"
    return reference_name(vr) + (" (a simulated vehicle's factory calibration)" if vr.errors_against == "truth" else "")


def extrinsic_html(vr: VehicleResult) -> str:
    T = np.asarray(vr.final.T)
    rep = vr.final.to_dict()["report"]
    s = np.asarray(vr.final.std, float)
    mat = "".join("<tr>" + "".join(num(T[i, j], ".5f", f"T{i}{j}") for j in range(4)) + "</tr>" for i in range(4))
    rows = [("roll (about camera z)", rep["roll_deg"], "roll_deg", s[2], STD_KEYS[2], "deg", ".3f"),
            ("pitch (about camera x)", rep["pitch_deg"], "pitch_deg", s[0], STD_KEYS[0], "deg", ".3f"),
            ("yaw (about camera y)", rep["yaw_deg"], "yaw_deg", s[1], STD_KEYS[1], "deg", ".3f"),
            ("t x (camera)", 100 * rep["t_m"][0], "t_x_cm", s[3], STD_KEYS[3], "cm", ".2f"),
            ("t y (camera)", 100 * rep["t_m"][1], "t_y_cm", s[4], STD_KEYS[4], "cm", ".2f"),
            ("t z (camera)", 100 * rep["t_m"][2], "t_z_cm", s[5], STD_KEYS[5], "cm", ".2f")]
    truth = None if vr.truth_T is None else extrinsic_report(vr.truth_T)
    # a real root's reference is its calibration tables, not the truth (docs/conventions.md)
    tables = vr.errors_against == "tables"
    head = "<tr><th class=l>axis</th><th>estimate</th><th>+- 1 sigma</th><th>unit</th>" + (
        f"<th>{'tables (reference)' if tables else 'truth at the drive end' if vr.truth_path else 'truth'}</th>"
        if truth else "") + "</tr>"
    body = ""
    for label, val, key, sd, skey, unit, fmt in rows:
        tv = ""
        if truth:
            tv = num(truth[key] if key in truth else 100 * truth["t_m"]["xyz".index(key[2])], fmt)
        body += f"<tr><td class=l>{label}</td>{num(val, fmt, key)}{num(sd, fmt, skey)}<td>{unit}</td>{tv}</tr>"
    err = ""
    if vr.error:
        e = vr.error
        # not "a few tenths of a degree off": the same page could put them 2.9 deg off by the radar's Doppler (p52)
        against = ("the calibration tables (a real root has no ground truth: the tables are themselves a "
                   "calibration, with errors of their own: nuScenes' a few tenths of a degree, a wrong record "
                   "degrees)" if tables else "the ground truth")
        mean = (f"{e['rot_mean_deg']:.3f} deg (mean of |roll|, |pitch|, |yaw|, as the terminal and compare) and "
                if "rot_mean_deg" in e else "")
        err = (f"<p>Error against {against}: rotation {mean}{e['geodesic_deg']:.3f} deg (geodesic), translation "
               f"{e['trans_norm_cm']:.2f} cm (norm); NEES {e.get('nees', float('nan')):.2f} (6 expected for an "
               f"honest covariance{', if the tables were the truth' if tables else ''}).</p>")
    return (f"<h2>Extrinsic T_cam_radar</h2><p class=meta>Convention: <code>T_cam_radar</code> maps radar "
            f"points to the camera frame; angles are camera-axis Euler angles of the rotation after the fixed "
            f"radar-to-camera axis swap, and the 1-sigma are per camera axis (see {_conventions_link()}).</p>"
            f"<table id=\"matrix\">{mat}</table><table id=\"estimate\">{head}{body}</table>{err}")


def status_html(vr: VehicleResult) -> str:
    f = vr.final
    weak = f.weak_directions
    if f.status == "ok" and not weak:
        words = "None: the drive pinned every direction to within the covariance's tolerance."
    else:
        words = ("The data could not pin: " + ", ".join(weak) + "." if weak else "") + f" Status: {f.status}."
        if f.regularised:
            words += " Those directions carry a weak regularising prior: they are not calibrated."
    crb = ""
    if vr.crb_std is not None:
        cells = "".join(num(x, ".3f" if j < 3 else ".2f") for j, x in enumerate(vr.crb_std))
        crb = ("<p class=meta>Cramer-Rao bound of this drive (oracle rows), 1-sigma per camera axis (deg x3, cm x3):"
               f"</p><table><tr>{''.join(f'<th>{esc(a)}</th>' for a in AXIS_NAMES)}</tr><tr>{cells}</tr></table>")
    return (f"<h2>What the data could not pin</h2><p id=\"status\">{esc(words.strip())}</p>{crb}{lidar_html(vr)}"
            f"{doppler_html(vr)}")


def lidar_html(vr: VehicleResult) -> str:
    """The hybrid's LiDAR alignment (``vr.lidar``, docs/conventions.md) in words, or "" without one."""
    both = bool((vr.lidar or {}).get("forward_applied"))  # the forward reading too (probe 67: only x was named)
    # a 1-sigma widened afterwards is no longer the LiDAR's alone (probe 120: "the camera-z ... 1-sigma above are the
    # LiDAR's" beside a z 1-sigma of 199 cm the Doppler's disagreement had widened from the LiDAR's 14 cm)
    wide = [w for w, block in (("its own disagreement with the estimate", vr.lidar),
                               ("the Doppler lever arm's (below)", vr.doppler if both else None))
            if (block or {}).get("widened")]
    return _alignment_html(vr.lidar, describe_lidar, "lidar", "LiDAR alignment (the radar's offset along camera x "
                           + ("and z " if both else "") + "against the LiDAR's scene)",
                           "camera-x and camera-z translations and their 1-sigma" if both else
                           "camera-x translation and its 1-sigma", "LiDAR's",
                           f"; the 1-sigma is then widened to cover {' and '.join(wide)}" if wide else "")


def doppler_html(vr: VehicleResult) -> str:
    """The hybrid's Doppler lever arm (``vr.doppler``, docs/conventions.md) in words, or "" without one."""
    return _alignment_html(vr.doppler, describe_doppler, "doppler", "Doppler lever arm (the radar's forward offset "
                           "from its own motion in turns)", "camera-z translation and its 1-sigma", "Doppler's")


def _alignment_html(block: dict | None, describe, pid: str, title: str, what: str, whose: str, then: str = "") -> str:
    """``block`` said in words (``describe``); when applied, ``what`` (the axes and their 1-sigma it set) named as
    ``whose``, and ``then`` what changed them afterwards."""
    if not block:
        return ""
    words = describe(block)
    if block["applied"]:
        words += f": the {what} above are the {whose}, not the network's{then}"
    return f"<p id=\"{pid}\">{esc(title)}: {esc(words)}</p>"


def _figures(vr: VehicleResult, ev: Evidence, tmp: Path) -> str:
    from hybrid_calib.plots.figure import short_name
    from hybrid_calib.plots.report import draw_before_after, plot_estimate_bands, plot_residual_histograms

    out = "<h2>Radar on the camera: start and result</h2>"
    if ev.frames:
        rings = any(sf.pairs_start is not None or sf.pairs_result is not None for sf in ev.frames)
        out += (f"<p class=meta>Radar points (coloured by depth) projected with the start ({esc(ev.start_label)}) and "
                "with the result (after a step in the drive: the estimate of the frame's part of the drive)"
                + ("; rings: the correspondences' observed pixels joined to their radar point (green: inlier at that "
                   "extrinsic, red: rejected).</p>" if rings else
                   "; no correspondences are drawn (see the notes below).</p>"))
        for sf in ev.frames:
            panels = [{"title": "start", "uv": sf.uv_start, "depth": sf.depth_start, "pairs": sf.pairs_start},
                      {"title": sf.result_label, "uv": sf.uv_result, "depth": sf.depth_result,
                       "pairs": sf.pairs_result}]
            where = frame_words(sf)
            png = draw_before_after(sf.image, panels, tmp / f"frame{sf.index}.png",
                                    title=f"{short_name(vr.vehicle)} {where} (sample {sf.token[:8]})")
            out += img_tag(png, f"{where} start and result")  # as its title (probe 67: the dataset's index)
    else:
        out += "<p class=note>No camera frames shown (see the notes below).</p>"
    out += "<h2>Estimate and 3-sigma band per axis</h2>"
    if vr.trajectory:
        out += img_tag(plot_estimate_bands(vr, tmp / "bands.png"), "estimate with 3-sigma band per axis")
    else:
        out += ("<p class=note>This result holds no per-frame trajectory (a batch solve keeps none): nothing to "
                "plot.</p>")
    out += "<h2>Residuals</h2>"
    if ev.residuals is not None:
        r = ev.residuals
        out += (f"<p class=meta>{len(r.residual_px)} rows of {n_frames(r.n_frames)} at the result: whitened residual "
                f"times the row's pixel sigma; {100 * r.inlier.mean():.0f} % inliers. Rows are gated on their whitened "
                f"residual: the dashed gate ({r.gate_px:.1f} px) holds for a row of the median pixel sigma.</p>")
        out += img_tag(plot_residual_histograms(r.residual_px, r.inlier, r.gate_px, tmp / "residuals.png"),
                       "residual histograms")
    else:
        out += "<p class=note>Residuals unavailable (see the notes below).</p>"
    return out


def network_html(vr: VehicleResult, ev: Evidence, attention: str) -> str:
    n = vr.network
    out = "<h2>The network</h2>"
    if n:
        out += (f"<p>The measurement files carried the network's own estimate on {esc(n['n_frames'])} frames (last: "
                f"{esc(n['frame_id'])}, iteration {esc(n['iteration'])})")
        if n.get("error"):
            e = n["error"]
            against = "the tables" if vr.errors_against == "tables" else "the truth"
            out += f"; its error against {against}: {e['geodesic_deg']:.3f} deg, {e['trans_norm_cm']:.2f} cm"
        out += ".</p>"
    return out + attention


@functools.lru_cache(maxsize=1)
def _code_digest() -> str:
    """SHA-1 of the source files of hybrid_calib, factors and learned (the page draws on all three: probe 59 N4): a
    page written by other code is written again."""
    h = hashlib.sha1()
    top = Path(__file__).resolve().parents[2]
    for package in ("hybrid_calib", "factors", "learned"):
        for f in sorted((top / package).rglob("*.py")):
            h.update(f.read_bytes())
    return h.hexdigest()


def page_key(result: str | Path, vehicle: str | None, data: str | Path | None, version: str | None,
             conf: ReportConfig) -> str:
    """What a vehicle's page is written from: the result file's bytes, the vehicle, the frames' root and the options,
    and the code (``written_from``: a rerun of a fleet whose results did not change keeps their pages; probe 57: 20
    pages rewritten in 38 s on a rerun that ran nothing)."""
    h = hashlib.sha1(Path(result).read_bytes())
    h.update(json.dumps([vehicle, None if data is None else str(Path(data).resolve()), version, to_dict(conf),
                         _code_digest()], sort_keys=True, default=str).encode())
    return h.hexdigest()


def write_report(result: str | Path, out: str | Path, vehicle: str | None = None, data: str | Path | None = None,
                 version: str | None = None, conf: ReportConfig | dict | None = None, keep: bool = False) -> Path:
    """Write one vehicle's self-contained HTML report of ``result`` (a ``result.json``) to ``out``.

    data / version: the nuScenes root for the camera frames (default: the run's own, when it is there). ``keep``: a
    page at ``out`` written from the same result, options and code (``page_key``) is kept as it is.
    Returns the path written. ``HybridCalibError`` / ``DataError`` for a bad result or vehicle; ``OutDirBusy`` when
    another run writes that page (``html.page_lock``)."""
    conf = merge(ReportConfig, conf)
    t0 = time.perf_counter()
    check_api_out(out, "report", page=True)
    with page_lock(Path(out), "report"):
        return _write_report(Path(result), Path(out), vehicle, data, version, conf, keep, t0)


def _write_report(result: Path, out: Path, vehicle: str | None, data: str | Path | None, version: str | None,
                  conf: ReportConfig, keep: bool, t0: float) -> Path:
    """``write_report`` under the page's lock."""
    from hybrid_calib.report.attention import attention_html

    key = page_key(result, vehicle, data, version, conf) if result.is_file() else ""
    if keep and key and written_from(Path(out), key):
        return Path(out)
    run = CalibrationRun.load(result)
    name = pick_vehicle(run, vehicle, str(result))
    vr = run.vehicles[name]
    v = verdict_of(vr, conf.tolerance)
    ev = gather(run, result, name, data, version, conf.frames)
    with figures_folder(Path(out)) as tmp:
        figs = _figures(vr, ev, tmp)
        att = attention_html(vr, ev, data or run.data, version or run.version, conf.checkpoint, tmp)
    # and what the run said of its data before reading a frame (CalibrationRun.notes: another vehicle's export of
    # the same name, samples left out, poses that jump; probe 109 found the first on the console only)
    notes = "".join(f"<li>{esc(x)}</li>" for x in [*ev.notes, *(f"the run said: {n}" for n in run.notes)])
    body = (f"<h1>Radar-camera calibration: {esc(name)}</h1>"
            f"<p class=meta>{n_frames(vr.n_frames)}, {esc(run.mode)} mode, correspondences: "
            f"{esc(run.correspondences)}; data: {esc(run.data)} ({esc(run.version)})"
            # the frames shown come from --data when given: the run's own root may have moved since (probe 30)
            + (f"; frames shown from {esc(str(data))} ({esc(version or run.version)})"
               if data is not None and Path(data).resolve() != Path(run.data).resolve() else "")
            + f"; result: {esc(result)}</p>"
            f"{verdict_html(v, vr)}{extrinsic_html(vr)}{status_html(vr)}{figs}{network_html(vr, ev, att)}"
            + (f"<h2>Notes</h2><ul id=\"notes\">{notes}</ul>" if notes else "")
            + f"<p class=meta>Written by hybrid-calib report in {time.perf_counter() - t0:.1f} s.</p>")
    return write_page(Path(out), f"{name}: {v.word}", body, key)
