"""How far each ego pose of a nuScenes root lies from the path its channel's neighbouring records' poses trace: the
margin ``NuScenesTables._check_smooth`` refuses a pose beyond (``tables.POSE_SMOOTH_*``), measured.

Per channel, over every sample_data record with both neighbours (``prev`` and ``next``) at most
``POSE_NEIGHBOUR_MAX_GAP_S`` apart: the gap, the distance (m) and angle (deg) of the record's ego pose from the pose
interpolated between them, and the allowance the check gives it; and how many records the check refuses (a clean
root: none). The same interpolation as the check (``NuScenesTables._off_path``), so the figures are its own.

    PYTHONPATH=. .venv/bin/python benchmarks/pose_smoothness.py --data ../shared/data/nuscenes-scene-0916 \
        --version v1.0-mini
"""

from __future__ import annotations

import argparse

import numpy as np


def measure(data: str, version: str) -> dict[str, dict]:
    """channel -> {"n", "gap_ms" (median, max), "m" / "deg" (median, p99, max), "allowed_m" / "allowed_deg" (min),
    "refused"}."""
    from hybrid_calib.data.tables import NuScenesTables
    from hybrid_calib.errors import DataError

    t = NuScenesTables(data, version)
    by = t.by_token["sample_data"]
    rows: dict[str, list] = {}
    for sd in t.records["sample_data"]:
        a, b = by.get(sd.get("prev") or ""), by.get(sd.get("next") or "")
        try:
            off = t._off_path(a, sd, b, t._T_global_ego(sd))
        except DataError:
            continue
        if off is None:
            continue
        refused = False
        try:
            t.T_global_ego(sd)
        except DataError:
            refused = True
        rows.setdefault(t.channel_of(sd), []).append((*off, (b["timestamp"] - a["timestamp"]) / 1e3, refused))
    out = {}
    for ch, v in sorted(rows.items()):
        x = np.asarray(v, float)
        out[ch] = {"n": len(x), "gap_ms": (float(np.median(x[:, 4])), float(x[:, 4].max())),
                   "m": (float(np.median(x[:, 0])), float(np.percentile(x[:, 0], 99)), float(x[:, 0].max())),
                   "deg": (float(np.median(x[:, 1])), float(np.percentile(x[:, 1], 99)), float(x[:, 1].max())),
                   "allowed_m": float(x[:, 2].min()), "allowed_deg": float(x[:, 3].min()),
                   "refused": int(x[:, 5].sum())}
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True)
    p.add_argument("--version", default="v1.0-mini")
    args = p.parse_args()
    res = measure(args.data, args.version)
    print("| channel | records | gap median / max (ms) | off path, m: median / p99 / max | deg: median / p99 / max | "
          "allowed at least (m, deg) | refused |")
    print("|---|---|---|---|---|---|---|")
    for ch, r in res.items():
        print(f"| {ch} | {r['n']} | {r['gap_ms'][0]:.0f} / {r['gap_ms'][1]:.0f} | "
              f"{' / '.join(f'{v:.4f}' for v in r['m'])} | {' / '.join(f'{v:.3f}' for v in r['deg'])} | "
              f"{r['allowed_m']:.2f}, {r['allowed_deg']:.2f} | {r['refused']} |")
    n = sum(r["n"] for r in res.values())
    print(f"{n} records; largest off the path: {max(r['m'][2] for r in res.values()):.4f} m, "
          f"{max(r['deg'][2] for r in res.values()):.3f} deg; refused: {sum(r['refused'] for r in res.values())}")


if __name__ == "__main__":
    main()
