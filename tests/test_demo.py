"""``hybrid-calib demo`` end to end on tiny drives: the single-vehicle calibration, then the fleet
with one verdict line and one report per vehicle, and the fleet page."""

import json

from hybrid_calib.cli import main


def test_demo_prints_a_verdict_per_fleet_vehicle(tmp_path, capsys):
    out = tmp_path / "demo"
    rc = main(["demo", "--out", str(out), "--set", "frames=3", "fleet_frames=24", "image_scale=0.125",
               "engine=local", "workers=1"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "calibration [sim-veh-000]: method hybrid" in text
    lines = {v: next(ln for ln in text.splitlines() if ln.startswith(f"  {v}-sim-veh-000: "))
             for v in ("urban", "knocked", "straight")}
    assert lines["knocked"].startswith("  knocked-sim-veh-000: FLAGGED"), text
    assert "step alarm at frame" in lines["knocked"]
    summary = json.loads((out / "summary.json").read_text())
    assert (out / "fleet" / "fleet.html").is_file() and summary["fleet_page"] == str(out / "fleet" / "fleet.html")
    for v in summary["fleet"].values():
        assert v["report"] and (out / "fleet" / v["report"]).is_file()
    # the knocked radar's true mount moved inside the drive: its result keeps where (the report's bands and the
    # per-frame plots score each frame against its own mount; probe 54), the unchanged vehicles' do not
    result = json.loads((out / "fleet" / "vehicles" / "knocked-sim-veh-000" / "result.json").read_text())
    (vehicle,) = result["vehicles"].values()
    assert [p["index"] for p in vehicle["truth"]["path"]][0] == 0 and len(vehicle["truth"]["path"]) == 2
    urban = json.loads((out / "fleet" / "vehicles" / "urban-sim-veh-000" / "result.json").read_text())
    assert all("path" not in v["truth"] for v in urban["vehicles"].values())
