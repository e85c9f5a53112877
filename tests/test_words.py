"""The sentences' lists (hybrid_calib.words): long lists cut, the closest names first."""

from hybrid_calib.words import above, close_to, join_and, join_or, some_of


def test_a_long_list_is_cut_with_a_count():
    names = [f"veh-{i:03d}" for i in range(200)]
    assert some_of(names) == "veh-000, veh-001, veh-002, veh-003, veh-004, veh-005, veh-006, veh-007 and 192 more"
    assert some_of(names[:3]) == "veh-000, veh-001, veh-002"
    assert some_of([]) == "none"


def test_the_closest_names_lead_the_list():
    names = [f"veh-{i:03d}" for i in range(200)]
    close = close_to("veh-1999", names)
    assert close and close[0] == "veh-199"
    text = some_of(names, close, most=4)
    assert text.startswith(", ".join(close)) and text.endswith(f"and {200 - 4} more")
    assert close_to("something else", names) == []


def test_joins():
    assert join_and(["a"]) == "a" and join_and(["a", "b", "c"]) == "a, b and c"
    assert join_or(["a", "b"]) == "a or b"


def test_a_value_just_over_a_round_limit_shows_the_digits_that_put_it_over():
    """Probe 37's "std 10.0 cm > max_std_m 10 cm", back under a >= (probe 74): every default limit is round."""
    assert above(0.1004, 0.1) == "10.04" and above(0.10004, 0.1) == "10.004" and above(0.131, 0.1) == "13.1"
    assert above(0.05, 0.1) == "5.0"


def test_a_markdown_cell_keeps_its_row_whole():
    """Probe 88: a vehicle named "pipe|veh" shifted its summary.md row one column, "new\\nline" split it in two."""
    from hybrid_calib.fleet.summary import summary_markdown
    from hybrid_calib.words import md_cell

    assert md_cell("pipe|veh") == "pipe\\|veh" and md_cell("new\nline") == "new line" and md_cell(3) == "3"
    counts = {k: 0 for k in ("done", "pending", "running", "out_of_tolerance", "fleet_outliers", "degenerate",
                             "weak", "drifted_in_drive")}
    s = {"out": "o", "method": "oracle", "seed": 0, "design_mount": {"source": "recorded"},
         "counts": {**counts, "vehicles": 2, "failed": 2},
         "vehicles": {"pipe|veh": {"state": "failed", "reason": "a|b"}, "new\nline": {"state": "failed",
                                                                                      "reason": "x\ny"}}}
    rows = [line for line in summary_markdown(s).splitlines() if line.startswith("| ") and "failed" in line]
    assert rows == ["| pipe\\|veh | failed | | | | | | a\\|b |", "| new line | failed | | | | | | x y |"]


def test_a_name_that_hides_its_spaces_is_quoted():
    """Probe 88: "did you mean vé hicle ? (vehicles: vé hicle , ...)" of a name ending in a space."""
    from hybrid_calib.words import did_you_mean, shown

    assert shown("sim-veh-000") == "sim-veh-000" and shown("vé hicle ") == "'vé hicle '" and shown("") == "''"
    assert shown("a\tb") == "'a\\tb'"
    assert some_of(["vé hicle ", "b"]) == "'vé hicle ', b"
    assert did_you_mean("vé hicle", ["vé hicle ", "x"])[1] == "; did you mean 'vé hicle '?"
