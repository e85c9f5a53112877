"""The radar mount monitor (``calib.mount_monitor``) on simulated drives: false alarms on drives with
no change, detection delay against the size of a yaw knock, and false flags of its end-of-drive test.

    PYTHONPATH=. .venv/bin/python benchmarks/mount_steps.py --out OUT [--seed 7001] [--frames 100]
        [--vehicles 3] [--scenarios urban highway rain straight] [--rot 0.25 0.5 1 2] [--set floor_deg=0.2 ...]
        [--sim-set radar_sweeps_per_frame=0 ...]

Per scenario, simulated at ``--image-scale`` (the monitor reads no image; reused when present):
one root of ``--vehicles`` drives with no change, and one per step size whose radar turns by that
many degrees about its z axis at the middle frame (the simulator's ``extrinsic_change`` step: the
radar's data change, not a relabelling). Seeds: ``--seed + 10 * scenario + step``. The monitor runs
over every drive with the first frame's ``T_ego_radar`` as reference (``monitor_drive``). A drive's
delay is its first alarm at or after the step minus the step frame (a miss when none follows);
alarms before the step and on unchanged drives are false alarms, per frame tested (the table's
rate: unchanged drives; the last line also counts those before a step and second alarms after one). The summary and
figure use ``benchmarks/bench_steps.py``'s format (``hybrid_calib.plots.steps``); ``OUT/summary.json``
also holds the per-drive noise scale and the size each alarm measured. Its parameters were chosen on
seeds 601-605 and the demo's (``benchmarks/hybrid_steps.py``); the default seeds here are others.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_steps import summarise, table  # noqa: E402

SCENARIOS = ("urban", "highway", "rain", "straight")


def monitor_root(root: Path, conf, step_at: int | None, kind: str, size: float, scenario: str) -> list[dict]:
    from hybrid_calib.calib.mount_monitor import monitor_drive
    from learned.dataset import open_frames

    frames = open_frames(root, "v1.0-sim", lidar=False)
    rows = []
    for v, idx in sorted(frames.frames_by_vehicle().items()):
        mon, readings = monitor_drive(frames, idx, frames[idx[0]].extras["T_ego_radar"], conf)
        alarms = [s.at for s in mon.steps]
        tested = sum(r.statistic is not None for r in readings)
        r = {"id": f"{root.name}/{v}", "kind": kind, "size": size, "scenario": scenario, "alarms": alarms,
             "tested": tested if step_at is None else sum(r.statistic is not None and r.position < step_at
                                                          for r in readings),
             "pairs": len(mon.series), "frames": len(idx), "measured_steps_deg": [s.step_deg for s in mon.steps],
             "levels": mon.levels(),  # the noise scale of the pairs before any change (all of them: unchanged drive)
             "scale_deg": float(mon.level_scale(0, sum(step_at is None or p < step_at for p, _ in mon.series)))
             if mon.series else None,
             "pairs_per_frame": float(np.median(mon.pairs)) if mon.pairs else 0.0}
        if step_at is None:
            r["false_alarms"] = len(alarms)
        else:
            after = [a for a in alarms if a >= step_at]
            r.update(step_at=step_at, false_alarms=len([a for a in alarms if a < step_at]),
                     delay=(after[0] - step_at) if after else None, extra_alarms=max(len(after) - 1, 0))
        r["tested_all"] = sum(x.statistic is not None for x in readings)
        r["tail_prefixes"], r["tail_fired"] = tail_fired(mon, conf)
        r["split_cuts"], r["split_fired"] = split_fired(mon, conf, step_at)
        rows.append(r)
    return rows


SPLIT_PARTS = ((5, 4), (3, 3), (2, 6))  # readings before and after the untested stretch: a short drive with a stop


def split_fired(mon, conf, step_at: int | None) -> tuple[int, int]:
    """(cuts, fired): short drives cut from this drive's readings, each a few readings (``SPLIT_PARTS``), an untested
    stretch of 3, 6 or 10 frames (a stop at a light) and a few more readings, fed to a fresh monitor, and how many its
    short-drive split test (``MountMonitor.short_split``) flags. On an unchanged drive every cut is one mount: each
    flag is false. On a drive with a step every cut whose stretch holds the step (readings on both sides of it) is a
    turn during the stop: each flag is a detection; cuts on one side of the step are not counted."""
    from hybrid_calib.calib.mount_monitor import MountMonitor

    cuts = fired = 0
    n = len(mon.series)
    for a, b in SPLIT_PARTS:
        for gap in (3, 6, 10):
            for s in range(0, n, 3):
                idx = [*range(s, s + a), *range(s + a + gap, s + a + gap + b)]
                if idx[-1] >= n:
                    break
                pos = [mon.series[k][0] for k in idx]
                if step_at is not None and not (pos[a - 1] < step_at <= pos[a]):
                    continue
                m = MountMonitor(frames=None, T_ego_radar=np.eye(4), conf=conf)
                for k in idx:
                    m.add_residual(mon.series[k][0], mon.series[k][1], mon.pairs[k], mon.own[k])
                cuts += 1
                fired += "split" in m.summary()
    return cuts, fired


def tail_fired(mon, conf) -> tuple[int, int]:
    """(prefixes, fired): the drive's readings cut after each reading from the fourth on, fed to a fresh monitor, and
    how many of those cuts its end-of-drive test (``MountMonitor.tail_turn``: the last readings turned beyond any
    mount) flags; on a drive whose radar turns less than ``max_level_deg`` every one is a false flag."""
    from hybrid_calib.calib.mount_monitor import MountMonitor

    fired = 0
    for n in range(4, len(mon.series) + 1):
        m = MountMonitor(frames=None, T_ego_radar=np.eye(4), conf=conf)
        for (p, y), k, own in zip(mon.series[:n], mon.pairs[:n], mon.own[:n]):
            m.add_residual(p, y, k, own)
        fired += "tail" in m.summary()
    return max(len(mon.series) - 3, 0), fired


def main(argv=None) -> int:
    from hybrid_calib.calib.mount_monitor import MountMonitorConfig
    from hybrid_calib.config import merge, parse_overrides, save_json_atomic, to_dict
    from hybrid_calib.plots.steps import plot_step_benchmark
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--seed", type=int, default=7001)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--vehicles", type=int, default=3)
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--rot", type=float, nargs="*", default=[0.25, 0.5, 1.0, 2.0], help="yaw step sizes, deg")
    ap.add_argument("--within", type=int, default=20)
    ap.add_argument("--image-scale", type=float, default=0.05)
    ap.add_argument("--workers", type=int, default=2, help="simulation processes")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="MountMonitorConfig overrides")
    ap.add_argument("--sim-set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="SimConfig overrides of the simulated drives (e.g. radar_sweeps_per_frame=0)")
    a = ap.parse_args(argv)
    conf = merge(MountMonitorConfig, parse_overrides(a.set))
    step_at, rows, t0 = a.frames // 2, [], time.perf_counter()
    for si, scen in enumerate(a.scenarios):
        for ki, size in enumerate([0.0, *a.rot]):
            o = {"scenario": scen, "vehicles": a.vehicles, "frames": a.frames, "seed": a.seed + 10 * si + ki,
                 "image_scale": a.image_scale, **parse_overrides(a.sim_set)}
            if size:
                o["extrinsic_change"] = {"kind": "step", "rotation_deg": (0.0, 0.0, size),
                                         "translation_m": (0.0, 0.0, 0.0)}
            name = f"{scen}-{'none' if not size else f'yaw{size:g}'}"
            root = simulate(merge(SimConfig, o), a.out / "data" / name, workers=a.workers, progress=False)
            got = monitor_root(root, conf, step_at if size else None, "rot" if size else "none", size, scen)
            rows += got
            print(f"{name:18s} alarms {[r['alarms'] for r in got]} scale {[round(r['scale_deg'], 2) for r in got]} deg "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
    summary = summarise(rows, a.within)
    per_scenario = {s: summarise([r for r in rows if r["scenario"] == s], a.within) for s in a.scenarios}
    # the reported step size (levels on either side of the first alarm after the step) against the knock
    z = []
    for r in rows:
        lv = r["levels"]
        j = next((k for k, x in enumerate(lv) if k and r.get("delay") is not None and x["from"] >= r["step_at"] - 3),
                 None)
        if j is not None:
            z.append((lv[j]["level_deg"] - lv[j - 1]["level_deg"] - r["size"])
                     / np.hypot(lv[j]["std_deg"], lv[j - 1]["std_deg"]))
    z = np.array(z)
    step_std = {"steps": len(z), "inside_1.96": float(np.mean(np.abs(z) < 1.96)) if len(z) else None,
                "mean_z2": float(np.mean(z ** 2)) if len(z) else None}
    fa = sum(r["false_alarms"] + r.get("extra_alarms", 0) for r in rows)
    tested = sum(r["tested_all"] for r in rows)
    summary.update(command=" ".join(sys.argv), config=to_dict(conf), per_scenario=per_scenario, runs=rows,
                   step_std=step_std,
                   false_alarm_all={"alarms": fa, "frames_tested": tested,
                                    "per_1000_frames": 1000 * fa / max(tested, 1)})
    a.out.mkdir(parents=True, exist_ok=True)
    save_json_atomic(a.out / "summary.json", summary)
    plot_step_benchmark(summary, a.out / "mount_steps.png", a.within, a.frames - step_at - 1,
                        titles={"rot": "yaw steps of the radar (about its z axis)"}, detector="radar mount monitor")
    print(table(summary, a.within))
    for s, ps in per_scenario.items():
        print(f"\n{s}:\n{table(ps, a.within)}")
    print(f"\nevery alarm that is not a step's first (unchanged drives, before a step, and a second alarm after "
          f"one): {fa} in {tested} tested frames ({1000 * fa / max(tested, 1):.2f} per 1000)")
    tp, tf = sum(r["tail_prefixes"] for r in rows), sum(r["tail_fired"] for r in rows)
    summary["tail"] = {"prefixes": tp, "fired": tf}
    save_json_atomic(a.out / "summary.json", summary)
    print(f"the end-of-drive test (the last readings turned beyond {conf.max_level_deg:g} deg) on every drive cut "
          f"after each of its readings: flagged {tf} of {tp} cuts (every radar here turns less: each flag is false)")
    for kind, words in (("none", "false"), ("rot", "detections of a turn inside the stretch")):
        for size in sorted({r["size"] for r in rows if r["kind"] == kind}):
            cu = sum(r["split_cuts"] for r in rows if r["kind"] == kind and r["size"] == size)
            fi = sum(r["split_fired"] for r in rows if r["kind"] == kind and r["size"] == size)
            summary.setdefault("split", {})[f"{kind}{size:g}"] = {"cuts": cu, "fired": fi}
            print(f"the short-drive split test (a few readings, 3-10 untested frames, a few more) on cuts of the "
                  f"{'unchanged drives' if kind == 'none' else f'{size:g} deg steps'}: flagged {fi} of {cu} ({words})")
    save_json_atomic(a.out / "summary.json", summary)
    if len(z):
        print(f"reported step size against the knock: {100 * step_std['inside_1.96']:.0f} % of {len(z)} steps inside "
              f"+-1.96 std, mean z^2 {step_std['mean_z2']:.2f} (1 if the std is honest)")
    scales = [r["scale_deg"] for r in rows]
    measured = {s: [m for r in rows if r["size"] == s for m in r["measured_steps_deg"]] for s in a.rot}
    print(f"\nnoise scale per drive (before the step): median {np.median(scales):.3f} deg, 10-90 % "
          f"{np.percentile(scales, 10):.3f}-{np.percentile(scales, 90):.3f} deg; measured steps: "
          + ", ".join(f"{s:g} deg -> median {np.median(m):.2f}" for s, m in measured.items() if m))
    print(f"wrote {a.out / 'summary.json'} and {a.out / 'mount_steps.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
