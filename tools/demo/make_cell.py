#!/usr/bin/env python3
"""Synthetic AFM sample for the tipforce demo: a soft cell on a hard substrate, 64 x 64 pixels.

Writes cell_k_n_per_m.csv (contact stiffness, N/m) and cell_h_m.csv (separation h from the
cantilever's rest position to the surface, m) next to this script: 64 rows (row = pixel_y, top
first) of 64 comma-separated values (column = pixel_x).

  substrate: k ~ 12 N/m, h ~ 45 nm (with 0.2 nm roughness)
  cell:      an elliptical dome of about 40 x 30 pixels, centred off-centre and tilted by 20
             degrees; k from ~1.5 N/m at the rim to ~3 N/m on top, with a stiffer nucleus
             (~4 N/m); its surface is raised toward the cantilever by up to 15 nm (h down to
             ~30 nm), smoothly.

Python 3 standard library only; deterministic (fixed seed), so re-running gives the same files.
"""
import math
import os
import random

N = 64
K_SUBSTRATE = 12.0       # N/m
H_SUBSTRATE = 45e-9      # m
DOME_HEIGHT = 15e-9      # m: the cell's top is this much nearer the cantilever
CELL_CX, CELL_CY = 37.5, 27.0   # pixel centre of the cell (off-centre)
CELL_A, CELL_B = 20.0, 15.0     # semi-axes in pixels: a 40 x 30 pixel ellipse
CELL_TILT = math.radians(20.0)
NUC_CX, NUC_CY = 41.0, 24.5     # nucleus centre, inside the cell
NUC_A, NUC_B = 8.0, 6.0
K_RIM, K_TOP, K_NUCLEUS = 1.5, 3.0, 4.0


def smoothstep(e0, e1, x):
    t = min(max((x - e0) / (e1 - e0), 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


def ellipse_r(x, y, cx, cy, a, b, tilt):
    """Normalised elliptical radius: 0 at the centre, 1 on the outline."""
    dx, dy = x - cx, y - cy
    u = dx * math.cos(tilt) + dy * math.sin(tilt)
    v = -dx * math.sin(tilt) + dy * math.cos(tilt)
    return math.hypot(u / a, v / b)


def main():
    rng = random.Random(20240611)
    k_rows, h_rows = [], []
    for py in range(N):
        k_row, h_row = [], []
        for px in range(N):
            r = ellipse_r(px, py, CELL_CX, CELL_CY, CELL_A, CELL_B, CELL_TILT)
            # Dome profile: 1 on top, 0 at and beyond the outline, smooth (C1) at both ends.
            dome = (1.0 - r * r) ** 1.5 if r < 1.0 else 0.0
            inside = 1.0 - smoothstep(0.85, 1.0, r)     # 1 in the cell, 0 on the substrate
            k_cell = K_RIM + (K_TOP - K_RIM) * dome
            rn = ellipse_r(px, py, NUC_CX, NUC_CY, NUC_A, NUC_B, CELL_TILT)
            nucleus = 1.0 - smoothstep(0.6, 1.0, rn)
            k_cell += (K_NUCLEUS - k_cell) * nucleus
            k = K_SUBSTRATE * (1.0 - inside) + k_cell * inside
            k *= 1.0 + 0.03 * rng.uniform(-1.0, 1.0)     # a few per cent pixel-to-pixel texture
            h = H_SUBSTRATE - DOME_HEIGHT * dome + 0.2e-9 * rng.uniform(-1.0, 1.0)
            k = min(max(k, 0.5), 15.0)
            h = min(max(h, 25e-9), 55e-9)
            k_row.append("%.4f" % k)
            h_row.append("%.4e" % h)
        k_rows.append(",".join(k_row))
        h_rows.append(",".join(h_row))
    here = os.path.dirname(os.path.abspath(__file__))
    with open(os.path.join(here, "cell_k_n_per_m.csv"), "w") as f:
        f.write("\n".join(k_rows) + "\n")
    with open(os.path.join(here, "cell_h_m.csv"), "w") as f:
        f.write("\n".join(h_rows) + "\n")


if __name__ == "__main__":
    main()
