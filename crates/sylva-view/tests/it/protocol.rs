//! What the page may send, checked before it reaches the renderer.

use sylva_view::orbit::Orbit;
use sylva_view::protocol::{
    decode_frame, encode_frame, parse_client_message, ClientMessage, FrameHeader, SunControl,
    ViewRequest, MAX_MESSAGE_BYTES,
};

pub(crate) fn request(seq: u64, elevation: f64, azimuth: f64) -> ViewRequest {
    ViewRequest {
        seq,
        sun: SunControl::Angles { elevation, azimuth },
        camera: Orbit {
            yaw_deg: 30.0,
            pitch_deg: 20.0,
            distance: 30.0,
            target: [0.0, 4.0, 0.0],
        },
        mode: "full".into(),
        gather_rays: 2,
        exposure: 0.0,
        width: 48,
        height: 32,
        interacting: true,
    }
}

#[test]
fn a_good_request_resolves_and_every_bad_field_is_refused_by_name() {
    let good = request(1, 40.0, 180.0);
    let view = good.resolve(1 << 20).unwrap();
    // Compass 180° (south, +z) at 40°: the sun is towards +z and up.
    assert!(view.to_sun.z > 0.7 && view.to_sun.y > 0.6 && view.to_sun.x.abs() < 1e-6);
    let cases: Vec<(ViewRequest, &str)> = vec![
        (
            ViewRequest {
                mode: "bright".into(),
                ..good.clone()
            },
            "mode",
        ),
        (
            ViewRequest {
                gather_rays: 100_000,
                ..good.clone()
            },
            "gather_rays",
        ),
        (
            ViewRequest {
                exposure: f32::NAN,
                ..good.clone()
            },
            "exposure",
        ),
        (
            ViewRequest {
                exposure: 40.0,
                ..good.clone()
            },
            "exposure",
        ),
        (
            ViewRequest {
                width: 0,
                ..good.clone()
            },
            "frame",
        ),
        (
            ViewRequest {
                width: 100_000,
                ..good.clone()
            },
            "frame",
        ),
        (
            ViewRequest {
                width: 2000,
                height: 2000,
                ..good.clone()
            },
            "pixels",
        ),
        (request(1, -5.0, 0.0), "horizon"),
        (request(1, f64::INFINITY, 0.0), "not numbers"),
        (
            ViewRequest {
                camera: Orbit {
                    pitch_deg: 90.0,
                    ..good.camera
                },
                ..good.clone()
            },
            "pitch",
        ),
        (
            ViewRequest {
                camera: Orbit {
                    distance: -1.0,
                    ..good.camera
                },
                ..good.clone()
            },
            "distance",
        ),
        (
            ViewRequest {
                camera: Orbit {
                    target: [f32::NAN, 0.0, 0.0],
                    ..good.camera
                },
                ..good.clone()
            },
            "not numbers",
        ),
    ];
    for (r, word) in cases {
        let e = r.resolve(1 << 20).unwrap_err();
        assert!(e.contains(word), "{r:?}: '{e}' should name {word}");
    }
}

#[test]
fn the_sun_of_a_clock_time_is_nrels_and_the_night_is_refused() {
    let clock = |time: &str| SunControl::Clock {
        lat: 48.1,
        lon: 11.6,
        date: "2026-06-21".into(),
        time: time.into(),
        utc_offset: Some("+02:00".into()),
    };
    // Munich at the June solstice, in summer time (solar noon is about 13:15: 11.6° east, equation of time -2 min): the sun
    // stands about 90 - 48.1 + 23.4 = 65.3° high, due south at solar noon.
    let (noon, to_sun) = clock("13:15").resolve().unwrap();
    assert!((noon.elevation - 65.3).abs() < 0.5, "{noon:?}");
    assert!((noon.azimuth - 180.0).abs() < 3.0, "{noon:?}");
    assert!(to_sun.z > 0.0, "south is +z: {to_sun}");
    let e = clock("01:00").resolve().unwrap_err();
    assert!(e.contains("below the horizon"), "{e}");
    let bad_date = SunControl::Clock {
        lat: 48.1,
        lon: 11.6,
        date: "2026-13-40".into(),
        time: "12:00".into(),
        utc_offset: None,
    };
    assert!(bad_date.resolve().unwrap_err().contains("date"));
    let bad_place = SunControl::Clock {
        lat: 91.0,
        lon: 11.6,
        date: "2026-06-21".into(),
        time: "12:00".into(),
        utc_offset: None,
    };
    assert!(bad_place.resolve().unwrap_err().contains("91"));
}

#[test]
fn messages_parse_strictly_and_frames_round_trip() {
    let r = request(7, 30.0, 90.0);
    let text = serde_json::to_string(&ClientMessage::View(r.clone())).unwrap();
    assert_eq!(parse_client_message(&text).unwrap(), ClientMessage::View(r));
    for bad in [
        "not json",
        r#"{"type":"render"}"#,
        r#"{"type":"save"}"#,
        r#"{"type":"save","format":"png","extra":1}"#,
    ] {
        assert!(parse_client_message(bad).is_err(), "{bad}");
    }
    let huge = format!(
        r#"{{"type":"save","format":"{}"}}"#,
        "x".repeat(MAX_MESSAGE_BYTES)
    );
    assert!(parse_client_message(&huge).unwrap_err().contains("bytes"));

    let header = FrameHeader {
        seq: 3,
        refined: true,
        width: 4,
        height: 2,
        samples: 5,
        render_ms: 1.5,
        encode_ms: 0.25,
        relight_ms: 0.5,
        sun_elevation: 30.0,
        sun_azimuth: 90.0,
        lb_solves: 0,
    };
    let bytes = encode_frame(&header, b"jpeg bytes");
    let (h, jpeg) = decode_frame(&bytes).unwrap();
    assert_eq!((h, jpeg), (header, &b"jpeg bytes"[..]));
    assert!(decode_frame(&bytes[..6]).is_err());
}
