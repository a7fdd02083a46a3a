"""Tests of the reference harness: the metrics and pictures on synthetic images (numpy only),
and, where Mitsuba is installed, the Mitsuba behaviour the classification relies on.

    python3 -m unittest discover -s tools/reference -v
"""

import math
import os
import tempfile
import unittest
from pathlib import Path

import numpy as np

import imaging
import metrics
import reference

try:
    import mitsuba  # noqa: F401

    HAVE_MITSUBA = True
except ImportError as e:
    # CI sets SYLVA_REQUIRE_MITSUBA=1: there the Mitsuba tests must run, not skip.
    if os.environ.get("SYLVA_REQUIRE_MITSUBA", "") not in ("", "0"):
        raise ImportError(
            "SYLVA_REQUIRE_MITSUBA is set but Mitsuba 3 cannot be imported "
            "(pip install -r tools/reference/requirements.txt)"
        ) from e
    HAVE_MITSUBA = False


class Luminance(unittest.TestCase):
    def test_weights_are_rec709_and_sum_to_one(self):
        img = np.array([[[1.0, 1.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]])
        np.testing.assert_allclose(metrics.luminance(img), [[1.0, 0.2126, 0.0722]])


class Classify(unittest.TestCase):
    def setUp(self):
        # Five pixels: pure sky, pure ground, pure plant (lit), pure plant (dark), mixed.
        self.sky = np.array([[1.0, 0.0, 0.0, 0.0, 0.5]])
        self.ground = np.array([[0.0, 1.0, 0.0, 0.0, 0.0]])
        self.sun = np.array([[0.0, 0.3, 0.2, 0.0, 0.1]])
        self.c = metrics.classify(self.sky, self.ground, self.sun)

    def test_classes_of_each_pixel(self):
        c = self.c
        self.assertEqual(c["sky"].tolist(), [[True, False, False, False, False]])
        self.assertEqual(c["ground"].tolist(), [[False, True, False, False, False]])
        self.assertEqual(c["ground sunlit"].tolist(), [[False, True, False, False, False]])
        self.assertEqual(c["plant"].tolist(), [[False, False, True, True, False]])
        self.assertEqual(c["plant sunlit"].tolist(), [[False, False, True, False, False]])
        self.assertEqual(c["plant shadowed"].tolist(), [[False, False, False, True, False]])
        self.assertEqual(c["mixed"].tolist(), [[False, False, False, False, True]])

    def test_pure_classes_and_mixed_partition_the_image(self):
        c = self.c
        parts = [c["sky"], c["ground"], c["plant"], c["mixed"]]
        self.assertTrue(np.all(sum(p.astype(int) for p in parts) == 1))
        self.assertTrue(np.array_equal(c["plant sunlit"] | c["plant shadowed"], c["plant"]))
        self.assertFalse(np.any(c["plant sunlit"] & c["plant shadowed"]))

    def test_one_sample_of_sky_in_64_makes_a_plant_pixel_mixed(self):
        c = metrics.classify(np.array([[1 / 64]]), np.array([[0.0]]), np.array([[1.0]]))
        self.assertTrue(c["mixed"][0, 0])
        self.assertFalse(c["plant"][0, 0])

    def test_size_mismatch_is_an_error(self):
        with self.assertRaises(ValueError):
            metrics.classify(np.zeros((2, 2)), np.zeros((2, 3)), np.zeros((2, 2)))
        with self.assertRaises(ValueError):
            metrics.classify(np.ones((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)), transmittance=np.ones((1, 2)))

    def test_sky_seen_through_a_medium_is_a_medium_pixel(self):
        # Four sky pixels: clear, a thin veil (above the clear threshold), a cloud's edge,
        # its opaque core; and one ground pixel behind nothing.
        sky = np.array([[1.0, 1.0, 1.0, 1.0, 0.0]])
        ground = np.array([[0.0, 0.0, 0.0, 0.0, 1.0]])
        t = np.array([[1.0, 0.99, 0.5, 0.01, 1.0]])
        c = metrics.classify(sky, ground, np.zeros((1, 5)), transmittance=t)
        self.assertEqual(c["sky"].tolist(), [[True, True, False, False, False]])
        self.assertEqual(c["medium"].tolist(), [[False, False, True, True, False]])
        self.assertEqual(c["medium edge"].tolist(), [[False, False, True, False, False]])
        self.assertEqual(c["medium opaque"].tolist(), [[False, False, False, True, False]])
        self.assertTrue(c["ground"][0, 4])
        # Without media there are none.
        self.assertFalse(self.c["medium"].any())


class Compare(unittest.TestCase):
    def test_identical_images(self):
        ref = np.linspace(0.1, 1.0, 100).reshape(10, 10)
        r = metrics.compare(ref, ref, ref, np.ones_like(ref, dtype=bool))
        self.assertEqual(r["pixels"], 100)
        self.assertAlmostEqual(r["ratio"], 1.0)
        self.assertEqual(r["rel_rmse"], 0.0)
        self.assertEqual(r["ref_noise"], 0.0)

    def test_scaled_image_closed_form(self):
        ref = np.linspace(0.1, 1.0, 100).reshape(10, 10)
        r = metrics.compare(2.0 * ref, ref, ref, np.ones_like(ref, dtype=bool))
        self.assertAlmostEqual(r["ratio"], 2.0)
        # RMS(2R − R) / mean(R) = sqrt(mean(R²)) / mean(R).
        expect = math.sqrt(np.mean(ref**2)) / np.mean(ref)
        self.assertAlmostEqual(r["rel_rmse"], expect)

    def test_reference_noise_is_measured_and_subtracted(self):
        rng = np.random.default_rng(7)
        truth = rng.uniform(0.5, 1.5, size=(400, 400))
        sigma, offset = 0.2, 0.05
        a = truth + rng.normal(0.0, sigma, truth.shape)
        b = truth + rng.normal(0.0, sigma, truth.shape)
        test = truth + offset
        r = metrics.compare(test, a, b, np.ones(truth.shape, dtype=bool))
        mean = truth.mean()
        # One render's noise is sigma; the mean of two carries sigma²/2 into the error.
        self.assertAlmostEqual(r["ref_noise"], sigma / mean, delta=0.01 * sigma / mean)
        self.assertAlmostEqual(
            r["rel_rmse_raw"], math.sqrt(offset**2 + sigma**2 / 2) / mean, delta=0.003
        )
        self.assertAlmostEqual(r["rel_rmse"], offset / mean, delta=0.003)
        self.assertGreater(r["noise_share"], 0.8)

    def test_mask_selects_pixels(self):
        ref = np.ones((4, 4))
        test = np.ones((4, 4))
        test[0, :] = 3.0
        mask = np.zeros((4, 4), dtype=bool)
        mask[0, :2] = True
        r = metrics.compare(test, ref, ref, mask)
        self.assertEqual(r["pixels"], 2)
        self.assertAlmostEqual(r["ratio"], 3.0)

    def test_empty_class_and_black_reference_give_no_numbers(self):
        z = np.zeros((3, 3))
        r = metrics.compare(z, z, z, np.zeros((3, 3), dtype=bool))
        self.assertEqual(r["pixels"], 0)
        self.assertIsNone(r["ratio"])
        r = metrics.compare(np.ones((3, 3)), z, z, np.ones((3, 3), dtype=bool))
        self.assertIsNone(r["ratio"])
        self.assertIsNone(r["rel_rmse"])

    def test_size_mismatch_is_an_error(self):
        with self.assertRaises(ValueError):
            metrics.compare(
                np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((3, 2)), np.ones((2, 2), bool)
            )


class EqualError(unittest.TestCase):
    def test_closed_form(self):
        # 4 % noise at 512 spp; sylva 8 % off: a quarter of the samples, a quarter the time.
        e = metrics.equal_error(0.08, 0.04, 512, 100.0, 5.0)
        self.assertAlmostEqual(e["spp_needed"], 128.0)
        self.assertAlmostEqual(e["seconds"], 25.0)
        self.assertAlmostEqual(e["speedup"], 5.0)
        # Halving sylva's error takes four times the samples.
        self.assertAlmostEqual(metrics.equal_error(0.04, 0.04, 512, 100.0, 5.0)["spp_needed"], 512.0)

    def test_error_within_the_reference_noise_has_no_answer(self):
        self.assertIsNone(metrics.equal_error(0.0, 0.04, 512, 100.0, 5.0))
        self.assertIsNone(metrics.equal_error(None, 0.04, 512, 100.0, 5.0))
        self.assertIsNone(metrics.equal_error(0.05, 0.04, 512, 100.0, 0.0))


class LbStage(unittest.TestCase):
    def test_cached_and_solved_runs(self):
        warm = "  LB catalpa: 128×108×116 grid from cache (0.25 s)\nstage  seconds\n  LB precompute          8.180\n"
        self.assertEqual(reference.lb_stage(warm), {"seconds": 8.18, "cached": True})
        cold = "  LB maple: 64×60×62 grid solved in 12.0 s, cached as x.sgrid\n  LB precompute   18.5\n"
        self.assertEqual(reference.lb_stage(cold), {"seconds": 18.5, "cached": False})
        # The physical light's forest grid is solved in every run: still a warm run.
        forest = warm + "  global grid: 32×20×32 solved in 0.50 s\n"
        self.assertTrue(reference.lb_stage(forest)["cached"])
        self.assertIsNone(reference.lb_stage("no summary")["seconds"])


class ChannelRatios(unittest.TestCase):
    def test_per_channel_mean_ratios_on_the_mask(self):
        ref = np.ones((2, 2, 3)) * [0.2, 0.4, 0.5]
        test = ref * [1.0, 2.0, 0.5]
        test[1, 1] = 100.0  # outside the mask
        mask = np.array([[True, True], [True, False]])
        np.testing.assert_allclose(metrics.channel_ratios(test, ref, mask), [1.0, 2.0, 0.5])

    def test_black_channel_and_empty_mask(self):
        ref = np.zeros((1, 1, 3))
        ref[..., 1] = 1.0
        self.assertEqual(metrics.channel_ratios(ref, ref, np.ones((1, 1), bool)), [None, 1.0, None])
        self.assertEqual(
            metrics.channel_ratios(ref, ref, np.zeros((1, 1), bool)), [None, None, None]
        )


class FitScale(unittest.TestCase):
    def test_recovers_the_scale_of_an_exact_model(self):
        rng = np.random.default_rng(3)
        base = rng.uniform(0, 1, (50, 50))
        basis = rng.uniform(0, 1, (50, 50))
        target = base + 0.37 * basis
        target[0, 0] = 1e6  # outside the mask: must not matter
        mask = np.ones(base.shape, dtype=bool)
        mask[0, 0] = False
        self.assertAlmostEqual(metrics.fit_scale(base, basis, target, mask), 0.37)

    def test_is_the_least_squares_minimum(self):
        rng = np.random.default_rng(4)
        base, basis, target = (rng.uniform(0, 1, (30, 30)) for _ in range(3))
        mask = np.ones(base.shape, dtype=bool)
        c = metrics.fit_scale(base, basis, target, mask)

        def sse(k):
            return float(np.sum((base + k * basis - target) ** 2))

        self.assertLess(sse(c), sse(c + 1e-3))
        self.assertLess(sse(c), sse(c - 1e-3))

    def test_zero_basis_has_no_fit(self):
        z = np.zeros((2, 2))
        self.assertIsNone(metrics.fit_scale(z, z, np.ones((2, 2)), np.ones((2, 2), bool)))


class Pictures(unittest.TestCase):
    def test_srgb_endpoints_and_knee(self):
        self.assertEqual(imaging.srgb8([0.0, 1.0, 2.0, -1.0]).tolist(), [0, 255, 255, 0])
        # 0.0031308 is where the linear segment meets the power curve: 12.92 x = 0.04045.
        self.assertEqual(int(imaging.srgb8([0.0031308])[0]), round(0.04045 * 255))

    def test_diverging_map(self):
        d = imaging.diverging(np.array([[0.0, 1.0, -1.0, 5.0, -5.0]]), 1.0)
        self.assertEqual(d[0, 0].tolist(), [221, 221, 221])
        self.assertEqual(d[0, 1].tolist(), [180, 4, 38])
        self.assertEqual(d[0, 2].tolist(), [59, 76, 192])
        self.assertEqual(d[0, 3].tolist(), d[0, 1].tolist())
        self.assertEqual(d[0, 4].tolist(), d[0, 2].tolist())

    def test_tonemap_keeps_order_and_shared_exposure_shows_brightness(self):
        ramp = np.linspace(0.0, 1.0, 16)[None, :, None] * np.ones((1, 16, 3))
        exposure = imaging.log_average(metrics.luminance(ramp))
        out = imaging.tonemap(ramp, exposure)[0, :, 1].astype(int)
        self.assertTrue(np.all(np.diff(out) >= 0))
        self.assertEqual(out[0], 0)
        # The same exposure for an image half as bright makes it darker.
        half = imaging.tonemap(0.5 * ramp, exposure)[0, :, 1].astype(int)
        self.assertTrue(np.all(half <= out))
        self.assertLess(half.sum(), out.sum())

    def test_class_map_colours(self):
        c = metrics.classify(np.array([[1.0, 0.0]]), np.array([[0.0, 0.0]]), np.array([[0.0, 1.0]]))
        m = imaging.class_map(c)
        self.assertEqual(tuple(m[0, 0]), imaging.CLASS_COLOURS["sky"])
        self.assertEqual(tuple(m[0, 1]), imaging.CLASS_COLOURS["plant sunlit"])

    def test_side_by_side(self):
        a = np.zeros((3, 2, 3), np.uint8)
        s = imaging.side_by_side([a, a, a], gap=1)
        self.assertEqual(s.shape, (3, 8, 3))
        with self.assertRaises(ValueError):
            imaging.side_by_side([a, np.zeros((4, 2, 3), np.uint8)])


# A scene shaped like `sylva export --format mitsuba`'s: camera looking down at a ground
# rectangle that fills the left half of the image, an opaque square above part of it (the
# "plant"), a fully transparent masked square beside it, sun and sky.
SCENE_XML = """<?xml version="1.0" encoding="utf-8"?>
<scene version="3.0.0">
    <default name="spp" value="4"/>
    <default name="max_depth" value="8"/>
    <integrator type="volpath"><integer name="max_depth" value="$max_depth"/></integrator>
    <sensor type="orthographic">
        <transform name="to_world">
            <scale x="2" y="2"/>
            <lookat origin="0, 10, 0" target="0, 0, 0" up="0, 0, 1"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="4"/><integer name="height" value="4"/>
            <string name="pixel_format" value="rgb"/><rfilter type="box"/>
        </film>
    </sensor>
    <emitter type="directional">
        <vector name="direction" value="0, -1, 0"/>
        <rgb name="irradiance" value="3, 3, 3"/>
    </emitter>
    <emitter type="constant"><rgb name="radiance" value="0.5, 0.6, 0.9"/></emitter>
    <shape type="rectangle" id="ground">
        <transform name="to_world">
            <matrix value="1 0 0 1  0 0 1 0  0 -2 0 0  0 0 0 1"/>
        </transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.3, 0.3, 0.3"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world">
            <matrix value="1 0 0 -1  0 0 1 1  0 -1 0 -1  0 0 0 1"/>
        </transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world">
            <matrix value="1 0 0 -1  0 0 1 1  0 -1 0 1  0 0 0 1"/>
        </transform>
        <bsdf type="mask">
            <float name="opacity" value="0"/>
            <bsdf type="principledthin"><float name="diff_trans" value="1"/></bsdf>
        </bsdf>
    </shape>
</scene>
"""


@unittest.skipUnless(
    HAVE_MITSUBA, "Mitsuba 3 is not installed (pip install -r tools/reference/requirements.txt)"
)
class MitsubaAssumptions(unittest.TestCase):
    """What the harness relies on, with the scalar variant (no LLVM needed)."""

    @classmethod
    def setUpClass(cls):
        reference.PROGRESS = False
        cls.m = reference.Mitsuba("scalar_rgb")
        cls.dir = tempfile.TemporaryDirectory()
        cls.export = Path(cls.dir.name)
        (cls.export / "scene.xml").write_text(SCENE_XML)

    @classmethod
    def tearDownClass(cls):
        cls.dir.cleanup()

    def render(self, kind, spp, seed, max_depth):
        xml = reference.harness_xml(self.export, kind, 8, 8)
        img, _ = self.m.render(xml, spp, seed, max_depth, 8, 8, kind)
        return img

    def test_coverage_sees_through_transparent_texels_and_stops_at_opaque_ones(self):
        cov = self.render("coverage", 64, 0, 1)
        sky, ground = cov[..., 0], cov[..., 1]
        self.assertTrue(np.all((sky >= 0) & (ground >= 0) & (sky + ground <= 1)))
        # Image x grows towards world -x (looking down with up = +z), so the ground (x ≥ 0)
        # fills columns 0-3, the opaque square (x ≤ 0, z ≤ 0) rows 4-7 of columns 4-7, and
        # the transparent one (x ≤ 0, z ≥ 0) rows 0-3, where the camera sees the sky.
        left, right = slice(0, 4), slice(4, 8)
        np.testing.assert_array_equal(ground[:, left], 1.0)
        np.testing.assert_array_equal(sky[:4, right], 1.0)
        np.testing.assert_array_equal(sky[4:, right] + ground[4:, right], 0.0)
        c = metrics.classify(sky, ground, np.ones((8, 8)))
        self.assertEqual(int(c["plant"].sum()), 16)
        self.assertEqual(int(c["sky"].sum()), 16)
        self.assertEqual(int(c["ground"].sum()), 32)

    def test_direct_sun_render_is_zero_only_in_shadow(self):
        sun = metrics.luminance(self.render("sun", 16, 0, 2))
        # The sun is straight above: the ground is lit, the opaque square lit from above.
        self.assertTrue(np.all(sun[:, :4] > 0))
        self.assertTrue(np.all(sun[4:, 4:] > 0))
        # Seen through the transparent square there is only sky, which emits nothing here.
        np.testing.assert_array_equal(sun[:4, 4:], 0.0)

    def test_two_seeds_differ_and_one_seed_repeats(self):
        a = self.render("reference", 4, 1, 8)
        b = self.render("reference", 4, 2, 8)
        a2 = self.render("reference", 4, 1, 8)
        np.testing.assert_array_equal(a, a2)
        self.assertGreater(float(np.abs(a - b).max()), 0.0)


if __name__ == "__main__":
    unittest.main()
