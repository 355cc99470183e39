#!/usr/bin/env python3
"""Independent reference values for `meso_materials::metrics::compare` (docs/formats/images.md).

Builds fixed image pairs deterministically (fixed numpy seeds), writes them as EXR
fixtures with the OpenEXR Python bindings, reads them back, and computes RMSE, PSNR,
MSSIM (scikit-image) and the largest error on exactly the stored samples. Writes
metrics_values.json next to this script. It does not use any Meso code.

Run from the repository root:  /work/venv/bin/python tests/reference/metrics_reference.py
"""

import json
from pathlib import Path

import numpy as np
import OpenEXR
import scipy
import skimage
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

HERE = Path(__file__).resolve().parent
FIXTURES = HERE / "metrics_fixtures"
VALUES = HERE / "metrics_values.json"

# Rec. 709 luminance weights (ITU-R BT.709-6, item 3.2).
LUMA = np.array([0.2126, 0.7152, 0.0722])

# The SSIM settings of Wang et al. 2004 as scikit-image spells them (its docstring:
# "To match the implementation of Wang et al. set gaussian_weights to True, sigma to
# 1.5, use_sample_covariance to False, and specify the data_range argument").
SSIM_SETTINGS = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0)


# ---------------------------------------------------------------------------------------
# Image pairs. Arrays are (height, width, 3), row 0 at the top, linear radiance.


def grid(width, height):
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    return x, y


def gradient_pattern(width, height, phase=0.0, contrast=1.0):
    """A smooth colour gradient from near 0 plus a sinusoidal texture."""
    x, y = grid(width, height)
    u, v = x / (width - 1), y / (height - 1)
    texture = 0.15 * contrast * np.sin(0.8 * x + phase) * np.cos(0.45 * y - 0.5 * phase)
    r = 0.02 + 0.6 * u + texture
    g = 0.05 + 0.5 * v - 0.5 * texture
    b = 0.3 * u * v + 0.1 + 0.3 * texture
    return np.stack([r, g, b], axis=-1)


def blur(img):
    """Separable binomial [1 4 6 4 1] / 16 blur with edge replication."""
    k = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0
    out = img
    for axis in (0, 1):
        pad = [(0, 0)] * 3
        pad[axis] = (2, 2)
        p = np.pad(out, pad, mode="edge")
        n = out.shape[axis]
        out = sum(k[i] * np.take(p, np.arange(i, i + n), axis=axis) for i in range(5))
    return out


def highlights(width, height):
    """An HDR scene: a dim gradient with bright spots up to about 4, so that the SSIM
    clamp to [0, 1] matters at exposure 0 and not at -2 stops."""
    x, y = grid(width, height)
    base = gradient_pattern(width, height) * 0.8
    spot = 3.5 * np.exp(-((x - 0.3 * width) ** 2 + (y - 0.4 * height) ** 2) / 18.0)
    spot += 2.0 * np.exp(-((x - 0.75 * width) ** 2 + (y - 0.7 * height) ** 2) / 8.0)
    return base + spot[..., None] * np.array([1.0, 0.9, 0.7])


def build_pairs():
    """Returns (images, pairs). images: fixture file stem -> (array, storage), storage
    'float' (RGB float32), 'half' (RGB half) or 'half_y' (Y-only half grey). pairs:
    (case name, reference stem, test stem, exposure_stops)."""
    images, pairs = {}, []
    ref = gradient_pattern(64, 48)
    images["gradient"] = (ref, "float")
    images["gradient_shifted"] = (gradient_pattern(64, 48, phase=0.7, contrast=0.8), "float")
    # The gradient starts near 0, so the noise also makes negative radiance: RMSE sees it
    # as it is, SSIM's luminance clamps it to 0.
    images["gradient_noisy"] = (ref + np.random.default_rng(20240611).normal(0.0, 0.05, ref.shape), "float")
    images["gradient_blurred"] = (blur(ref), "float")
    pairs += [
        ("identical", "gradient", "gradient", 0.0),
        ("pattern_shift", "gradient", "gradient_shifted", 0.0),
        ("gaussian_noise", "gradient", "gradient_noisy", 0.0),
        ("blurred", "gradient", "gradient_blurred", 0.0),
    ]

    small = gradient_pattern(29, 13, phase=0.3)
    images["small"] = (small, "float")
    images["small_noisy"] = (small + np.random.default_rng(7).normal(0.0, 0.03, small.shape), "float")
    pairs.append(("non_square_small", "small", "small_noisy", 0.5))

    hdr = highlights(40, 32)
    images["highlights"] = (hdr, "float")
    images["highlights_brighter"] = (hdr * 1.1 + np.random.default_rng(99).normal(0.0, 0.02, hdr.shape), "float")
    pairs.append(("highlights_clamped", "highlights", "highlights_brighter", 0.0))
    pairs.append(("highlights_exposed", "highlights", "highlights_brighter", -2.0))

    outlier = gradient_pattern(37, 23, phase=1.1)
    spiked = outlier + np.random.default_rng(5).normal(0.0, 0.01, outlier.shape)
    spiked[9, 17, 1] += 5.0  # row 9, column 17, green: the largest error by far
    images["outlier"] = (outlier, "float")
    images["outlier_spiked"] = (spiked, "float")
    pairs.append(("single_outlier", "outlier", "outlier_spiked", 0.0))

    grey = np.repeat((gradient_pattern(33, 21, phase=2.0) @ LUMA)[..., None], 3, axis=-1)
    images["grey_y_half"] = (grey, "half_y")
    images["grey_noisy_half"] = (grey + np.random.default_rng(11).normal(0.0, 0.04, grey.shape), "half")
    pairs.append(("half_and_luminance_only", "grey_y_half", "grey_noisy_half", 1.0))
    return images, pairs


# ---------------------------------------------------------------------------------------
# EXR files.


def write_exr(path, img, storage):
    dtype = np.float32 if storage == "float" else np.float16
    if storage == "half_y":
        channels = {"Y": np.ascontiguousarray(img[..., 0], dtype=dtype)}
    else:
        channels = {c: np.ascontiguousarray(img[..., i], dtype=dtype) for i, c in enumerate("RGB")}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, channels).write(str(path))


def read_exr(path):
    """The stored samples as float64 (height, width, 3); a Y-only file becomes grey."""
    channels = OpenEXR.File(str(path), separate_channels=True).channels()
    if all(c in channels for c in "RGB"):
        planes = [channels[c].pixels for c in "RGB"]
    else:
        planes = [channels["Y"].pixels] * 3
    return np.stack([p.astype(np.float64) for p in planes], axis=-1)


# ---------------------------------------------------------------------------------------
# Metrics, exactly as docs/formats/images.md defines them.


def valid_mssim_direct(a, b):
    """Mean SSIM over the positions where the 11x11 window fits, by brute force: the
    definition Meso states. Used only to confirm that scikit-image's cropped mean of its
    'reflect'-padded map is the same number (the crop removes exactly the padded part)."""
    r = 5
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / 1.5) ** 2)
    k /= k.sum()
    w2 = np.outer(k, k)
    c1, c2 = 0.01**2, 0.03**2
    h, w = a.shape
    vals = []
    for cy in range(r, h - r):
        for cx in range(r, w - r):
            pa, pb = a[cy - r : cy + r + 1, cx - r : cx + r + 1], b[cy - r : cy + r + 1, cx - r : cx + r + 1]
            ma, mb = (w2 * pa).sum(), (w2 * pb).sum()
            va, vb = (w2 * pa * pa).sum() - ma * ma, (w2 * pb * pb).sum() - mb * mb
            cov = (w2 * pa * pb).sum() - ma * mb
            vals.append((2 * ma * mb + c1) * (2 * cov + c2) / ((ma * ma + mb * mb + c1) * (va + vb + c2)))
    return float(np.mean(vals))


def metrics(ref, test, stops):
    s = 2.0**stops
    d = (test - ref) * s
    rmse = float(np.sqrt(np.mean(d * d)))
    psnr = None if rmse == 0.0 else float(20.0 * np.log10(1.0 / rmse))
    if psnr is not None:
        # scikit-image's PSNR (10 log10(range^2 / MSE)) on the exposed images must agree.
        sk = peak_signal_noise_ratio(ref * s, test * s, data_range=1.0)
        assert abs(sk - psnr) <= 1e-12 * abs(psnr), (sk, psnr)
    flat = int(np.argmax(np.abs(d)))  # first maximum in (row, column, channel) order
    pixel = flat // 3
    h, w = ref.shape[:2]

    def luma(img):
        return np.clip((LUMA[0] * img[..., 0] + LUMA[1] * img[..., 1] + LUMA[2] * img[..., 2]) * s, 0.0, 1.0)

    lr, lt = luma(ref), luma(test)
    assert lr.dtype == np.float64  # scikit-image computes in the input's float type
    mssim = float(structural_similarity(lr, lt, **SSIM_SETTINGS))
    direct = valid_mssim_direct(lr, lt)
    assert abs(direct - mssim) < 1e-12, (direct, mssim)
    return dict(
        rmse=rmse,
        psnr_db=psnr,
        mssim=mssim,
        max_abs_error=float(np.abs(d).max()),
        max_error_pixel=[pixel % w, pixel // w],
        width=w,
        height=h,
    )


def main():
    FIXTURES.mkdir(exist_ok=True)
    images, pairs = build_pairs()
    for stem, (img, storage) in images.items():
        write_exr(FIXTURES / f"{stem}.exr", img, storage)
    cases = []
    for name, ref_stem, test_stem, stops in pairs:
        ref_path, test_path = FIXTURES / f"{ref_stem}.exr", FIXTURES / f"{test_stem}.exr"
        # Measure the samples as stored (float32 or half), which is what Meso reads.
        case = dict(
            name=name,
            reference=ref_path.relative_to(HERE).as_posix(),
            test=test_path.relative_to(HERE).as_posix(),
            exposure_stops=stops,
        )
        case.update(metrics(read_exr(ref_path), read_exr(test_path), stops))
        cases.append(case)
        print(f"{name:24s} rmse {case['rmse']:.6e}  mssim {case['mssim']:.6f}  max {case['max_abs_error']:.4f}")

    out = dict(
        generator="tests/reference/metrics_reference.py",
        versions=dict(
            numpy=np.__version__, scipy=scipy.__version__, scikit_image=skimage.__version__, openexr=OpenEXR.__version__
        ),
        definitions=dict(
            exposure="both images scaled by 2**exposure_stops",
            rmse="sqrt(mean over pixels and 3 channels of (test - ref)**2), linear, unclamped, float64",
            psnr_db="20 log10(1 / rmse); null when rmse = 0",
            mssim="skimage.metrics.structural_similarity(ref_luma, test_luma, "
            + ", ".join(f"{k}={v}" for k, v in SSIM_SETTINGS.items())
            + ") on clip((0.2126 R + 0.7152 G + 0.0722 B) * 2**stops, 0, 1) in float64",
            max_abs_error="max |test - ref| after exposure; max_error_pixel = [x, y] of the first maximum",
        ),
        cases=cases,
    )
    VALUES.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {VALUES.relative_to(HERE.parent.parent)} and {len(images)} fixtures")


if __name__ == "__main__":
    main()
