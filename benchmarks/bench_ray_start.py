"""Ray: how long the first tasks wait for a worker, with and without a job-level ``runtime_env``.

One command:

    PYTHONPATH=. .venv/bin/python benchmarks/bench_ray_start.py --out /tmp/ray_start --repeat 3

A local Ray of ``--cpus`` CPUs (object store 100 MB, files under ``--out``) is started ``2 x --repeat``
times, alternating ``ray.init()`` without and with ``runtime_env={"env_vars": {...}}`` (what
``fleet.engines`` passed before issue 12's follow-up); each time ``--cpus`` trivial tasks are
submitted at once and the time until the last one starts in its worker is recorded (the tasks
themselves take no time). Ray prestarts ``--cpus`` workers at ``ray.init``; tasks of a job with a
``runtime_env`` cannot use them and wait for new workers. The 1-minute load average is recorded:
the box is shared.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path


def started() -> float:
    return time.time()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/ray_start"))
    ap.add_argument("--cpus", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    from hybrid_calib.fleet.engines import _local_ray_env, ray_temp_dir

    tmp = ray_temp_dir(a.out / "rt")
    _local_ray_env(tmp)
    import ray

    rows = []
    for i in range(2 * a.repeat):
        env = {"runtime_env": {"env_vars": {"TQDM_DISABLE": "1"}}} if i % 2 else {}
        t0 = time.perf_counter()
        ray.init(num_cpus=a.cpus, object_store_memory=100 * 2 ** 20, _temp_dir=str(tmp), include_dashboard=False,
                 log_to_driver=False, **env)
        init_s = time.perf_counter() - t0
        task = ray.remote(num_cpus=1)(started)
        load = os.getloadavg()[0]
        t = time.time()
        wait_s = max(ray.get([task.remote() for _ in range(a.cpus)])) - t
        ray.shutdown()
        rows.append({"runtime_env": bool(env), "init_s": init_s, "first_tasks_wait_s": wait_s, "load_avg_1min": load})
        print(f"runtime_env {bool(env)!s:5}: init {init_s:.1f} s, last of {a.cpus} first tasks started after "
              f"{wait_s:.2f} s; load average {load:.1f}", flush=True)
    rec = {"command": " ".join(os.sys.argv), "cpus": a.cpus, "rows": rows}
    (a.out / "bench_ray_start.json").write_text(json.dumps(rec, indent=2))
    print(f"wrote {a.out / 'bench_ray_start.json'}")


if __name__ == "__main__":
    main()
