#!/usr/bin/env python3
"""Trace the rays `sylva bench rays --export DIR` wrote through Embree and set its speed and
answers beside sylva's kd-tree (issue 28 item 3).

    sylva --threads 1 bench rays catalpa --export out/rays --json > out/rays/sylva.json
    python3 tools/embree/compare.py out/rays

Embree comes from PyPI's `embreex` (Embree 4, one ray at a time, one thread: compare it with
sylva's figures per CPU-second). embreex has no filter callbacks, so the alpha test of leaf
textures is emulated: a hit on a transparent texel continues the ray just past it with a new
query, the way a filter function would reject it. Only Embree's own calls are timed ("Embree
s"); the numpy work of the emulation is reported beside it. Without the alpha test (every
leaf opaque) Embree is timed as well, `OCCLUDED` for shadow rays, which is Embree at its
fastest on the same triangles.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

FORMAT = "sylva-rays-1"
# Embree's "no hit" distance, and its geometry id of none.
MISS = -1


class ExportError(Exception):
    pass


def _read(dir_, name, dtype, shape):
    path = dir_ / name
    try:
        data = np.fromfile(path, dtype=dtype)
    except OSError as e:
        raise ExportError(f"{path}: cannot read ({e.strerror})") from e
    count = int(np.prod(shape))
    if data.size != count:
        raise ExportError(
            f"{path}: {data.size} values of {np.dtype(dtype).name}, expected {count} "
            f"(shape {shape}); the export is truncated or from another run"
        )
    return data.reshape(shape)


class Export:
    """The scene and rays of one export, flattened to world space."""

    def __init__(self, dir_, max_triangles=40_000_000):
        self.dir = Path(dir_)
        manifest = self.dir / "manifest.json"
        try:
            self.manifest = json.loads(manifest.read_text())
        except OSError as e:
            raise ExportError(f"{manifest}: cannot read ({e.strerror}); run `sylva bench rays SCENE --export {dir_}` first") from e
        except json.JSONDecodeError as e:
            raise ExportError(f"{manifest}: not JSON ({e})") from e
        if self.manifest.get("format") != FORMAT:
            raise ExportError(f"{manifest}: format {self.manifest.get('format')!r}, expected {FORMAT!r}")
        m = self.manifest
        n_inst = m["instances"]
        self.instance_model = _read(self.dir, "instance_model.u32", np.uint32, (n_inst,))
        self.to_world = _read(self.dir, "instance_to_world.f32", np.float32, (n_inst, 3, 4))
        total = sum(m["models"][k]["triangles"] for k in self.instance_model)
        if total > max_triangles:
            raise ExportError(
                f"{manifest}: {total} instanced triangles flatten to {total * 36 / 2**30:.1f} GiB "
                f"of vertices for Embree (which has no instancing here); the limit is {max_triangles}"
            )
        self.models = []
        for k, model in enumerate(m["models"]):
            nv, nt = model["vertices"], model["triangles"]
            self.models.append(
                {
                    "positions": _read(self.dir, f"model{k}_positions.f32", np.float32, (nv, 3)),
                    "indices": _read(self.dir, f"model{k}_indices.u32", np.uint32, (nt, 3)),
                    "mask": _read(self.dir, f"model{k}_mask.i32", np.int32, (nt,)),
                    "uv": _read(self.dir, f"model{k}_uv.f32", np.float32, (nt, 3, 2)),
                }
            )
        self.masks = [
            (_read(self.dir, f"mask{k}.u8", np.uint8, (e["height"], e["width"])).astype(bool), e["wrap"])
            for k, e in enumerate(m["masks"])
        ]
        self.sets = {}
        for s in m["sets"]:
            rows = _read(self.dir, f"{s['name']}_rays.f32", np.float32, (s["rays"], 8))
            if s["query"] == "any":
                answer = _read(self.dir, f"{s['name']}_blocked.u8", np.uint8, (s["rays"],)).astype(bool)
            else:
                answer = _read(self.dir, f"{s['name']}_hits.u32", np.uint32, (s["rays"], 3))
            self.sets[s["name"]] = (s["query"], rows, answer)

    def world_vertices(self, i):
        """Instance i's model vertices in world space."""
        p = self.models[self.instance_model[i]]["positions"]
        m = self.to_world[i]
        return (p @ m[:, :3].T + m[:, 3]).astype(np.float32)


def texel_opaque(mask, wrap, u, v):
    """sylva's nearest-texel rule (sylva_geom::nearest_texel_coords) on arrays of u, v."""
    h, w = mask.shape
    x = np.floor(u * w).astype(np.int64)
    y = np.floor(v * h).astype(np.int64)
    if wrap == "repeat":
        x, y = np.mod(x, w), np.mod(y, h)
    else:
        x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    return mask[y, x]


def _segments(rows):
    """Rays as Embree takes them: origins moved to t_min (its tnear is 0), directions, and
    the segment's length (Embree's "no limit" for an infinite one)."""
    o = rows[:, 0:3].astype(np.float32) + rows[:, 4:7] * rows[:, 3:4]
    d = np.ascontiguousarray(rows[:, 4:7], dtype=np.float32)
    far = (rows[:, 7] - rows[:, 3]).astype(np.float32)
    far = np.where(np.isfinite(far), far, np.float32(1e37)).astype(np.float32)
    return o, d, far


class EmbreeScene:
    """The export's instances flattened into Embree meshes: geometry i is instance i, the
    ground (two triangles) the last one."""

    def __init__(self, export):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.export = export
        self.scene = rtcore_scene.EmbreeScene()
        self._meshes = []
        for i in range(len(export.instance_model)):
            model = export.models[export.instance_model[i]]
            self._meshes.append(
                TriangleMesh(self.scene, export.world_vertices(i), model["indices"].astype(np.int32))
            )
        self.ground_id = None
        if export.manifest.get("ground"):
            hx, hz = export.manifest["ground"]
            v = np.array([[-hx, 0, -hz], [hx, 0, -hz], [hx, 0, hz], [-hx, 0, hz]], np.float32)
            self._meshes.append(TriangleMesh(self.scene, v, np.array([[0, 1, 2], [0, 2, 3]], np.int32)))
            self.ground_id = len(self._meshes) - 1
        n = len(export.instance_model)
        # Per geometry id: its model's mask ids and uvs (the ground has none).
        self._mask_of = [export.models[export.instance_model[i]]["mask"] for i in range(n)]
        self._uv_of = [export.models[export.instance_model[i]]["uv"] for i in range(n)]

    def _transparent(self, geom, prim, u, v):
        """Whether each hit lands on a transparent texel of an alpha-tested triangle."""
        out = np.zeros(geom.shape, bool)
        for g in np.unique(geom):
            if g == MISS or g == self.ground_id:
                continue
            sel = np.nonzero(geom == g)[0]
            mids = self._mask_of[g][prim[sel]]
            tested = mids >= 0
            if not tested.any():
                continue
            sel, mids = sel[tested], mids[tested]
            uv = self._uv_of[g][prim[sel]]
            b0 = 1.0 - u[sel] - v[sel]
            tu = uv[:, 0, 0] * b0 + uv[:, 1, 0] * u[sel] + uv[:, 2, 0] * v[sel]
            tv = uv[:, 0, 1] * b0 + uv[:, 1, 1] * u[sel] + uv[:, 2, 1] * v[sel]
            for mid in np.unique(mids):
                k = mids == mid
                mask, wrap = self.export.masks[mid]
                out[sel[k]] = ~texel_opaque(mask, wrap, tu[k], tv[k])
        return out

    def closest(self, rows, alpha=True):
        """Closest opaque hits: (t, geometry, primitive) per ray, with Embree's seconds and the
        emulation's seconds."""
        o, d, far = _segments(rows)
        n = len(rows)
        t_hit = np.full(n, np.inf, np.float32)
        g_hit = np.full(n, MISS, np.int64)
        p_hit = np.full(n, MISS, np.int64)
        travelled = np.zeros(n, np.float32)
        active = np.arange(n)
        embree_s = emul_s = 0.0
        while active.size:
            t0 = time.perf_counter()
            r = self.scene.run(o[active], d[active], dists=far[active], output=1)
            embree_s += time.perf_counter() - t0
            t0 = time.perf_counter()
            geom = r["geomID"].astype(np.int64)
            prim = r["primID"].astype(np.int64)
            t = r["tfar"]
            hit = geom != MISS
            clear = self._transparent(geom, prim, r["u"], r["v"]) if alpha else np.zeros_like(hit)
            done = hit & ~clear
            k = active[done]
            t_hit[k] = travelled[k] + t[done]
            g_hit[k], p_hit[k] = geom[done], prim[done]
            go = hit & clear
            k = active[go]
            # Continue just past the transparent texel, over what is left of the segment.
            step = t[go] + 1e-5 * np.maximum(1.0, np.abs(o[k]).max(axis=1))
            o[k] = o[k] + d[k] * step[:, None]
            far[k] = far[k] - step
            travelled[k] += step
            active = k[far[k] > 0]
            emul_s += time.perf_counter() - t0
        return (t_hit, g_hit, p_hit), embree_s, emul_s

    def occluded(self, rows, alpha=True):
        """Whether each ray is blocked (alpha: the first opaque hit; else Embree's OCCLUDED)."""
        if alpha:
            (t, _, _), embree_s, emul_s = self.closest(rows, alpha=True)
            return np.isfinite(t), embree_s, emul_s
        o, d, far = _segments(rows)
        t0 = time.perf_counter()
        r = self.scene.run(o, d, dists=far, query="OCCLUDED")
        return np.asarray(r) != MISS, time.perf_counter() - t0, 0.0


def sylva_ids(export, hits):
    """sylva's answers as (geometry, primitive) in this scene's numbering."""
    inst = hits[:, 1].astype(np.int64)
    tri = hits[:, 2].astype(np.int64)
    n = len(export.instance_model)
    ground = export.manifest.get("ground") is not None
    miss = inst == 0xFFFFFFFF
    on_ground = miss & (tri == 0)
    geom = np.where(miss, MISS, inst)
    geom = np.where(on_ground & ground, n, geom)
    prim = np.where(geom == MISS, MISS, np.where(on_ground, -2, tri))
    return geom, prim


def compare(dir_, sylva_json=None, runs=3):
    export = Export(dir_)
    scene = EmbreeScene(export)
    sylva = None
    path = Path(sylva_json) if sylva_json else export.dir / "sylva.json"
    if path.exists():
        sylva = {s["name"]: s for s in json.loads(path.read_text())["sets"]}
    results = []
    for name, (query, rows, answer) in export.sets.items():
        row = {"name": name, "query": query, "rays": len(rows)}
        for alpha in (True, False):
            secs, emul = [], []
            for _ in range(runs):
                if query == "any":
                    got, s, e = scene.occluded(rows, alpha)
                else:
                    got, s, e = scene.closest(rows, alpha)
                secs.append(s)
                emul.append(e)
            key = "alpha" if alpha else "opaque"
            row[f"embree_{key}_seconds"] = float(np.median(secs))
            row[f"embree_{key}_mrays_per_second"] = len(rows) / max(row[f"embree_{key}_seconds"], 1e-12) * 1e-6
            if alpha:
                row["emulation_seconds"] = float(np.median(emul))
                if query == "any":
                    row["agree"] = float(np.mean(got == answer))
                else:
                    geom, prim = sylva_ids(export, answer)
                    _, g, p = got
                    same = (g == geom) & ((p == prim) | (prim == -2))
                    row["agree"] = float(np.mean(same))
        if sylva:
            s = sylva[name]
            row["sylva_mrays_per_cpu_second"] = s["mrays_per_cpu_second"]
            row["sylva_over_embree_alpha"] = s["mrays_per_cpu_second"] / row["embree_alpha_mrays_per_second"]
        results.append(row)
    return results


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", help="directory written by `sylva bench rays SCENE --export DIR`")
    ap.add_argument("--sylva", help="sylva's `bench rays --json` output (default: DIR/sylva.json)")
    ap.add_argument("--runs", type=int, default=3, help="timed passes per set (medians)")
    ap.add_argument("--json", action="store_true", help="print JSON instead of a table")
    a = ap.parse_args(argv)
    try:
        rows = compare(a.dir, a.sylva, a.runs)
    except ExportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if a.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"{'rays':<11} {'query':>7} {'count':>8} {'agree':>7} {'Embree+α':>9} {'(numpy s)':>9} {'Embree':>7} {'sylva/CPU':>9} {'sylva/Embree+α':>14}")
    for r in rows:
        sy = r.get("sylva_mrays_per_cpu_second")
        ratio = r.get("sylva_over_embree_alpha")
        print(
            f"{r['name']:<11} {r['query']:>7} {r['rays']:>8} {100 * r['agree']:>6.2f}% "
            f"{r['embree_alpha_mrays_per_second']:>9.2f} {r['emulation_seconds']:>9.3f} "
            f"{r['embree_opaque_mrays_per_second']:>7.2f} "
            f"{'' if sy is None else f'{sy:.2f}':>9} {'' if ratio is None else f'{ratio:.2f}':>14}"
        )
    print("Mrays per second on one thread (sylva: per CPU-second); Embree+α: alpha test emulated, Embree's calls timed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
