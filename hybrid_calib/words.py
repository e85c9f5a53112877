"""English for the sentences users read (layer 1): lists and counts, one way everywhere."""

from __future__ import annotations


def join_and(names: list[str]) -> str:
    """"a", "a and b", "a, b and c"."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def n_vehicles(n: int) -> str:
    """"1 vehicle", "3 vehicles": the count of a fleet's vehicles in words."""
    return f"{n} vehicle{'' if n == 1 else 's'}"
