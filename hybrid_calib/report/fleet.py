"""The fleet page: the fleet plot (each vehicle's offset from the design mount with +-2 sigma as fleet.png, the
outliers named), a sortable table of vehicles with verdict and status, links to per-vehicle pages.

Inputs are plain (the fleet engine wires them): result files (``result.json``, one or more vehicles
each), an optional design mount (4, 4) ``T_cam_radar``, optional names of flagged vehicles. Offsets
are the camera-axis change of each final estimate from the design mount (``calib.covariance.camera_offset``, as
summary.json and the reference test); without a design mount, against each vehicle's own reference (its drift
block).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from urllib.parse import quote

import numpy as np

from hybrid_calib.calib.covariance import camera_offset
from hybrid_calib.calib.drift import doppler_level_words
from hybrid_calib.calib.mount_monitor import told_steps
from hybrid_calib.calib.result import CalibrationRun, VehicleResult
from hybrid_calib.config import merge
from hybrid_calib.data.files import file_part
from hybrid_calib.errors import DataError, HybridCalibError, check_api_out
from hybrid_calib.report.html import esc, figures_folder, img_tag, num, page_lock, verdict_class, write_page
from hybrid_calib.report.vehicle import ReportConfig, write_report
from hybrid_calib.report.verdict import DELTA_KEYS, VERDICTS, Verdict, verdict_of
from hybrid_calib.words import n_vehicles


def moved_cell(v: Verdict, vr: VehicleResult) -> str:
    """The fleet table's "moved in drive" cell: the vehicle report's answer (``Verdict.moved_answer``: alarms on an
    estimate that is not trusted are "not told", probe 75 read "yes" beside the report's "not told"), the frames of
    its alarms, and where the radar mount monitor placed the change (an alarm lags its change by a few frames)."""
    if not v.moved_frames:
        return v.moved_answer
    changes = sorted({int(st["change"]) for st in told_steps(vr.mount) if "change" in st})
    since = f"; changed from about frame {', '.join(map(str, changes))}" if changes and v.moved_answer == "yes" else ""
    return f"{v.moved_answer} (alarm at frame {', '.join(map(str, v.moved_frames))}{since})"


def _offset(vr: VehicleResult, design: np.ndarray | None) -> np.ndarray | None:
    """(6,) camera-axis change [deg x3, cm x3] of the final estimate from the design mount (or the
    vehicle's reference when ``design`` is None); None when neither is known."""
    if design is not None:
        return camera_offset(design, vr.final.T)
    d = (vr.drift or {}).get("delta_camera")
    return None if d is None else np.array([float(d[k]) for k in DELTA_KEYS])


def write_fleet_page(results: Sequence[str | Path], out: str | Path, design: np.ndarray | None = None,
                     flagged: Sequence[str] | Mapping[str, Sequence[str]] = (),
                     reports: Mapping[str, str | Path] | None = None,
                     data: str | Path | None = None, version: str | None = None,
                     conf: ReportConfig | dict | None = None, labels: Sequence[str] | None = None,
                     not_done: Mapping[str, str] | None = None) -> Path:
    """Write the fleet page ``out`` (HTML) from per-vehicle result files.

    results: ``result.json`` paths. design: (4, 4) design-mount ``T_cam_radar`` or None. flagged: names
    of vehicles the fleet engine flagged, or name -> its flags (``fleet.summary``'s: the figure colours them as the
    fleet command's fleet.png does) (named in the plot and the table; when empty, the vehicles whose
    sensor stepped during the drive are flagged; a mount that only differs from the design shows in its
    verdict, "recalibrate"). reports: vehicle ->
    its report page, already written; when None, each vehicle's page is written next to its result
    (``report.html``, ``report-<vehicle>.html`` for a result with several vehicles) with ``data`` /
    ``version`` / ``conf``. labels: one name per result file (a fleet's job ids), shown instead of the
    vehicle name of a single-vehicle result (two roots may both hold ``sim-veh-000``); ``flagged`` and
    ``reports`` then use the labels. not_done: vehicle -> why it has no result ("failed: <reason>", "pending"):
    listed on the page and counted, so a fleet with failures does not read as a smaller, clean one. Returns the
    path written; ``OutDirBusy`` when another run writes that page (``html.page_lock``)."""
    conf = merge(ReportConfig, conf)
    out = Path(out)
    check_api_out(out, "fleet", page=True)
    with page_lock(out, "fleet"):  # a library call is kept apart from another writer of the page as report's is
        return _write_fleet_page(results, out, design, flagged, reports, data, version, conf, labels, not_done)


def _write_fleet_page(results: Sequence[str | Path], out: Path, design: np.ndarray | None,
                      flagged: Sequence[str] | Mapping[str, Sequence[str]], reports: Mapping[str, str | Path] | None,
                      data: str | Path | None, version: str | None, conf: ReportConfig, labels: Sequence[str] | None,
                      not_done: Mapping[str, str] | None) -> Path:
    """``write_fleet_page`` under the page's lock."""
    from hybrid_calib.plots.fleet import COLOURS, draw_fleet

    if not results:
        raise DataError("no result file given for the fleet page")
    design = None if design is None else np.asarray(design, np.float64)
    if design is not None and design.shape != (4, 4):
        raise DataError(f"design mount must be a 4x4 T_cam_radar, got shape {design.shape}")
    vehicles: dict[str, tuple[VehicleResult, Path]] = {}
    pages: dict[str, Path] = {}
    unwritten: dict[str, str] = {}  # vehicle -> why its page was not written
    if labels is not None and len(labels) != len(results):
        raise DataError(f"{len(labels)} labels for {len(results)} result files")
    for i, p in enumerate(map(Path, results)):
        run = CalibrationRun.load(p)
        for vname, vr in sorted(run.vehicles.items()):
            name = vname if labels is None or len(run.vehicles) > 1 else labels[i]
            if name in vehicles:
                raise DataError(f"vehicle {name} appears in two result files ({vehicles[name][1]} and {p})",
                                path=str(p))
            vehicles[name] = (vr, p)
            if reports is not None and name in reports:
                pages[name] = Path(reports[name])
            elif reports is None:
                page = p.parent / ("report.html" if len(run.vehicles) == 1 else f"report-{file_part(name)}.html")
                try:  # one page that cannot be written stopped the fleet page and every later one (probe 59)
                    pages[name] = write_report(p, page, vname, data, version, conf, keep=True)
                except (OSError, HybridCalibError) as e:
                    unwritten[name] = f"{page}: {e.strerror or e}" if isinstance(e, OSError) else f"{page}: {e}"
    names = list(vehicles)
    verdicts = {n: verdict_of(vr, conf.tolerance) for n, (vr, _) in vehicles.items()}
    # the flags the figure colours: "step_not_tested" is no finding (the table's "moved in drive" says "not tested";
    # probe 125: a fleet of short drives read "Flagged:" every vehicle, the figure drawing them all unflagged)
    flags = ({n: tuple(x for x in f if x in COLOURS) for n, f in flagged.items()} if isinstance(flagged, Mapping) else
             {n: ("flagged",) for n in flagged})
    if not any(flags.values()):
        flags = {n: ("drifted_in_drive",) for n in names if verdicts[n].moved_answer == "yes"}
    flagged = [n for n in names if flags.get(n)]
    offsets = {n: _offset(vr, design) for n, (vr, _) in vehicles.items()}
    reference = "design mount" if design is not None else "vehicle's own reference (calibration tables)"

    plotted = [n for n in names if offsets[n] is not None]
    with figures_folder(Path(out)) as tmp:  # beside the page (probe 111: a killed run left /tmp/hc-fleet-*)
        fig = ("<p class=note>No offsets to plot: no design mount given and no result holds a reference "
               "comparison.</p>")
        if plotted:
            png = draw_fleet(plotted, np.array([offsets[n] for n in plotted]),
                             np.array([vehicles[n][0].final.std for n in plotted]),
                             [flags.get(n, ()) for n in plotted], Path(tmp) / "fleet.png",
                             f"offset from the {reference} per vehicle")
            fig = img_tag(png, "fleet plot")

    rows = ""
    for n in names:
        vr, p = vehicles[n]
        v = verdicts[n]
        link = esc(n)
        if n in pages:
            # a URL: a folder named with %-escapes (data.files.file_part) is escaped once more, or the browser
            # decodes it to a folder that does not exist
            rel = Path(os.path.relpath(pages[n], out.parent)).as_posix()
            link = f'<a href="{esc(quote(rel, safe="/"))}">{esc(n)}</a>'
        o = offsets[n]
        rot = float(np.linalg.norm(o[:3])) if o is not None else float("nan")
        tr = float(np.linalg.norm(o[3:])) if o is not None else float("nan")
        moved = esc(moved_cell(v, vr))
        # the radar's Doppler against its tables, the one direct evidence on an untrusted estimate: in the row, not
        # only on the vehicle's page (probe 52)
        doppler = (" <span class=note>(its radar's Doppler puts its yaw off its tables: check the radar's yaw)</span>"
                   if doppler_level_words(vr.drift) else "")
        rows += (f'<tr data-vehicle="{esc(n)}"><td class=l>{link}</td>'
                 f'<td class="l {verdict_class(v.word)}" data-key="verdict" title="{esc(v.why)}">{esc(v.word)}'
                 f'{doppler}</td>'
                 f'<td class=l>{"yes" if n in flagged else "no"}</td>'
                 f'<td class=l data-key="status">{esc(vr.final.status)}</td><td class=l>{moved}</td>'
                 f"{num(rot, '.2f', 'offset_rot_deg')}{num(tr, '.1f', 'offset_trans_cm')}"
                 f"{num(max(vr.final.std[:3]), '.3f', 'max_rot_sigma_deg')}"
                 f"{num(max(vr.final.std[3:]), '.2f', 'max_t_sigma_cm')}<td>{vr.n_frames}</td></tr>")
    counts = {w: sum(v.word == w for v in verdicts.values()) for w in VERDICTS}
    not_done = dict(not_done or {})
    missing = ""
    if not_done:
        items = "".join(f"<li><b>{esc(n)}</b>: {esc(why)}</li>" for n, why in sorted(not_done.items()))
        missing = f"<h2>Vehicles without a result ({len(not_done)})</h2><ul id=\"not-done\">{items}</ul>"
    if unwritten:
        items = "".join(f"<li><b>{esc(n)}</b>: {esc(why)}</li>" for n, why in sorted(unwritten.items()))
        missing += f"<h2>Report pages not written ({len(unwritten)})</h2><ul id=\"unwritten\">{items}</ul>"
    exported = {n: ((vr.drift or {}).get("reference") or {}) for n, (vr, _) in vehicles.items()}
    exported = {n: src.get("path") for n, src in exported.items() if src.get("kind") == "export"}
    against = ("<p id=\"reference\">Verdicts checked against an earlier export (--reference), not the tables: "
               + "; ".join(f"{esc(', '.join(sorted(n for n in exported if exported[n] == path)))} against the mount "
                           f"in {esc(str(path))}" for path in sorted(set(exported.values())))
               + ("; the others against their tables" if len(exported) < len(names) else "") + ".</p>"
               if exported else "")
    total = len(names) + len(not_done)
    body = (f"<h1>Fleet calibration: {n_vehicles(total)}"
            + (f", {len(names)} with a result" if not_done else "") + "</h1>"
            f"<p id=\"fleet-summary\"><b>{counts['recalibrate']} to recalibrate, "
            f"{counts['cannot tell']} cannot tell (the data do not decide against the tolerance, or the estimate "
            "is not trusted), "
            f"{counts['within tolerance']} within tolerance"
            + (f", {len(not_done)} without a result (failed or not run)" if not_done else "") + ".</b> Flagged: "
            f"{esc(', '.join(flagged)) if flagged else 'none'}. Tolerance: "
            f"{esc(next(iter(verdicts.values())).tolerance)}.</p>{against}"
            f"<h2>Offsets from the {esc(reference)}</h2>{fig}"
            "<h2>Vehicles</h2><p class=meta>Click a column to sort. Offsets: rotation angle and translation norm "
            f"of each estimate from the {esc(reference)} (as the plot above), camera axes; "
            # both used to be called "the change" (probe 30)
            + ("the change from a vehicle's own tables, which its verdict judges, is in its report; "
               if design is not None else "")
            + "sigma: the largest per-axis 1-sigma.</p>"
            "<table class=sortable id=\"vehicles\"><thead><tr><th class=l>vehicle</th><th class=l>verdict</th>"
            "<th class=l>flagged</th><th class=l>status</th><th class=l>moved in drive</th><th>offset rot (deg)</th>"
            "<th>offset t (cm)</th><th>max rot sigma (deg)</th><th>max t sigma (cm)</th><th>frames</th></tr></thead>"
            f"<tbody>{rows}</tbody></table>{missing}"
            f"<p class=meta>Results: {esc(', '.join(str(p) for _, p in vehicles.values()))}</p>")
    page = write_page(out, f"fleet: {n_vehicles(total)}", body)
    if unwritten:  # everything else written first: said, and the command fails
        first = next(iter(sorted(unwritten.items())))
        raise HybridCalibError(f"{len(unwritten)} vehicle report page(s) could not be written (first: {first[0]}: "
                               f"{first[1]}); the fleet page {page} and the other pages are written and list them; "
                               "fix the path and rerun")
    return page


def write_fleet_pages(summary: dict, out: str | Path) -> Path | None:
    """The fleet page ``out/fleet.html`` and one report per done vehicle (beside its result.json) of a fleet run's
    ``summary`` (``fleet.summary``'s: its vehicles' states and result paths relative to ``out``, the design mount,
    the flags), with the fleet's design mount and the vehicles it flagged; None when no vehicle is done."""
    out = Path(out)
    done = {jid: r for jid, r in summary["vehicles"].items() if r["state"] == "done"}
    if not done:
        return None
    # about 2 s a page (probe 57: 48 s of silence after the fleet's bar on 20 vehicles); unchanged ones are kept
    print(f"writing the fleet page and {len(done)} vehicle report page(s) (a page whose result did not change since "
          "it was written is kept) ...", file=sys.stderr, flush=True)
    design = (summary.get("design_mount") or {}).get("T_cam_radar")
    others = {jid: (r["state"] if r["state"] != "failed" else f"failed: {r.get('reason') or ''}")
              for jid, r in summary["vehicles"].items() if r["state"] != "done"}
    return write_fleet_page([out / r["result"] for r in done.values()], out / "fleet.html",
                            design=None if design is None else np.asarray(design),
                            flagged={jid: r.get("flags") or () for jid, r in done.items()}, labels=list(done),
                            not_done=others)
