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
    """channel -> {"n", "gap_ms" (median, max), "m" / "yaw" / "tilt" (median, p99, max; m, deg, deg), "allowed"
    (the smallest allowance of each), "refused"}, over the records with both neighbours, interpolated between them."""
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
        out[ch] = {"n": len(x), "gap_ms": (float(np.median(x[:, 6])), float(x[:, 6].max())),
                   **{k: (float(np.median(x[:, j])), float(np.percentile(x[:, j], 99)), float(x[:, j].max()))
                      for j, k in enumerate(("m", "yaw", "tilt"))},
                   "allowed": tuple(float(x[:, j].min()) for j in (3, 4, 5)), "refused": int(x[:, 7].sum())}
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True)
    p.add_argument("--version", default="v1.0-mini")
    args = p.parse_args()
    res = measure(args.data, args.version)
    print("| channel | records | gap median / max (ms) | off the path, m: median / p99 / max | yaw deg | roll / pitch "
          "deg | allowed at least (m, yaw, roll / pitch) | refused |")
    print("|---|---|---|---|---|---|---|---|")
    for ch, r in res.items():
        print(f"| {ch} | {r['n']} | {r['gap_ms'][0]:.0f} / {r['gap_ms'][1]:.0f} | "
              f"{' / '.join(f'{v:.4f}' for v in r['m'])} | {' / '.join(f'{v:.3f}' for v in r['yaw'])} | "
              f"{' / '.join(f'{v:.3f}' for v in r['tilt'])} | {', '.join(f'{v:.2f}' for v in r['allowed'])} | "
              f"{r['refused']} |")
    n = sum(r["n"] for r in res.values())
    print(f"{n} records; largest off the path: {max(r['m'][2] for r in res.values()):.4f} m, "
          f"{max(r['yaw'][2] for r in res.values()):.3f} deg in yaw, {max(r['tilt'][2] for r in res.values()):.3f} "
          f"deg in roll / pitch; refused: {sum(r['refused'] for r in res.values())}")

if __name__ == "__main__":
    main()
