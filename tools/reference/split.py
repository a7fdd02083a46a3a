"""Split sylva's difference from the reference into direct sunlight and the rest, per class.

usage: python3 tools/reference/split.py OUT/SCENE LOCAL_BLACK_SKY.exr [SYLVA_DIR ...]

OUT/SCENE is a scene's directory of a `reference.py` run (its cached Mitsuba renders give the
reference, the classes and the direct-sun render); LOCAL_BLACK_SKY.exr is sylva's `--mode local`
image of the same scene and size with the sky colour set to black (the local image otherwise
also holds the sky seen between leaves), e.g.

    sylva scene source demo | sed 's/^color = \\[0.55, 0.70, 0.95\\]/color = [0.0, 0.0, 0.0]/' > nosky.toml
    sylva render nosky.toml --mode local --hdr --rpp 16 --width 240 -o nosky/sylva.png

and each SYLVA_DIR holds a `sylva-full.exr` and `sylva-local.exr` to compare (default:
OUT/SCENE/sylva). Per class it prints the direct sun (sylva's black-sky local image against
Mitsuba's direct-sun render), the sky sylva sees between leaves, and the rest (full image less
direct sun, in both) with its ratio.
"""

import sys
from pathlib import Path

import numpy as np

import metrics


def main(argv):
    if len(argv) < 2:
        sys.exit(__doc__)
    import mitsuba as mi

    mi.set_variant("scalar_rgb")

    def read(p):
        b = mi.Bitmap(str(p)).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False)
        return np.array(b)

    scene_dir = Path(argv[0]).resolve()
    nosky = metrics.luminance(read(Path(argv[1]).resolve()))
    dirs = [Path(d).resolve() for d in argv[2:]] or [scene_dir / "sylva"]
    caches = sorted((scene_dir / "mitsuba").iterdir(), key=lambda p: p.stat().st_mtime)
    if not caches:
        sys.exit(f"{scene_dir / 'mitsuba'}: no cached renders")
    cache = caches[-1]
    refs = [read(p) for p in sorted(cache.glob("reference-*seed*.exr"))]
    ref = metrics.luminance(0.5 * (refs[0] + refs[1]))
    cov = read(sorted(cache.glob("coverage-*.exr"))[0])
    sun = metrics.luminance(read(sorted(cache.glob("sun-*.exr"))[0]))
    classes = metrics.classify(cov[..., 0], cov[..., 1], sun)
    for d in dirs:
        full = metrics.luminance(read(d / "sylva-full.exr"))
        local = metrics.luminance(read(d / "sylva-local.exr"))
        print(d)
        print(f"  {'class':16s} {'direct: sylva':>14s} {'Mitsuba':>8s} {'sky seen':>9s} "
              f"{'rest: sylva':>12s} {'Mitsuba':>8s} {'ratio':>6s}")
        for name in ("plant", "plant sunlit", "plant shadowed", "ground", "ground shadowed"):
            m = classes[name]
            if not m.any():
                continue
            rest_s = (full - nosky)[m].mean()
            rest_m = (ref - sun)[m].mean()
            ratio = rest_s / rest_m if rest_m > 0 else float("nan")
            print(f"  {name:16s} {nosky[m].mean():14.4f} {sun[m].mean():8.4f} "
                  f"{(local - nosky)[m].mean():9.4f} {rest_s:12.4f} {rest_m:8.4f} {ratio:6.3f}")


if __name__ == "__main__":
    main(sys.argv[1:])
