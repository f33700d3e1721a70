//! Edge cases of the codec the golden vectors do not show, each as the reference decoder
//! decides it.

use rmpv::Value;

use super::*;

fn frame() -> DetectionFrame {
    DetectionFrame {
        vehicle: "veh-1".into(),
        sensor: "lidar".into(),
        seq: 3,
        stamp_ns: 1_700_000_000_000_000_000,
        frame_id: "base_link".into(),
        pose: None,
        key_frame: true,
        session_id: Some(12345),
        extrinsic: None,
        boxes: BoxColumns::from_detections(
            &["Car", "Pedestrian"],
            &[
                Detection {
                    class: "Car".into(),
                    center: [1.0, 2.0, 0.5],
                    size: [4.0, 2.0, 1.5],
                    yaw: 0.1,
                    score: 0.9,
                    velocity: Some([1.0, 0.0]),
                },
                Detection {
                    class: "Pedestrian".into(),
                    center: [5.0, -1.0, 0.9],
                    size: [0.8, 0.7, 1.8],
                    yaw: 1.0,
                    score: 0.6,
                    velocity: Some([0.0, 1.0]),
                },
            ],
        ),
    }
}

fn bytes(v: &Value) -> Vec<u8> {
    let mut out = Vec::new();
    rmpv::encode::write_value(&mut out, v).unwrap();
    out
}

/// The valid frame's map, changed by `f`, encoded again.
fn mutated(f: impl FnOnce(&mut Vec<(Value, Value)>)) -> Vec<u8> {
    let encoded = encode_detection_frame(&frame()).unwrap();
    let mut value = rmpv::decode::read_value(&mut encoded.as_slice()).unwrap();
    if let Value::Map(pairs) = &mut value {
        f(pairs);
    }
    bytes(&value)
}

fn entry<'a>(pairs: &'a mut [(Value, Value)], key: &str) -> &'a mut Value {
    &mut pairs
        .iter_mut()
        .find(|(k, _)| k.as_str() == Some(key))
        .unwrap()
        .1
}

fn boxes_entry<'a>(pairs: &'a mut [(Value, Value)], key: &str) -> &'a mut Value {
    match entry(pairs, "boxes") {
        Value::Map(b) => entry(b, key),
        _ => unreachable!(),
    }
}

fn refused(payload: &[u8]) -> (ErrorReason, Option<String>) {
    let r = decode_detection_frame(payload, &DecodeLimits::default()).unwrap_err();
    (r.reason, r.field)
}

fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

#[test]
fn a_frame_round_trips() {
    let f = frame();
    let payload = encode_detection_frame(&f).unwrap();
    assert_eq!(
        decode_detection_frame(&payload, &DecodeLimits::default()).unwrap(),
        f
    );
}

#[test]
fn a_repeated_key_keeps_its_last_value() {
    let payload = mutated(|m| m.push(("seq".into(), 9.into())));
    assert_eq!(
        decode_detection_frame(&payload, &DecodeLimits::default())
            .unwrap()
            .seq,
        9
    );
}

#[test]
fn a_bin_key_is_an_invalid_value_named_as_python_prints_bytes() {
    let payload = mutated(|m| m.push((Value::Binary(b"speed".to_vec()), 1.into())));
    assert_eq!(
        refused(&payload),
        (ErrorReason::InvalidValue, Some("b'speed'".into()))
    );
}

#[test]
fn an_extra_key_inside_boxes_is_named_by_its_path() {
    let payload = mutated(|m| {
        if let Value::Map(b) = entry(m, "boxes") {
            b.push(("speed".into(), 1.into()));
        }
    });
    assert_eq!(
        refused(&payload),
        (ErrorReason::ExtraField, Some("boxes.speed".into()))
    );
}

#[test]
fn nil_for_key_frame_is_a_wrong_type_but_nil_for_pose_is_no_pose() {
    let payload = mutated(|m| m.push(("key_frame".into(), Value::Nil)));
    assert_eq!(
        refused(&payload),
        (ErrorReason::WrongType, Some("key_frame".into()))
    );
    let payload = mutated(|m| m.push(("pose".into(), Value::Nil)));
    assert_eq!(
        decode_detection_frame(&payload, &DecodeLimits::default())
            .unwrap()
            .pose,
        None
    );
}

#[test]
fn unreadable_msgpack_is_malformed() {
    let good = encode_detection_frame(&frame()).unwrap();
    let mut trailing = good.clone();
    trailing.push(0xc0);
    let int_key = bytes(&Value::Map(vec![(1.into(), 2.into())]));
    let mut bad_utf8 = mutated(|m| *entry(m, "frame_id") = "QQ".into());
    let at = bad_utf8.windows(3).position(|w| w == b"\xa2QQ").unwrap();
    bad_utf8[at + 1..at + 3].copy_from_slice(&[0xff, 0xfe]);
    let bad_timestamp = mutated(|m| m.push(("t".into(), Value::Ext(-1, vec![0; 5]))));
    let not_a_map = bytes(&Value::Array(vec![]));
    for payload in [
        trailing,
        int_key,
        bad_utf8,
        bad_timestamp,
        not_a_map,
        vec![0xc1],
    ] {
        assert_eq!(
            refused(&payload),
            (ErrorReason::Malformed, Some("payload".into())),
            "{payload:02x?}"
        );
    }
}

#[test]
fn the_first_failing_check_wins() {
    // NaN in center (an earlier column) comes before the bad length of yaw.
    let payload = mutated(|m| {
        *boxes_entry(m, "center") = Value::Binary(f32_bytes(&[f32::NAN, 0.0, 0.0, 1.0, 1.0, 1.0]));
        *boxes_entry(m, "yaw") = Value::Binary(vec![0; 4]);
    });
    assert_eq!(
        refused(&payload),
        (ErrorReason::NonFinite, Some("boxes.center".into()))
    );
    // A structural error anywhere comes before any column is looked at.
    let payload = mutated(|m| {
        *boxes_entry(m, "yaw") = Value::Binary(vec![0; 4]);
        *entry(m, "frame_id") = "".into();
    });
    assert_eq!(
        refused(&payload),
        (ErrorReason::InvalidValue, Some("frame_id".into()))
    );
}

#[test]
fn a_class_name_over_64_characters_is_named_by_its_index() {
    let payload = mutated(|m| {
        *boxes_entry(m, "classes") = Value::Array(vec!["Car".into(), "é".repeat(65).into()]);
    });
    assert_eq!(
        refused(&payload),
        (ErrorReason::InvalidValue, Some("boxes.classes.1".into()))
    );
    // 64 two-byte characters are 64 characters, not 128.
    let payload = mutated(|m| {
        *boxes_entry(m, "classes") = Value::Array(vec!["Car".into(), "é".repeat(64).into()]);
    });
    assert!(decode_detection_frame(&payload, &DecodeLimits::default()).is_ok());
}

#[test]
fn caps_refuse_too_large_payloads_and_box_counts() {
    let payload = encode_detection_frame(&frame()).unwrap();
    let small = DecodeLimits {
        max_bytes: payload.len() - 1,
        ..DecodeLimits::default()
    };
    let r = decode_detection_frame(&payload, &small).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::TooLarge, Some("payload"))
    );
    let few = DecodeLimits {
        max_boxes: 1,
        ..DecodeLimits::default()
    };
    let r = decode_detection_frame(&payload, &few).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::TooLarge, Some("boxes.count"))
    );
}

#[test]
fn a_pose_must_be_finite_rigid_and_within_bounds() {
    let eye = [
        1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ];
    let with = |pose: [f64; 16]| DetectionFrame {
        pose: Some(pose),
        ..frame()
    };
    assert!(encode_detection_frame(&with(eye)).is_ok());
    let mut reflection = eye;
    reflection[10] = -1.0;
    let mut far = eye;
    far[7] = 1.5e5;
    let mut nan = eye;
    nan[3] = f64::NAN;
    for (pose, reason) in [
        (reflection, ErrorReason::InvalidValue),
        (far, ErrorReason::InvalidValue),
        (nan, ErrorReason::NonFinite),
    ] {
        let r = encode_detection_frame(&with(pose)).unwrap_err();
        assert_eq!((r.reason, r.field.as_deref()), (reason, Some("pose")));
    }
    // The decoder says the same of the same pose, and refuses 15 numbers as a bad length.
    let payload = mutated(|m| {
        m.push((
            "pose".into(),
            Value::Array(reflection.iter().map(|&v| v.into()).collect()),
        ))
    });
    assert_eq!(
        refused(&payload),
        (ErrorReason::InvalidValue, Some("pose".into()))
    );
    let payload = mutated(|m| {
        m.push((
            "pose".into(),
            Value::Array(eye[..15].iter().map(|&v| v.into()).collect()),
        ))
    });
    assert_eq!(
        refused(&payload),
        (ErrorReason::InvalidValue, Some("pose".into()))
    );
    let payload = mutated(|m| m.push(("pose".into(), Value::Array(vec![true.into(); 16]))));
    assert_eq!(
        refused(&payload),
        (ErrorReason::WrongType, Some("pose.0".into()))
    );
}

#[test]
fn the_encoder_refuses_what_the_decoder_would() {
    let cases: Vec<(DetectionFrame, ErrorReason, &str)> = vec![
        (
            DetectionFrame {
                vehicle: "veh/1".into(),
                ..frame()
            },
            ErrorReason::InvalidValue,
            "vehicle",
        ),
        (
            DetectionFrame {
                seq: u64::MAX,
                ..frame()
            },
            ErrorReason::InvalidValue,
            "seq",
        ),
        (
            DetectionFrame {
                frame_id: String::new(),
                ..frame()
            },
            ErrorReason::InvalidValue,
            "frame_id",
        ),
        (
            {
                let mut f = frame();
                f.boxes.yaw.pop();
                f
            },
            ErrorReason::ColumnLength,
            "boxes.yaw",
        ),
        (
            {
                let mut f = frame();
                f.boxes.size[1][2] = 0.0;
                f
            },
            ErrorReason::NonPositiveSize,
            "boxes.size",
        ),
        (
            {
                let mut f = frame();
                f.boxes.velocity = Some(vec![[0.0, 0.0], [250.0, 0.0]]);
                f
            },
            ErrorReason::InvalidValue,
            "boxes.velocity",
        ),
        (
            {
                let mut f = frame();
                f.boxes.class_index[0] = 2;
                f
            },
            ErrorReason::InvalidValue,
            "boxes.class_index",
        ),
        (
            {
                let mut f = frame();
                f.boxes.score[0] = f64::INFINITY;
                f
            },
            ErrorReason::NonFinite,
            "boxes.score",
        ),
    ];
    for (f, reason, field) in cases {
        let r = encode_detection_frame(&f).unwrap_err();
        assert_eq!((r.reason, r.field.as_deref()), (reason, Some(field)), "{r}");
    }
}

#[test]
fn detections_without_velocity_for_every_box_send_none_and_new_classes_are_appended() {
    let d = |class: &str, velocity| Detection {
        class: class.into(),
        center: [0.0; 3],
        size: [1.0; 3],
        yaw: 0.0,
        score: 0.5,
        velocity,
    };
    let b = BoxColumns::from_detections(&["Car"], &[d("Car", Some([1.0, 0.0])), d("Tram", None)]);
    assert_eq!(b.velocity, None);
    assert_eq!(b.classes, ["Car", "Tram"]);
    assert_eq!(b.class_index, [0, 1]);
    let f = DetectionFrame {
        boxes: b,
        ..frame()
    };
    let r = check_known_classes(&f, &["Car", "Pedestrian", "Cyclist"]).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::UnknownClass, Some("boxes.classes.1"))
    );
    assert!(BoxColumns::from_detections(&["Car"], &[])
        .velocity
        .is_none());
}

#[test]
fn a_notice_stands_for_its_seqs_its_seq_or_for_missed_none_it_can_name() {
    let e = FrameError {
        vehicle: "v".into(),
        sensor: "s".into(),
        seq: Some(4),
        stamp_ns: Some(10),
        reason: ErrorReason::DroppedQueueFull,
        field: None,
        detail: "shed".into(),
        instance: "svc".into(),
        received_ns: 11,
        seqs: Some(vec![Some(4), None, Some(6)]),
    };
    let back =
        decode_frame_error(&encode_frame_error(&e).unwrap(), &DecodeLimits::default()).unwrap();
    assert_eq!(back, e);
    assert_eq!(back.frames(), [Some(4), None, Some(6)]);
    assert_eq!(
        FrameError {
            seqs: None,
            ..e.clone()
        }
        .frames(),
        [Some(4)]
    );
    let missed = FrameError {
        seqs: None,
        seq: None,
        stamp_ns: None,
        reason: ErrorReason::Missed,
        ..e
    };
    assert!(missed.frames().is_empty());
}

#[test]
fn an_unknown_reason_is_an_invalid_value_and_a_bin_reason_is_read() {
    let e = FrameError {
        vehicle: "v".into(),
        sensor: "s".into(),
        seq: None,
        stamp_ns: None,
        reason: ErrorReason::Missed,
        field: None,
        detail: "3 frames".into(),
        instance: "svc".into(),
        received_ns: 1,
        seqs: None,
    };
    let encoded = encode_frame_error(&e).unwrap();
    let with_reason = |reason: Value| {
        let mut v = rmpv::decode::read_value(&mut encoded.as_slice()).unwrap();
        if let Value::Map(m) = &mut v {
            *entry(m, "reason") = reason;
        }
        bytes(&v)
    };
    let r =
        decode_frame_error(&with_reason("exploded".into()), &DecodeLimits::default()).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::InvalidValue, Some("reason"))
    );
    let back = decode_frame_error(
        &with_reason(Value::Binary(b"missed".to_vec())),
        &DecodeLimits::default(),
    );
    assert_eq!(back.unwrap().reason, ErrorReason::Missed);
}

#[test]
fn keys_name_a_sensor_and_back() {
    let k = Keys::default();
    assert_eq!(k.detections("veh", "lidar"), "fleet/veh/lidar/detections");
    assert_eq!(
        k.sensor_of("fleet/veh/lidar/tracks"),
        Some(("veh", "lidar"))
    );
    assert_eq!(k.sensor_of("fleet/veh/tracks"), None);
    assert_eq!(k.sensor_of("other/veh/lidar/tracks"), None);
}

fn track_frame(version: u64) -> TrackFrame {
    let n = 2;
    let mut upper = [0.0f32; 21];
    upper
        .iter_mut()
        .enumerate()
        .for_each(|(i, v)| *v = i as f32);
    TrackFrame {
        vehicle: "veh-1".into(),
        sensor: "lidar".into(),
        seq: 3,
        stamp_ns: 9,
        frame_id: "world".into(),
        pose: None,
        key_frame: true,
        instance: "svc".into(),
        received_ns: 10,
        published_ns: 11,
        tracks: TrackColumns {
            classes: vec!["Car".into()],
            id: vec![7, 1 << 40],
            class_index: vec![0; n],
            center: vec![[1.0, 2.0, 0.5]; n],
            size: vec![[4.0, 2.0, 1.5]; n],
            yaw: vec![0.0; n],
            score: vec![0.5; n],
            velocity: vec![[0.0; 3]; n],
            state: vec![1; n],
            hits: vec![3; n],
            age: vec![4; n],
            time_since_update: vec![0; n],
            covariance: (version >= 2).then(|| vec![upper; n]),
            age_s: (version >= 2).then(|| vec![0.4, 12.5]),
            time_since_update_s: (version >= 2).then(|| vec![0.0, 0.1]),
            existence: None,
            sensor_stamp_ns: None,
        },
        schema_version: version,
        epoch: None,
    }
}

#[test]
fn track_frames_of_both_versions_round_trip_and_version_1_has_no_new_columns() {
    for version in [1, 2] {
        let t = track_frame(version);
        let bytes = encode_track_frame(&t).unwrap();
        let back = decode_track_frame(&bytes, &DecodeLimits::default()).unwrap();
        assert_eq!(back, t);
        assert_eq!(back.tracks.age_s.is_some(), version == 2);
    }
    // A version-1 frame with version 2's columns is refused, as a version-1 reader would.
    let v2 = encode_track_frame(&track_frame(2)).unwrap();
    let mut value = rmpv::decode::read_value(&mut &v2[..]).unwrap();
    if let Value::Map(m) = &mut value {
        m[0].1 = Value::from(1);
    }
    let mut relabelled = Vec::new();
    rmpv::encode::write_value(&mut relabelled, &value).unwrap();
    let r = decode_track_frame(&relabelled, &DecodeLimits::default()).unwrap_err();
    assert_eq!(r.reason, ErrorReason::ExtraField);
    assert_eq!(r.field.as_deref(), Some("tracks.covariance"));
}

#[test]
fn an_epoch_travels_in_version_3_only() {
    let mut t = track_frame(3);
    t.epoch = Some(1 << 40);
    let bytes = encode_track_frame(&t).unwrap();
    let back = decode_track_frame(&bytes, &DecodeLimits::default()).unwrap();
    assert_eq!((back.schema_version, back.epoch), (3, Some(1 << 40)));
    assert_eq!(back, t);
    // Version 2 has no such field: the encoder leaves it out (the bytes a version-2 reader
    // takes), and a version-2 frame that holds one is refused, as such a reader would.
    t.schema_version = 2;
    let v2 = encode_track_frame(&t).unwrap();
    assert_eq!(v2, encode_track_frame(&track_frame(2)).unwrap());
    let mut value = rmpv::decode::read_value(&mut &bytes[..]).unwrap();
    if let Value::Map(m) = &mut value {
        m[0].1 = Value::from(2);
    }
    let mut relabelled = Vec::new();
    rmpv::encode::write_value(&mut relabelled, &value).unwrap();
    let r = decode_track_frame(&relabelled, &DecodeLimits::default()).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::ExtraField, Some("epoch"))
    );
    // Version 3 without an epoch, and one out of range.
    let plain = decode_track_frame(
        &encode_track_frame(&track_frame(3)).unwrap(),
        &DecodeLimits::default(),
    )
    .unwrap();
    assert_eq!(plain.epoch, None);
    t.schema_version = 3;
    t.epoch = Some(1 << 63);
    assert_eq!(
        encode_track_frame(&t).unwrap_err().field.as_deref(),
        Some("epoch")
    );
}

#[test]
fn a_version_2_frame_without_ages_is_not_encoded_and_version_4_is_refused() {
    let mut t = track_frame(2);
    t.tracks.age_s = None;
    assert_eq!(
        encode_track_frame(&t).unwrap_err().field.as_deref(),
        Some("tracks.age_s")
    );
    t.schema_version = 4;
    assert_eq!(
        encode_track_frame(&t).unwrap_err().reason,
        ErrorReason::WrongVersion
    );
}

#[test]
fn covariance_elements_and_global_ids() {
    let t = track_frame(2);
    let upper = &t.tracks.covariance.as_ref().unwrap()[0];
    assert_eq!(covariance_at(upper, 0, 0), 0.0);
    assert_eq!(covariance_at(upper, 0, 5), 5.0);
    assert_eq!(covariance_at(upper, 1, 1), 6.0);
    assert_eq!(covariance_at(upper, 4, 1), 9.0); // (1, 4): symmetric
    assert_eq!(covariance_at(upper, 5, 5), 20.0);
    assert_eq!(t.global_id(1).as_deref(), Some("veh-1/lidar/1099511627776"));
    assert_eq!(t.global_id(2), None);
}
