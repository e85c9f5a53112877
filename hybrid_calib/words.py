"""English for the sentences users read (layer 1): lists and counts, one way everywhere."""

from __future__ import annotations


def md_cell(text) -> str:
    """``text`` as one cell of a Markdown table: its pipes escaped and its line breaks spaces (probe 88: a vehicle
    named "a|b" shifted its row's values one column, one with a newline split its row in two)."""
    return " ".join(str(text).replace("|", "\\|").splitlines())


def join_and(names: list[str]) -> str:
    """"a", "a and b", "a, b and c"."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def shown(name) -> str:
    """A name as a sentence lists it: itself, or quoted (``repr``) where the quotes show what the eye would miss: an
    empty name, spaces at its ends, a character that does not print (probe 88: "did you mean vé hicle ?" of a name
    ending in a space)."""
    name = str(name)
    return repr(name) if not name or name != name.strip() or not name.isprintable() else name


def some_of(names: list[str], first: list[str] = (), most: int = 8) -> str:
    """At most ``most`` of ``names``, comma-separated, ``first`` (those of them to say first) leading, then "and N
    more": a list a user reads in one line (a root of 200 vehicles put all their names into one error)."""
    names = [str(n) for n in names]
    if not names:
        return "none"
    lead = [n for n in first if n in names]
    listed = lead + [n for n in names if n not in lead][:max(most - len(lead), 0)]
    return ", ".join(shown(n) for n in listed) + (f" and {len(names) - len(listed)} more"
                                                  if len(names) > len(listed) else "")


def close_to(wanted: str, names: list[str]) -> list[str]:
    """Up to three of ``names`` spelled like ``wanted`` (a mistyped vehicle or key), closest first."""
    import difflib

    return difflib.get_close_matches(str(wanted), [str(n) for n in names], n=3, cutoff=0.6)


def did_you_mean(wanted: str, names: list[str]) -> tuple[list[str], str]:
    """(the names spelled like ``wanted``, ``close_to``; "; did you mean a or b?" or "" when none): what a refusal of
    an unknown name says, with the close names to lead its list (``some_of``)."""
    close = close_to(wanted, names)
    return close, f"; did you mean {join_or([shown(n) for n in close])}?" if close else ""


def join_or(names: list[str]) -> str:
    """"a", "a or b", "a, b or c"."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " or " + names[-1]


def n_vehicles(n: int) -> str:
    """"1 vehicle", "3 vehicles": the count of a fleet's vehicles in words."""
    return f"{n} vehicle{'' if n == 1 else 's'}"


def n_frames(n: int) -> str:
    """"1 frame", "16 frames"."""
    return f"{n} frame{'' if n == 1 else 's'}"


def above(value_m: float, limit_m: float) -> str:
    """``value_m`` (m) in cm, with the digits that show it beyond ``limit_m``: "10.04" against a 10 cm limit, where
    one decimal read "10.0 cm > max_std_x_m 10 cm" (probe 37); "13.1" otherwise."""
    for digits in (1, 2, 3, 4):
        if round(value_m * 100, digits) > limit_m * 100 or value_m <= limit_m:
            return f"{value_m * 100:.{digits}f}"
    return f"{value_m * 100:.12g}"
