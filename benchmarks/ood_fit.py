"""Fit the network's out-of-domain score on simulated validation drives, measure it, and store it in the checkpoint.

    PYTHONPATH=. python benchmarks/ood_fit.py --checkpoint CKPT --data VAL1 VAL2 VAL3 \
        --heldout HOLD1 HOLD2 HOLD3 [--real REAL_ROOT --real-version v1.0-mini --real-seeds 0 1 2] \
        --out OUTDIR [--fit-into]

1. The network runs on every frame of the ``--data`` roots (in-domain: simulated VALIDATION drives,
   never the test drives) from starts drawn in the checkpoint's range (one per frame and fit seed);
   each candidate feature set of ``learned.ood`` (descriptor, signals, all) is fitted on those frames
   (``learned.ood.fit_ood``: half fits the density, half the threshold).
2. Each candidate is measured on the ``--heldout`` roots (clean: the fraction flagged is the false
   alarm rate), on the same frames corrupted (``hybrid_calib.hybrid.ood.CORRUPTIONS``: pure-noise
   image, another frame's radar, blank depth), and, with ``--real``, on a real root (its tables are
   the reference; ``--real-depth``, default lidar-densified): fraction flagged, AUROC against the
   clean held-out frames, the Spearman correlation of the score with the rotation error and NEES,
   and the NEES / 95 % coverage of the frames kept and flagged.
3. Candidates are (feature set, threshold quantile) pairs (``--quantiles``). The one kept flags the
   largest mean fraction of corrupted frames among those whose held-out false-alarm rate is <=
   ``--max-false-alarm`` (the real root is measured, never used to choose). With ``--fit-into`` it is
   written into the checkpoint's ``export["ood"]`` with this command, the roots and the frame counts
   (``learned.checkpoint.set_export_overrides``).

Writes ``OUT/ood.json`` (every number) and prints a summary table.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def auroc(neg: np.ndarray, pos: np.ndarray) -> float:
    """P(score of a positive > score of a negative) (ties count half); NaN when a side is empty."""
    neg, pos = np.asarray(neg, float), np.asarray(pos, float)
    if not len(neg) or not len(pos):
        return float("nan")
    gt = (pos[:, None] > neg[None, :]).mean()
    eq = (pos[:, None] == neg[None, :]).mean()
    return float(gt + 0.5 * eq)


def spearman(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < 3:
        return float("nan")
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def _group(recs: list[dict], scores: np.ndarray) -> dict:
    from hybrid_calib.metrics import consistency

    nees = np.array([r["nees"] for r in recs])
    rot = np.array([r["rot_deg"] for r in recs])
    flag = scores > 1.0
    out = {"frames": len(recs), "n_flagged": int(flag.sum()),
           "flagged_fraction": float(flag.mean()) if len(recs) else 0.0,
           "score_median": float(np.median(scores)) if len(recs) else float("nan"),
           "spearman_score_rot": spearman(scores, rot), "spearman_score_nees": spearman(scores, nees)}
    for name, m in (("all", np.ones_like(flag)), ("kept", ~flag), ("flagged", flag)):
        c = consistency(nees[m])  # None figures for a group without frames
        out[name] = {"frames": int(m.sum()), "rot_mean_deg": float(rot[m].mean()) if m.any() else None,
                     "nees_mean": c["nees_mean"], "inside_95": c["coverage_95"]}
    return out


def _describe(root: Path) -> dict:
    """A root as provenance: its path and, for a simulated one, what made it (``sim_config.json``)."""
    d = {"path": str(root)}
    cfg = Path(root) / "sim_config.json"
    if cfg.is_file():
        c = json.loads(cfg.read_text())
        d.update({k: c.get(k) for k in ("scenario", "seed", "vehicles", "frames", "image_scale")})
    return d


def _records(runner_of, roots, version, seeds, corruption="", lidar=False):
    from hybrid_calib.hybrid.drives import open_drives
    from hybrid_calib.hybrid.loop import HybridConfig
    from hybrid_calib.hybrid.ood import ood_passes

    recs = []
    for root in roots:
        frames, drives = open_drives(root, version, HybridConfig(), lidar=lidar)
        runner = runner_of(root, frames)
        for d in drives.values():
            for s in seeds:
                recs += ood_passes(runner, d.indices, d.base, runner.range, s, d.vehicle, corruption)
    return recs


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--checkpoint", required=True)
    p.add_argument("--data", nargs="+", required=True, type=Path, help="simulated VALIDATION roots (fit)")
    p.add_argument("--heldout", nargs="+", required=True, type=Path, help="other simulated roots (measure)")
    p.add_argument("--version", default="v1.0-sim")
    p.add_argument("--real", type=Path, help="a real nuScenes root to measure on (never used to choose)")
    p.add_argument("--real-version", default="v1.0-mini")
    p.add_argument("--real-depth", default="lidar-densified")
    p.add_argument("--real-seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--fit-seeds", nargs="+", type=int, default=[0, 1], help="one start per frame per seed")
    p.add_argument("--features", default="auto", help="auto (choose by the corruptions) | descriptor | signals | all")
    p.add_argument("--k", type=int, default=16, help="principal directions of the density model")
    p.add_argument("--quantiles", nargs="+", type=float, default=[0.9, 0.95, 0.99],
                   help="candidate thresholds: quantiles of d2 on the calibration half of the fit frames")
    p.add_argument("--max-false-alarm", type=float, default=0.05)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--device", default="cpu", help="torch device of the network (cpu, cuda)")
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--fit-into", action="store_true", help="write the chosen model into the checkpoint")
    a = p.parse_args(argv)

    from hybrid_calib.config import save_json_atomic
    from hybrid_calib.hybrid.network import NetworkRunner
    from hybrid_calib.hybrid.ood import CORRUPTIONS
    from learned.checkpoint import set_export_overrides
    from learned.ood import FEATURE_SETS, fit_ood

    a.out.mkdir(parents=True, exist_ok=True)

    def runner_of(depth):
        def make(root, frames):
            tag = Path(root).name + "-" + (depth or "ckpt")
            return NetworkRunner(a.checkpoint, frames, depth, a.out / "cache" / tag, a.out / "depth" / tag, a.threads,
                                 device=a.device)
        return make

    from hybrid_calib.hybrid.drives import trained_depth
    from learned.depth import needs_lidar

    lidar = needs_lidar(trained_depth(a.checkpoint))  # its own depth path reads the LiDAR
    fit = _records(runner_of(""), a.data, a.version, a.fit_seeds, lidar=lidar)
    if not fit:
        raise SystemExit(f"no usable frame in {a.data} for {a.checkpoint}: see the skipped frames above")
    feats = {k: np.stack([r[k] for r in fit]) for k in ("descriptor", "signals")}
    held = {"clean": _records(runner_of(""), a.heldout, a.version, [100], lidar=lidar)}
    for c in CORRUPTIONS:
        held[c] = _records(runner_of(""), a.heldout, a.version, [100], corruption=c, lidar=lidar)
    if a.real is not None:
        held["real"] = _records(runner_of(a.real_depth), [a.real], a.real_version, a.real_seeds, lidar=True)

    cmd = "PYTHONPATH=. python benchmarks/ood_fit.py " + " ".join(sys.argv[1:] if argv is None else argv)
    prov = {"command": cmd, "roots": [_describe(d) for d in a.data], "version": a.version, "fit_seeds": a.fit_seeds,
            "frames": len(fit), "tokens": sorted({r["token"] for r in fit})}
    candidates = {}
    for fs, q in [(f, q) for f in ([a.features] if a.features != "auto" else FEATURE_SETS) for q in a.quantiles]:
        m = fit_ood(feats, fs, a.k, q, fitted=prov)
        scores = {g: m.score({k: np.stack([r[k] for r in recs]) for k in ("descriptor", "signals")})
                  if recs else np.zeros(0) for g, recs in held.items()}
        res = {g: _group(held[g], s) for g, s in scores.items()}
        for g in held:
            if g != "clean":
                res[g]["auroc_vs_clean"] = auroc(scores["clean"], scores[g])
        candidates[f"{fs}@{q:g}"] = {
            "model": m, "results": res, "false_alarm": res["clean"]["flagged_fraction"],
            "worst_corruption_auroc": min(res[c]["auroc_vs_clean"] for c in CORRUPTIONS),
            "corruption_flagged_mean": float(np.mean([res[c]["flagged_fraction"] for c in CORRUPTIONS]))}
    ok = {k: v for k, v in candidates.items() if v["false_alarm"] <= a.max_false_alarm} or candidates
    chosen = max(ok, key=lambda k: ok[k]["corruption_flagged_mean"])
    report = {"checkpoint": a.checkpoint, "command": cmd, "fit_frames": len(fit), "chosen": chosen,
              "candidates": {k: {kk: vv for kk, vv in v.items() if kk != "model"} for k, v in candidates.items()}}
    save_json_atomic(a.out / "ood.json", report)
    for fs, v in candidates.items():
        print(f"== {fs}{' (chosen)' if fs == chosen else ''}: false alarm {v['false_alarm']:.3f}, corrupted frames "
              f"flagged {v['corruption_flagged_mean']:.3f}, worst corruption AUROC {v['worst_corruption_auroc']:.3f}")
        for g, r in v["results"].items():
            kept, all_ = r["kept"], r["all"]
            print(f"  {g:15s} n={r['frames']:4d} flagged={r['flagged_fraction']:.2f} "
                  f"AUROC={r.get('auroc_vs_clean', float('nan')):.3f} median score={r['score_median']:.2f} "
                  f"rho(score,rot)={r['spearman_score_rot']:.2f} NEES all={all_['nees_mean']} "
                  f"kept={kept['nees_mean']} inside95 all={all_['inside_95']} kept={kept['inside_95']}")
    if a.fit_into:
        m = candidates[chosen]["model"]
        summary = {g: {"flagged_fraction": r["flagged_fraction"], "auroc_vs_clean": r.get("auroc_vs_clean")}
                   for g, r in candidates[chosen]["results"].items()}
        m_dict = m.to_dict()
        m_dict["fitted"]["measured"] = summary
        set_export_overrides(a.checkpoint, {"ood": m_dict},
                             f"{cmd}: out-of-domain density model ({chosen}) fitted on {len(fit)} simulated "
                             f"validation frames of {[str(d) for d in a.data]}; measured in {a.out / 'ood.json'}")
        print(f"wrote export.ood ({chosen}) into {a.checkpoint}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
