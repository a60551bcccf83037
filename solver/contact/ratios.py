"""The flat-seat bar and how its ratios read: light (no numpy), so that the bars' module
(`solver.scene.quality`) and the evaluation's texts (`solver.contact.evaluate`) share one home
for both without loading the evaluation."""

from __future__ import annotations

import math

PEAK_OF_FLAT_BAR = 0.6  # the most a surface's peak may be of the flat seat's at the same load


def ratio_text(ratio: float | None, bar: float = PEAK_OF_FLAT_BAR) -> str:
    """A peak over the flat seat's as the bar reads it: two decimals, more where two would show
    a ratio over the bar as the bar itself (0.602 is "0.602", 0.6001 "0.6001", not "0.60");
    "not measured" for None or a value that is not a number."""
    if ratio is None or not math.isfinite(ratio):
        return "not measured"
    for digits in range(2, 7):
        text = f"{ratio:.{digits}f}"
        if not (ratio > bar and float(text) <= bar):
            return text
    return f"{ratio:.6g} (just over {bar:g})"
