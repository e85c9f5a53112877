"""Inference speed of RC-AutoCalib: frames per second at the paper's 400x192 input, N = 3 iterations.

Measures ``model(batch)`` under ``torch.inference_mode`` (the data transform of every iteration
included; depth estimation and image decoding excluded) for batch 1 and batched, on the CPU with
``--threads`` threads (default 2) and on CUDA when available. Weights are random: speed does not
depend on them. Inputs mimic one nuScenes CAM_FRONT / RADAR_FRONT frame (125 radar points, a
ground-plane depth map).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_inference.py --preset paper --threads 2

Prints a markdown table and writes ``--out`` (JSON: one record per device and batch size with
frames_per_s, ms_per_frame, ms_per_batch, repeats, threads, torch version).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch


def make_batch(cfg, batch_size: int, n_radar: int = 125, device: str = "cpu") -> dict:
    """A plausible frame at the model input size, repeated ``batch_size`` times."""
    from hybrid_calib.geometry import R_AXES_CAM_FROM_RADAR, make_T, perturb_camera_frame

    H, W = (int(v) for v in cfg.input_hw)
    f = 1266.4 * W / 1600  # nuScenes CAM_FRONT focal length scaled to the input width
    K = np.array([[f, 0, W / 2 - 0.5], [0, f * (H / W) / (900 / 1600), H / 2 - 0.5], [0, 0, 1.0]])
    g = np.random.default_rng(0)
    v = np.arange(H)[:, None].repeat(W, 1)
    with np.errstate(divide="ignore"):
        depth = np.where(v > K[1, 2] + 1, 1.5 * K[1, 1] / np.maximum(v - K[1, 2], 1e-6), 80.0).clip(0.5, 80.0)
    radar = np.stack([g.uniform(2, 80, n_radar), g.uniform(-20, 20, n_radar), np.zeros(n_radar)], 1)
    T_gt = make_T(R_AXES_CAM_FROM_RADAR, np.array([0.0, 1.0, 1.7]))
    T_init = perturb_camera_frame(T_gt, np.radians([5.0, -4.0, 6.0]), np.array([0.1, -0.1, 0.2]))

    def rep(a, dtype=torch.float32):
        return torch.as_tensor(np.asarray(a), dtype=dtype)[None].repeat(batch_size, *([1] * np.ndim(a))).to(device)

    return {"image": rep(g.uniform(0, 1, (3, H, W))), "depth": rep(depth[None]), "K": rep(K), "radar": rep(radar),
            "radar_mask": rep(np.ones(n_radar, bool), torch.bool), "T_init": rep(T_init)}


def bench(model, batch: dict, repeats: int, warmup: int, device: str) -> float:
    """Seconds per forward pass (median of ``repeats`` after ``warmup``)."""
    times = []
    with torch.inference_mode():
        for i in range(warmup + repeats):
            if device == "cuda":
                torch.cuda.synchronize()
            t0 = time.perf_counter()
            model(batch)
            if device == "cuda":
                torch.cuda.synchronize()
            if i >= warmup:
                times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main(argv=None) -> int:
    from learned.config import model_config
    from learned.model import RCAutoCalib

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="paper", help="model preset (paper = 400x192)")
    p.add_argument("--iterations", type=int, default=3, help="LSTM iterations N (paper 3)")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    p.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 8], help="batch sizes to time")
    p.add_argument("--repeats", type=int, default=10, help="timed forward passes per setting")
    p.add_argument("--warmup", type=int, default=2, help="untimed passes first")
    p.add_argument("--devices", nargs="+", default=None, help="cpu and/or cuda (default: cpu, plus cuda if available)")
    p.add_argument("--out", type=Path, default=Path("outputs/bench_inference.json"), help="JSON results")
    args = p.parse_args(argv)

    torch.set_num_threads(args.threads)
    cfg = model_config(args.preset, {"iterations": args.iterations})
    devices = args.devices or (["cpu"] + (["cuda"] if torch.cuda.is_available() else []))
    records = []
    for device in devices:
        torch.manual_seed(0)
        model = RCAutoCalib(cfg).to(device).eval()
        for bs in args.batch_sizes:
            s = bench(model, make_batch(cfg, bs, device=device), args.repeats, args.warmup, device)
            rec = {"device": device if device == "cpu" else torch.cuda.get_device_name(), "batch": bs,
                   "threads": args.threads if device == "cpu" else None, "input_hw": list(cfg.input_hw),
                   "iterations": cfg.iterations, "preset": args.preset, "ms_per_batch": round(1e3 * s, 2),
                   "ms_per_frame": round(1e3 * s / bs, 2), "frames_per_s": round(bs / s, 2),
                   "repeats": args.repeats, "torch": torch.__version__,
                   "cpu": platform.processor() or platform.machine()}
            records.append(rec)
            print(json.dumps(rec))
    print("\n| device | batch | ms / batch | ms / frame | frames / s |\n|---|---|---|---|---|")
    for r in records:
        dev = f"{r['device']} ({r['threads']} threads)" if r["threads"] else r["device"]
        print(f"| {dev} | {r['batch']} | {r['ms_per_batch']} | {r['ms_per_frame']} | {r['frames_per_s']} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(args.out.name + ".tmp")
    tmp.write_text(json.dumps(records, indent=2))
    tmp.replace(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
