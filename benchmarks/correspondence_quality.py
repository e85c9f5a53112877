"""How good, and how honestly scaled, are the correspondences the network exports for the hybrid?

Reads an evaluation folder written by ``hybrid-calib evaluate`` on a simulated root (``frames/*.npz``
measurement files, ``factors.io``, with the rows of the last iteration) and the simulator's radar
truth of the same root.
Every exported row is matched back to its radar point (same coordinates), and so to the true
reflector that produced it; the reflector projected by the true extrinsic is the pixel the row
should have found. Per row:

- ``err_px``: |exported pixel - true pixel| (model-input pixels);
- ``r2 = err_px^2 / sigma_px^2``: chi-square with 2 dof if ``sigma_px`` is honest (mean 2; 95 % of
  rows below 5.99);
- three baselines on the same rows: the recorded radar point (z = 0) projected by the start T_init
  (what the rows improve on), by the network's own final estimate (what a row would be if it only
  restated the estimate), and by the true extrinsic (the elevation-ambiguity floor: a 2D radar
  does not know the reflector's height).

Clutter and ghost detections (no true reflector) are counted as outliers and reported separately.
Errors (and the baselines') are medians over the inlier rows. Prints a markdown table per confidence
bin and the ``sigma_scale`` that would make the inliers' median r2 match the chi-square median
(1.386); writes ``--out`` as JSON.

    PYTHONPATH=. .venv/bin/python benchmarks/correspondence_quality.py --eval EVAL --data TEST
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

CHI2_2_MEDIAN = 1.3862943611198906  # chi-square, 2 dof: median
CHI2_2_95 = 5.991464547107979


def collect(eval_dir: Path, roots: list[str], version: str) -> dict[str, np.ndarray]:
    """Per exported row: err_px, sigma_px, confidence, err_init_px, err_own_px, err_flat_px, real (bool)."""
    from scipy.spatial import cKDTree
    from tqdm import tqdm

    from hybrid_calib.geometry import project_points
    from learned.dataset import open_roots

    frames = open_roots(roots, version, lidar=False)
    by_token = {ref.camera_sd["token"]: i for i, ref in enumerate(frames.frames)}
    keys = ("err_px", "sigma_px", "confidence", "err_init_px", "err_own_px", "err_flat_px", "real")
    cols: dict[str, list] = {k: [] for k in keys}
    files = sorted((eval_dir / "frames").glob("*.npz"))
    if not files:
        raise SystemExit(f"no exported frames in {eval_dir / 'frames'}: run hybrid-calib evaluate first")
    for path in tqdm(files, desc="rows"):
        z = np.load(path, allow_pickle=False)
        token = str(z["frame_id"])
        if token not in by_token:
            raise SystemExit(f"{path.name}: camera token {token} is not in {roots}; pass the root it was evaluated on")
        pts, pix, K = z["points_radar"], z["pixels"], z["K"]
        if not len(pts):
            continue
        frame = frames[by_token[token]]
        ex = frame.extras
        with np.load(ex["radar_truth_path"]) as t:
            true_xyz, kind = t["true_xyz"], t["kind"]
        rows = np.asarray(ex["radar_rows"], np.int64)
        dist, j = cKDTree(frame.radar_points).query(pts)
        if np.any(dist > 1e-3):
            raise SystemExit(f"{path.name}: exported points do not match the radar sweep of {token}")
        T_true = np.asarray(frame.T_cam_radar, np.float64)
        true_uv, depth = project_points(K, T_true, true_xyz[rows[j]])
        real = (kind[rows[j]] == 0) & (depth > 0.5) & np.all(np.isfinite(true_uv), 1)
        own_uv, _ = project_points(K, z["T_iters"][-1], pts)
        init_uv, _ = project_points(K, z["T_start"], pts)
        cols["err_init_px"].append(np.linalg.norm(init_uv - true_uv, axis=1))
        flat_uv, _ = project_points(K, T_true, pts)
        cols["err_px"].append(np.linalg.norm(pix - true_uv, axis=1))
        cols["err_own_px"].append(np.linalg.norm(own_uv - true_uv, axis=1))
        cols["err_flat_px"].append(np.linalg.norm(flat_uv - true_uv, axis=1))
        cols["sigma_px"].append(z["sigma_px"])
        cols["confidence"].append(z["confidence"])
        cols["real"].append(real)
    return {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}


def summarise(rows: dict[str, np.ndarray], bins=(0.1, 0.3, 0.5, 0.7, 1.01)) -> dict:
    real = rows["real"].astype(bool)
    out = {"rows": int(len(real)), "outlier_fraction": float(1 - real.mean()) if len(real) else 0.0, "bins": []}
    edges = list(zip(bins[:-1], bins[1:])) + [(bins[0], bins[-1])]
    for lo, hi in edges:
        m = (rows["confidence"] >= lo) & (rows["confidence"] < hi)
        mi = m & real
        if not mi.any():
            continue
        r2 = (rows["err_px"][mi] / rows["sigma_px"][mi]) ** 2
        out["bins"].append({
            "confidence": [lo, min(hi, 1.0)], "rows": int(m.sum()), "outliers": float(1 - real[m].mean()),
            "median_err_px": float(np.median(rows["err_px"][mi])),
            "median_err_init_px": float(np.median(rows["err_init_px"][mi])),
            "median_err_own_px": float(np.median(rows["err_own_px"][mi])),
            "median_err_flat_px": float(np.median(rows["err_flat_px"][mi])),
            "median_sigma_px": float(np.median(rows["sigma_px"][mi])),
            "mean_r2": float(r2.mean()), "inside_95": float(np.mean(r2 < CHI2_2_95)),
            "sigma_scale_fit": float(np.sqrt(np.median(r2) / CHI2_2_MEDIAN)),
        })
    return out


def markdown(s: dict) -> str:
    lines = [f"{s['rows']} exported rows, {100 * s['outlier_fraction']:.1f} % from clutter/ghosts (no reflector)", "",
             "| confidence | rows | outliers | median err (px) | start T_init | network estimate | true extrinsic, z=0 "
             "| median sigma_px | inliers inside 95 % | sigma_scale fit |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for b in s["bins"]:
        lo, hi = b["confidence"]
        lines.append(f"| {lo:.1f}-{hi:.1f} | {b['rows']} | {100 * b['outliers']:.1f} % | {b['median_err_px']:.2f} | "
                     f"{b['median_err_init_px']:.2f} | {b['median_err_own_px']:.2f} | {b['median_err_flat_px']:.2f} | "
                     f"{b['median_sigma_px']:.2f} | {100 * b['inside_95']:.1f} % | {b['sigma_scale_fit']:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--eval", required=True, type=Path, help="folder written by hybrid-calib evaluate")
    ap.add_argument("--data", required=True, nargs="+", help="the simulated root(s) it was evaluated on")
    ap.add_argument("--version", default="v1.0-sim")
    ap.add_argument("--out", type=Path, default=None, help="JSON summary (default EVAL/correspondence_quality.json)")
    ap.add_argument("--fit-into", type=Path, default=None, metavar="CKPT",
                    help="store the fitted sigma_scale (all confidences) in this checkpoint's export overrides; "
                         "fit on validation scenes, never on the test split")
    args = ap.parse_args(argv)
    s = summarise(collect(args.eval, args.data, args.version))
    print(markdown(s))
    if args.fit_into is not None:
        from learned.checkpoint import set_export_overrides

        used = json.loads((args.eval / "export_config.json").read_text())["eval"].get("export", {})
        scale = float(used.get("sigma_scale", 1.0)) * s["bins"][-1]["sigma_scale_fit"]
        set_export_overrides(args.fit_into, {"sigma_scale": scale},
                             f"fitted on {s['rows']} rows of {args.eval} by benchmarks/correspondence_quality.py")
        print(f"sigma_scale {scale:.3f} -> {args.fit_into}")
    out = args.out or args.eval / "correspondence_quality.json"
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(json.dumps(s, indent=2))
    tmp.replace(out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
