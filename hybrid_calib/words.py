"""English for the sentences users read (layer 1): lists and counts, one way everywhere."""

from __future__ import annotations


def join_and(names: list[str]) -> str:
    """"a", "a and b", "a, b and c"."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def n_vehicles(n: int) -> str:
    """"1 vehicle", "3 vehicles": the count of a fleet's vehicles in words."""
    return f"{n} vehicle{'' if n == 1 else 's'}"


def above(value_m: float, limit_m: float) -> str:
    """``value_m`` (m) in cm, with the digits that show it beyond ``limit_m``: "10.04" against a 10 cm limit, where
    one decimal read "10.0 cm > max_std_x_m 10 cm" (probe 37); "13.1" otherwise."""
    for digits in (1, 2, 3, 4):
        if round(value_m * 100, digits) > limit_m * 100 or value_m <= limit_m:
            return f"{value_m * 100:.{digits}f}"
    return f"{value_m * 100:.12g}"
