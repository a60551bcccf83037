"""Writes `viridis.npy`: the 256 RGB entries of the viridis colour map (van der Walt and Smith,
CC0), as matplotlib defines it, so that pictures and mesh colours use it without loading
matplotlib.

    python solver/data/make_viridis.py

The table is (256, 3) float64 in [0, 1]; a value t in [0, 1] takes entry min(int(t * 256), 255),
as matplotlib's listed colour maps do.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

OUT = Path(__file__).with_name("viridis.npy")


def main() -> None:
    from matplotlib import colormaps

    table = colormaps["viridis"](np.arange(256) / 255.0)[:, :3]
    np.save(OUT, table.astype(np.float64))


if __name__ == "__main__":
    main()
