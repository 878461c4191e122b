"""Generate ``app/assets/land_mask_1deg.npz``: the land/sea mask the dashboard's Earth uses.

Source: the ``global-land-mask`` package (PyPI, MIT licence, by T. Karin), which ships the
NOAA GLOBE 30-arc-second land mask as ``globe_combined_mask_compressed.npz`` (True = ocean).
The dashboard does not depend on that 2.5 MB package at run time: this script reduces its
mask once to a 1-degree land-fraction grid (180 x 360 cells, packed bits, a few kB) that is
committed to the repository. Nothing is fetched when the dashboard runs.

Regenerate with (into a throw-away directory, not the project venv)::

    python -m pip install --no-deps --target /tmp/glm global-land-mask
    PYTHONPATH=/tmp/glm python assets/make_land_asset.py

Output arrays: ``land`` (180, 360) bool, row 0 = latitude band [89, 90) deg north... i.e.
row ``i`` covers latitudes ``90 - i - 1 .. 90 - i`` deg and column ``j`` longitudes
``-180 + j .. -180 + j + 1`` deg; a cell is land when at least ``LAND_FRACTION`` of its
30" samples are land.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

CELL_DEG = 1.0
LAND_FRACTION = 0.4  # a 1-degree cell is drawn as land above this fraction of land samples
OUT = Path(__file__).resolve().parents[1] / "app" / "assets" / "land_mask_1deg.npz"


def main() -> None:
    from global_land_mask import globe  # only needed to regenerate the asset

    ocean = globe._mask  # (21600, 43200) bool, True = ocean
    lat_deg = globe._lat  # (21600,) decreasing or increasing: handle both
    n_lat, n_lon = ocean.shape
    k_lat = int(round(n_lat / (180 / CELL_DEG)))
    k_lon = int(round(n_lon / (360 / CELL_DEG)))
    # Block-average in row chunks to keep memory small.
    frac = np.empty((n_lat // k_lat, n_lon // k_lon))
    for i in range(frac.shape[0]):
        block = ~ocean[i * k_lat:(i + 1) * k_lat]
        frac[i] = block.reshape(k_lat, -1, k_lon).mean(axis=(0, 2))
    if lat_deg[0] < lat_deg[-1]:  # stored south -> north: flip to north -> south
        frac = frac[::-1]
    land = frac >= LAND_FRACTION
    np.savez_compressed(OUT, land_bits=np.packbits(land), shape=np.array(land.shape),
                        cell_deg=np.array(CELL_DEG))
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes), land fraction {land.mean():.3f}")


if __name__ == "__main__":
    main()
