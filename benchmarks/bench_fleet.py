"""Fleet calibration: throughput against workers, Ray's overhead, kill-and-resume, the fleet prior.

One command (everything under ``--out``; simulated roots are reused when present):

    PYTHONPATH=. .venv/bin/python benchmarks/bench_fleet.py --out outputs/bench_fleet

1. Fleet: ``--fleet`` vehicles over four presets (urban, highway, rain, straight; one root each),
   plus one knocked radar (urban, ``--extrinsic-change step`` of ``--knock-deg`` about radar x, y, z
   at frame 1) and one corrupt vehicle (every radar file garbage); ``--frames`` keyframes each,
   ``image_scale`` 0.125, mount spreads as measured on the 850 nuScenes trainval scenes
   (``../shared/data/nuscenes-trainval-tables``: CAM_FRONT rotation std 0.16-0.41 deg, translation
   ~1 cm; RADAR_FRONT yaw std 0.27 deg): uniform +-0.6 deg / +-1.7 cm camera, +-0.5 deg / +-1 cm radar.
2. Reference run: ``--engine ray --workers 2`` uninterrupted. Kill-and-resume run: the CLI with
   ``--engine process --workers 2`` SIGKILLed after ``--kill-after`` result files, then rerun;
   compared with the reference (lost: vehicles missing; duplicated: results rewritten by the rerun;
   identical: every result equal to the reference's except wall-clock fields).
3. Fleet prior: ``fleet_prior.json`` of the reference run; second pass with ``--prior`` (each inlier's
   leave-one-out prior, none for a named outlier); per-axis RMS error, median reported std and
   NEES (chi2(6): mean 6, 95 % below 12.59) before and after, over the inlier vehicles with truth.
4. Throughput: the urban and highway roots (about ``--fleet`` / 2 vehicles): local; process 1 and 2 workers;
   ray 1 and 2 workers (Ray's start-up timed apart), ``--repeat`` rounds. Speed-up = wall(1) / wall(2);
   overhead per vehicle = (wall - sum of the jobs' own wall times / workers) / vehicles; Ray's daemons'
   (raylet, GCS, agents) CPU seconds during the run are recorded apart. The 1-minute load
   average before each run, the jobs' own CPU seconds and the driver's are recorded: on a shared machine
   they decide the figures (cpu_share = job CPU seconds / (wall x workers): 1 = every worker had a core).
   ``--ray-variants ray-nice15`` adds a local Ray with its workers reniced +15 (Ray's default, the
   engine's setting before issue 12's follow-up), interleaved in each round. The table is printed at
   the end (``--parts throughput`` runs this part alone).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ("urban", "highway", "rain", "straight")
MOUNTS = ["mounts.camera_rotation_deg=0.6", "mounts.camera_translation_m=0.017", "mounts.radar_rotation_deg=0.5",
          "mounts.radar_translation_m=0.01"]
TIMING = ("solve_ms", "cov_ms")
PARTS = ("reference", "kill", "prior", "throughput")
KNOCKED = "knocked-urban-sim-veh-000"


def cli(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hybrid_calib.cli", *args], cwd=ROOT, check=True,
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, **kw)


def simulate_fleet(out: Path, n: int, frames: int, knock_deg: float) -> list[Path]:
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    roots = []
    per = [n // len(PRESETS) + (i < n % len(PRESETS)) for i in range(len(PRESETS))]
    specs = [(p, k, 10 + i, []) for i, (p, k) in enumerate(zip(PRESETS, per))]
    specs += [("urban", 1, 90, ["--extrinsic-change", "step", "--change-frame", "1", "--set",
                                f"extrinsic_change.rotation_deg=[{knock_deg / 3},{knock_deg},{knock_deg}]"]),
              ("urban", 1, 91, [])]
    for i, (preset, k, seed, extra) in enumerate(specs):
        name = ["", "", "", "", "knocked-", "corrupt-"][i] + preset
        root = out / "roots" / name
        if not (root / "v1.0-sim" / "sim_vehicle.json").is_file():
            t0 = time.perf_counter()
            cli("simulate", "--scenario", preset, "--vehicles", str(k), "--frames", str(frames), "--seed", str(seed),
                "--workers", "2", "--out", str(root), *extra, "--set", "image_scale=0.125", *MOUNTS)
            print(f"simulated {name}: {k} x {frames} frames in {time.perf_counter() - t0:.0f} s", flush=True)
            if name.startswith("corrupt"):
                ds = NuScenesRadarCamera(root, "v1.0-sim", conf={"check_images": False})
                for f in ds.frames:
                    (root / f.radar_sd["filename"]).write_bytes(b"garbage, not a PCD\x00")
        roots.append(root)
    return roots


def results(out: Path) -> dict:
    def strip(x):
        if isinstance(x, dict):
            return {k: strip(v) for k, v in x.items() if k not in TIMING}
        return [strip(v) for v in x] if isinstance(x, list) else x
    files = (out / "vehicles").glob("*/result.json")
    return {p.parent.name: strip(json.loads(p.read_text())["vehicles"]) for p in files}


def mtimes(out: Path) -> dict:
    return {p.parent.name: p.stat().st_mtime_ns for p in (out / "vehicles").glob("*/result.json")}


def fleet(roots, out, engine="process", workers=2, priors=None, ray_temp=None):
    from hybrid_calib.fleet.driver import FleetOptions, run_fleet

    t0 = time.perf_counter()
    s = run_fleet([str(r) for r in roots], None, "v1.0-sim", "oracle", out, seed=0, priors=priors,
                  options=FleetOptions(engine=engine, workers=workers, ray_temp=ray_temp))
    return s, time.perf_counter() - t0


def kill_and_resume(roots, out: Path, kill_after: int, ref: dict) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "hybrid_calib.cli", "fleet", "--data", *map(str, roots), "--out", str(out),
           "--engine", "process", "--workers", "2", "--no-plots"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    while proc.poll() is None and len(mtimes(out)) < kill_after:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)  # the driver and its pool workers, as a machine failure would
    proc.wait()
    before = mtimes(out)
    m = json.loads((out / "manifest.json").read_text())
    states = {s: sum(e["state"] == s for e in m["jobs"].values()) for s in ("pending", "running", "done", "failed")}
    s, wall = fleet(roots, out)
    after = mtimes(out)
    got = results(out)
    return {"killed_after_results": len(before), "manifest_at_kill": states, "resume_wall_s": wall,
            "lost": sorted(set(ref) - set(got)), "duplicated": sorted(k for k in before if after[k] != before[k]),
            "identical_to_uninterrupted": got == ref, "counts": s["counts"]}


def gain(before: dict, after: dict, outliers: list) -> dict:
    """Per-axis RMS error (camera axes, deg / cm), median std and NEES over vehicles with truth."""
    from hybrid_calib.calib.result import CalibrationRun
    from hybrid_calib.metrics import CHI2_6_95, signed_errors

    rows = {"before": [], "after": []}
    for tag, s in (("before", before), ("after", after)):
        base = Path(s["out"])
        for jid, r in sorted(s["vehicles"].items()):
            if r["state"] != "done" or jid in outliers:
                continue
            v = next(iter(CalibrationRun.load(base / r["result"]).vehicles.values()))
            if v.truth_T is None:
                continue
            e = signed_errors(v.final.T, v.truth_T)
            e = np.concatenate([np.degrees(e[:3]), 100 * e[3:]])[[1, 2, 0, 3, 4, 5]]  # -> rot about x, y, z
            rows[tag].append((e, v.final.std, v.error["nees"]))
    out = {}
    for tag, rr in rows.items():
        E, S, N = np.array([r[0] for r in rr]), np.array([r[1] for r in rr]), np.array([r[2] for r in rr])
        out[tag] = {"vehicles": len(rr), "rms_error": np.sqrt((E ** 2).mean(0)).round(3).tolist(),
                    "median_std": np.median(S, 0).round(3).tolist(), "mean_nees": float(N.mean()),
                    "nees_below_12.59": float((N < CHI2_6_95).mean()),
                    "coverage_2sigma_per_axis": (np.abs(E) < 2 * S).mean(0).round(2).tolist()}
    return out


RAY_AGENTS = ("ray::DashboardAgent", "ray::RuntimeEnvAgent")


def ray_daemon_cpu_s() -> float:
    """CPU seconds so far of this process's Ray daemons (raylet, GCS server, monitors, agents): its
    children that are not workers (a worker's title starts ``ray::``, an agent's is in ``RAY_AGENTS``)."""
    import psutil

    total = 0.0
    for p in psutil.Process().children(recursive=True):
        try:
            title = " ".join(p.cmdline())
            if not title.startswith("ray::") or title.startswith(RAY_AGENTS):
                t = p.cpu_times()
                total += t.user + t.system
        except psutil.Error:
            pass
    return total


# Variants of the ray engine for an A/B in the same invocation (``--ray-variants``): name -> the local
# Ray's ``_system_config`` (``engines.LOCAL_RAY_CONFIG`` replaced while it runs); "ray" is the engine as shipped.
RAY_VARIANTS = {"ray-nice15": {"worker_niceness": 15}}  # Ray's default before issue 12's follow-up


def throughput(roots: list[Path], out: Path, repeat: int = 1, max_workers: int = 2,
               variants: tuple[str, ...] = ()) -> dict:
    from hybrid_calib.fleet import engines

    ws = [w for w in (1, 2, 4, 8, 16, 32) if w <= max_workers]
    shipped = dict(engines.LOCAL_RAY_CONFIG)
    rec = {"rounds": [], "ray_config": shipped, "variants": {v: RAY_VARIANTS[v] for v in variants}}
    for r in range(repeat):
        rnd = {}
        for name, workers in [("local", 1)] + [(e, w) for e in ("process", "ray", *variants) for w in ws]:
            engine = "ray" if name.startswith("ray") else name
            d = out / f"{name}{workers}"
            shutil.rmtree(d, ignore_errors=True)
            init_s = daemons = None
            if engine == "ray":
                engines.LOCAL_RAY_CONFIG = {**shipped, **RAY_VARIANTS.get(name, {})}
                t0 = time.perf_counter()
                engines.start_ray(workers, None, out / f"rt{workers}", 200)  # before importing ray: its token file
                init_s = time.perf_counter() - t0
                import ray
                daemons = ray_daemon_cpu_s()
            load = os.getloadavg()[0]
            driver = time.process_time()
            s, wall = fleet(roots, d, engine, workers)
            driver = time.process_time() - driver
            if engine == "ray":
                daemons = ray_daemon_cpu_s() - daemons
                ray.shutdown()
                engines.LOCAL_RAY_CONFIG = shipped
            m = json.loads((d / "manifest.json").read_text())
            job_s = sum(e["wall_s"] for e in m["jobs"].values())
            cpu_s = sum(e.get("cpu_s") or 0 for e in m["jobs"].values())
            n = len(m["jobs"])
            rnd[f"{name}{workers}"] = {"engine": name, "workers": workers, "vehicles": n, "wall_s": wall,
                                         "ray_init_s": init_s, "sum_job_s": job_s, "sum_job_cpu_s": cpu_s,
                                         "cpu_share": cpu_s / (wall * workers),
                                         "overhead_per_vehicle_s": (wall - job_s / workers) / n,
                                         "ray_daemon_cpu_s": daemons, "driver_cpu_s": driver,
                                         "vehicles_per_min": 60 * n / wall,
                                         "done": s["counts"]["done"], "load_avg_1min_before": load,
                                         "load_avg_1min_after": os.getloadavg()[0]}
            print(f"round {r + 1}: {name} x{workers}: {wall:.1f} s for {n} vehicles (jobs {job_s:.1f} s, CPU "
                  f"{cpu_s:.1f} s)" + (f", ray init {init_s:.1f} s, Ray daemons {daemons:.2f} CPU s" if init_s else "")
                  + f"; driver {driver:.2f} CPU s; load average before {load:.1f}", flush=True)
        for e in ("process", "ray", *variants):
            for w in ws[1:]:
                rnd[f"{e}_speedup_{w}"] = rnd[f"{e}1"]["wall_s"] / rnd[f"{e}{w}"]["wall_s"]
        print(f"round {r + 1}: speed-up: " + ", ".join(f"{k.split('_')[0]} x{k.split('_')[-1]} {v:.2f}"
                                                       for k, v in rnd.items() if "_speedup_" in k), flush=True)
        rec["rounds"].append(rnd)
    return rec


def throughput_table(rec: dict) -> str:
    """The throughput record as the markdown table of ``docs/benchmarks.md`` (one row per run, then the
    speed-ups per round)."""
    rows = ["| round | engine | workers | wall [s] | ray.init [s] | sum of job wall [s] | job CPU [s] | cpu_share "
            "| overhead / vehicle [s] | driver CPU [s] | Ray daemons CPU [s] | load avg before |", "|" + "---|" * 12]
    speed = []
    for i, rnd in enumerate(rec["rounds"], 1):
        for v in rnd.values():
            if isinstance(v, dict):
                f = {x: "" if v[x] is None else f"{v[x]:.2f}" for x in ("ray_init_s", "ray_daemon_cpu_s")}
                rows.append(f"| {i} | {v['engine']} | {v['workers']} | {v['wall_s']:.1f} | {f['ray_init_s']} | "
                            f"{v['sum_job_s']:.1f} | {v['sum_job_cpu_s']:.1f} | {v['cpu_share']:.2f} | "
                            f"{v['overhead_per_vehicle_s']:.2f} | {v['driver_cpu_s']:.2f} | {f['ray_daemon_cpu_s']} | "
                            f"{v['load_avg_1min_before']:.1f} |")
        speed.append(f"round {i}: " + ", ".join(f"{k.split('_speedup_')[0]} x{k.split('_')[-1]} {v:.2f} "
                                                f"({v / int(k.split('_')[-1]):.2f} x linear)"
                                                for k, v in rnd.items() if "_speedup_" in k))
    return "\n".join(rows + ["", "speed-up = wall(1 worker) / wall(W workers), ray.init timed apart:", *speed])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_fleet"))
    ap.add_argument("--fleet", type=int, default=20, help="good vehicles over the four presets (default: 20)")
    ap.add_argument("--frames", type=int, default=10, help="keyframes per vehicle (default: 10)")
    ap.add_argument("--knock-deg", type=float, default=3.0, help="knocked radar: deg about radar y and z (x: 1/3)")
    ap.add_argument("--kill-after", type=int, default=6, help="SIGKILL the driver after this many results")
    ap.add_argument("--repeat", type=int, default=1, help="rounds of the throughput part (default: 1)")
    ap.add_argument("--max-workers", type=int, default=2,
                    help="throughput: 1, 2, 4, ... workers up to this (default: 2)")
    ap.add_argument("--ray-variants", nargs="*", default=[], choices=sorted(RAY_VARIANTS),
                    help="throughput: also run these settings of a local Ray, interleaved (A/B; see RAY_VARIANTS)")
    ap.add_argument("--parts", nargs="+", default=list(PARTS), choices=PARTS,
                    help="what to run (default: all; without 'reference' the reference run is resumed)")
    a = ap.parse_args()
    a.parts = tuple(p for p in PARTS if p in a.parts)
    a.out = a.out.resolve()  # its subprocesses run in the checkout (probe 117: a relative --out went there)
    a.out.mkdir(parents=True, exist_ok=True)
    rec = {"machine": f"{platform.node()} {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs",
           "command": " ".join(sys.argv)}
    roots = simulate_fleet(a.out, a.fleet, a.frames, a.knock_deg)
    ref_out = a.out / "reference"
    if "reference" in a.parts:
        shutil.rmtree(ref_out, ignore_errors=True)
    if a.parts != ("throughput",):  # the other parts compare with the reference (resumed when present)
        s1, wall = fleet(roots, ref_out, "ray", 2, ray_temp=str(a.out / "rt"))
        ref = results(ref_out)
        rec["reference"] = {"wall_s": wall, "counts": s1["counts"], "outliers": s1["fleet_prior"]["outliers"],
                            "failed": {k: v["reason"] for k, v in s1["vehicles"].items() if v["state"] == "failed"},
                            "flags": {k: v["flags"] for k, v in s1["vehicles"].items() if v["flags"]},
                            "spread_std_cam": s1["fleet_prior"]["spread_std_cam"]}
        print(json.dumps(rec["reference"], indent=1), flush=True)
    if "kill" in a.parts:
        rec["kill_and_resume"] = kr = kill_and_resume(roots, a.out / "killed", a.kill_after, ref)
        print(json.dumps(kr, indent=1), flush=True)
    if "prior" in a.parts:
        from hybrid_calib.fleet.prior import load_priors

        shutil.rmtree(a.out / "with_prior", ignore_errors=True)
        s2, wall2 = fleet(roots, a.out / "with_prior", priors=load_priors(ref_out / "fleet_prior.json"))
        rec["prior_pass"] = {"wall_s": wall2, "counts": s2["counts"],
                             "gain": gain(s1, s2, list(s1["fleet_prior"]["outliers"])),
                             "knocked": {"before": s1["vehicles"][KNOCKED]["offset_from_design"],
                                         "with_prior": s2["vehicles"][KNOCKED]["offset_from_design"]}}
        print(json.dumps(rec["prior_pass"], indent=1), flush=True)
    if "throughput" in a.parts:
        rec["throughput"] = throughput(roots[:2], a.out / "throughput", a.repeat, a.max_workers, tuple(a.ray_variants))
        print(throughput_table(rec["throughput"]), flush=True)
    name = "bench_fleet.json" if a.parts == PARTS else f"bench_fleet_{'_'.join(a.parts)}.json"
    (a.out / name).write_text(json.dumps(rec, indent=2))
    print(f"wrote {a.out / name}")


if __name__ == "__main__":
    main()
