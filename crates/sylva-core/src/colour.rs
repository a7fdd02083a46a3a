//! Colour of light: black-body emitters in linear sRGB.
//!
//! [`blackbody_rgb`] integrates Planck's law against the CIE 1931 2° colour-matching functions
//! (the table below, 360-830 nm in 5 nm steps) and converts the XYZ result to linear sRGB
//! (Rec. 709 primaries, D65 white), scaled to luminance 1. The sun of the renderer and the
//! Mitsuba export is a 6500 K black body ([`SUN_TEMPERATURE_K`]).

use thiserror::Error;

/// The sun's colour temperature in sylva (SPEC §2: "the sun's colour is that of a 6500 K black
/// body").
pub const SUN_TEMPERATURE_K: f64 = 6500.0;

#[derive(Debug, Error, PartialEq)]
pub enum ColourError {
    #[error("colour temperature {0} K must be positive and finite")]
    Temperature(f64),
}

/// First wavelength of [`CIE1931_XYZ`], nm.
const CMF_START_NM: f64 = 360.0;
/// Spacing of [`CIE1931_XYZ`], nm.
const CMF_STEP_NM: f64 = 5.0;

/// CIE 1931 2° standard observer x̄, ȳ, z̄ from 360 nm to 830 nm every 5 nm.
#[rustfmt::skip]
const CIE1931_XYZ: [[f64; 3]; 95] = [
    [0.0001299, 3.917e-06, 0.0006061], // 360
    [0.0002321, 6.965e-06, 0.001086], // 365
    [0.0004149, 1.239e-05, 0.001946], // 370
    [0.0007416, 2.202e-05, 0.003486], // 375
    [0.001368, 3.9e-05, 0.00645], // 380
    [0.002236, 6.4e-05, 0.01055], // 385
    [0.004243, 0.00012, 0.02005], // 390
    [0.00765, 0.000217, 0.03621], // 395
    [0.01431, 0.000396, 0.06785], // 400
    [0.02319, 0.00064, 0.1102], // 405
    [0.04351, 0.00121, 0.2074], // 410
    [0.07763, 0.00218, 0.3713], // 415
    [0.13438, 0.004, 0.6456], // 420
    [0.21477, 0.0073, 1.03905], // 425
    [0.2839, 0.0116, 1.3856], // 430
    [0.3285, 0.01684, 1.62296], // 435
    [0.34828, 0.023, 1.74706], // 440
    [0.34806, 0.0298, 1.7826], // 445
    [0.3362, 0.038, 1.77211], // 450
    [0.3187, 0.048, 1.7441], // 455
    [0.2908, 0.06, 1.6692], // 460
    [0.2511, 0.0739, 1.5281], // 465
    [0.19536, 0.09098, 1.28764], // 470
    [0.1421, 0.1126, 1.0419], // 475
    [0.09564, 0.13902, 0.81295], // 480
    [0.05795, 0.1693, 0.6162], // 485
    [0.03201, 0.20802, 0.46518], // 490
    [0.0147, 0.2586, 0.3533], // 495
    [0.0049, 0.323, 0.272], // 500
    [0.0024, 0.4073, 0.2123], // 505
    [0.0093, 0.503, 0.1582], // 510
    [0.0291, 0.6082, 0.1117], // 515
    [0.06327, 0.71, 0.07825], // 520
    [0.1096, 0.7932, 0.05725], // 525
    [0.1655, 0.862, 0.04216], // 530
    [0.22575, 0.91485, 0.02984], // 535
    [0.2904, 0.954, 0.0203], // 540
    [0.3597, 0.9803, 0.0134], // 545
    [0.43345, 0.99495, 0.00875], // 550
    [0.51205, 1.0, 0.00575], // 555
    [0.5945, 0.995, 0.0039], // 560
    [0.6784, 0.9786, 0.00275], // 565
    [0.7621, 0.952, 0.0021], // 570
    [0.8425, 0.9154, 0.0018], // 575
    [0.9163, 0.87, 0.00165], // 580
    [0.9786, 0.8163, 0.0014], // 585
    [1.0263, 0.757, 0.0011], // 590
    [1.0567, 0.6949, 0.001], // 595
    [1.0622, 0.631, 0.0008], // 600
    [1.0456, 0.5668, 0.0006], // 605
    [1.0026, 0.503, 0.00034], // 610
    [0.9384, 0.4412, 0.00024], // 615
    [0.85445, 0.381, 0.00019], // 620
    [0.7514, 0.321, 0.0001], // 625
    [0.6424, 0.265, 5e-05], // 630
    [0.5419, 0.217, 3e-05], // 635
    [0.4479, 0.175, 2e-05], // 640
    [0.3608, 0.1382, 1e-05], // 645
    [0.2835, 0.107, 0.0], // 650
    [0.2187, 0.0816, 0.0], // 655
    [0.1649, 0.061, 0.0], // 660
    [0.1212, 0.04458, 0.0], // 665
    [0.0874, 0.032, 0.0], // 670
    [0.0636, 0.0232, 0.0], // 675
    [0.04677, 0.017, 0.0], // 680
    [0.0329, 0.01192, 0.0], // 685
    [0.0227, 0.00821, 0.0], // 690
    [0.01584, 0.005723, 0.0], // 695
    [0.0113592, 0.004102, 0.0], // 700
    [0.00811092, 0.002929, 0.0], // 705
    [0.00579035, 0.002091, 0.0], // 710
    [0.00410946, 0.001484, 0.0], // 715
    [0.00289933, 0.001047, 0.0], // 720
    [0.00204919, 0.00074, 0.0], // 725
    [0.00143997, 0.00052, 0.0], // 730
    [0.000999949, 0.0003611, 0.0], // 735
    [0.000690079, 0.0002492, 0.0], // 740
    [0.000476021, 0.0001719, 0.0], // 745
    [0.000332301, 0.00012, 0.0], // 750
    [0.000234826, 8.48e-05, 0.0], // 755
    [0.00016615, 6e-05, 0.0], // 760
    [0.000117413, 4.24e-05, 0.0], // 765
    [8.30753e-05, 3e-05, 0.0], // 770
    [5.87065e-05, 2.12e-05, 0.0], // 775
    [4.15099e-05, 1.499e-05, 0.0], // 780
    [2.93533e-05, 1.06e-05, 0.0], // 785
    [2.06738e-05, 7.4657e-06, 0.0], // 790
    [1.45598e-05, 5.2578e-06, 0.0], // 795
    [1.0254e-05, 3.7029e-06, 0.0], // 800
    [7.22146e-06, 2.6078e-06, 0.0], // 805
    [5.08587e-06, 1.8366e-06, 0.0], // 810
    [3.58165e-06, 1.2934e-06, 0.0], // 815
    [2.52252e-06, 9.1093e-07, 0.0], // 820
    [1.77651e-06, 6.4153e-07, 0.0], // 825
    [1.25114e-06, 4.5181e-07, 0.0], // 830

];

/// Second radiation constant c₂ = h·c / k_B in m·K.
const C2: f64 = 1.438_776_877e-2;

/// CIE XYZ of a black body at `kelvin`, up to a common factor (relative spectral radiance
/// integrated against the colour-matching functions).
fn blackbody_xyz(kelvin: f64) -> Result<[f64; 3], ColourError> {
    if !(kelvin.is_finite() && kelvin > 0.0) {
        return Err(ColourError::Temperature(kelvin));
    }
    // ln of Planck's spectral radiance without constant factors: -5 ln λ - ln(e^{c2/λT} - 1).
    // Working in logs and subtracting the largest keeps every temperature in range (at 100 K
    // the exponent is ~400, far past what exp() holds in f64 at 10 K).
    let ln_planck = |lambda_m: f64| {
        let x = C2 / (lambda_m * kelvin);
        // ln(e^x - 1) = x + ln(1 - e^-x), exact and overflow-free for every x > 0.
        -5.0 * lambda_m.ln() - (x + (-(-x).exp_m1()).ln())
    };
    let lambdas: Vec<f64> = (0..CIE1931_XYZ.len())
        .map(|i| (CMF_START_NM + CMF_STEP_NM * i as f64) * 1e-9)
        .collect();
    let logs: Vec<f64> = lambdas.iter().map(|&l| ln_planck(l)).collect();
    let max = logs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let mut xyz = [0.0f64; 3];
    for (cmf, ln_e) in CIE1931_XYZ.iter().zip(&logs) {
        let e = (ln_e - max).exp();
        for c in 0..3 {
            xyz[c] += e * cmf[c];
        }
    }
    Ok(xyz)
}

/// CIE 1931 chromaticity (x, y) of a black body at `kelvin`.
pub fn blackbody_xy(kelvin: f64) -> Result<[f64; 2], ColourError> {
    let [x, y, z] = blackbody_xyz(kelvin)?;
    let s = x + y + z;
    Ok([x / s, y / s])
}

/// CIE XYZ → linear sRGB (IEC 61966-2-1, D65 white).
pub fn xyz_to_linear_srgb(xyz: [f64; 3]) -> [f64; 3] {
    let [x, y, z] = xyz;
    [
        3.240_454_2 * x - 1.537_138_5 * y - 0.498_531_4 * z,
        -0.969_266_0 * x + 1.876_010_8 * y + 0.041_556_0 * z,
        0.055_643_4 * x - 0.204_025_9 * y + 1.057_225_2 * z,
    ]
}

/// The sRGB transfer function inverted (IEC 61966-2-1): an encoded component in [0, 1] →
/// linear.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.040_45 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The sRGB transfer function (IEC 61966-2-1): a linear component, clamped to [0, 1] →
/// encoded.
pub fn linear_to_srgb(c: f32) -> f32 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// A linear component, clamped to [0, 1] → 8-bit sRGB, rounded to nearest.
pub fn linear_to_srgb8(c: f32) -> u8 {
    (linear_to_srgb(c) * 255.0).round() as u8
}

/// Luminance (CIE Y) of a linear sRGB colour.
pub fn luminance(rgb: [f32; 3]) -> f32 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// Linear sRGB colour of a black body at `kelvin`, normalised to luminance 1. Temperatures
/// whose colour lies outside the sRGB gamut (below about 1900 K) have their negative
/// components clipped to 0 before the normalisation.
pub fn try_blackbody_rgb(kelvin: f64) -> Result<[f32; 3], ColourError> {
    let rgb = xyz_to_linear_srgb(blackbody_xyz(kelvin)?).map(|c| c.max(0.0));
    let lum = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
    Ok(rgb.map(|c| (c / lum) as f32))
}

/// Linear sRGB colour of a black body at `kelvin`, luminance 1: `blackbody_rgb(6500.0)` is the
/// sun's colour. See [`try_blackbody_rgb`].
///
/// # Panics
/// If `kelvin` is not positive and finite (a programming error: temperatures from users go
/// through [`try_blackbody_rgb`]).
pub fn blackbody_rgb(kelvin: f64) -> [f32; 3] {
    try_blackbody_rgb(kelvin).unwrap_or_else(|e| panic!("blackbody_rgb: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_transfer_known_values_and_round_trip() {
        assert_eq!([0.0, 1.0, 0.5].map(linear_to_srgb8), [0, 255, 188]);
        assert!((linear_to_srgb(0.5) - 0.735_357).abs() < 1e-5);
        assert_eq!(linear_to_srgb(-1.0), 0.0);
        assert_eq!(linear_to_srgb(2.0), linear_to_srgb(1.0));
        // The two pieces meet at the thresholds.
        let t = 0.003_130_8f32;
        assert!((12.92 * t - (1.055 * t.powf(1.0 / 2.4) - 0.055)).abs() < 1e-6);
        let t = 0.040_45f32;
        assert!((t / 12.92 - ((t + 0.055) / 1.055).powf(2.4)).abs() < 1e-6);
        for b in 0..=255u8 {
            assert_eq!(linear_to_srgb8(srgb_to_linear(b as f32 / 255.0)), b);
        }
    }

    /// Planckian-locus chromaticities (CIE 1931 2°) from the literature, e.g. Wyszecki &
    /// Stiles, Table 1(3.11), and the tabulated CIE values used by colour-science packages.
    const LOCUS: [(f64, f64, f64); 5] = [
        (2000.0, 0.5267, 0.4133),
        (3000.0, 0.4369, 0.4041),
        (4000.0, 0.3805, 0.3768),
        (6500.0, 0.3135, 0.3236),
        (10000.0, 0.2807, 0.2884),
    ];

    #[test]
    fn chromaticity_on_the_planckian_locus() {
        for (t, x, y) in LOCUS {
            let [bx, by] = blackbody_xy(t).unwrap();
            assert!(
                (bx - x).abs() < 1.5e-3 && (by - y).abs() < 1.5e-3,
                "{t} K: ({bx:.4}, {by:.4}) vs ({x}, {y})"
            );
        }
    }

    #[test]
    fn sun_is_close_to_d65_white() {
        let c = blackbody_rgb(SUN_TEMPERATURE_K);
        assert!((luminance(c) - 1.0).abs() < 1e-5, "{c:?}");
        // D65 itself is (1, 1, 1); the 6500 K Planckian sits just below it, a touch magenta:
        // (1.043, 0.984, 1.035).
        assert!(c[1] < c[0] && c[1] < c[2], "{c:?}");
        for v in c {
            assert!((v - 1.0).abs() < 0.05, "{c:?}");
        }
        // D65 is at (0.3127, 0.3290): within Δxy 0.006 of the 6500 K black body.
        let [x, y] = blackbody_xy(6500.0).unwrap();
        assert!(((x - 0.3127).powi(2) + (y - 0.3290).powi(2)).sqrt() < 0.006);
    }

    #[test]
    fn warm_is_red_and_hot_is_blue() {
        let warm = blackbody_rgb(3000.0);
        assert!(warm[0] > warm[1] && warm[1] > warm[2], "{warm:?}");
        assert!(warm[0] > 1.2 && warm[2] < 0.6, "{warm:?}");
        let hot = blackbody_rgb(12000.0);
        assert!(hot[2] > hot[1] && hot[1] > hot[0], "{hot:?}");
        // Blue over red grows with temperature.
        let mut last = 0.0;
        for t in [2000.0, 2500.0, 4000.0, 6500.0, 9000.0, 20000.0] {
            let c = blackbody_rgb(t);
            assert!((luminance(c) - 1.0).abs() < 1e-5, "{t}: {c:?}");
            assert!(c.iter().all(|v| v.is_finite() && *v >= 0.0), "{t}: {c:?}");
            let ratio = c[2] / c[0];
            assert!(ratio > last, "{t}: {c:?}");
            last = ratio;
        }
    }

    #[test]
    fn extreme_and_invalid_temperatures() {
        // Far outside the visible peak the log-space integration still gives a colour.
        // Out of gamut: blue clipped to 0, still luminance 1.
        let deep = blackbody_rgb(1500.0);
        assert_eq!(deep[2], 0.0);
        assert!((luminance(deep) - 1.0).abs() < 1e-5, "{deep:?}");
        let cold = try_blackbody_rgb(50.0).unwrap();
        assert!(
            cold[0] > 0.0 && cold.iter().all(|v| v.is_finite()),
            "{cold:?}"
        );
        let [x, _] = blackbody_xy(1e7).unwrap();
        assert!((x - 0.2399).abs() < 0.003, "{x}"); // the locus tends to (0.240, 0.234)
        for bad in [0.0, -5.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                try_blackbody_rgb(bad),
                Err(ColourError::Temperature(_))
            ));
        }
    }
}
