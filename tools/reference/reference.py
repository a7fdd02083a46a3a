#!/usr/bin/env python3
"""Compare sylva's renderer with a Mitsuba 3 path-traced reference, pixel class by class.

    python3 tools/reference/reference.py catalpa demo --spp 512

For each scene (a built-in name or a scene file): export it with `sylva export --format
mitsuba`, render the reference at --spp with two seeds (cached under the export's content
hash), render sylva (`sylva render --mode all --hdr --rpp 16`) at the same resolution, classify
the pixels with two cheap Mitsuba renders, and write results.md / results.json and PNGs. See
tools/reference/README.md and docs/reference.md.
"""

import argparse
import glob
import hashlib
import json
import math
import os
import re
import shlex
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(HERE))

import imaging  # noqa: E402
import metrics  # noqa: E402

# Samples per pixel of the two classification renders (stratified: 8×8 per pixel).
CLASS_SPP = 64
# Print each render's progress (the tests turn it off).
PROGRESS = True
# Camera rays per pass of the LLVM variant: bounds the wavefront's memory (about 1 GiB).
LLVM_LANES_PER_PASS = 1 << 22

# The probe run in a child process before the LLVM variant is trusted: drjit with an old
# libLLVM (14, 15) aborts the whole process inside LLVM ("Cannot select ... fminimum") when
# it compiles volpath with a mask, which Python cannot catch.
_LLVM_PROBE = """
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
s = mi.load_dict({
    "type": "scene",
    "integrator": {"type": "volpath", "max_depth": 4},
    "sensor": {"type": "perspective", "to_world": mi.ScalarTransform4f().look_at(
        origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0]),
        "film": {"type": "hdrfilm", "width": 8, "height": 8},
        "sampler": {"type": "independent", "sample_count": 2}},
    "sun": {"type": "directional", "direction": [0, -1, -1]},
    "sky": {"type": "constant"},
    "leaf": {"type": "rectangle", "bsdf": {"type": "mask", "opacity": 0.5,
        "bsdf": {"type": "principledthin", "diff_trans": 1.0}}},
})
mi.render(s)
print("ok")
"""


def say(msg):
    print(msg, flush=True)


class HarnessError(Exception):
    """A problem to report in one line (bad input, a failed command, an unreadable file)."""


def fail(msg):
    raise HarnessError(msg)


# ---------------------------------------------------------------------------------- variant


def libllvm_candidates():
    """libLLVM shared libraries on this machine, newest major version first."""
    found = {}
    pats = [
        "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
        "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
        "/usr/lib/llvm-*/lib/libLLVM*.so*",
        "/usr/lib/libLLVM*.so*",
        "/usr/local/lib/libLLVM*.so*",
        "/opt/homebrew/opt/llvm/lib/libLLVM.dylib",
        "/usr/local/opt/llvm/lib/libLLVM.dylib",
    ]
    for pat in pats:
        for p in glob.glob(pat):
            m = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", Path(p).name)
            major = int(m.group(1)) if m else 0
            found.setdefault(major, p)
    return [found[k] for k in sorted(found, reverse=True)]


def llvm_works(lib):
    env = dict(os.environ)
    if lib:
        env["DRJIT_LIBLLVM_PATH"] = lib
    try:
        r = subprocess.run(
            [sys.executable, "-c", _LLVM_PROBE],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
    except subprocess.TimeoutExpired:
        return False
    return r.returncode == 0 and r.stdout.strip().endswith("ok")


def choose_variant(requested):
    """The Mitsuba variant to use, and why. Sets DRJIT_LIBLLVM_PATH for the LLVM variant
    (before mitsuba is imported)."""
    if requested and requested != "llvm_ad_rgb":
        return requested, "requested"
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        lib = os.environ["DRJIT_LIBLLVM_PATH"]
        if llvm_works(lib):
            return "llvm_ad_rgb", f"DRJIT_LIBLLVM_PATH={lib}"
        fail(f"the LLVM variant does not run with DRJIT_LIBLLVM_PATH={lib} (try libLLVM 19)")
    for lib in libllvm_candidates():
        if llvm_works(lib):
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
            return "llvm_ad_rgb", f"with {lib}"
    if requested == "llvm_ad_rgb":
        fail("the LLVM variant does not run with any libLLVM here (apt-get install libllvm19)")
    return "scalar_rgb", "no working libLLVM (apt-get install libllvm19 for the faster llvm_ad_rgb)"


# ---------------------------------------------------------------------------------- files


def atomic_write_bytes(path, data):
    tmp = path.with_name(f".{path.name}.partial")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def atomic_write_text(path, text):
    atomic_write_bytes(path, text.encode("utf-8"))


def write_exr(mi, path, array):
    # Bitmap picks the format from the extension, so the temporary name keeps ".exr".
    tmp = path.with_name(f".partial-{path.name}")
    mi.Bitmap(np.ascontiguousarray(array, dtype=np.float32)).write(str(tmp))
    os.replace(tmp, path)


def write_png(mi, path, array):
    tmp = path.with_name(f".partial-{path.name}")
    mi.Bitmap(np.ascontiguousarray(array, dtype=np.uint8)).write(str(tmp))
    os.replace(tmp, path)


def read_exr(mi, path):
    try:
        a = np.array(mi.Bitmap(str(path)), dtype=np.float32)
    except Exception as e:  # Mitsuba raises RuntimeError with its own message
        fail(f"{path}: cannot read as OpenEXR ({str(e).strip()})")
    if a.ndim != 3 or a.shape[2] < 3:
        fail(f"{path}: expected an RGB image, got shape {a.shape}")
    if not np.all(np.isfinite(a[..., :3])):
        fail(f"{path}: the image has NaN or infinite pixels")
    return a[..., :3]


def export_hash(export_dir):
    """SHA-256 over the exported files (scene.xml, meshes/, textures/, media/): names and
    bytes."""
    h = hashlib.sha256()
    files = [export_dir / "scene.xml"]
    for sub in ("meshes", "textures", "media"):
        files += sorted((export_dir / sub).glob("*"))
    for f in files:
        rel = f.relative_to(export_dir).as_posix()
        h.update(rel.encode() + b"\0")
        h.update(f.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:16]


def git_commit():
    try:
        head = subprocess.run(
            ["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        return head + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return None


# ---------------------------------------------------------------------------------- sylva


def run_sylva(sylva, args, what):
    say(f"$ {shlex.join([str(sylva)] + args)}")
    t = time.time()
    r = subprocess.run([str(sylva)] + args, capture_output=True, text=True)
    if r.returncode != 0:
        fail(f"{what} failed (exit {r.returncode}):\n{r.stderr.strip() or r.stdout.strip()}")
    return r.stdout, time.time() - t


def sylva_default_indirect(sylva):
    """`--indirect`'s default, read from `sylva render --help` so the harness follows it."""
    out = subprocess.run([str(sylva), "render", "--help"], capture_output=True, text=True).stdout
    m = re.search(r"--indirect <[A-Z_]+>[^\[]*\[default: ([0-9.eE+-]+)\]", out)
    if not m:
        fail(f"cannot read --indirect's default from `{sylva} render --help`")
    return float(m.group(1))


def render_sylva(sylva, scene, out_dir, rpp, width, indirect, extra):
    """`sylva render --mode all --hdr`: full, local, ambient and lb images, and the matched
    ambient c that turns (ambient − local) back into the albedo image."""
    out_dir.mkdir(parents=True, exist_ok=True)
    args = ["render", scene, "--mode", "all", "--hdr", "--rpp", str(rpp)]
    args += ["-o", str(out_dir / "sylva.png")]
    if width:
        args += ["--width", str(width)]
    if indirect is not None:
        args += ["--indirect", repr(indirect)]
    args += extra
    stdout, seconds = run_sylva(sylva, args, "sylva render")
    m = re.search(r"\(ambient mode, mean luminance [0-9.]+, ambient ([0-9.eE+-]+)\)", stdout)
    if not m:
        fail(f"sylva render printed no matched ambient (ambient mode line):\n{stdout}")
    return args, float(m.group(1)), seconds, lb_stage(stdout)


def lb_stage(stdout):
    """The render's LB stage from its stage summary: seconds (None if it printed none) and
    whether every model's light came from the cache (a warm run) or some was solved."""
    m = re.search(r"^[ \t]*LB precompute[ \t]+([0-9.]+)[ \t]*$", stdout, re.M)
    solved = re.search(r"^[ \t]*(LB|basis) [^:\n]+:.*\bsolved\b", stdout, re.M)
    return {
        "seconds": float(m.group(1)) if m else None,
        "cached": solved is None,
    }


# ---------------------------------------------------------------------------------- mitsuba


def harness_xml(export_dir, kind, width, height):
    """A copy of the exported scene.xml for one kind of render, beside it (the textures and
    meshes are relative paths):

    - reference: unchanged but for the film size;
    - coverage: no sun, no media; the sky emits (1, 0, 0) and the ground (0, 1, 0), paths end
      at the first surface (max_depth 1; volpath passes transparent leaf texels without
      counting a bounce), so R = sky coverage, G = ground coverage of each pixel;
    - sun: the sun alone, direct light only (max_depth 2), no media: zero where a surface sees
      no sun (a cloud's shadow does not count: Mitsuba's direct-only render of a medium gives
      NaN pixels);
    - transmittance (scenes with media): no sun, the sky emits (1, 1, 1), the ground nothing,
      media absorb only (albedo 0), paths end at their first event (max_depth 1; at 2 a few
      pixels come out NaN): each pixel is its rays' transmittance up to the sky.

    The classification renders use the stratified sampler (8×8 per pixel at 64 spp)."""
    tree = ET.parse(export_dir / "scene.xml")
    root = tree.getroot()
    film = root.find("sensor/film")
    if film is None:
        fail(f"{export_dir / 'scene.xml'}: no sensor/film element")
    for el in film.findall("integer"):
        if el.get("name") == "width":
            el.set("value", str(width))
        elif el.get("name") == "height":
            el.set("value", str(height))
    if kind != "reference":
        root.find("sensor/sampler").set("type", "stratified")
        for em in root.findall("emitter"):
            if kind in ("coverage", "transmittance") or em.get("type") != "directional":
                root.remove(em)
        for shape in root.findall("shape"):
            medium = shape.find("medium")
            if medium is None:
                continue
            if kind in ("coverage", "sun"):
                root.remove(shape)
            elif kind == "transmittance":
                for el in medium.findall("rgb"):
                    if el.get("name") == "albedo":
                        el.set("value", "0, 0, 0")
        if kind == "transmittance":
            sky = ET.SubElement(root, "emitter", type="constant")
            ET.SubElement(sky, "rgb", name="radiance", value="1, 1, 1")
            for shape in root.findall("shape"):
                if shape.get("id") == "ground":
                    for el in shape.iter("rgb"):
                        if el.get("name") == "reflectance":
                            el.set("value", "0, 0, 0")
        if kind == "coverage":
            sky = ET.SubElement(root, "emitter", type="constant")
            ET.SubElement(sky, "rgb", name="radiance", value="1, 0, 0")
            for shape in root.findall("shape"):
                if shape.get("id") == "ground":
                    em = ET.SubElement(shape, "emitter", type="area")
                    ET.SubElement(em, "rgb", name="radiance", value="0, 1, 0")
    path = export_dir / f"harness-{kind}-{width}x{height}.xml"
    atomic_write_bytes(path, ET.tostring(root, encoding="utf-8", xml_declaration=True))
    return path


class Mitsuba:
    def __init__(self, variant):
        import mitsuba as mi

        mi.set_variant(variant)
        self.mi = mi
        self.variant = variant

    def render(self, xml, spp, seed, max_depth, width, height, label):
        """Mean of passes (the LLVM variant holds a pass's paths in memory at once). Pass k of
        P uses Mitsuba seed seed·P + k, so two seeds never share a pass's random numbers.
        Returns the image and the seconds."""
        mi = self.mi
        t0 = time.time()
        scene = mi.load_file(str(xml), spp=spp, max_depth=max_depth)
        if self.variant.startswith("scalar"):
            per_pass = max(1, min(spp, 64))
        else:
            per_pass = max(1, min(spp, LLVM_LANES_PER_PASS // (width * height)))
        passes = -(-spp // per_pass)
        # The scalar variants seed pixel i of a render with seed·W·H + i in 32 bits: beyond
        # 2³² seeds would wrap onto each other (LLVM hashes the seed with the lane instead).
        if self.variant.startswith("scalar") and (seed + 1) * passes * width * height >= 1 << 32:
            fail(
                f"seed {seed} is too large for {self.variant} at {width}x{height}: "
                "use smaller --seeds"
            )
        acc = np.zeros((height, width, 3), dtype=np.float64)
        done, k = 0, 0
        while done < spp:
            n = min(per_pass, spp - done)
            img = np.array(mi.render(scene, spp=n, seed=seed * passes + k))[..., :3]
            acc += img.astype(np.float64) * n
            done += n
            k += 1
            if PROGRESS:
                el = time.time() - t0
                left = el / done * (spp - done)
                line = f"  {label}: {done}/{spp} spp, {el:.0f} s, about {left:.0f} s left"
                if sys.stdout.isatty():
                    print(f"\r{line}   ", end="" if done < spp else "\n", flush=True)
                elif k % max(1, passes // 8) == 0 or done == spp:
                    say(line)
        return (acc / spp).astype(np.float32), time.time() - t0

    def cached(self, cache_dir, xml, name, spp, seed, max_depth, width, height):
        """The render `name` from the cache, or rendered and cached (EXR + a JSON sidecar)."""
        path = cache_dir / f"{name}.exr"
        meta_path = cache_dir / f"{name}.json"
        if path.exists() and meta_path.exists():
            try:
                meta = json.loads(meta_path.read_text())
                img = read_exr(self.mi, path)
                if img.shape[:2] != (height, width):
                    fail(f"{path}: {img.shape[1]}x{img.shape[0]}, expected {width}x{height}")
                return img, meta, True
            except (HarnessError, ValueError) as e:
                say(f"warning: cached render unusable ({e}); rendering it again")
        img, seconds = self.render(xml, spp, seed, max_depth, width, height, name)
        if not np.all(np.isfinite(img)):
            fail(f"Mitsuba render {name} has NaN or infinite pixels")
        write_exr(self.mi, path, img)
        meta = {
            "spp": spp,
            "seed": seed,
            "max_depth": max_depth,
            "variant": self.variant,
            "mitsuba": self.mi.__version__,
            "seconds": round(seconds, 2),
            "cores": os.cpu_count(),
        }
        atomic_write_text(meta_path, json.dumps(meta, indent=2) + "\n")
        return img, meta, False


def has_media(export_dir):
    """Whether the exported scene holds a participating medium (a cloud)."""
    root = ET.parse(export_dir / "scene.xml").getroot()
    return any(shape.find("medium") is not None for shape in root.findall("shape"))


def exported_max_depth(export_dir):
    root = ET.parse(export_dir / "scene.xml").getroot()
    for d in root.findall("default"):
        if d.get("name") == "max_depth":
            return int(d.get("value"))
    return -1


# ---------------------------------------------------------------------------------- report


def fmt(x, digits=3):
    return "—" if x is None else f"{x:.{digits}f}"


def pct(x):
    return "—" if x is None else f"{100 * x:.1f} %"


def scene_markdown(r):
    s = r["sylva"]
    ref = r["reference"]
    lines = [
        f"### {r['scene']} ({r['width']}×{r['height']})",
        "",
        f"sylva {s['commit'] or '?'} at {s['rpp']} rays/pixel, `--indirect {s['indirect']}`; "
        f"Mitsuba {ref['mitsuba']} `{ref['variant']}`, volpath max_depth {ref['max_depth']}, "
        f"{ref['spp']} spp × seeds {ref['seeds'][0]} and {ref['seeds'][1]} "
        f"({ref['seconds'][0]:.0f} s + {ref['seconds'][1]:.0f} s), export {ref['export_hash']}.",
        "",
        "| class | pixels | ref. mean L | sylva / ref. | (R, G, B) | rel. RMSE | ref. noise | "
        "best ambient rel. RMSE | best LB rel. RMSE |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name in metrics.CLASSES:
        c = r["classes"][name]
        full, amb, lb = c["sylva"], c.get("ambient_fit"), c.get("lb_fit")
        if full["pixels"] == 0:
            lines.append(f"| {name} | 0 | | | | | | | |")
            continue
        lines.append(
            f"| {name} | {full['pixels']} ({pct(c['fraction'])}) | {fmt(full['ref_mean'], 4)} "
            f"| {fmt(full['ratio'])} | {', '.join(fmt(x, 2) for x in c['ratio_rgb'])} "
            f"| {pct(full['rel_rmse'])} | {pct(full['ref_noise'])} "
            f"| {pct(amb['rel_rmse']) if amb else ''} | {pct(lb['rel_rmse']) if lb else ''} |"
        )
    f = r["fits"]
    lines += [
        "",
        f"Best constant ambient on plant pixels: c = {fmt(f['ambient_c'], 4)} "
        f"(sylva's `--mode ambient` matched c = {fmt(f['sylva_matched_c'], 4)}); "
        f"best `--indirect` = {fmt(f['indirect'], 4)} (used: {s['indirect']}). "
        f"Difference image: full red/blue at ± {fmt(r['difference_scale']['luminance'], 4)} "
        f"luminance ({r['difference_scale']['multiple_of_plant_ref_mean']:g} × the reference's "
        "mean plant luminance).",
        "",
    ]
    e = r.get("equal_error") or {}
    whole, warm = e.get("whole_render"), e.get("without_lb")
    if whole:
        lb = e["lb"]
        lines += [
            f"Time to equal error on plants: Mitsuba needs {whole['spp_needed']:.0f} spp "
            f"({whole['seconds']:.1f} s) for sylva's plant error; sylva took "
            f"{whole['sylva_seconds']:.1f} s with its LB {'from the cache' if lb['cached'] else 'solved'}"
            f" (**{whole['speedup']:.1f}×**)"
            + (
                f", {warm['sylva_seconds']:.1f} s without the LB stage (**{warm['speedup']:.1f}×**)"
                if warm
                else ""
            )
            + ".",
            "",
        ]
    return "\n".join(lines)


def results_markdown(results, command):
    head = [
        "# sylva against a Mitsuba 3 reference",
        "",
        f"`{command}`",
        "",
        "Luminance per pixel class (linear images). *sylva / ref.*: ratio of mean luminances "
        "(and of each colour channel's mean). "
        "*rel. RMSE*: RMS of the per-pixel luminance difference over the reference's mean in "
        "that class, with the reference's noise subtracted. *ref. noise*: one reference "
        "render's RMS noise over that mean (the comparison uses the mean of two, so half its "
        "variance is subtracted). *best ambient*: sylva's local image + c × albedo, c fitted "
        "by least squares on plant pixels; *best LB*: local + LB light with the fitted "
        "`--indirect` (both only on plant classes).",
        "",
    ]
    return "\n".join(head + [scene_markdown(r) for r in results])


# ---------------------------------------------------------------------------------- one scene


def scene_slug(scene):
    p = Path(scene)
    name = p.stem if p.suffix == ".toml" else scene
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "scene"


def run_scene(a, mitsuba, scene):
    mi = mitsuba.mi
    slug = scene_slug(scene)
    out = Path(a.out) / slug
    out.mkdir(parents=True, exist_ok=True)
    say(f"== {scene}")

    # 1. sylva: full, local, ambient, lb at the harness's resolution.
    indirect = a.indirect if a.indirect is not None else sylva_default_indirect(a.sylva)
    sylva_args, matched_c, sylva_seconds, lb = render_sylva(
        a.sylva,
        scene,
        out / "sylva",
        a.rpp,
        a.width,
        a.indirect,
        ["--leaf-optics", a.leaf_optics] + shlex.split(a.sylva_args),
    )
    sy = {
        m: read_exr(mi, out / "sylva" / f"sylva-{m}.exr")
        for m in ("full", "local", "ambient", "lb")
    }
    height, width = sy["full"].shape[:2]

    # 2. Export; the renders are cached under the export's content hash.
    export_dir = out / "export"
    export_args = ["export", scene, "--format", "mitsuba", "-o", str(export_dir)]
    # The same leaves on both sides, whatever the mode: like for like.
    export_args += ["--leaf-optics", a.leaf_optics] + shlex.split(a.export_args)
    run_sylva(a.sylva, export_args, "sylva export")
    key = export_hash(export_dir)
    cache = out / "mitsuba" / f"{key}-mitsuba{mi.__version__}"
    cache.mkdir(parents=True, exist_ok=True)
    max_depth = exported_max_depth(export_dir)
    size = f"{width}x{height}"
    say(f"export {key}; Mitsuba {mi.__version__} {mitsuba.variant}; renders cached in {cache}")

    # 3. Reference (two seeds) and the two classification renders.
    ref_xml = harness_xml(export_dir, "reference", width, height)
    refs, ref_meta = [], []
    for seed in a.seeds:
        img, meta, hit = mitsuba.cached(
            cache,
            ref_xml,
            f"reference-{size}-{a.spp}spp-seed{seed}",
            a.spp,
            seed,
            max_depth,
            width,
            height,
        )
        say(
            f"  reference seed {seed}: {'cached, ' if hit else ''}"
            f"{meta['seconds']} s ({meta['variant']})"
        )
        refs.append(img)
        ref_meta.append(meta)
    cov_xml = harness_xml(export_dir, "coverage", width, height)
    cov, _, _ = mitsuba.cached(
        cache, cov_xml, f"coverage-{size}-{CLASS_SPP}spp", CLASS_SPP, 0, 1, width, height
    )
    sun_xml = harness_xml(export_dir, "sun", width, height)
    sun, _, _ = mitsuba.cached(
        cache, sun_xml, f"sun-{size}-{CLASS_SPP}spp", CLASS_SPP, 0, 2, width, height
    )
    transmittance = None
    if has_media(export_dir):
        tr_xml = harness_xml(export_dir, "transmittance", width, height)
        tr, _, _ = mitsuba.cached(
            cache, tr_xml, f"transmittance-{size}-{CLASS_SPP}spp", CLASS_SPP, 0, 1, width, height
        )
        transmittance = metrics.luminance(tr)
    classes = metrics.classify(
        cov[..., 0], cov[..., 1], metrics.luminance(sun), transmittance=transmittance
    )

    # 4. Metrics.
    L = {m: metrics.luminance(img) for m, img in sy.items()}
    ra, rb = (metrics.luminance(r) for r in refs)
    ref_mean_rgb = 0.5 * (refs[0] + refs[1])
    L_ref = metrics.luminance(ref_mean_rgb)
    if matched_c <= 0.0:
        fail(f"sylva's matched ambient is {matched_c}: no albedo image can be recovered")
    albedo = (sy["ambient"] - sy["local"]) / matched_c
    lb_unit = sy["lb"] / indirect if indirect > 0 else None
    plant = classes["plant"]
    c_amb = metrics.fit_scale(L["local"], metrics.luminance(albedo), L_ref, plant)
    s_lb = (
        metrics.fit_scale(L["local"], metrics.luminance(lb_unit), L_ref, plant)
        if lb_unit is not None
        else None
    )
    fitted = {}
    if c_amb is not None:
        fitted["ambient_fit"] = sy["local"] + c_amb * albedo
    if s_lb is not None:
        fitted["lb_fit"] = sy["local"] + s_lb * lb_unit
    class_rows = {}
    for name in metrics.CLASSES:
        m = classes[name]
        row = {
            "fraction": float(m.mean()),
            "sylva": metrics.compare(L["full"], ra, rb, m),
            "ratio_rgb": metrics.channel_ratios(sy["full"], ref_mean_rgb, m),
        }
        if name.startswith("plant"):
            for k, img in fitted.items():
                row[k] = metrics.compare(metrics.luminance(img), ra, rb, m)
        class_rows[name] = row

    # Time to equal error on plants: the path tracer's samples for sylva's plant error, from
    # one reference render's noise and time; sylva's whole render (its LB as this run had
    # it, cached or solved) and without the LB stage.
    plant_row = class_rows["plant"]["sylva"]
    one_ref = sum(m["seconds"] for m in ref_meta) / len(ref_meta)
    equal = {"lb": lb}
    for key, secs in (
        ("whole_render", sylva_seconds),
        ("without_lb", sylva_seconds - lb["seconds"] if lb["seconds"] is not None else None),
    ):
        equal[key] = metrics.equal_error(
            plant_row["rel_rmse"], plant_row["ref_noise"], a.spp, one_ref, secs
        )

    # 5. Pictures: sylva | reference | difference, the difference alone, the classes.
    exposure = imaging.log_average(L_ref)
    diff = L["full"] - L_ref
    plant_ref = float(L_ref[plant].mean()) if plant.any() else float(L_ref.mean())
    scale = a.diff_scale * plant_ref
    diff_png = imaging.diverging(diff, scale)
    strip = imaging.side_by_side(
        [imaging.tonemap(sy["full"], exposure), imaging.tonemap(ref_mean_rgb, exposure), diff_png]
    )
    write_png(mi, out / f"{slug}_compare.png", strip)
    write_png(mi, out / f"{slug}_diff.png", diff_png)
    write_png(mi, out / f"{slug}_classes.png", imaging.class_map(classes))
    write_exr(mi, out / "reference.exr", ref_mean_rgb)

    return {
        "scene": scene,
        "width": width,
        "height": height,
        "sylva": {
            "binary": str(a.sylva),
            "commit": git_commit(),
            "render": shlex.join(["sylva"] + sylva_args),
            "export": shlex.join(["sylva"] + export_args),
            "rpp": a.rpp,
            "indirect": indirect,
            "leaf_optics": a.leaf_optics,
            "seconds": round(sylva_seconds, 2),
        },
        "reference": {
            "export_hash": key,
            "spp": a.spp,
            "seeds": list(a.seeds),
            "max_depth": max_depth,
            "variant": ref_meta[0]["variant"],
            "mitsuba": ref_meta[0]["mitsuba"],
            "seconds": [m["seconds"] for m in ref_meta],
            "class_spp": CLASS_SPP,
        },
        "fits": {"ambient_c": c_amb, "sylva_matched_c": matched_c, "indirect": s_lb},
        "difference_scale": {"multiple_of_plant_ref_mean": a.diff_scale, "luminance": scale},
        "classes": class_rows,
        "equal_error": equal,
        "images": {
            "compare": f"{slug}_compare.png",
            "difference": f"{slug}_diff.png",
            "classes": f"{slug}_classes.png",
        },
    }


def main(argv=None):
    p = argparse.ArgumentParser(
        description="Compare sylva's renderer with a Mitsuba 3 path-traced reference "
        "(see tools/reference/README.md)."
    )
    p.add_argument("scenes", nargs="+", help="built-in scene names or scene files (TOML)")
    p.add_argument(
        "--spp", type=int, default=512, help="reference samples per pixel per seed (512)"
    )
    p.add_argument(
        "--seeds",
        type=int,
        nargs=2,
        default=(1, 2),
        metavar=("A", "B"),
        help="the two reference seeds; their difference measures the reference's noise (1 2)",
    )
    p.add_argument("--rpp", type=int, default=16, help="sylva's rays per pixel (16)")
    p.add_argument(
        "--width", type=int, help="image width (default: the scene's; height follows its aspect)"
    )
    p.add_argument(
        "--indirect", type=float, help="sylva's --indirect (default: sylva's own default)"
    )
    p.add_argument(
        "--leaf-optics",
        choices=["measured", "texture"],
        default="measured",
        help="the leaves of both the render and the export (measured: the species' measured "
        "R and T, sylva's default; texture: the look before issue 29)",
    )
    p.add_argument("--sylva-args", default="", help="more arguments for `sylva render`, one string")
    p.add_argument(
        "--export-args", default="", help="more arguments for `sylva export`, e.g. '--max-depth -1'"
    )
    p.add_argument(
        "--out", default="sylva-out/reference", help="output folder (sylva-out/reference)"
    )
    p.add_argument(
        "--sylva",
        type=Path,
        default=REPO / "target" / "release" / "sylva",
        help="the sylva binary (target/release/sylva; build it with cargo build --release)",
    )
    p.add_argument(
        "--variant",
        choices=["llvm_ad_rgb", "scalar_rgb", "cuda_ad_rgb"],
        help="Mitsuba variant (default: llvm_ad_rgb when a libLLVM works, else scalar_rgb)",
    )
    p.add_argument(
        "--diff-scale",
        type=float,
        default=2.0,
        help="the difference image saturates at ± this × the reference's mean plant luminance (2)",
    )
    a = p.parse_args(argv)
    if a.spp < 1 or a.rpp < 1:
        fail("--spp and --rpp must be at least 1")
    if a.seeds[0] == a.seeds[1]:
        fail("--seeds: the two seeds must differ (their difference is the noise estimate)")
    if a.width is not None and not 1 <= a.width <= 32768:
        fail("--width must be 1 to 32768")
    if a.indirect is not None and not (math.isfinite(a.indirect) and a.indirect >= 0):
        fail("--indirect must be finite and ≥ 0")
    if not (math.isfinite(a.diff_scale) and a.diff_scale > 0):
        fail("--diff-scale must be finite and > 0")
    if not a.sylva.is_file():
        fail(f"{a.sylva}: no sylva binary (cargo build --release, or pass --sylva PATH)")

    variant, why = choose_variant(a.variant)
    say(f"Mitsuba variant {variant} ({why}), {os.cpu_count()} cores")
    mitsuba = Mitsuba(variant)
    out = Path(a.out)
    command = shlex.join(["python3", "tools/reference/reference.py"] + (argv or sys.argv[1:]))
    t0 = time.time()
    results = []
    for scene in a.scenes:
        r = run_scene(a, mitsuba, scene)
        results.append(r)
        # Each scene's results beside its images, the run's together at the top.
        scene_dir = out / scene_slug(scene)
        atomic_write_text(
            scene_dir / "results.json",
            json.dumps({"command": command, "scenes": [r]}, indent=2) + "\n",
        )
        atomic_write_text(scene_dir / "results.md", results_markdown([r], command) + "\n")
    atomic_write_text(
        out / "results.json", json.dumps({"command": command, "scenes": results}, indent=2) + "\n"
    )
    md = results_markdown(results, command)
    atomic_write_text(out / "results.md", md + "\n")
    say("\n" + md)
    say(f"wrote {out / 'results.md'} and results.json ({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    try:
        main()
    except HarnessError as e:
        sys.exit(f"error: {e}")
    except KeyboardInterrupt:
        sys.exit("interrupted")
