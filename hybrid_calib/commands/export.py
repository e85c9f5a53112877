"""``hybrid-calib export``: the calibrated radar mounts as the root's ``calibrated_sensor.json``
(``hybrid_calib.calib.export``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from hybrid_calib.commands import version_name

HELP = "write the calibrated radar mounts of result.json files as the root's nuScenes calibrated_sensor table"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("results", nargs="+", type=Path, metavar="RESULT",
                   help="result.json files of one root (calibrate, fleet's vehicles/<v>/result.json, demo)")
    p.add_argument("--out", type=Path, required=True,
                   help="folder for calibrated_sensor.json and export.json (never the root's own version folder)")
    p.add_argument("--data", type=Path, default=None, help="the nuScenes root (default: the one the results record)")
    p.add_argument("--version", type=version_name,
                   default=None, help="its version folder (default: the results')")
    p.add_argument("--which", default="recalibrate", choices=("recalibrate", "trusted"),
                   help="recalibrate (default): only vehicles whose verdict against the tables is 'recalibrate'; "
                        "trusted: every trusted estimate. An untrusted one (not converged, out of the network's "
                        "domain, degenerate) is never exported")
    p.add_argument("--vehicle", action="append", default=None, metavar="NAME",
                   help="export only this vehicle (repeatable; default: every vehicle of the results)")
    p.add_argument("--overwrite", action="store_true", help="replace an export already in --out")


def run(args: argparse.Namespace) -> int:
    from hybrid_calib.calib.export import export_mounts

    exp = export_mounts(args.results, args.out, args.data, args.version, args.which, args.vehicle, args.overwrite)
    for name, v in exp.vehicles.items():
        line = f"{name}: {v['why']}"
        if v["exported"] and not v.get("carried"):  # a carried mount is the reference's: its why says so
            ch = v["records"][0]["change"]
            written = [f"{w} {a['std']:.2f} {a['unit']}" for w, a in v["std_camera"].items()
                       if a["written"] in ("estimate", "doppler")]  # the kept axes hold the tables': no std of ours
            # from the reference the verdict used (export.json "reference"): the tables' camera-radar calibration,
            # on a simulated root its factory one in sim_vehicle.json, not the record it replaces (probe 30)
            line += (f"; moved {ch['rot_deg']:.2f} deg, {ch['trans_cm']:.1f} cm from the camera-radar calibration the "
                     f"verdict compared with; 1-sigma of what it wrote (camera axes): {', '.join(written)}")
        print(line)
    for note in exp.notes:
        print(f"note: {note}")
    # a vehicle that carried its reference export's mount was refused its own estimate all the same
    refused = [n for n, v in exp.vehicles.items() if v.get("own_why", v["why"]).startswith("not exported")]
    carried = [n for n, v in exp.vehicles.items() if v.get("carried")]
    print(f"{len(exp.exported)} of {len(exp.vehicles)} vehicle(s) exported"
          + (f" ({len(carried)} carrying the reference export's mount unchanged)" if carried else "")
          + (f", {len(refused)} refused" if refused else "") + "; the camera records are the tables' (taken as "
          f"exact); wrote {Path(args.out) / 'calibrated_sensor.json'} and export.json")
    return 1 if refused else 0  # a script can tell "some could not be written" from "nothing needed writing"
