"""Scene draws: the same synthetic room generated at another generator seed.

A draw of a room is named `ROOM@N` (e.g. `pantry@1`: the room `pantry` built with generator seed N: other
words, other places, the same kind of room). Draw 0 is the room's own name: `pantry@0` is an alias of `pantry`,
whose cache key and figures are those of the scenes built before draws existed. Every non-negative integer
is a draw; a card lists the draws it *registers* (`REGISTERED_DRAWS`, the ones the suite's tables are made on).

This module only names and parses draws (the tables group a draw's cells back to their room with `split_draw`);
the synthetic cards build them (datasets/synthetic/__init__.py).
"""

from __future__ import annotations

from strings_bench.core.errors import DatasetError

DRAW_SEP = "@"
# The draws every synthetic360 card registers (`datasets list`, the card's notes): the calibration over draws
# uses these three. Any other non-negative integer is a draw too.
REGISTERED_DRAWS = (0, 1, 2)


def parse_draw(text: str, what: str = "draw") -> int:
    """A draw number from its text ('1' -> 1); DatasetError for anything but a non-negative integer."""
    t = text.strip()
    if not t.isdigit() or not t.isascii():
        raise DatasetError(f"{what} {text!r} is not a draw: a draw is a non-negative integer (the generator seed)",
                           hint="e.g. pantry@1 (generator seed 1); pantry and pantry@0 are the room's seed-0 scene")
    return int(t)


def split_draw(scene: str) -> tuple[str, int]:
    """(room, draw) of a scene name: 'pantry@2' -> ('pantry', 2), 'pantry' -> ('pantry', 0). A scene name without
    '@' is draw 0 of itself (real scenes too). DatasetError for a malformed draw ('pantry@x', 'pantry@-1')."""
    room, sep, draw = str(scene).partition(DRAW_SEP)
    if not sep:
        return room, 0
    if not room:
        raise DatasetError(f"scene {scene!r} names a draw but no room", hint="e.g. pantry@1")
    return room, parse_draw(draw, f"the draw of {scene!r},")


def draw_name(room: str, draw: int) -> str:
    """The scene name of draw `draw` of `room`: the room itself for draw 0 (so its cells are today's), else ROOM@N."""
    if isinstance(draw, bool) or not isinstance(draw, int) or draw < 0:
        raise DatasetError(f"draw {draw!r} is not a non-negative integer", hint="draws are generator seeds 0, 1, 2, ...")
    return room if draw == 0 else f"{room}{DRAW_SEP}{draw}"


def parse_draws(text: str) -> list[int]:
    """'0,1,2' -> [0, 1, 2] (order kept, duplicates dropped); DatasetError for an empty list or a bad draw."""
    draws = [parse_draw(p, "draw") for p in str(text).split(",") if p.strip()]
    if not draws:
        raise DatasetError(f"no draws in {text!r}", hint="e.g. --draws 0,1,2")
    return list(dict.fromkeys(draws))
