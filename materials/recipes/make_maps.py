#!/usr/bin/env python3
"""Weight and cluster maps for the authored SPMM packs in materials/.

Writes tileable 64x64 8-bit PNG maps next to each recipe (procedural, seeded, so a
rerun reproduces them byte for byte). The packs themselves are then built with
    meso pack new materials/recipes/<name>/recipe.toml -o materials/<name>.spmm
Needs numpy and imageio (pip install numpy imageio).
"""
import os

import imageio.v3 as iio
import numpy as np

N = 64
HERE = os.path.dirname(os.path.abspath(__file__))
y, x = np.mgrid[0:N, 0:N].astype(np.float64)


def save(folder, name, img):
    os.makedirs(os.path.join(HERE, folder), exist_ok=True)
    arr = np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)
    iio.imwrite(os.path.join(HERE, folder, name), arr)


def grey(v):
    return np.stack([v, v, v], axis=-1)


def woven():
    """2/2 twill, 8 texels per thread: warp (vertical, red) and weft (horizontal,
    cream) threads alternate in diagonal steps; across each thread the weight falls
    off towards its edges (the groove between threads)."""
    t = 8
    col, row = (x // t).astype(int), (y // t).astype(int)
    warp_up = ((col + row) % 4) < 2                      # twill step
    # cluster: 0 warp centre, 1 weft centre, 2 warp edge (normal tilted +x / -x
    # handled by two clusters), 3 weft edge
    u = (x % t + 0.5) / t                                 # across a warp thread
    v = (y % t + 0.5) / t                                 # across a weft thread
    edge_w = np.abs(u - 0.5) > 0.3
    edge_f = np.abs(v - 0.5) > 0.3
    cluster = np.where(warp_up, np.where(edge_w, np.where(u < 0.5, 2, 3), 0),
                       np.where(edge_f, np.where(v < 0.5, 4, 5), 1))
    save("woven_wool", "clusters.png", cluster / 255.0)
    fall_w = np.sin(np.pi * u) ** 0.5                     # brightest on the thread's crown
    fall_f = np.sin(np.pi * v) ** 0.5
    rng = np.random.default_rng(7)
    fibre = 0.85 + 0.15 * rng.random((N, N))              # fibre-to-fibre variation
    save("woven_wool", "warp_weight.png", grey(fall_w * fibre))
    save("woven_wool", "weft_weight.png", grey(fall_f * fibre))


def leather():
    """Pebble grain: cells of a tileable Voronoi pattern, each a bump whose slope
    direction picks one of five clusters (flat top, tilted +x, -x, +y, -y); the creases
    between cells are darker."""
    rng = np.random.default_rng(11)
    pts = rng.random((40, 2)) * N
    d1 = np.full((N, N), 1e9)
    d2 = np.full((N, N), 1e9)
    cx = np.zeros((N, N))
    cy = np.zeros((N, N))
    for px, py in pts:
        for ox in (-N, 0, N):
            for oy in (-N, 0, N):
                dx, dy = x + 0.5 - (px + ox), y + 0.5 - (py + oy)
                d = np.hypot(dx, dy)
                closer = d < d1
                d2 = np.where(closer, d1, np.minimum(d2, d))
                cx = np.where(closer, dx, cx)
                cy = np.where(closer, dy, cy)
                d1 = np.where(closer, d, d1)
    crease = np.clip((d2 - d1) / 2.0, 0, 1)               # 0 on a cell border
    r = np.hypot(cx, cy) + 1e-9
    slope = np.clip(d1 / (d1 + (d2 - d1) / 2 + 1e-9), 0, 1)
    steep = slope > 0.45
    ax_ = np.abs(cx) > np.abs(cy)
    cluster = np.where(~steep, 0, np.where(ax_, np.where(cx > 0, 1, 2), np.where(cy > 0, 4, 3)))
    save("leather", "clusters.png", cluster / 255.0)
    tone = 0.75 + 0.25 * crease
    save("leather", "albedo.png", grey(tone))


def brushed():
    """Brushed metal: streaks along x (brush direction) of random intensity, constant
    along each streak with slow variation, tileable."""
    rng = np.random.default_rng(3)
    rows = rng.random(N)
    rows = 0.5 * rows + 0.5 * np.roll(rows, 1)            # soften neighbouring streaks
    wobble = 0.06 * np.sin(2 * np.pi * (x / N) * 2 + rows[y.astype(int)] * 6)
    streak = 0.8 + 0.2 * rows[y.astype(int)] + wobble
    save("brushed_metal", "streaks.png", grey(np.clip(streak, 0, 1)))
    cluster = (rows[y.astype(int)] > 0.7).astype(int)    # a few deeper scratches
    save("brushed_metal", "clusters.png", cluster / 255.0)


if __name__ == "__main__":
    woven()
    leather()
    brushed()
