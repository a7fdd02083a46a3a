"""Render a scene exported by `sylva export SCENE --format mitsuba -o DIR` with Mitsuba 3.

    pip install mitsuba
    python render_mitsuba.py DIR/scene.xml out.png [SPP] [SCALE]

Writes the linear HDR image as render.exr beside scene.xml. SCALE > 1 averages SCALE×SCALE
pixel blocks of the linear image before the sRGB PNG is written (smaller files for docs).
"""
import sys
import time
from pathlib import Path

import mitsuba as mi

mi.set_variant("scalar_rgb")
xml, png = sys.argv[1], sys.argv[2]
spp = int(sys.argv[3]) if len(sys.argv) > 3 else 64
scale = int(sys.argv[4]) if len(sys.argv) > 4 else 1

t = time.time()
scene = mi.load_file(xml, spp=spp)
print(f"loaded {xml} in {time.time() - t:.1f} s")
t = time.time()
image = mi.render(scene)
print(f"rendered {spp} spp in {time.time() - t:.1f} s")
mi.util.write_bitmap(str(Path(xml).with_name("render.exr")), image)
if scale > 1:
    import numpy as np

    a = np.array(image)
    h, w = a.shape[0] // scale, a.shape[1] // scale
    a = a[: h * scale, : w * scale].reshape(h, scale, w, scale, -1).mean(axis=(1, 3))
    image = mi.TensorXf(a)
mi.util.write_bitmap(png, image)
