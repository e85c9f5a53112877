"""Issue 11's real-scene tables in one command: the pure network per frame (R1, R2) and the hybrid
and pure-avg from R1 starts, on a real nuScenes root, errors against the tables' extrinsic.

    PYTHONPATH=. python benchmarks/real_scene.py --data ROOT --version V --out OUT \
        [--checkpoint-r1 CKPT] [--checkpoint-r2 CKPT] [--seeds 5] [--depth lidar-densified] \
        [--split test --split-by time [--test-fraction 0.2 --val-fraction 0.1 --gap-frames 3]]

Frames: every frame of the root (``--split all``, the default: a held-out real scene), or one part of
the split flags (``learned.dataset.SplitConfig``; ``--split test --split-by time``: the end of each
scene behind a guard gap, the frames a checkpoint fine-tuned with ``split.by=time`` never saw).
``--split train`` (or ``all`` on the scene a checkpoint was fine-tuned on) gives TRAINING figures; the
output says which.

1. Pure network, per frame (``learned.evaluate``, as ``hybrid-calib evaluate``): for each range R1 /
   R2 and each of ``--seeds`` seeds (1000, 1001, ...), one start per frame drawn in the range around
   the tables' extrinsic; pooled over seeds: start and after errors (rotation mean / roll / pitch /
   yaw deg, translation per axis cm), mean NEES and the share inside the 95 % ellipsoid of the
   exported covariance (with the checkpoint's fitted ``cov_scale``), and per axis the share of starts
   the network made worse.
2. Hybrid, pure-avg and pure from R1 starts (``hybrid_calib.compare``, the R1 checkpoint): one trial
   per seed (the vehicle's start: ``perturbation.vehicle_start``); per trial the status, the error, the
   reported 3-sigma per axis (right tangent, radar frame) and a flag when an ``ok`` status has an
   error outside its 3-sigma on any axis.
3. Issue 11's targets checked. Writes ``OUT/real_scene.md`` (markdown tables) and
   ``OUT/real_scene.json``; rerunning reuses the finished evaluations and trials (caches under OUT).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

RANGES = ("R1", "R2")
AXES_ROT = ("roll_deg", "pitch_deg", "yaw_deg")
AXES_T = ("x_cm", "y_cm", "z_cm")
TANGENT = ("rot x", "rot y", "rot z", "t x", "t y", "t z")  # right tangent, radar frame [rad, m]


def _frames_label(split: str, split_options: dict) -> str:
    if split == "all":
        return ("all frames (TRAINING figures for a checkpoint fine-tuned on this scene; held out only for a scene "
                "no checkpoint was trained on)")
    by = split_options.get("by", "scene")
    kind = "TRAINING figures" if split == "train" else "frames not trained on"
    return f"split {split} (by {by}, {json.dumps(split_options, sort_keys=True)}): {kind}"


def pure_per_frame(data: Path, version: str, ckpt: Path, rng: str, seeds: int, split: str, split_options: dict,
                   depth: str, out: Path, threads: int) -> dict:
    """Section 1 for one range: the network alone, one start per frame and seed, pooled."""
    from hybrid_calib.metrics import CHI2_6_95
    from hybrid_calib.metrics import nees as nees_of
    from learned.checkpoint import load_model
    from learned.dataset import open_frames
    from learned.evaluate import evaluate, tangent_errors

    model, meta = load_model(ckpt)
    frames = open_frames(data, version, lidar=True)
    start, after, xi, covs, tokens = [], [], [], [], []
    for k in range(seeds):
        conf = {"method": "pure", "perturbation": rng, "split": split, "split_options": split_options,
                "seed": 1000 + k, "depth": depth, "export": dict(meta.export), "threads": threads,
                "depth_cache": str(out / "depth-cache")}
        res = evaluate(model, frames, conf, out / f"pure-{rng}" / f"seed-{1000 + k}", checkpoint=ckpt,
                       progress=False)
        start += res.per_frame["initial"]
        after += res.per_frame["pure"]
        tokens += res.tokens
        e, c = tangent_errors(out / f"pure-{rng}" / f"seed-{1000 + k}")
        xi.append(e)
        covs.append(c)
    xi, covs = np.concatenate(xi), np.concatenate(covs)
    nees = nees_of(xi, covs)  # the one NEES (metrics.nees: refuses a covariance that is not one)
    keys = ("rot_mean_deg", *AXES_ROT, "trans_mean_cm", *AXES_T)
    mean = {name: {k: float(np.mean([e[k] for e in errs])) for k in keys}
            for name, errs in (("start", start), ("after", after))}
    worse = {k: float(np.mean([a[k] > s[k] for s, a in zip(start, after)])) for k in (*AXES_ROT, *AXES_T)}
    return {"range": rng, "checkpoint": str(ckpt), "seeds": seeds, "n": len(after), "frames": len(set(tokens)),
            "start": mean["start"], "after": mean["after"], "worse_fraction": worse,
            "nees_mean": float(nees.mean()), "nees_median": float(np.median(nees)),
            "inside_95": float(np.mean(nees < CHI2_6_95)), "cov_scale": meta.export.get("cov_scale", 1.0)}


def _trial_row(vr) -> dict:
    from hybrid_calib.calib.covariance import untrusted_status
    from hybrid_calib.geometry import local

    e = local(vr.truth_T, vr.final.T)  # error in the right tangent of the tables' extrinsic
    sd = np.sqrt(np.clip(np.diag(vr.final.cov), 0.0, None))
    outside = [TANGENT[i] for i in range(6) if abs(e[i]) > 3.0 * sd[i]]
    scale = np.array([np.degrees(1.0)] * 3 + [100.0] * 3)  # deg, cm
    # a result its status trusts ("ok" or "weak": weak names poorly observed axes, with their sigma); only "ok" was
    # flagged, and with the vertical offset prior-pinned every result reads "weak": the gate could not fail (probe 51)
    ok = not untrusted_status(vr.final.status)
    return {"seed": vr.start["seed"] if vr.start else None, "status": vr.final.status, "frames": vr.n_frames,
            "rot_mean_deg": vr.error["rot_mean_deg"], "trans_norm_cm": vr.error["trans_norm_cm"],
            "nees": vr.error["nees"], "error_tangent": (e * scale).tolist(), "three_sigma": (3 * sd * scale).tolist(),
            "outside_3sigma": outside, "flag_ok_outside_3sigma": bool(ok and outside)}


def loop_methods(data: Path, version: str, ckpt: Path, seeds: int, split: str, split_options: dict, depth: str,
                 out: Path, threads: int, methods: tuple[str, ...]) -> dict:
    """Section 2: the methods from R1 starts, one trial per seed."""
    from hybrid_calib.compare import compare, load_trials

    hybrid = {"checkpoint": str(ckpt), "split": split, "split_options": split_options, "depth": depth,
              "threads": threads, "depth_cache": str(out / "depth-cache")}
    conf = {"range": "R1", "trials": seeds, "seed": 0, "methods": methods, "hybrid": hybrid}
    summary = compare([data], version, out / "compare-R1", conf, progress=False)
    res = {}
    for m in methods:
        rows = [_trial_row(vr) for vr in load_trials(out / "compare-R1", m, seeds)]
        s = summary.methods[m]
        res[m] = {"mean": s.mean, "median": s.median, "consistency": s.consistency,
                  "not_ok_fraction": s.not_ok_fraction, "inconclusive_fraction": s.inconclusive_fraction,
                  "ms_per_frame": s.ms_per_frame,
                  "frames_mean": s.frames_mean, "trials": rows,
                  "flagged": sum(r["flag_ok_outside_3sigma"] for r in rows)}
    return res


def targets(pure: dict, loop: dict) -> dict:
    """Issue 11's targets on this data (value, met)."""
    t = {}
    if "R1" in pure:
        a = pure["R1"]["after"]
        t["R1 rotation mean <= 1.0 deg"] = (a["rot_mean_deg"], a["rot_mean_deg"] <= 1.0)
        t["R1 yaw <= 1.0 deg"] = (a["yaw_deg"], a["yaw_deg"] <= 1.0)
    if "R2" in pure:
        s, a = pure["R2"]["start"], pure["R2"]["after"]
        t["R2 translation not worse than the start on any axis (means)"] = (
            {k: [round(s[k], 2), round(a[k], 2)] for k in AXES_T}, all(a[k] <= s[k] for k in AXES_T))
    for r, p in pure.items():
        t[f"{r} mean NEES <= 12"] = (p["nees_mean"], p["nees_mean"] <= 12)
        t[f"{r} >= 85 % inside the 95 % ellipsoid"] = (p["inside_95"], p["inside_95"] >= 0.85)
    if "hybrid" in loop:
        h = loop["hybrid"]
        inconclusive = h["inconclusive_fraction"] == 1.0  # the word: not "every status weak or worse"
        t["hybrid rotation mean <= 0.3 deg (or every trial inconclusive)"] = (
            h["mean"]["rot_mean_deg"], h["mean"]["rot_mean_deg"] <= 0.3 or inconclusive)
    for m, r in loop.items():
        t[f"{m}: no trusted status (ok or weak) with the error outside 3-sigma"] = (r["flagged"], r["flagged"] == 0)
    return t


def markdown(rep: dict) -> str:
    L = [f"# Real scene: {rep['data']} ({rep['version']})", "", f"Command: `{rep['command']}`", "",
         f"Frames: {rep['frames_label']}. Errors against the tables' extrinsic (itself uncertain to a few tenths "
         f"of a degree). Depth: {rep['depth']}.", "",
         "## Pure network, one start per frame and seed", "",
         "| range | checkpoint | starts (frames x seeds) | start rot mean / yaw (deg) | after rot mean / roll / "
         "pitch / yaw (deg) | start x / y / z (cm) | after x / y / z (cm) | mean NEES | inside 95 % |",
         "|---|---|---|---|---|---|---|---|---|"]
    for r, p in rep["pure"].items():
        s, a = p["start"], p["after"]
        L.append(f"| {r} | {Path(p['checkpoint']).name} | {p['n']} ({p['frames']} x {p['seeds']}) | "
                 f"{s['rot_mean_deg']:.2f} / {s['yaw_deg']:.2f} | {a['rot_mean_deg']:.2f} / {a['roll_deg']:.2f} / "
                 f"{a['pitch_deg']:.2f} / {a['yaw_deg']:.2f} | {s['x_cm']:.1f} / {s['y_cm']:.1f} / {s['z_cm']:.1f} | "
                 f"{a['x_cm']:.1f} / {a['y_cm']:.1f} / {a['z_cm']:.1f} | {p['nees_mean']:.1f} | "
                 f"{100 * p['inside_95']:.0f} % |")
    L += ["", "Share of starts the network made worse, per axis (roll / pitch / yaw / x / y / z): "]
    for r, p in rep["pure"].items():
        w = p["worse_fraction"]
        L.append(f"- {r}: " + " / ".join(f"{100 * w[k]:.0f} %" for k in (*AXES_ROT, *AXES_T)))
    if rep["loop"]:
        L += ["", f"## From R1 starts ({Path(rep['checkpoint_r1']).name}), one trial per seed", "",
              "| method | trials | rot mean / roll / pitch / yaw (deg) | trans mean / x / y / z (cm) | mean NEES | "
              "inside 95 % | inconclusive | trusted outside 3-sigma |", "|---|---|---|---|---|---|---|---|"]
        for m, r in rep["loop"].items():
            e, c = r["mean"], r["consistency"]
            L.append(f"| {m} | {len(r['trials'])} | {e['rot_mean_deg']:.2f} / {e['roll_deg']:.2f} / "
                     f"{e['pitch_deg']:.2f} / {e['yaw_deg']:.2f} | {e['trans_mean_cm']:.1f} / {e['x_cm']:.1f} / "
                     f"{e['y_cm']:.1f} / {e['z_cm']:.1f} | {c['nees_mean']:.1f} | {100 * c['coverage_95']:.0f} % | "
                     f"{100 * r['inconclusive_fraction']:.0f} % | {r['flagged']} |")
        L += ["", "Per trial: status, error and reported 3-sigma in the right tangent (rot x/y/z deg, t x/y/z cm, "
              "radar frame); FLAG = a trusted status (ok or weak) with the error outside its 3-sigma.", "",
              "| method | seed | frames | status | rot mean (deg) | |t| (cm) | error | 3-sigma | flag |",
              "|---|---|---|---|---|---|---|---|---|"]
        for m, r in rep["loop"].items():
            for t in r["trials"]:
                err = " ".join(f"{v:.2f}" for v in t["error_tangent"])
                sig = " ".join(f"{v:.2f}" for v in t["three_sigma"])
                out3 = ", ".join(t["outside_3sigma"])
                flag = f"FLAG ({out3})" if t["flag_ok_outside_3sigma"] else (f"untrusted; outside: {out3}" if out3
                                                                             else "")
                status = t["status"].split(":")[0].split(" (")[0]  # the kind; the full text is in the JSON
                L.append(f"| {m} | {t['seed']} | {t['frames']} | {status} | {t['rot_mean_deg']:.2f} | "
                         f"{t['trans_norm_cm']:.1f} | {err} | {sig} | {flag} |")
    L += ["", "## Issue 11 targets", "", "| target | value | met |", "|---|---|---|"]
    for name, (v, ok) in rep["targets"].items():
        val = f"{v:.3f}" if isinstance(v, float) else json.dumps(v)
        L.append(f"| {name} | {val} | {'yes' if ok else 'NO'} |")
    return "\n".join(L) + "\n"


def main(argv=None) -> int:
    from hybrid_calib.commands import add_split_arguments, split_overrides

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="real nuScenes root (VERSION/, samples/)")
    p.add_argument("--version", default="v1.0-mini")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--checkpoint-r1", type=Path, default=None, help="R1 checkpoint (default: the shipped one)")
    p.add_argument("--checkpoint-r2", type=Path, default=None, help="R2 checkpoint (default: the shipped one)")
    p.add_argument("--seeds", type=int, default=5, help="starts per frame (pure) and trials (hybrid, pure-avg)")
    p.add_argument("--depth", default="lidar-densified", help="depth estimator (default: lidar-densified)")
    p.add_argument("--methods", default="pure,pure-avg,hybrid", help="methods from R1 starts ('' = none)")
    p.add_argument("--ranges", nargs="+", default=list(RANGES), choices=RANGES, help="pure network ranges")
    p.add_argument("--threads", type=int, default=1)
    add_split_arguments(p, "all", "all (a held-out root) or one part of the split flags below")
    a = p.parse_args(argv)

    from hybrid_calib.atomic import write_bytes_atomic
    from hybrid_calib.config import save_json_atomic
    from hybrid_calib.hybrid.network import shipped_checkpoint

    ckpts = {"R1": a.checkpoint_r1 or shipped_checkpoint("R1"), "R2": a.checkpoint_r2 or shipped_checkpoint("R2")}
    split_options = split_overrides(a) if a.split != "all" else {}
    a.out.mkdir(parents=True, exist_ok=True)
    pure = {r: pure_per_frame(a.data, a.version, Path(ckpts[r]), r, a.seeds, a.split, split_options, a.depth,
                              a.out, a.threads) for r in a.ranges}
    methods = tuple(m.strip() for m in a.methods.split(",") if m.strip())
    loop = loop_methods(a.data, a.version, Path(ckpts["R1"]), a.seeds, a.split, split_options, a.depth, a.out,
                        a.threads, methods) if methods else {}
    rep = {"command": "PYTHONPATH=. python benchmarks/real_scene.py " + " ".join(sys.argv[1:] if argv is None
                                                                                   else argv),
           "data": str(a.data), "version": a.version, "split": a.split, "split_options": split_options,
           "frames_label": _frames_label(a.split, split_options), "depth": a.depth,
           "checkpoint_r1": str(ckpts["R1"]), "checkpoint_r2": str(ckpts["R2"]), "pure": pure, "loop": loop}
    rep["targets"] = targets(pure, loop)
    save_json_atomic(a.out / "real_scene.json", rep)
    text = markdown(rep)
    write_bytes_atomic(a.out / "real_scene.md", text.encode())
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
