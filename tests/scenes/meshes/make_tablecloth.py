"""Writes tablecloth.obj: a square cloth draped over a round table top, with vertical
folds that deepen towards the hem. Procedural (no simulation): the flat cloth's
material coordinates (u, v) map to the table top inside radius R_TOP and hang down
outside it, the fold amplitude growing with the distance hung. UVs are the flat
cloth's coordinates, so a tiled material stays continuous across the drape.
Run: python3 make_tablecloth.py  (numpy only; written by the Meso project, CC0)."""
import numpy as np

N = 100            # grid vertices per side
HALF = 0.8         # half side of the flat cloth (m)
R_TOP = 0.45       # table top radius (m)
HEIGHT = 0.75      # table height (m)
EDGE = 0.04        # radius of the rounded table edge the cloth bends over
FOLDS = 9          # folds around the table
AMP = 0.045        # fold amplitude at one metre hung


def drape(u, v):
    s = np.hypot(u, v)
    th = np.arctan2(v, u)
    # Arc length over the rounded edge, then straight down.
    hung = np.maximum(s - R_TOP, 0.0)
    bend = np.minimum(hung, 0.5 * np.pi * EDGE)
    ang = bend / EDGE
    down = hung - bend
    rho = np.where(s < R_TOP, s, R_TOP + EDGE * np.sin(ang))
    y = HEIGHT - EDGE * (1.0 - np.cos(ang)) - down
    # Folds: the hem gathers into waves; the swing grows with the length hung.
    wave = AMP * np.sin(FOLDS * th + 1.3 * np.sin(3 * th)) * np.minimum(down, 1.0) * 4.0
    rho = rho + np.maximum(wave, -0.6 * wave) + 0.15 * down
    return np.stack([rho * np.cos(th), y, rho * np.sin(th)], axis=-1)


def main():
    t = np.linspace(-HALF, HALF, N)
    u, v = np.meshgrid(t, t, indexing="xy")
    p = drape(u, v)
    uv = np.stack([(u + HALF) / (2 * HALF), (v + HALF) / (2 * HALF)], axis=-1)
    idx = np.arange(N * N).reshape(N, N)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    # Counter-clockwise seen from above (+y) on the table top.
    tris = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    pts = p.reshape(-1, 3)
    e1 = pts[tris[:, 1]] - pts[tris[:, 0]]
    e2 = pts[tris[:, 2]] - pts[tris[:, 0]]
    fn = np.cross(e1, e2)
    n = np.zeros_like(pts)
    for k in range(3):
        np.add.at(n, tris[:, k], fn)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    with open("tablecloth.obj", "w") as f:
        f.write("# Meso tablecloth: make_tablecloth.py (CC0)\n")
        for q in pts:
            f.write(f"v {q[0]:.4f} {q[1]:.4f} {q[2]:.4f}\n")
        for q in uv.reshape(-1, 2):
            f.write(f"vt {q[0]:.4f} {q[1]:.4f}\n")
        for q in n:
            f.write(f"vn {q[0]:.3f} {q[1]:.3f} {q[2]:.3f}\n")
        for t3 in tris + 1:
            f.write("f " + " ".join(f"{i}/{i}/{i}" for i in t3) + "\n")
    print(f"{len(pts)} vertices, {len(tris)} triangles; y in [{pts[:,1].min():.3f}, {pts[:,1].max():.3f}]")


if __name__ == "__main__":
    main()
