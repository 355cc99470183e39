#!/usr/bin/env python3
"""Reference values of the analytic BRDF dictionary, independent of the Rust code.

Evaluates each model of docs/brdf.md straight from its written formula (angles,
1 - cos^2, acos/atan2: the textbook forms the Rust code deliberately avoids) in 40-digit
mpmath arithmetic, at directions written as 17-significant-digit decimals, taken on both sides
as the same binary64 values. Writes brdf_values.csv and brdf_basis_values.csv beside
this file; tests/src/brdf_reference.rs compares Meso against them.

Run: /work/venv/bin/python tests/reference/brdf_reference.py   (needs mpmath)
"""
import csv
import os

import mpmath as mp

mp.mp.dps = 40
HERE = os.path.dirname(os.path.abspath(__file__))


def dec(x):
    """17 significant digits: round-trips an f64 exactly."""
    return "%.17g" % float(x)


def direction(cos_theta, phi):
    c = mp.mpf(cos_theta)
    s = mp.sqrt(1 - c * c)
    return [dec(s * mp.cos(phi)), dec(s * mp.sin(phi)), dec(c)]


def mirror(d):
    return [dec(-mp.mpf(d[0])), dec(-mp.mpf(d[1])), d[2]]


def rotate_about_z(d, angle):
    x, y = mp.mpf(d[0]), mp.mpf(d[1])
    ca, sa = mp.cos(angle), mp.sin(angle)
    return [dec(ca * x - sa * y), dec(sa * x + ca * y), d[2]]


def tilt(d, dtheta):
    """Moves d away from the normal by dtheta within its azimuthal plane."""
    x, y, z = (mp.mpf(v) for v in d)
    theta, phi = mp.acos(z), mp.atan2(y, x)
    return direction(mp.cos(theta + dtheta), phi)


def vec(d):
    """The exact binary64 values the Rust side parses from the same decimals, not
    renormalised: nearly opposite grazing directions make wi + wo sensitive to the last
    bit of each component, so both sides must start from the very same numbers."""
    return [mp.mpf(float(v)) for v in d]


def dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def normalize(a):
    n = mp.sqrt(dot(a, a))
    return [x / n for x in a]


def half(wi, wo):
    return normalize([a + b for a, b in zip(wi, wo)])


def cos_d(wi, wo, h):
    """The spec's wi.h, which equals wo.h for unit vectors. The binary64 inputs are unit
    only to ~1e-16, and where wi ~ -wo (grazing, nearly opposite) the literal wi.h and
    wo.h then differ by ~1e-16 / (1 + wi.wo), up to 1e-4 relative at these cases: a
    property of the rounded inputs, not of the spec. So the reference reads it as their
    mean, ((wi + wo)/2).h, which is symmetric and changes only by ~1e-16 / |wi + wo|."""
    return (dot(wi, h) + dot(wo, h)) / 2


def schlick(f0, wi, wo, h):
    """Schlick with 1 - wi.h written as the mean of |wi - h|^2 / 2 and |wo - h|^2 / 2,
    equal to it for unit vectors; the rounding of |wi| enters squared, so it stays
    accurate where wi ~ h and keeps the exact zero at retro-reflection with f0 = 0."""
    a = [x - y for x, y in zip(wi, h)]
    b = [x - y for x, y in zip(wo, h)]
    return f0 + (1 - f0) * ((dot(a, a) + dot(b, b)) / 4) ** 5


def f_model(model, p, wi, wo):
    """f(wi, wo) of docs/brdf.md, as written there."""
    ci, co = wi[2], wo[2]
    if ci <= 0 or co <= 0:
        return mp.mpf(0)
    if model == "lambertian":
        return 1 / mp.pi
    if model == "oren_nayar":
        s2 = mp.mpf(p["sigma"]) ** 2
        A = 1 - mp.mpf("0.5") * s2 / (s2 + mp.mpf("0.33"))
        B = mp.mpf("0.45") * s2 / (s2 + mp.mpf("0.09"))
        ti, to = mp.acos(ci), mp.acos(co)
        if ti == 0 or to == 0:  # the spec: B term is 0 when either is the normal
            return A / mp.pi
        pi_, po = mp.atan2(wi[1], wi[0]), mp.atan2(wo[1], wo[0])
        alpha, beta = max(ti, to), min(ti, to)
        return (A + B * max(0, mp.cos(pi_ - po)) * mp.sin(alpha) * mp.tan(beta)) / mp.pi
    h = half(wi, wo)
    ch = h[2]
    if model == "blinn_phong":
        n = mp.mpf(p["n"])
        return (n + 8) / (8 * mp.pi) * ch ** n
    if model == "ward":
        ax, ay = mp.mpf(p["ax"]), mp.mpf(p["ay"])
        e = -((h[0] / ax) ** 2 + (h[1] / ay) ** 2) / ch ** 2
        return mp.exp(e) / (4 * mp.pi * ax * ay * mp.sqrt(ci * co))
    if model == "cook_torrance":
        m, f0 = mp.mpf(p["m"]), mp.mpf(p["f0"])
        D = mp.exp(-(1 - ch ** 2) / (ch ** 2 * m ** 2)) / (mp.pi * m ** 2 * ch ** 4)
        F = schlick(f0, wi, wo, h)
        woh = cos_d(wi, wo, h)
        G = min(1, 2 * ch * co / woh, 2 * ch * ci / woh)
        return D * F * G / (4 * ci * co)
    if model == "lafortune":
        s = mp.mpf(p["cx"]) * wi[0] * wo[0] + mp.mpf(p["cy"]) * wi[1] * wo[1] + mp.mpf(p["cz"]) * wi[2] * wo[2]
        return s ** mp.mpf(p["n"]) if s > 0 else mp.mpf(0)
    if model == "ashikhmin_shirley":
        nu, nv, rs = mp.mpf(p["nu"]), mp.mpf(p["nv"]), mp.mpf(p["rs"])
        den = 1 - ch ** 2
        pw = mp.mpf(1) if den == 0 else ch ** ((nu * h[0] ** 2 + nv * h[1] ** 2) / den)
        wih = cos_d(wi, wo, h)
        return mp.sqrt((nu + 1) * (nv + 1)) / (8 * mp.pi) * pw / (wih * max(ci, co)) * schlick(rs, wi, wo, h)
    raise ValueError(model)


def spmm_frame(n):
    """The R_j frame rule of docs/brdf.md, literally."""
    x = [mp.mpf(1), mp.mpf(0), mp.mpf(0)]
    xp = [a - dot(x, n) * b for a, b in zip(x, n)]
    if mp.sqrt(dot(xp, xp)) < mp.mpf("1e-6"):
        y = [mp.mpf(0), mp.mpf(1), mp.mpf(0)]
        xp = normalize([a - dot(y, n) * b for a, b in zip(y, n)])
        yp = cross(n, xp)
        xp = cross(yp, n)
    else:
        xp = normalize(xp)
        yp = cross(n, xp)
    return xp, yp, n


def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def rho(model, p, n_dec, wi, wo):
    n = normalize(vec(n_dec))
    c = dot(n, wi)
    if c <= 0:
        return mp.mpf(0)
    fx, fy, fz = spmm_frame(n)
    loc = lambda v: [dot(v, fx), dot(v, fy), dot(v, fz)]
    return f_model(model, p, loc(wi), loc(wo)) * c


PARAMS = {
    "lambertian": [{}],
    "oren_nayar": [{"sigma": "0"}, {"sigma": "0.3"}, {"sigma": "1.5707963267948966"}],
    "blinn_phong": [{"n": "0"}, {"n": "1"}, {"n": "50"}, {"n": "10000"}, {"n": "100000"}],
    "ward": [{"ax": "0.2", "ay": "0.2"}, {"ax": "0.0001", "ay": "0.0001"}, {"ax": "0.0001", "ay": "0.5"}, {"ax": "1", "ay": "0.05"}],
    "cook_torrance": [{"m": "0.3", "f0": "0.04"}, {"m": "0.0001", "f0": "1"}, {"m": "1", "f0": "0"}, {"m": "0.05", "f0": "0.5"}],
    "lafortune": [
        {"cx": "-1", "cy": "-1", "cz": "1", "n": "20"},
        {"cx": "-0.8", "cy": "-0.3", "cz": "0.9", "n": "0"},
        {"cx": "-1", "cy": "-1", "cz": "1", "n": "10000"},
        {"cx": "1", "cy": "1", "cz": "-1", "n": "2"},
        {"cx": "-3", "cy": "2", "cz": "0.5", "n": "1.5"},
    ],
    "ashikhmin_shirley": [
        {"nu": "100", "nv": "100", "rs": "0.5"},
        {"nu": "1", "nv": "100000", "rs": "0.05"},
        {"nu": "100000", "nv": "100000", "rs": "1"},
        {"nu": "1", "nv": "1", "rs": "0"},
    ],
}


def direction_pairs():
    """Typical, grazing (cos 1e-7, 1e-4), near-mirror (for sharp lobes), normal,
    retro-reflection, and below-horizon pairs."""
    pairs = []
    for ci, phi in [("0.8", 0.3), ("0.3", 1.9), ("1e-4", 0.7), ("1e-7", 2.5), ("1", 0.0), ("0.999999", 4.0)]:
        wi = direction(ci, phi)
        mr = mirror(wi)
        pairs.append((wi, mr))  # exact mirror: h = n
        for d in ["1e-5", "1e-3", "0.05", "0.4"]:
            pairs.append((wi, rotate_about_z(mr, mp.mpf(d))))
            pairs.append((wi, tilt(mr, -mp.mpf(d))))  # towards the normal, stays above the horizon
        pairs.append((wi, wi))  # retro-reflection
        pairs.append((wi, direction("0.5", phi + 1.0)))
    # both grazing, nearly opposite: wi + wo is tiny
    pairs.append((direction("1e-7", 0.0), direction("1e-7", mp.pi)))
    pairs.append((direction("1e-7", 0.0), direction("2e-7", mp.pi + mp.mpf("1e-6"))))
    # below the horizon and on it
    pairs.append((direction("-0.5", 0.1), direction("0.5", 3.0)))
    pairs.append((direction("0.5", 0.1), direction("-1e-7", 3.0)))
    pairs.append((direction("0", 0.1), direction("0.5", 3.0)))
    return pairs


def main():
    pairs = direction_pairs()
    with open(os.path.join(HERE, "brdf_values.csv"), "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["model", "params", "wix", "wiy", "wiz", "wox", "woy", "woz", "f"])
        for model, plist in PARAMS.items():
            for p in plist:
                ps = ";".join("%s=%s" % kv for kv in p.items())
                for wi, wo in pairs:
                    val = f_model(model, p, vec(wi), vec(wo))
                    w.writerow([model, ps] + wi + wo + [mp.nstr(val, 20, strip_zeros=False)])
    normals = [
        ["0", "0", "1"],
        direction("0.9", 0.4),
        direction("0.2", 2.2),
        ["0.99999999999999", "0", "1e-7"],  # |x - (x.n)n| < 1e-6: the spec's fallback frame
        direction("0.6", 0.0),
    ]
    with open(os.path.join(HERE, "brdf_basis_values.csv"), "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["model", "params", "nx", "ny", "nz", "wix", "wiy", "wiz", "wox", "woy", "woz", "rho"])
        cases = [("ward", {"ax": "0.2", "ay": "0.05"}), ("ashikhmin_shirley", {"nu": "300", "nv": "10", "rs": "0.3"}),
                 ("oren_nayar", {"sigma": "0.5"}), ("lambertian", {}), ("cook_torrance", {"m": "0.2", "f0": "0.1"})]
        for model, p in cases:
            ps = ";".join("%s=%s" % kv for kv in p.items())
            for n in normals:
                for wi, wo in pairs[::3]:
                    val = rho(model, p, n, vec(wi), vec(wo))
                    w.writerow([model, ps] + n + wi + wo + [mp.nstr(val, 20, strip_zeros=False)])


if __name__ == "__main__":
    main()
