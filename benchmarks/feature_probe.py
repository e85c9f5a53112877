"""Linear probe: which corrections does the network's fused descriptor carry, per iteration?

For frames of a split (perturbed starts, fixed seed) the checkpoint runs its N iterations; at
iteration n the regression head reads the fused descriptor x_n (B, D) and should output the
correction Log(T_in^-1 T_gt) (right tangent, radar frame: rotation x/y/z in rad, translation x/y/z
in metres; radar x forward, y left, z up). A ridge regression from x_n to the needed correction is
fitted on half the frames and scored (R^2) on the other half; the head's own translation output is
scored the same way. A probe R^2 near 1 with a head R^2 near 0 means the head is under-trained; both
near 0 means the features do not carry that correction. The mean BEV map value (Y + h, metres) is
also correlated with the needed translation (the paper's height channel reads the vertical offset).

    PYTHONPATH=. .venv/bin/python benchmarks/feature_probe.py --checkpoint learned/checkpoints/small-sim-r1.json \
        --data TRAIN2 TRAIN3 --split val --frames 400
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

AXES = ("rot_x", "rot_y", "rot_z", "t_x", "t_y", "t_z")


def probe(checkpoint: str, roots: list[str], split: str, frames: int, rng: str, seed: int, ridge: float = 10.0
          ) -> dict:
    from tqdm import tqdm

    from learned import lie
    from learned.checkpoint import load_model
    from learned.dataset import CalibDataset, DatasetConfig, collate, open_roots, split_indices
    from learned.depth import build_depth_estimator

    model, ckpt = load_model(checkpoint)
    H, W = (int(v) for v in model.cfg.input_hw)
    # with the LiDAR where a root has it: the release-2 checkpoints' depth is lidar-densified (probe 117: every frame
    # was skipped, then a traceback)
    data = open_roots(roots, lidar=True)
    idx = split_indices(data, split, ckpt.train_config.get("split"))
    idx = idx[:: max(1, len(idx) // frames)][:frames]
    depth = build_depth_estimator(ckpt.train_config.get("depth", "corrupted-truth"))
    ds = CalibDataset(data, DatasetConfig(height=H, width=W, perturbation=rng, seed=seed), depth, indices=idx,
                      train=False)
    n_it = model.cfg.iterations
    feats, need, head, bev = ([[] for _ in range(n_it)] for _ in range(4))
    seen = []
    hook = model.head.register_forward_hook(
        lambda m, inp, out: seen.append((inp[0].detach(), out[0]["trans"].detach())))
    with torch.no_grad():
        for s in tqdm(range(0, len(ds), 16), desc="probe"):
            items = [x for x in (ds[i] for i in range(s, min(s + 16, len(ds)))) if x is not None]
            if not items:
                continue
            b = collate(items)
            seen.clear()
            out = model({k: b[k] for k in ("image", "depth", "K", "radar", "radar_mask", "T_init")})
            for n in range(n_it):
                feats[n].append(seen[n][0].numpy())
                head[n].append(seen[n][1].numpy())
                need[n].append(lie.local(out["T_inputs"][n], b["T_gt"]).numpy())
                m = out["render"][n]["bev"]
                occ = (m > 0).float()
                bev[n].append(((m * occ).sum((1, 2, 3)) / occ.sum((1, 2, 3)).clamp_min(1)).numpy())
    hook.remove()
    if not feats[0]:
        raise SystemExit(f"feature_probe: no usable frame of {len(idx)} in {roots} (split {split}); the skips "
                         "above say why")
    result = {"frames": len(ds) - len(ds.bad), "checkpoint": str(checkpoint), "split": split, "range": rng,
              "axes": list(AXES), "iterations": []}
    for n in range(n_it):
        X, Y, P, B = (np.concatenate(v) for v in (feats[n], need[n], head[n], bev[n]))
        half = len(X) // 2
        Xa = np.c_[X, np.ones(len(X))]
        A = Xa[:half]
        w = np.linalg.solve(A.T @ A + ridge * np.eye(A.shape[1]), A.T @ Y[:half])
        resid = Y[half:] - Xa[half:] @ w
        var = ((Y[half:] - Y[half:].mean(0)) ** 2).sum(0)
        r2_probe = 1 - (resid ** 2).sum(0) / var
        r2_head = 1 - ((Y[half:, 3:] - P[half:]) ** 2).sum(0) / var[3:]
        corr = [float(np.corrcoef(B, Y[:, k])[0, 1]) for k in range(3, 6)]
        result["iterations"].append({
            "iteration": n + 1, "probe_r2": r2_probe.tolist(), "head_r2_translation": r2_head.tolist(),
            "corr_mean_bev_value_translation": corr, "needed_std": (Y.std(0)).tolist()})
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--data", required=True, nargs="+")
    ap.add_argument("--split", default="val")
    ap.add_argument("--frames", type=int, default=320)
    ap.add_argument("--range", dest="rng", default="R1", choices=("R1", "R2"))
    ap.add_argument("--seed", type=int, default=77)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--ridge", type=float, default=10.0, help="ridge penalty of the probe (descriptor units)")
    ap.add_argument("--out", type=Path, default=Path("outputs/bench/feature_probe.json"))
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    res = probe(args.checkpoint, args.data, args.split, args.frames, args.rng, args.seed, args.ridge)
    print(f"{res['frames']} frames, {res['split']} split, {res['range']} starts; R^2 on held-out half")
    print("| iteration | probe R^2 rot x/y/z | probe R^2 t x/y/z | head R^2 t x/y/z | corr(mean BEV value, t x/y/z) |")
    print("|---|---|---|---|---|")
    for it in res["iterations"]:
        f = lambda v: " / ".join(f"{x:.2f}" for x in v)  # noqa: E731
        print(f"| {it['iteration']} | {f(it['probe_r2'][:3])} | {f(it['probe_r2'][3:])} | "
              f"{f(it['head_r2_translation'])} | {f(it['corr_mean_bev_value_translation'])} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(args.out.name + ".tmp")
    tmp.write_text(json.dumps(res, indent=2))
    tmp.replace(args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
