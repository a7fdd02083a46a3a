"""Pixel classes, per-class comparison metrics and least-squares fits (numpy only).

Everything here works on linear images (H×W×3 float arrays) or their luminance (H×W), so the
module can be tested on synthetic images without Mitsuba or sylva.
"""

import math

import numpy as np

# Rec. 709 / linear sRGB luminance weights, as sylva_core::luminance.
LUMA = np.array([0.2126, 0.7152, 0.0722])

# A pixel belongs to a pure class when at least this fraction of its samples saw that class.
PURE = 0.99

# A sky pixel whose transmittance through media is below this shows a medium (a cloud).
MEDIUM_CLEAR = 0.98
# A medium pixel with transmittance below this is opaque: its light is the medium's alone.
MEDIUM_OPAQUE = 0.05

# Report order. "mixed" pixels straddle an outline (plant against sky or ground). The
# medium classes only exist for scenes with media: sky pixels seen through a cloud.
CLASSES = (
    "all",
    "sky",
    "ground",
    "ground sunlit",
    "ground shadowed",
    "plant",
    "plant sunlit",
    "plant shadowed",
    "mixed",
    "medium",
    "medium opaque",
    "medium edge",
)


def luminance(rgb):
    """Luminance of an H×W×C (C ≥ 3) linear RGB image, as float64."""
    return np.asarray(rgb, dtype=np.float64)[..., :3] @ LUMA


def classify(sky_coverage, ground_coverage, direct_sun, pure=PURE, transmittance=None):
    """Boolean masks of the pixel classes in `CLASSES`.

    `sky_coverage`, `ground_coverage`: per pixel, the fraction of its samples whose camera ray
    escaped to the sky or hit the ground (through transparent leaf texels; media left out);
    the rest hit a plant. `direct_sun`: the luminance of a direct-sunlight-only render; a pixel
    with none is shadowed (occluded, or wood facing away from the sun), any is sunlit.
    `transmittance` (scenes with media): per pixel, the mean transmittance of its camera rays
    through the media up to the sky; sky pixels below `MEDIUM_CLEAR` are medium pixels, split
    into opaque (below `MEDIUM_OPAQUE`) and edge.
    """
    sky_coverage = np.asarray(sky_coverage, dtype=np.float64)
    ground_coverage = np.asarray(ground_coverage, dtype=np.float64)
    direct_sun = np.asarray(direct_sun, dtype=np.float64)
    if not (sky_coverage.shape == ground_coverage.shape == direct_sun.shape):
        raise ValueError(
            f"class images differ in size: sky {sky_coverage.shape}, "
            f"ground {ground_coverage.shape}, sun {direct_sun.shape}"
        )
    plant_coverage = 1.0 - sky_coverage - ground_coverage
    sky = sky_coverage >= pure
    if transmittance is None:
        transmittance = np.ones(sky.shape)
    transmittance = np.asarray(transmittance, dtype=np.float64)
    if transmittance.shape != sky.shape:
        raise ValueError(
            f"class images differ in size: sky {sky.shape}, transmittance {transmittance.shape}"
        )
    medium = sky & (transmittance < MEDIUM_CLEAR)
    opaque = medium & (transmittance < MEDIUM_OPAQUE)
    ground = ground_coverage >= pure
    plant = plant_coverage >= pure
    lit = direct_sun > 0.0
    return {
        "all": np.ones(sky.shape, dtype=bool),
        "sky": sky & ~medium,
        "ground": ground,
        "ground sunlit": ground & lit,
        "ground shadowed": ground & ~lit,
        "plant": plant,
        "plant sunlit": plant & lit,
        "plant shadowed": plant & ~lit,
        "mixed": ~(sky | ground | plant),
        "medium": medium,
        "medium opaque": opaque,
        "medium edge": medium & ~opaque,
    }


def fit_scale(base, basis, target, mask):
    """The c minimising Σ (base + c·basis − target)² over `mask` (closed form), or None when
    the basis is zero there (nothing to fit)."""
    b = np.asarray(basis, dtype=np.float64)[mask]
    r = np.asarray(target, dtype=np.float64)[mask] - np.asarray(base, dtype=np.float64)[mask]
    denom = float(np.dot(b, b))
    if denom <= 0.0 or not math.isfinite(denom):
        return None
    return float(np.dot(b, r) / denom)


def _finite_or_none(x):
    return float(x) if x is not None and math.isfinite(x) else None


def compare(test, ref_a, ref_b, mask):
    """Luminance metrics of `test` against the reference (mean of `ref_a` and `ref_b`, two
    renders with different seeds) over `mask`.

    The reference's own noise is estimated from the two seeds: per pixel E[(a − b)²] = 2σ²,
    so mean((a − b)²)/2 is one render's noise variance and half of that the variance of their
    mean, which is what the squared error of `test` against the mean contains on top of the
    real difference; it is subtracted (clamped at zero).

    Returns a dict: pixels, ref_mean, test_mean, ratio (test/ref mean luminance),
    rel_rmse_raw (RMS difference / ref mean, noise included), rel_rmse (noise subtracted),
    ref_noise (one render's RMS noise / ref mean), noise_share (the fraction of the raw squared
    error that was reference noise). Values that are undefined (no pixels, zero reference)
    are None.
    """
    test = np.asarray(test, dtype=np.float64)
    a = np.asarray(ref_a, dtype=np.float64)
    b = np.asarray(ref_b, dtype=np.float64)
    if not (test.shape == a.shape == b.shape == np.shape(mask)):
        raise ValueError(
            f"images differ in size: test {test.shape}, references {a.shape} and {b.shape}, "
            f"mask {np.shape(mask)}"
        )
    n = int(np.count_nonzero(mask))
    out = {
        "pixels": n,
        "ref_mean": None,
        "test_mean": None,
        "ratio": None,
        "rel_rmse_raw": None,
        "rel_rmse": None,
        "ref_noise": None,
        "noise_share": None,
    }
    if n == 0:
        return out
    t, a, b = test[mask], a[mask], b[mask]
    ref = 0.5 * (a + b)
    ref_mean = float(ref.mean())
    test_mean = float(t.mean())
    render_noise_var = float(np.mean((a - b) ** 2)) / 2.0
    mse = float(np.mean((t - ref) ** 2))
    corrected = max(mse - render_noise_var / 2.0, 0.0)
    out["ref_mean"] = ref_mean
    out["test_mean"] = test_mean
    if ref_mean > 0.0:
        out["ratio"] = test_mean / ref_mean
        out["rel_rmse_raw"] = math.sqrt(mse) / ref_mean
        out["rel_rmse"] = math.sqrt(corrected) / ref_mean
        out["ref_noise"] = math.sqrt(render_noise_var) / ref_mean
    if mse > 0.0:
        out["noise_share"] = min(render_noise_var / 2.0 / mse, 1.0)
    return {k: (_finite_or_none(v) if k != "pixels" else v) for k, v in out.items()}


def channel_ratios(test_rgb, ref_rgb, mask):
    """Mean of each colour channel of `test_rgb` over that of `ref_rgb` on `mask` (R, G, B),
    None for a channel whose reference mean is zero or a class without pixels: shows a
    colour shift (e.g. a per-colour transmission) that luminance alone hides."""
    t = np.asarray(test_rgb, dtype=np.float64)[..., :3][mask]
    r = np.asarray(ref_rgb, dtype=np.float64)[..., :3][mask]
    if t.shape[0] == 0:
        return [None, None, None]
    tm, rm = t.mean(axis=0), r.mean(axis=0)
    return [float(a / b) if b > 0 else None for a, b in zip(tm, rm)]


def equal_error(rel_rmse, ref_noise, spp, ref_seconds, sylva_seconds):
    """What the path tracer would take to reach sylva's error (issue 28's "time to equal error").

    One reference render at `spp` samples has relative RMS noise `ref_noise`, which falls as
    1/sqrt(samples), so the path tracer reaches sylva's `rel_rmse` (its difference from the
    two-seed reference, that reference's noise subtracted) at
    `spp_needed = spp · (ref_noise / rel_rmse)²`, taking `ref_seconds · spp_needed / spp`
    (`ref_seconds`: one render at `spp`, on the same cores). `speedup` is that over
    `sylva_seconds`. Returns a dict of those, or None where sylva's error is not above zero
    (within the reference's noise: the reference cannot tell how many samples would match it).
    """
    if not (rel_rmse and ref_noise and spp and ref_seconds and sylva_seconds):
        return None
    if rel_rmse <= 0.0 or ref_noise <= 0.0 or sylva_seconds <= 0.0:
        return None
    spp_needed = spp * (ref_noise / rel_rmse) ** 2
    seconds = ref_seconds * spp_needed / spp
    return {
        "spp_needed": spp_needed,
        "seconds": seconds,
        "sylva_seconds": sylva_seconds,
        "speedup": seconds / sylva_seconds,
    }

