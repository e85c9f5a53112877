"""Fit the hybrid's measurement model on validation drives and store it in a checkpoint.

    PYTHONPATH=. python benchmarks/hybrid_fit.py --data VAL1 VAL2 ... --checkpoint CKPT --start R1 \
        --max-frames 40 --out FITDIR [--refine CKPT_R0] [--fit-into]

With ``--refine`` the loop runs the cascade (``hybrid.network.CascadeRunner``) and the fitted block
is written into the REFINING checkpoint (the one whose covariance the measurement model scales).

Runs ``hybrid_calib.hybrid.fit.fit_measurement`` (module doc there), prints the candidates and, with
``--fit-into``, writes the chosen values into the checkpoint's ``export["hybrid"]`` block with the
command and the validation roots (``learned.checkpoint.set_export_overrides``). Never pass test drives.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", nargs="+", required=True, type=Path, help="simulated VALIDATION roots")
    p.add_argument("--version", default="v1.0-sim")
    p.add_argument("--checkpoint", required=True)
    p.add_argument("--refine", default="", help="refining checkpoint (cascade); the fit is stored in it")
    p.add_argument("--start", default="R1", choices=("R1", "R2"))
    p.add_argument("--max-frames", type=int, default=40)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--rows", nargs="+", default=["first", "last", "none"])
    p.add_argument("--no-motion-scale", action="store_true",
                   help="skip round 3 (the drive term recalibrated on the loop with the motion constraint on)")
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--fit-into", action="store_true", help="write the chosen values into the checkpoint")
    a = p.parse_args(argv)

    from hybrid_calib.config import save_json_atomic
    from hybrid_calib.hybrid.fit import fit_measurement
    from learned.checkpoint import set_export_overrides

    res = fit_measurement([str(d) for d in a.data], a.version, a.checkpoint, a.out, a.start, tuple(a.rows),
                          a.max_frames, a.seed, a.threads, refine=a.refine,
                          motion_scale=not a.no_motion_scale)
    save_json_atomic(a.out / "fit.json", res)
    print(json.dumps(res, indent=1))
    if a.fit_into:
        cmd = "PYTHONPATH=. python benchmarks/hybrid_fit.py " + " ".join(sys.argv[1:] if argv is None else argv)
        note = (f"{cmd}; validation roots {[str(d) for d in a.data]} (simulated, never the test drives), start "
                f"{a.start}, {a.max_frames} frames each; candidates {json.dumps(res['candidates'])}")
        target = a.refine or a.checkpoint
        set_export_overrides(target, {"hybrid": res["chosen"]}, note)
        print(f"wrote export.hybrid into {target}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
