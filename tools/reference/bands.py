#!/usr/bin/env python3
"""A scene's spectral bands (`[bands]`) against Mitsuba: sylva renders the scene's first band
group (`sylva render`, 16 rays/pixel; its EXR has a part per band), Mitsuba renders the same
group's export (`sylva export --band-group 0`), and each band's mean radiance is compared over
the pixels that are not sky and over those in the image's upper half. Without `--bands` the
scene is compared in RGB the same way (`render --hdr`), as a baseline.

    python3 tools/reference/bands.py docs/examples/red_nir.toml --bands --spp 64
    python3 tools/reference/bands.py docs/examples/glade.toml --spp 64

Needs `pip install OpenEXR` (to read the multi-part EXR) beside requirements.txt. A mean over
a region, not a per-pixel error: tools/reference/reference.py measures those in RGB.
"""

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import reference  # noqa: E402  (the Mitsuba variant's choice)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--bands", action="store_true", help="the scene has [bands]: compare band group 0")
    ap.add_argument("--spp", type=int, default=64, help="Mitsuba's samples per pixel")
    ap.add_argument("--out", default="sylva-out/bands-reference", help="working directory")
    ap.add_argument("--sylva", default="target/release/sylva")
    a = ap.parse_args(argv)
    variant, why = reference.choose_variant(None)
    import mitsuba as mi

    mi.set_variant(variant)
    out = Path(a.out)
    os.makedirs(out, exist_ok=True)
    t = time.time()
    render = [a.sylva, "render", a.scene, "--rpp", "16", "-o", str(out / "sylva.png")]
    if not a.bands:
        render.append("--hdr")
    subprocess.run(render, check=True, capture_output=True)
    t_sylva = time.time() - t
    if a.bands:
        import OpenEXR

        parts = OpenEXR.File(str(out / "sylva.exr")).parts
        names = [p.name() for p in parts][:3]
        sy = np.stack([np.asarray(p.channels["Y"].pixels, np.float32) for p in parts[:3]], -1)
    else:
        names = ["R", "G", "B"]
        sy = np.array(mi.Bitmap(str(out / "sylva.exr")))[..., :3]
    export = [a.sylva, "export", a.scene, "--format", "mitsuba", "-o", str(out / "mitsuba")]
    if a.bands:
        export += ["--band-group", "0"]
    subprocess.run(export, check=True, capture_output=True)
    t = time.time()
    ref = np.array(mi.render(mi.load_file(str(out / "mitsuba" / "scene.xml")), spp=a.spp))[..., :3]
    t_mitsuba = time.time() - t
    # Sky: sylva's pixels equal, in every channel, to its top-left pixel (the sky's radiance).
    sky = np.all(np.abs(sy - sy[0, 0]) < 1e-6, axis=-1)
    upper = np.zeros_like(sky)
    upper[: sky.shape[0] // 2] = True
    print(
        f"{a.scene}: sylva 16 rays/pixel {t_sylva:.1f} s, Mitsuba {variant} ({why}) "
        f"{a.spp} spp {t_mitsuba:.1f} s; sky {sky.mean():.2f} of the image"
    )
    for c, n in enumerate(names):
        for label, m in [("not sky", ~sky), ("upper half, not sky", ~sky & upper)]:
            s, r = sy[..., c][m].mean(), ref[..., c][m].mean()
            print(f"  {n:<6} {label:<20} sylva {s:.4f}  Mitsuba {r:.4f}  ratio {s / r:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
