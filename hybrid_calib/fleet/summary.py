"""The fleet view: ``OUT/summary.json``, ``OUT/summary.md``, ``OUT/fleet_prior.json`` and ``OUT/fleet.png``.

``summary.json`` (``schema`` "hybrid-calib/fleet-summary/v1")::

    {"schema": ..., "out": OUT, "method": str, "seed": int,
     "counts": {"vehicles", "pending", "running", "done", "failed", "out_of_tolerance",
                "drifted_in_drive", "fleet_outliers", "degenerate", "inconclusive", "weak", "doppler_off_tables",
                "step_not_tested", "fit_change", "batch"},   # batch: results of --set mode=batch (no step test)
     "step_test": bool,   # whether the method looks for a step inside the drive (hybrid.loop.STEP_METHODS)
     "design_mount": {"T_cam_radar": 4x4, "source": "recorded" | "mean of the tables"},
     "fleet_prior": {"T_mean", "spread_std_cam", "mean_std_cam", "inliers", "outliers"} | null,
     "vehicles": {JOB_ID: VEHICLE}}

    VEHICLE = {"vehicle", "data", "state", "reason", "file", "attempts", "wall_s", "host",
               "result": "vehicles/<id>/result.json" | null,     # relative to OUT (calib.result schema)
               "plots": ["vehicles/<id>/plots/<vehicle>_trajectory.png", ...],
               # only when done:
               "n_frames", "status", "offset_from_design": OFFSET, "offset_from_tables": OFFSET,
               "std_cam": STD, "verdict": str, "drift": {"drifted", "p_value", "statistic"},
               "step_alarms": [frame, ...], "error": {...} | null,
               "mount_steps": [{"at", "change", "step_deg", "std_deg", "statistic"}, ...],  # hybrid: mount monitor
               "fleet_test": {"d2", "p_value", "reference"} | {"left_out": why} | null,
               "mode": "window" | "batch",
               "flags": ["out_of_tolerance", "drifted_in_drive", "fleet_outlier", "degenerate", "inconclusive",
                         "doppler_off_tables", "step_not_tested", "fit_change"]}
               # "fit_change": a batch result whose fit of the rows before and after a frame says the mount likely
               # moved inside the drive (calib.batch.fit_change; batch mode runs no step test)
               # "doppler_off_tables": the radar's own Doppler puts its yaw on the vehicle beyond 3 x the tolerance
               # from its tables (calib.drift.doppler_level_note: "check the radar's yaw"), said in the verdict
               # "inconclusive": the status is "inconclusive: ..." (the estimate is not trusted: input out of the
               # network's domain, a solve that did not converge, ...); its verdict is "cannot tell" whatever the
               # drift block says

    OFFSET = {"rot_x_cam_deg", "rot_y_cam_deg", "rot_z_cam_deg", "t_x_cam_cm", "t_y_cam_cm", "t_z_cam_cm"}:
    B local(T_ref, T_est) (the right-tangent offset mapped to camera axes exactly as the std blocks,
    docs/conventions.md), so it reads against ``std_cam`` as offset +- sigma.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hybrid_calib.atomic import finished
from hybrid_calib.calib.covariance import camera_offset, inconclusive_reason, status_kind
from hybrid_calib.calib.drift import alarms_say_moved, doppler_level_words, step_tests_ran
from hybrid_calib.calib.mount_monitor import told_steps
from hybrid_calib.calib.result import stored_digest
from hybrid_calib.config import save_json_atomic, save_text_atomic
from hybrid_calib.fleet.manifest import Manifest, rel_path
from hybrid_calib.hybrid.loop import STEP_METHODS
from hybrid_calib.words import md_cell, n_vehicles

SCHEMA = "hybrid-calib/fleet-summary/v1"


UNRESOLVED = 0.1  # a fleet spread under this fraction of the vehicles' own median std: not resolved (summary.md)


def design_mount(jobs: list[dict]) -> tuple[np.ndarray | None, str]:
    """The fleet's design T_cam_radar (4, 4) and where it came from: the recorded design mounts
    (their mean, when roots record one) or else the mean of the tables' extrinsics (the vehicles' references: with
    --reference, an earlier export's mounts); None when no job has either (every vehicle without a frame: each job
    failed, and the summary says why; probe 102 read "no vehicle has a tables extrinsic", rc 2, no summary)."""
    from hybrid_calib.geometry import local, retract

    recorded = [np.asarray(j["design_T"]) for j in jobs if j.get("design_T") is not None]
    Ts = recorded or [np.asarray(j["tables_T"]) for j in jobs if j.get("tables_T") is not None]
    if not Ts:
        return None, "none: no vehicle of the fleet has a tables extrinsic (none has a frame)"
    T = Ts[0]
    for _ in range(3):  # Karcher mean on SE(3) (right tangent)
        T = retract(T, np.mean([local(T, Ti) for Ti in Ts], axis=0))
    referenced = any((j.get("calib") or {}).get("reference") for j in jobs)  # tables_T: the export's where it wrote
    return T, "recorded" if recorded else (  # one (probe 77: labelled "the tables" on real roots)
        "mean of the vehicles' references (an earlier export's mounts where --reference replaced the tables)"
        if referenced else "mean of the tables")


def common_cov(jobs: list[dict]) -> np.ndarray:
    """(6, 6) the covariance every vehicle's estimate shares (fleet.prior module doc): the
    prior-pinned variances (``calib.covariance.prior_pinned_std``) of the factor the jobs ran with
    (the largest over the jobs' configs), radar right tangent [rad^2, m^2]."""
    from hybrid_calib.calib.covariance import prior_pinned_std
    from hybrid_calib.calib.pipeline import CalibrateConfig
    from hybrid_calib.config import merge

    std = np.zeros(6)
    for j in jobs:
        c = merge(CalibrateConfig, j.get("calib") or {})
        std = np.maximum(std, prior_pinned_std(c.window.factor if c.mode == "window" else c.batch.factor))
    return np.diag(std ** 2)


def unmeasured_cov(covs: list[np.ndarray], method: str) -> np.ndarray:
    """(6, 6) radar right tangent [rad^2, m^2]: for a learned ``method``, the median of the vehicles' own variances
    (``covs``, (6, 6) each) along the directions it does not measure (``hybrid.corrections.LEARNED_NOT_MEASURED``: roll
    and pitch are the network's learned prior of the fleet's mount, the height the start's), else zeros. The fleet's
    spread there is not the mounts' (every vehicle reads the same prior), so the priors it hands out carry no
    information there (``fleet.prior.FleetPrior.unmeasured_cov``). Probe 126: a hybrid fleet fitted a roll spread of
    0.13 deg where the true one was 1.06, handed out roll priors of 0.25-0.30 deg (7 of 12 3.4-7.7 sigma off the
    truth), and an oracle pass with them read NEES 12.3 (7.7 without)."""
    if method == "oracle" or not covs:
        return np.zeros((6, 6))
    from hybrid_calib.hybrid.corrections import LEARNED_NOT_MEASURED

    var = np.median([np.clip(np.diag(c), 0.0, None) for c in covs], axis=0)
    return np.diag(np.where(LEARNED_NOT_MEASURED > 0, var, 0.0))


def build_summary(m: Manifest, fit_prior: bool = True, alpha: float = 1e-3):
    """(summary dict of the module doc, FleetPrior or None) from the manifest and the result files."""
    from hybrid_calib.calib.result import STD_FRAME, CalibrationRun
    from hybrid_calib.fleet.prior import MIN_VEHICLES, fit_fleet_prior
    from hybrid_calib.metrics import std_dict, std_keys

    keys = std_keys(STD_FRAME)
    base = m.path.parent
    T_ref, source = design_mount([e["job"] for e in m.jobs.values()])
    rows: dict[str, dict] = {}
    results = {}
    for jid, e in sorted(m.jobs.items()):
        j = e["job"]
        row = {"vehicle": j["vehicle"], "data": j["data"], **{k: e.get(k) for k in (
            "state", "reason", "file", "attempts", "wall_s", "host", "result")}, "plots": [], "flags": []}
        pj = j.get("prior")
        row["prior"] = None if pj is None else {"file": pj.get("file"), "source": pj.get("source")}
        rows[jid] = row
        if e["state"] != "done" or not e.get("result"):
            continue
        run = CalibrationRun.load(base / e["result"])
        vr = next(iter(run.vehicles.values()))
        row["mode"] = run.mode
        results[jid] = vr
        plots = Path(j["out"]) / "plots"
        row["plots"] = sorted(rel_path(p, base) for p in finished(plots.glob("*.png"))) if plots.is_dir() else []
        d = vr.drift or {}
        row["reference"] = d.get("reference") or {"kind": "tables"}  # what "vs tables" and offset_from_tables are from
        row.update(n_frames=vr.n_frames, status=vr.final.status,
                   offset_from_design=None if T_ref is None else dict(zip(
                       keys, camera_offset(T_ref, vr.final.T).tolist())),
                   offset_from_tables=None if j.get("tables_T") is None else dict(zip(
                       keys, camera_offset(np.asarray(j["tables_T"]), vr.final.T).tolist())),
                   std_cam=std_dict(vr.final.std, STD_FRAME),
                   drift={k: d.get(k) for k in ("drifted", "p_value", "statistic")},
                   # an untrusted estimate cannot tell, unless the radar mount monitor measured a turn beyond the
                   # tolerance (calib.drift.with_mount_step: "recalibrate", as calibrate, result.json and the
                   # reports say; the fleet's text view read "cannot tell" for it: probe 30)
                   verdict=f"cannot tell: the estimate is not trusted (inconclusive: "
                           f"{inconclusive_reason(vr.final.status)})" + (
                               f"; {doppler_level_words(d)}" if doppler_level_words(d) else "")
                   if status_kind(vr.final.status) == "inconclusive" and not d.get("at_end") else (
                       d.get("verdict") or ("out of tolerance" if d.get("drifted") else "within tolerance")),
                   step_alarms=[f.index for f in vr.trajectory if f.step_alarm], error=vr.error, fleet_test=None,
                   mount_steps=told_steps(vr.mount))
        if row["prior"] is not None and (d.get("prior") or {}).get("refused"):  # calib.drift.refused_prior
            row["prior"]["refused"] = d["prior"]["words"]
        elif row["prior"] is not None and d.get("prior"):  # calib.drift.prior_note: the axes it decided or moved
            row["prior"]["decided"] = sorted(set(d["prior"].get("dominated") or ())
                                             | set(d["prior"].get("pulled") or ()))
        if d.get("drifted"):
            row["flags"].append("out_of_tolerance")
        if row["step_alarms"] and alarms_say_moved(vr.final.status, vr.mount):  # as the report's "did it move"
            row["flags"].append("drifted_in_drive")
        elif run.mode == "batch":  # no step test at all (probe 145: read "too short" on 16-frame drives); its fit
            if d.get("fit_change"):  # of the rows before and after a frame says whether the mount likely moved
                row["flags"].append("fit_change")
        elif m.method in STEP_METHODS and not any(step_tests_ran(vr.trajectory, vr.mount)):
            row["flags"].append("step_not_tested")  # its "no step" is not an answer (as the report's "not tested")
        if doppler_level_words(d):  # the radar's Doppler puts its yaw off its tables: the
            # one direct evidence on an untrusted estimate, dropped by the fleet view (probe 52)
            row["flags"].append("doppler_off_tables")
        if status_kind(vr.final.status) == "degenerate":
            row["flags"].append("degenerate")
        if status_kind(vr.final.status) == "inconclusive":
            row["flags"].append("inconclusive")
    prior = None
    # an estimate its own status calls untrusted (out of the network's domain, degenerate, not converged) says
    # nothing about where the fleet's mounts are: it is left out of the fit (and said);
    # and a radar its own verdict says is off its tables beyond the tolerance (moved, or its tables wrong): a knocked
    # radar is no sample of the fleet's build, and a fleet too small for the outlier test to name it took it in
    # unsaid (probe 125: one radar 5 deg off in a fleet of 6, d2 122 at p 0.0026 against alpha 1e-3, moved the prior's
    # mean yaw 0.83 deg and its spread 0.39 -> 1.94 deg); one whose tables alone were wrong is one sample fewer
    left = {n: why for n, vr in results.items() if (why := prior_left_out(vr))}
    trusted = {n: vr for n, vr in results.items() if n not in left}
    for n, why in sorted(left.items()):
        rows[n]["fleet_test"] = {"left_out": f"not in the fleet prior: {why}"}
    if fit_prior and len(trusted) >= MIN_VEHICLES and T_ref is not None:
        names = sorted(trusted)
        own = {n: _own_estimate(results[n]) for n in names}
        prior = fit_fleet_prior(names, [own[n][0] for n in names], [own[n][1] for n in names], T_ref, alpha,
                                common_cov=common_cov([m.jobs[n]["job"] for n in names]),
                                unmeasured_cov=unmeasured_cov([own[n][1] for n in names], m.method),
                                sources={n: {"data": str(Path(m.jobs[n]["job"]["data"]).resolve()),
                                             "version": m.jobs[n]["job"]["version"],
                                             "vehicle": m.jobs[n]["job"]["vehicle"], "frames": results[n].n_frames,
                                             # the data, wherever the root is later (a copy, another mount)
                                             "digest": stored_digest(m.jobs[n]["job"]["out"]) or None}
                                         for n in names})
        for n in names:
            rows[n]["fleet_test"] = prior.tests[n]
            if n in prior.outliers:
                rows[n]["flags"].append("fleet_outlier")
    counts = {**m.counts(), "vehicles": len(rows)}
    for flag in ("out_of_tolerance", "drifted_in_drive", "step_not_tested", "fleet_outlier", "degenerate",
                 "inconclusive", "doppler_off_tables", "fit_change"):
        counts[flag + ("s" if flag == "fleet_outlier" else "")] = sum(flag in r["flags"] for r in rows.values())
    counts["batch"] = sum(r.get("mode") == "batch" for r in rows.values())
    counts["weak"] = sum(status_kind(r.get("status", "")) == "weak" for r in rows.values())
    pd = None if prior is None else prior.to_dict()
    summary = {
        "schema": SCHEMA, "out": str(base), "method": m.method, "seed": m.seed, "counts": counts,
        "step_test": m.method in STEP_METHODS,
        "design_mount": {"T_cam_radar": None if T_ref is None else T_ref.tolist(), "source": source},
        # --reference: the earlier export each vehicle it exported was checked against (rows' "reference" say which)
        "reference": next((j["job"]["calib"]["reference"] for j in m.jobs.values()
                           if (j["job"].get("calib") or {}).get("reference")), None),
        "fleet_prior": None if pd is None else {**{k: pd[k] for k in (
            "T_mean", "spread_std_cam", "mean_std_cam", "inliers", "outliers")},
            **({"unmeasured": True} if "unmeasured_cov_right_radar" in pd else {})},
        "vehicles": rows,
    }
    if fit_prior and prior is None and results:  # fleet_prior.json was missing without a word (probe 52)
        summary["fleet_prior_note"] = (
            f"no fleet prior (fleet_prior.json): {len(trusted)} of the {len(results)} done vehicle(s) have a trusted "
            f"estimate and a verdict other than recalibrate, fewer than the {MIN_VEHICLES} a fit needs" + (
                " (an inconclusive, degenerate or unconverged estimate says nothing about where the fleet's mounts "
                "are, nor does a radar to recalibrate)" if len(trusted) < len(results) else ""))
    return summary, prior


def prior_left_out(vr) -> str:
    """Why vehicle result ``vr`` is left out of the fleet prior's fit ("" when it is not): its status is untrusted
    (inconclusive, degenerate, not converged), or its verdict against its tables is "recalibrate"."""
    from hybrid_calib.calib.covariance import untrusted_status

    if why := untrusted_status(vr.final.status):
        return why
    if (vr.drift or {}).get("verdict_kind") == "recalibrate":
        return TO_RECALIBRATE
    return ""


# why a radar to recalibrate is not in the fleet prior (``prior_left_out``; summary.md's prior line names them by it)
TO_RECALIBRATE = ("its verdict is recalibrate (its mount is off its tables beyond the tolerance: a radar that moved is "
                  "no sample of the fleet's build)")


def _own_estimate(vr) -> tuple[np.ndarray, np.ndarray]:
    """(T (4, 4), cov (6, 6)) of what the vehicle's own drive measured: with a fleet prior applied, the same
    calibration without it (``drift.own_estimate``, ``calib.pipeline.calibrate_vehicle``), for a prior fitted on
    estimates that hold a prior counts that prior's information again and narrows on every reuse (probe 21 MED-4:
    roll spread 0.685 -> 0.606 -> 0.586 deg over three passes); else the result's estimate."""
    own = (vr.drift or {}).get("own_estimate") or {}
    try:
        T, cov = np.asarray(own["T_cam_radar"], np.float64), np.asarray(own["cov_right_radar"], np.float64)
        if T.shape == (4, 4) and cov.shape == (6, 6) and np.isfinite(T).all() and np.isfinite(cov).all():
            return T, cov
    except (KeyError, TypeError, ValueError):
        pass
    return vr.final.T, vr.final.cov


def write_summary(m: Manifest, plot: bool = True, alpha: float = 1e-3, notes: list[str] | None = None,
                  roots_left_out: dict[str, str] | None = None) -> dict:
    """Write ``summary.json``, ``summary.md``, ``fleet_prior.json`` (with >= 3 done vehicles) and
    ``fleet.png`` beside the manifest; returns the summary. ``notes``: sentences for the reader (which fleet
    prior a vehicle got and why; ``run_fleet``); ``roots_left_out``: root -> why none of its vehicles is a job."""
    summary, prior = build_summary(m, alpha=alpha)
    summary["notes"] = list(notes or []) + ([summary["fleet_prior_note"]] if "fleet_prior_note" in summary else [])
    summary["roots_left_out"] = dict(roots_left_out or {})
    base = m.path.parent
    if prior is not None:
        prior.save(base / "fleet_prior.json")
    if plot and any(r["state"] == "done" for r in summary["vehicles"].values()):
        from hybrid_calib.plots.fleet import plot_fleet

        summary["plot"] = str(plot_fleet(summary, base / "fleet.png").relative_to(base))
    save_json_atomic(base / "summary.json", summary)
    save_text_atomic(base / "summary.md", summary_markdown(summary))
    return summary


def drifted_words(s: dict) -> str:
    """"N drifted inside the drive", or, for a method that looks for no step (``summary["step_test"]`` false),
    that it was not looked for: a count of 0 read as "no radar moved". With what its test cannot see (probes 123,
    129): the hybrid's, a shift without a turn; the window's, a step in a drive's first frames."""
    if not s.get("step_test", True):
        return f"a step inside the drive not looked for (method {s['method']} has no step test: use hybrid or oracle)"
    if batch := s["counts"].get("batch", 0):  # probe 145: batch results read "too short for the window's test"
        moved = s["counts"].get("fit_change", 0)
        return (f"a step inside the drive not looked for on {batch} batch result(s) (batch mode runs no step test: "
                f"use the window); {moved} of them whose fit says the mount likely moved inside the drive (fit_change)")
    blind = s["counts"].get("step_not_tested", 0)
    said = [f"{blind} not tested: no step test could run on {'its drive' if blind == 1 else 'their drives'}, too short "
            "for the window's test and the radar mount monitor"] if blind else []
    if s.get("method") == "hybrid":
        said.append("the hybrid looks for a turn in yaw, with the radar mount monitor; a shift without a turn is not "
                    "looked for")
    elif s.get("method") == "oracle" and blind < s["counts"].get("done", 0):
        said.append("the window's step test sees no step in a drive's first frames, from which its long-run estimate "
                    "is first built: 15 by default")
    return f"{s['counts']['drifted_in_drive']} drifted inside the drive" + (f" ({'; '.join(said)})" if said else "")


def summary_markdown(s: dict) -> str:
    """The fleet view as a Markdown table (one row per vehicle) with counts and the fleet prior."""
    c = s["counts"]
    lines = [f"# Fleet calibration: {s['out']}", "",
             f"method {s['method']}, seed {s['seed']}; design mount: {s['design_mount']['source']}", "",
             f"**{n_vehicles(c['vehicles'])}**: {c['done']} done, {c['failed']} failed, {c['pending'] + c['running']} "
             f"not finished; {c['out_of_tolerance']} out of tolerance, {drifted_words(s)}, "
             f"{c['fleet_outliers']} fleet outlier(s), {c['degenerate']} degenerate, "
             f"{c.get('inconclusive', 0)} inconclusive (status: the estimate is not trusted), {c['weak']} weak"
             + (f"; {c['doppler_off_tables']} whose radar's Doppler puts its yaw off its tables (check those radars' "
                "yaw)" if c.get("doppler_off_tables") else "") + ".", ""]
    lines += [f"Note: {n}" for n in s.get("notes") or []] + ([""] if s.get("notes") else [])
    lines += [f"**Root left out** {r}: {why}" for r, why in (s.get("roots_left_out") or {}).items()] + (
        [""] if s.get("roots_left_out") else [])
    applied = sorted({(r.get("prior") or {}).get("file") for r in s["vehicles"].values()} - {None})
    if applied:
        given = [r["prior"] for r in s["vehicles"].values() if r.get("prior")]
        refused = sum(bool(p.get("refused")) for p in given)
        decided = sum(bool(p.get("decided")) for p in given)
        lines += [f"Fleet prior (from {', '.join(applied)}): given to {len(given)} of {n_vehicles(c['vehicles'])}, "
                  f"applied to {len(given) - refused}" + (f", not applied to {refused} (the drive's data disagree "
                                                           "with it: their verdicts say so)" if refused else "")
                  + (f"; on {decided} of them it holds most of an axis's information or moved the estimate by a "
                     "sigma of the drive's own (their verdicts name the axes; their verdicts against the tables are "
                     "the drive's own)" if decided else "") + ".", ""]
    fp = s.get("fleet_prior")
    if fp:
        sp = list(fp["spread_std_cam"].values())
        own = [list(r["std_cam"].values()) for n, r in s["vehicles"].items()
               if n in fp["inliers"] and r.get("std_cam")]
        floor = UNRESOLVED * np.median(own, axis=0) if own else np.zeros(6)
        shown = [f"{v:.{3 if i < 3 else 2}f}" if v >= floor[i] else "n.r." for i, v in enumerate(sp)]
        if fp.get("unmeasured"):  # pitch, roll, vertical (camera axes): a learned method's prior, not measured
            shown = ["n.m." if i in (0, 2, 4) else v for i, v in enumerate(shown)]
        out = [n for n, r in s["vehicles"].items() if str((r.get("fleet_test") or {}).get("left_out", "")).endswith(
            TO_RECALIBRATE)]
        lines += [f"Fleet prior: {len(fp['inliers'])} inliers"
                  + (f" (left out of the fit, to recalibrate: {', '.join(sorted(out))})" if out else "")
                  + "; spread (1 sigma, camera axes) rot "
                  f"{'/'.join(shown[:3])} deg, t {'/'.join(shown[3:])} cm; outliers (named): "
                  f"{', '.join(fp['outliers']) or 'none'}"
                  + (f" (n.r.: not resolved: the vehicles agree within their own 1-sigma along that axis, the spread "
                     f"fitted there is under {UNRESOLVED:g} of it)" if "n.r." in shown else "")
                  + (" (n.m.: not measured by a learned method: its pitch and roll are the network's prior of the "
                     "fleet's mount and its vertical offset the start's, alike for every vehicle; the priors it hands "
                     "out carry no information there)" if "n.m." in shown else ""), ""]
    if s.get("reference"):
        against = [n for n, r in s["vehicles"].items() if (r.get("reference") or {}).get("kind") == "export"]
        lines += [f"Checked against the earlier export {s['reference']} (--reference): "
                  f"{', '.join(against) or 'no vehicle'} (their \"verdict vs tables\" and offsets from the tables are "
                  "against the exported mount); the others against their tables.", ""]
    lines += ["No design mount (no vehicle has a frame): each vehicle's failure below." if  # probe 103
              str(s["design_mount"].get("source", "")).startswith("none") else
              "Offsets from the design mount, camera axes (rot x/y/z deg, t x/y/z cm), +- 1 sigma.", "",
              "| vehicle | state | status | rot offset [deg] | t offset [cm] | verdict vs tables | flags | note |",
              "|---|---|---|---|---|---|---|---|"]
    for jid, r in s["vehicles"].items():
        if r["state"] == "done":
            o, sd = list(r["offset_from_design"].values()), list(r["std_cam"].values())
            rot = " / ".join(f"{o[i]:+.2f}±{sd[i]:.2f}" for i in range(3))
            tr = " / ".join(f"{o[i]:+.1f}±{sd[i]:.1f}" for i in range(3, 6))
            status = r["status"].split(":")[0]
            # what the p-value is of (probe 91: a bare "p 0" in the column)
            note = f"chi2 vs reference p {r['drift']['p_value']:.2g}" if r["drift"].get("p_value") is not None else ""
            lines.append(f"| {md_cell(jid)} | done | {status} | {rot} | {tr} | {r['verdict']} | "
                         f"{', '.join(r['flags'])} | {note} |")
        else:
            lines.append(f"| {md_cell(jid)} | {r['state']} | | | | | | {md_cell((r.get('reason') or '')[:300])} |")
    return "\n".join(lines) + "\n"
