"""The signal floors of an OCR-CER: how much text a scene must hold, and how much of it the renders must read, before
a CER (or a difference of two CERs) says something.

Both floors come from one piece of reasoning: characters counted as independent. With N GT characters one
character is 1/N of the CER and the CER's standard error is at most 0.5/sqrt(N).

- GT floor (`MIN_GT_CHARS`): 0.07 at N = 50, so two methods' difference has a standard error of about 0.1; the
  paper's 7K gap between STRinGS and 3DGS (0.177 against 0.736 on STRinGS-360, 63.6 % relative, section 5) stands
  out of it, a gap read on 6 characters does not. Applied to every scene without known text (a user's own photos
  included): below it the run leaves `cer` empty and says why.
- Read floor (`MIN_READ_CHARS`): with N above the floor a CER can still rest on almost nothing when the renders
  read almost nothing (every method at CER ~1 differs only by the characters OCR adds or gets right by chance).
  Count the characters the best method reads, r (GT characters less errors), as a Poisson count: standard error
  sqrt(r). For a method reading half as much (the paper's 7K gap, about 60 % relative) to stand two standard
  errors apart: r / 2 >= 2 sqrt(r + r / 2), i.e. r >= 24. Below it a CER claim on that scene is "not scorable".
"""

MIN_GT_CHARS = 50
MIN_READ_CHARS = 24


def read_characters(chars: int | float, errors: int | float) -> float:
    """The GT characters a render reads (its GT characters less its errors; 0 when OCR added more than it read)."""
    return max(0.0, float(chars) - float(errors))


def gt_floor(settings, views) -> int | None:
    """The floor on GT characters for a scene's OCR-CER: its `min_gt_chars` setting when it has one (the captures
    set it), else MIN_GT_CHARS for a scene without known text (a user's own photos: only the GT OCR tells what the
    text is; the module docstring says why 50), else None (synthetic scenes: their known text is scored as well)."""
    floor = settings.get("min_gt_chars") if isinstance(settings, dict) else None
    if floor is not None:
        return int(floor)
    if all(v.known_words is None for v in views):
        return MIN_GT_CHARS
    return None
