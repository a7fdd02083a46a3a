"""Tests of tools/embree/compare.py on exports written here: the alpha test's emulation lets
a ray through a transparent texel to the leaf behind, the answers are compared hit for hit,
and a damaged export is refused with the file named."""

import json
import os
import tempfile
import unittest
from pathlib import Path

import numpy as np

import compare


def write_export(dir_, blocked_answers=None):
    """Two unit squares facing -z at z = 1 (alpha-tested: its mask is transparent on the left
    half, u < 0.5) and z = 2 (opaque); one instance moved by +10 in x; rays along +z."""
    d = Path(dir_)
    pos = np.array(
        [[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1], [0, 0, 2], [1, 0, 2], [1, 1, 2], [0, 1, 2]],
        np.float32,
    )
    idx = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], np.uint32)
    mask_ids = np.array([0, 0, -1, -1], np.int32)
    # uv = the corner's (x, y) on the near square.
    uv = np.zeros((4, 3, 2), np.float32)
    for t in range(2):
        uv[t] = pos[idx[t]][:, :2]
    mask = np.zeros((4, 4), np.uint8)
    mask[:, 2:] = 1  # opaque where u >= 0.5 (rows are v, columns u)
    to_world = np.array([[1, 0, 0, 10], [0, 1, 0, 0], [0, 0, 1, 0]], np.float32)
    # Rays at x = 10.25 (through the transparent half) and 10.75 (stopped by the near square),
    # and one that misses.
    rays = np.array(
        [
            [10.25, 0.5, 0, 0, 0, 0, 1, np.inf],
            [10.75, 0.5, 0, 0, 0, 0, 1, np.inf],
            [13.0, 0.5, 0, 0, 0, 0, 1, np.inf],
        ],
        np.float32,
    )
    miss = 0xFFFFFFFF
    hits = np.array(
        [
            [np.float32(2).view(np.uint32), 0, 3],
            [np.float32(1).view(np.uint32), 0, 0],
            [np.float32(np.inf).view(np.uint32), miss, miss],
        ],
        np.uint32,
    )
    blocked = np.array(blocked_answers or [1, 1, 0], np.uint8)
    files = {
        "model0_positions.f32": pos,
        "model0_indices.u32": idx,
        "model0_mask.i32": mask_ids,
        "model0_uv.f32": uv,
        "mask0.u8": mask,
        "instance_model.u32": np.array([0], np.uint32),
        "instance_to_world.f32": to_world,
        "primary_rays.f32": rays,
        "primary_hits.u32": hits,
        "shadow_rays.f32": rays,
        "shadow_blocked.u8": blocked,
    }
    for name, a in files.items():
        a.tofile(d / name)
    manifest = {
        "format": "sylva-rays-1",
        "scene": "squares",
        "ground": None,
        "to_sun": [0, 0, 1],
        "models": [{"name": "squares", "vertices": 8, "triangles": 4}],
        "masks": [{"width": 4, "height": 4, "wrap": "clamp"}],
        "instances": 1,
        "sets": [
            {"name": "primary", "query": "closest", "rays": 3},
            {"name": "shadow", "query": "any", "rays": 3},
        ],
    }
    (d / "manifest.json").write_text(json.dumps(manifest))
    sylva = {
        "sets": [
            {"name": "primary", "mrays_per_cpu_second": 1.0},
            {"name": "shadow", "mrays_per_cpu_second": 2.0},
        ]
    }
    (d / "sylva.json").write_text(json.dumps(sylva))


class CompareTest(unittest.TestCase):
    def test_alpha_emulation_passes_transparent_texels_and_agrees_with_sylva(self):
        with tempfile.TemporaryDirectory() as d:
            write_export(d)
            export = compare.Export(d)
            scene = compare.EmbreeScene(export)
            (t, g, p), _, _ = scene.closest(export.sets["primary"][1])
            np.testing.assert_allclose(t[:2], [2.0, 1.0], rtol=1e-5)
            self.assertEqual(list(g), [0, 0, compare.MISS])
            self.assertEqual(list(p[:2]), [3, 0])
            # Without the alpha test the near square stops both rays.
            (t, _, _), _, _ = scene.closest(export.sets["primary"][1], alpha=False)
            np.testing.assert_allclose(t[:2], [1.0, 1.0], rtol=1e-5)
            rows = {r["name"]: r for r in compare.compare(d, runs=1)}
            self.assertEqual(rows["primary"]["agree"], 1.0)
            self.assertEqual(rows["shadow"]["agree"], 1.0)
            self.assertIn("sylva_over_embree_alpha", rows["shadow"])

    def test_a_disagreement_is_counted(self):
        with tempfile.TemporaryDirectory() as d:
            write_export(d, blocked_answers=[0, 1, 0])
            rows = {r["name"]: r for r in compare.compare(d, runs=1)}
            self.assertAlmostEqual(rows["shadow"]["agree"], 2 / 3)

    def test_a_truncated_file_is_named(self):
        with tempfile.TemporaryDirectory() as d:
            write_export(d)
            path = Path(d) / "model0_indices.u32"
            path.write_bytes(path.read_bytes()[:-4])
            with self.assertRaises(compare.ExportError) as e:
                compare.Export(d)
            self.assertIn("model0_indices.u32", str(e.exception))
            self.assertIn("truncated", str(e.exception))

    def test_a_missing_export_says_how_to_make_one(self):
        with tempfile.TemporaryDirectory() as d:
            with self.assertRaises(compare.ExportError) as e:
                compare.Export(os.path.join(d, "none"))
            self.assertIn("sylva bench rays", str(e.exception))


if __name__ == "__main__":
    unittest.main()
