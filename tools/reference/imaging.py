"""Pictures for people (numpy only): tone mapping, a diverging map of signed differences, a
map of the pixel classes, and a side-by-side strip. All return H×W×3 uint8 sRGB arrays."""

import numpy as np

from metrics import LUMA, luminance

# Moreland's cool-warm diverging map: blue (negative), light grey (zero), red (positive).
_COOL = np.array([59, 76, 192], dtype=np.float64)
_MID = np.array([221, 221, 221], dtype=np.float64)
_WARM = np.array([180, 4, 38], dtype=np.float64)

# Colours of the class map (sRGB bytes).
CLASS_COLOURS = {
    "sky": (150, 200, 255),
    "ground sunlit": (220, 190, 130),
    "ground shadowed": (120, 95, 60),
    "plant sunlit": (170, 230, 60),
    "plant shadowed": (20, 90, 30),
    "mixed": (230, 60, 200),
    "medium opaque": (250, 250, 250),
    "medium edge": (170, 170, 185),
}


def srgb8(linear):
    """Linear [0, 1] values to 8-bit sRGB (IEC 61966-2-1)."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def log_average(lum, delta=1e-6):
    """Reinhard's log-average luminance."""
    return float(np.exp(np.mean(np.log(delta + np.asarray(lum, dtype=np.float64)))))


def tonemap(rgb, exposure_lum, key=0.18):
    """Reinhard's global operator (as `sylva render`): the log-average `exposure_lum` maps to
    `key`, white = the largest scaled colour value (any channel) of the image's lit pixels, so
    a blue sky that is the brightest thing in view keeps its hue. Pass the same `exposure_lum`
    to images that should be compared, so a brighter image looks brighter."""
    rgb = np.asarray(rgb, dtype=np.float64)[..., :3]
    lw = rgb @ LUMA
    scaled = key * lw / max(exposure_lum, 1e-12)
    top = np.where(lw > 0.0, rgb.max(axis=-1), 0.0)
    white2 = max(float(top.max()) * key / max(exposure_lum, 1e-12), 1e-12) ** 2
    ld = scaled * (1.0 + scaled / white2) / (1.0 + scaled)
    ratio = np.where(lw > 0.0, ld / np.maximum(lw, 1e-30), 0.0)
    return srgb8(rgb * ratio[..., None])


def diverging(signed, scale):
    """Signed values to the cool-warm map: 0 is grey, ±`scale` and beyond full blue/red."""
    t = np.clip(np.asarray(signed, dtype=np.float64) / scale, -1.0, 1.0)[..., None]
    pos = _MID + (_WARM - _MID) * np.clip(t, 0.0, 1.0)
    neg = _MID + (_COOL - _MID) * np.clip(-t, 0.0, 1.0)
    return np.round(np.where(t >= 0.0, pos, neg)).astype(np.uint8)


def class_map(classes):
    """The pixel classes in `CLASS_COLOURS`' colours (see metrics.classify)."""
    shape = classes["all"].shape
    out = np.zeros(shape + (3,), dtype=np.uint8)
    for name, colour in CLASS_COLOURS.items():
        out[classes[name]] = colour
    return out


def side_by_side(images, gap=4, background=255):
    """Images of one height, left to right, `gap` pixels apart."""
    h = images[0].shape[0]
    if any(im.shape[0] != h for im in images):
        raise ValueError("side_by_side: images differ in height")
    parts = []
    for k, im in enumerate(images):
        if k:
            parts.append(np.full((h, gap, 3), background, dtype=np.uint8))
        parts.append(im)
    return np.concatenate(parts, axis=1)


def luminance_difference(test, ref):
    """Per-pixel luminance of test − ref."""
    return luminance(test) - luminance(ref)
