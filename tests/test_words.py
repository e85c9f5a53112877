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
