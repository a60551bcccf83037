"""Writes `scenarios/fig1_multipurpose.obj`: the start of the paper's figure 1 scene, a bench
with a back under the three sitters that turns, to their right, into a wall the three standers
lean back against.

    python solver/data/make_fig1_start.py

The sitters' part is the bench template's own control mesh (six 0.5 m seats, 0.36 m high,
0.45 m deep, a back 0.6 m long at 10 degrees). Each of its columns' profiles, from the seat's
front edge up to the top of the back, is blended over `BLEND` (x, metres: from where the last
sitter's hips end to where the first stander's begin) into the wall's: from 0.35 m up to 1.3 m
above the floor, `WALL_Z` in front of the seat's rear line up to 1.05 m (a few centimetres
behind the standers' buttocks and lower back, well behind their legs), leaning back above that
as their shoulders do. The blend keeps the profile's parameter (its share of the profile's
length), so the quads stay quads and face the bodies as the template's do.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

OUT = Path(__file__).with_name("scenarios") / "fig1_multipurpose.obj"
BENCH = dict(back=True, seams=False, back_height=0.6, back_angle_deg=10.0, seats=6,
             seat_width=0.5, seat_height=0.36, seat_depth=0.45, seat_tilt_deg=6.0,
             position=(0.0, -0.12))
BLEND = (-0.26, 0.02)  # x, m: the sitters' side ends at the first, the standers' begins at
# the second
WALL_Z = 0.24  # m: the wall's z below WALL_KNEE (the standers' buttocks are at z 0.28)
WALL_KNEE = 1.05  # m above the floor: the wall leans back above this ...
WALL_LEAN = 0.35  # ... by this many metres per metre up
WALL_Y = (0.35, 1.3)  # m: the wall's foot and top above the floor


def wall_profile(t: np.ndarray) -> np.ndarray:
    """(k, 2) (z, y) of the wall at profile parameters t (k,) in [0, 1], foot to top."""
    y = WALL_Y[0] + t * (WALL_Y[1] - WALL_Y[0])
    z = WALL_Z - WALL_LEAN * np.maximum(0.0, y - WALL_KNEE)
    return np.stack([z, y], axis=1)


def fig1_start() -> tuple[np.ndarray, np.ndarray]:
    """The start's control vertices (n, 3) m and quads (F, 4)."""
    from solver.surface.templates import make_template

    bench = make_template("bench", **BENCH)
    v = bench.vertices.copy()
    for column in bench.grid:  # u across the width: one profile each, v along it
        zy = v[column][:, [2, 1]]
        run = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(zy, axis=0), axis=1))])
        t = run / run[-1]
        x = v[column[0], 0]
        s = np.clip((x - BLEND[0]) / (BLEND[1] - BLEND[0]), 0.0, 1.0)
        b = s * s * (3.0 - 2.0 * s)  # smoothstep
        blended = (1.0 - b) * zy + b * wall_profile(t)
        v[column, 2], v[column, 1] = blended[:, 0], blended[:, 1]
    return v, bench.quads


def main() -> None:
    from solver.io.export import obj_text

    v, quads = fig1_start()
    OUT.write_text(obj_text(v, quads, comment=(
        "sitrelax: the start of the figure 1 scenario (solver/data/make_fig1_start.py)\n"
        "units: m; up: +Y; right-handed")))


if __name__ == "__main__":
    main()
