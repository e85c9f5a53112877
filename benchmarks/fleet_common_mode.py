"""The fleet prior's common-mode part on hybrid fleets: how much of a vehicle's covariance in the prior-pinned
directions (radar pitch, radar z) the fleet model treats as shared (``fleet.prior.common_part``), against the
alternatives, on fleets none of them was tuned on.

Simulates 5 roots (16 keyframes each, ``image_scale`` 0.25): urban x 4 (seed 6801), highway x 4 (6802), rain x 4
(6803), straight x 3 (6805), one urban radar knocked at frame 4 by 1 / 3 / 3 deg about radar x / y / z (6804), and
calibrates them all with ``fleet --method hybrid`` (process engine, 2 workers; resumed when ``OUT`` holds it). Then
refits the fleet model on the vehicles' results with each way of taking the common part out of a vehicle's
covariance:

- ``loaded``: ``common_part`` (the code's): ``L P L^T`` with ``L[:, k] = C[:, k] / max(P_kk, C_kk)``;
- ``all-P``: ``C - P`` with its eigenvalues clipped at 1e-4 of C's (the code before session 36);
- ``all-P floor 1 %``: the same, clipped at 1e-2 of C's.

and reports, over fleets drawn from the 15 healthy vehicles (``--draws`` each, seed 7): the RMS error of the fleet
mean against the vehicles' true mean mount per radar axis (deg, cm), how often the mean lies outside the vehicles'
span on some axis, how many healthy vehicles the leave-one-out test names outliers (alpha 1e-3); for fleets of 12 of
the healthy vehicles plus the knocked one (``--draws`` / 4), how often the knocked radar is named; and, on all 16,
the knocked radar's d2 and the spread in the pinned directions (radar pitch and z) against the true spread.

    PYTHONPATH=. .venv/bin/python benchmarks/fleet_common_mode.py --out outputs/bench_common_mode [--draws 80]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOTS = (("urban", 4, 6801, None), ("highway", 4, 6802, None), ("rain", 4, 6803, None), ("straight", 3, 6805, None),
         ("urban", 1, 6804, {"kind": "step", "frame": 4, "rotation_deg": (1.0, 3.0, 3.0),
                             "translation_m": (0.0, 0.0, 0.0)}))


def build(out: Path) -> Path:
    """The roots and the hybrid fleet over them (resumed)."""
    from hybrid_calib.config import merge
    from hybrid_calib.fleet.driver import FleetOptions, run_fleet
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    roots = []
    for scenario, n, seed, change in ROOTS:
        root = out / "roots" / f"{'knocked-' if change else ''}{scenario}{seed}"
        conf = {"scenario": scenario, "vehicles": n, "frames": 16, "seed": seed, "image_scale": 0.25,
                **({"extrinsic_change": change} if change else {})}
        if not (root / "v1.0-sim" / "sim_vehicle.json").is_file():
            simulate(merge(SimConfig, conf), root, workers=2)
        roots.append(str(root))
    run_fleet(roots, None, "v1.0-sim", "hybrid", out / "fleet", options=FleetOptions(engine="process", workers=2))
    return out / "fleet"


def vehicles(fleet: Path) -> tuple[dict, np.ndarray, np.ndarray]:
    """name -> (x (6,), C (6, 6), true x (6,)) in the radar tangent at the design mount; P; the design mount."""
    import json

    from hybrid_calib.calib.result import CalibrationRun
    from hybrid_calib.fleet.summary import common_cov, design_mount
    from hybrid_calib.geometry import local

    jobs = json.loads((fleet / "manifest.json").read_text())["jobs"]
    done = {k: e for k, e in jobs.items() if e["state"] == "done"}
    T_ref, _ = design_mount([e["job"] for e in jobs.values()])
    out = {}
    for name, e in sorted(done.items()):
        vr = next(iter(CalibrationRun.load(fleet / e["result"]).vehicles.values()))
        out[name] = (local(T_ref, vr.final.T), np.asarray(vr.final.cov), local(T_ref, vr.truth_T))
    return out, common_cov([e["job"] for e in done.values()]), T_ref


def variants() -> dict:
    from hybrid_calib.fleet import prior

    def clipped(floor_frac):
        def own(C, P):
            C = prior._sym(C)
            w, V = np.linalg.eigh(C - P)
            floor = floor_frac * np.einsum("ij,ik,kj->j", V, C, V)
            return prior._sym((V * np.maximum(w, floor)) @ V.T)
        return own

    return {"loaded": prior._own, "all-P": clipped(1e-4), "all-P floor 1 %": clipped(1e-2)}


def fit(vs: dict, names: list[str], P: np.ndarray, own):
    from hybrid_calib.fleet import prior
    from hybrid_calib.geometry import retract

    keep, prior._own = prior._own, own
    try:
        return prior.fit_fleet_prior(names, [retract(np.eye(4), vs[n][0]) for n in names], [vs[n][1] for n in names],
                                     np.eye(4), common_cov=P)
    finally:
        prior._own = keep


def true_mean(vs: dict, names: list[str]) -> np.ndarray:
    from hybrid_calib.geometry import local, retract

    T, Ts = np.eye(4), [retract(np.eye(4), vs[n][2]) for n in names]
    for _ in range(5):
        T = retract(T, np.mean([local(T, t) for t in Ts], axis=0))
    return local(np.eye(4), T)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--draws", type=int, default=80)
    a = ap.parse_args()
    vs, P, _ = vehicles(build(a.out))
    healthy = [n for n in vs if not n.startswith("knocked")]
    knocked = [n for n in vs if n.startswith("knocked")]
    scale = np.r_[np.degrees(np.ones(3)), 100 * np.ones(3)]
    print(f"{len(healthy)} healthy vehicles, {len(knocked)} knocked; radar axes: rot x, y, z [deg], t x, y, z [cm]")
    for label, own in variants().items():
        g = np.random.default_rng(7)
        for size in (3, 10):
            err, outside, named = [], 0, 0
            for _ in range(a.draws):
                pick = sorted(g.choice(healthy, size, replace=False))
                f = fit(vs, pick, P, own)
                xs = np.array([vs[n][0] for n in pick])
                err.append((f.fit.mu - true_mean(vs, pick)) * scale)
                outside += bool(((f.fit.mu < xs.min(0) - 1e-9) | (f.fit.mu > xs.max(0) + 1e-9)).any())
                named += len(f.outliers)
            rms = np.sqrt(np.mean(np.square(err), axis=0))
            print(f"{label:16s} {size:2d} vehicles: RMS mean error {np.round(rms, 2).tolist()}, mean outside the "
                  f"span {outside}/{a.draws}, healthy named {named}/{a.draws * size}")
        hits = sum(knocked[0] in fit(vs, [*sorted(g.choice(healthy, 12, replace=False)), knocked[0]], P, own).outliers
                   for _ in range(a.draws // 4))
        whole = fit(vs, [*healthy, *knocked], P, own)
        spread = np.sqrt(np.diag(whole.fit.S)) * scale
        truth = np.std([vs[n][2] for n in healthy], axis=0, ddof=1) * scale
        print(f"{label:16s} 12 + knocked: knocked named {hits}/{a.draws // 4}; 15 + knocked: d2 "
              f"{[round(whole.tests[k]['d2'], 1) for k in knocked]}, spread radar pitch {spread[1]:.3f} deg "
              f"(true {truth[1]:.3f}), radar z {spread[5]:.2f} cm (true {truth[5]:.2f})")


if __name__ == "__main__":
    main()
