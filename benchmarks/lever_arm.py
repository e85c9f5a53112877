"""The radar's forward offset from its Doppler in turns (``calib.lever_arm``) on simulated drives: its error,
its reported std, and the two terms of its covariance, ``noise_scale`` and ``systematic_m``, fitted together.

    PYTHONPATH=. .venv/bin/python benchmarks/lever_arm.py --data ROOT [ROOT ...] --out OUT.json
        [--frames 30 60 100 200] [--trials 1] [--seed 0] [--fit] [--set noise_scale=1 systematic_m=0 ...]

Per drive, window of ``--frames`` consecutive frames (windows of a length start every max(length, 50)
frames) and trial, the truth (``T_cam_radar_static``) is perturbed the way a hybrid estimate is off
(translation uniform in +-``--trans`` m per radar axis, rotation normal with ``--rot`` deg std about radar
x / y / z), the fit runs from there on the window, and its ``rho_x`` is compared with what it measures,
``h @ xi`` (``xi = local(start, truth)``; ``err_raw_m``: against ``xi[3]`` alone). ``--fit`` (run with
``--set noise_scale=1 systematic_m=0`` on validation drives): the ``(noise_scale, systematic_m)`` whose
mean z^2 is closest to 1 at every window length (least squares of log mean z^2 over a grid); the check:
NEES and coverage with the stored values on other drives. Drives without turns (highway, straight) are
reported as not applied (``calib.lever_arm.refusal``).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from alignment_args import parser, start_error  # noqa: E402


def main(argv=None) -> int:
    from hybrid_calib.calib.ego_doppler import drive_sweeps
    from hybrid_calib.calib.lever_arm import RADAR_X, LeverArmConfig, fit, refusal
    from hybrid_calib.config import merge, parse_overrides, save_json_atomic
    from hybrid_calib.geometry import local, se3_exp
    from learned.dataset import open_frames

    ap = parser(__doc__, 0.3, "LeverArmConfig")
    ap.add_argument("--frames", type=int, nargs="+", default=[200], help="window lengths, frames")
    ap.add_argument("--fit", action="store_true", help="fit noise_scale and systematic_m (module doc)")
    args = ap.parse_args(argv)
    conf = merge(LeverArmConfig, parse_overrides(args.set))
    rng = np.random.default_rng(args.seed)
    rows = []
    for root in args.data:
        frames = open_frames(root, args.version)
        for vehicle, idx in sorted(frames.frames_by_vehicle().items()):
            all_sweeps, T_ego_cam = drive_sweeps(frames, idx, between=conf.sweeps)
            truth = np.asarray(frames[idx[0]].extras["T_cam_radar_static"], np.float64)
            for n, off in [(m, o) for m in args.frames for o in range(0, max(len(idx) - m, 0) + 1, max(m, 50))]:
                sweeps = [s for s in all_sweeps if off <= s.position < off + n]
                for t in range(args.trials):
                    xi = start_error(rng, args)
                    start = truth @ se3_exp(xi)
                    t0 = time.perf_counter()
                    a, why = fit(sweeps, start, T_ego_cam, conf)
                    xi = local(start, truth)
                    row = {"root": root.name, "vehicle": vehicle, "frames": len({s.position for s in sweeps}),
                           "offset": off, "trial": t,
                           "start_dx_m": float(xi[RADAR_X]), "seconds": time.perf_counter() - t0}
                    if a is None:
                        row["failed"] = why
                    else:
                        need = float(a.h @ xi)
                        row.update(dx_m=float(a.delta[1]), err_m=float(a.delta[1]) - need,
                                   err_raw_m=float(a.delta[1] - xi[RADAR_X]), h=[float(c) for c in a.h],
                                   std_m=a.dx_std, fit_var=float(a.cov[1, 1]) - a.terms[1] ** 2,
                                   noise_scale=a.terms[0],
                                   pairs=a.pairs, turning=a.turning,
                                   heading_bias_deg=float(np.degrees(a.delta[0])), applied=not refusal(a, conf))
                    rows.append(row)
                    print(f"{root.name}/{vehicle} frames {off}-{off + row['frames'] - 1} trial {t}: start dx "
                          f"{xi[RADAR_X]:+.3f} m -> " + (f"error {row['err_m']:+.3f} m (std {row['std_m']:.3f}, "
                                                          f"{a.pairs} pairs, {a.turning} turning)" if a else why),
                          flush=True)
    ok = [r for r in rows if "err_m" in r and r["applied"]]
    summary = {"config": vars(args) | {"data": [str(d) for d in args.data], "out": str(args.out)},
               "runs": len(rows), "failed": sum("err_m" not in r for r in rows),
               "not_applied": sum(("err_m" in r and not r["applied"]) for r in rows)}
    if ok:
        err = np.array([r["err_m"] for r in ok])
        var = np.array([r["std_m"] ** 2 for r in ok])
        z2 = err ** 2 / var
        summary.update(applied=len(ok), rmse_m=float(np.sqrt(np.mean(err ** 2))),
                       mean_abs_m=float(np.mean(np.abs(err))),
                       median_abs_m=float(np.median(np.abs(err))), mean_std_m=float(np.mean(np.sqrt(var))),
                       nees=float(np.mean(z2)), inside_95=float(np.mean(z2 < 3.841)),
                       start_rmse_m=float(np.sqrt(np.mean([r["start_dx_m"] ** 2 for r in ok]))),
                       rmse_raw_m=float(np.sqrt(np.mean([r["err_raw_m"] ** 2 for r in ok]))),
                       h_median=np.median([r["h"] for r in ok], axis=0).tolist(),
                       seconds_median=float(np.median([r["seconds"] for r in rows])))
        by_len = {}
        for n in sorted({r["frames"] for r in ok}):
            e = np.array([r["err_m"] for r in ok if r["frames"] == n])
            z = np.array([r["err_m"] ** 2 / r["std_m"] ** 2 for r in ok if r["frames"] == n])
            by_len[str(n)] = {"runs": len(e), "rmse_m": float(np.sqrt(np.mean(e ** 2))),
                              "mean_abs_m": float(np.mean(np.abs(e))), "median_abs_m": float(np.median(np.abs(e))),
                              "mean_std_m": float(np.mean([r["std_m"] for r in ok if r["frames"] == n])),
                              "nees": float(np.mean(z)), "inside_95": float(np.mean(z < 3.841))}
        summary["by_length"] = by_len
        if args.fit:
            summary["fit"] = _fit(ok)
        per = {}
        for name in sorted({r["root"] for r in rows}):
            sel = [r for r in ok if r["root"] == name]
            if not sel:
                per[name] = {"runs": sum(r["root"] == name for r in rows), "applied": 0}
                continue
            e = np.array([r["err_m"] for r in sel])
            z = np.array([r["err_m"] ** 2 / r["std_m"] ** 2 for r in sel])
            per[name] = {"runs": sum(r["root"] == name for r in rows), "applied": len(sel),
                         "rmse_m": float(np.sqrt(np.mean(e ** 2))), "nees": float(np.mean(z)),
                         "inside_95": float(np.mean(z < 3.841)),
                         "mean_std_m": float(np.mean([r["std_m"] for r in sel]))}
        summary["per_root"] = per
    summary["rows"] = rows
    save_json_atomic(args.out, summary)
    print(json.dumps({k: v for k, v in summary.items() if k not in ("rows", "config")}, indent=1))
    return 0


def _fit(rows: list[dict]) -> dict:
    """(noise_scale, systematic_m) making mean z^2 ~ 1 at every window length (module doc); each row's ``fit_var``
    scales with the ``noise_scale`` it was measured with (``LeverArmConfig.terms``)."""
    e2 = np.array([r["err_m"] ** 2 for r in rows])
    v = np.array([r["fit_var"] / r["noise_scale"] for r in rows])
    n = np.array([r["frames"] for r in rows])
    best = None
    for k in np.linspace(0.5, 6.0, 111):
        for s in np.linspace(0.0, 0.08, 161):
            g = [float(np.mean(e2[n == q] / (k * v[n == q] + s ** 2))) for q in np.unique(n)]
            c = float(np.sum(np.log(g) ** 2))
            if best is None or c < best[0]:
                best = (c, k, s, g)
    return {"noise_scale": round(best[1], 3), "systematic_m": round(best[2], 4),
            "mean_z2_by_length": dict(zip([str(q) for q in np.unique(n)], best[3]))}


if __name__ == "__main__":
    sys.exit(main())
