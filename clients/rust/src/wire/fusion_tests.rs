//! Vehicle fusion on the wire: a detection frame's extrinsic (version 2), a vehicle's fused
//! tracks, the status of fused vehicles, and the reasons that come with them.

use rmpv::Value;

use super::*;

const REAR: [f64; 16] = [
    -1.0, 0.0, 0.0, -3.5, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.5, 0.0, 0.0, 0.0, 1.0,
];

fn detections(extrinsic: Option<[f64; 16]>) -> DetectionFrame {
    DetectionFrame {
        vehicle: "veh-1".into(),
        sensor: "radar".into(),
        seq: 3,
        stamp_ns: 1_700_000_000_000_000_000,
        frame_id: "radar".into(),
        pose: None,
        key_frame: true,
        session_id: Some(5),
        boxes: BoxColumns::from_detections(
            &["Car"],
            &[Detection {
                class: "Car".into(),
                center: [1.0, 2.0, 0.5],
                size: [4.0, 2.0, 1.5],
                yaw: 0.1,
                score: 0.9,
                velocity: None,
            }],
        ),
        extrinsic,
    }
}

fn value_of(payload: &[u8]) -> Value {
    rmpv::decode::read_value(&mut &payload[..]).unwrap()
}

fn packed(v: &Value) -> Vec<u8> {
    let mut out = Vec::new();
    rmpv::encode::write_value(&mut out, v).unwrap();
    out
}

fn set(v: &mut Value, key: &str, to: Value) {
    if let Value::Map(pairs) = v {
        match pairs.iter_mut().find(|(k, _)| k.as_str() == Some(key)) {
            Some((_, slot)) => *slot = to,
            None => pairs.push((key.into(), to)),
        }
    }
}

#[test]
fn an_extrinsic_makes_version_2_and_round_trips() {
    let f = detections(Some(REAR));
    assert_eq!(f.schema_version(), 2);
    let payload = encode_detection_frame(&f).unwrap();
    let keys: Vec<String> = match value_of(&payload) {
        Value::Map(pairs) => pairs
            .iter()
            .map(|(k, _)| k.as_str().unwrap().to_owned())
            .collect(),
        _ => unreachable!(),
    };
    assert_eq!(keys[0], "schema_version");
    assert_eq!(
        &keys[keys.len() - 3..],
        ["boxes", "session_id", "extrinsic"]
    );
    assert_eq!(
        decode_detection_frame(&payload, &DecodeLimits::default()).unwrap(),
        f
    );
    let plain = encode_detection_frame(&detections(None)).unwrap();
    assert_eq!(plain[16], 1, "schema_version 1 without an extrinsic");
    assert_eq!(payload[16], 2);
}

#[test]
fn a_version_1_frame_with_an_extrinsic_and_a_bad_extrinsic_are_refused() {
    let mut v = value_of(&encode_detection_frame(&detections(Some(REAR))).unwrap());
    set(&mut v, "schema_version", 1.into());
    let r = decode_detection_frame(&packed(&v), &DecodeLimits::default()).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::ExtraField, Some("extrinsic"))
    );
    let mut scaled = REAR;
    scaled[0] = -2.0;
    let r = encode_detection_frame(&detections(Some(scaled))).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::InvalidValue, Some("extrinsic"))
    );
    let mut v = value_of(&encode_detection_frame(&detections(Some(REAR))).unwrap());
    set(
        &mut v,
        "extrinsic",
        Value::Array(scaled.iter().map(|&x| x.into()).collect()),
    );
    let r = decode_detection_frame(&packed(&v), &DecodeLimits::default()).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::InvalidValue, Some("extrinsic"))
    );
    set(&mut v, "schema_version", 3.into());
    let r = decode_detection_frame(&packed(&v), &DecodeLimits::default()).unwrap_err();
    assert_eq!(r.reason, ErrorReason::WrongVersion);
}

fn fused() -> VehicleTrackFrame {
    let n = 2;
    VehicleTrackFrame {
        vehicle: "veh-1".into(),
        seq: 100,
        stamp_ns: 2_000,
        sensor: "lidar".into(),
        sensor_seq: 7,
        frame_id: "base_link".into(),
        pose: None,
        instance: "svc".into(),
        received_ns: 3_000,
        published_ns: 4_000,
        sensors: vec!["lidar".into(), "radar".into()],
        sensor_state: vec![SensorCondition::Ok, SensorCondition::Extrinsic],
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
            covariance: None,
            age_s: Some(vec![0.4, 12.5]),
            time_since_update_s: Some(vec![0.0, 0.1]),
            existence: Some(vec![1.0, 0.25]),
            sensor_stamp_ns: Some(vec![vec![2_000, 1_950], vec![2_000, NEVER_UPDATED]]),
        },
        epoch: None,
    }
}

#[test]
fn a_vehicle_frame_with_an_epoch_is_version_2_and_one_without_version_1() {
    let mut f = fused();
    f.epoch = Some((1 << 32) + 1);
    let payload = encode_vehicle_track_frame(&f).unwrap();
    let back = decode_vehicle_track_frame(&payload, &DecodeLimits::default()).unwrap();
    assert_eq!(
        (back.schema_version(), back.epoch),
        (2, Some((1 << 32) + 1))
    );
    assert_eq!(back, f);
    let plain = encode_vehicle_track_frame(&fused()).unwrap();
    assert_eq!(plain[16], 1, "schema_version 1 without an epoch");
    // An epoch in a frame that says version 1 is refused, as a version-1 reader would.
    let mut v = rmpv::decode::read_value(&mut &payload[..]).unwrap();
    set(&mut v, "schema_version", 1.into());
    let r = decode_vehicle_track_frame(&packed(&v), &DecodeLimits::default()).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::ExtraField, Some("epoch"))
    );
    f.epoch = Some(1 << 63);
    let r = encode_vehicle_track_frame(&f).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::InvalidValue, Some("epoch"))
    );
}

#[test]
fn a_vehicle_frame_round_trips_and_names_its_tracks() {
    let f = fused();
    let payload = encode_vehicle_track_frame(&f).unwrap();
    let back = decode_vehicle_track_frame(&payload, &DecodeLimits::default()).unwrap();
    assert_eq!(back, f);
    assert_eq!(
        back.global_id(1).as_deref(),
        Some("veh-1/@vehicle/1099511627776")
    );
    assert_eq!(back.last_update_ns(0, "radar"), Some(1_950));
    assert_eq!(back.last_update_ns(1, "radar"), None);
    assert_eq!(back.last_update_ns(1, "camera"), None);
    assert_eq!(back.count(), 2);
    assert_eq!(
        back.global_ids(),
        ["veh-1/@vehicle/7", "veh-1/@vehicle/1099511627776"]
    );
    assert_eq!((back.existence(1), back.existence(2)), (Some(0.25), None));
    assert_eq!(back.contributors(0), [("lidar", 2_000), ("radar", 1_950)]);
    assert_eq!(back.contributors(1), [("lidar", 2_000)]);
    assert!(back.contributors(2).is_empty());
    assert_eq!(back.condition("radar"), Some(SensorCondition::Extrinsic));
    assert_eq!(back.condition("camera"), None);
    // A sensor's TrackFrame decoder does not take it, nor the other way round.
    assert!(decode_track_frame(&payload, &DecodeLimits::default()).is_err());
}

fn refused_vehicle(f: impl FnOnce(&mut Value)) -> (ErrorReason, Option<String>) {
    let mut v = value_of(&encode_vehicle_track_frame(&fused()).unwrap());
    f(&mut v);
    let r = decode_vehicle_track_frame(&packed(&v), &DecodeLimits::default()).unwrap_err();
    assert_eq!((r.seq, r.stamp_ns), (Some(100), Some(2_000)));
    (r.reason, r.field)
}

fn set_column(v: &mut Value, key: &str, to: Vec<u8>) {
    if let Value::Map(pairs) = v {
        let tracks = pairs
            .iter_mut()
            .find(|(k, _)| k.as_str() == Some("tracks"))
            .unwrap();
        set(&mut tracks.1, key, Value::Binary(to));
    }
}

#[test]
fn a_vehicle_frame_breaking_its_own_rules_is_refused_with_its_field() {
    let width: Vec<u8> = [2_000i64, 2_000]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    assert_eq!(
        refused_vehicle(|v| set_column(v, "sensor_stamp_ns", width)),
        (
            ErrorReason::ColumnLength,
            Some("tracks.sensor_stamp_ns".into())
        )
    );
    let existence: Vec<u8> = [0.5f64, 1.5].iter().flat_map(|v| v.to_le_bytes()).collect();
    assert_eq!(
        refused_vehicle(|v| set_column(v, "existence", existence)),
        (ErrorReason::InvalidValue, Some("tracks.existence".into()))
    );
    let early: Vec<u8> = [2_000i64, -2, 0, 0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    assert_eq!(
        refused_vehicle(|v| set_column(v, "sensor_stamp_ns", early)),
        (
            ErrorReason::InvalidValue,
            Some("tracks.sensor_stamp_ns".into())
        )
    );
    let names = |n: &[&str]| Value::Array(n.iter().map(|&s| s.into()).collect());
    assert_eq!(
        refused_vehicle(|v| set(v, "sensors", names(&["lidar", "lidar"]))),
        (ErrorReason::InvalidValue, Some("sensors".into()))
    );
    assert_eq!(
        refused_vehicle(|v| set(v, "sensor_state", names(&["ok"]))),
        (ErrorReason::InvalidValue, Some("sensor_state".into()))
    );
    assert_eq!(
        refused_vehicle(|v| set(v, "sensor_state", names(&["ok", "asleep"]))),
        (ErrorReason::InvalidValue, Some("sensor_state.1".into()))
    );
    assert_eq!(
        refused_vehicle(|v| set(v, "sensor", "camera".into())),
        (ErrorReason::InvalidValue, Some("sensor".into()))
    );
    assert_eq!(
        refused_vehicle(|v| set(v, "schema_version", 3.into())),
        (ErrorReason::WrongVersion, Some("schema_version".into()))
    );
    assert_eq!(
        refused_vehicle(|v| set(v, "key_frame", true.into())),
        (ErrorReason::ExtraField, Some("key_frame".into()))
    );
}

#[test]
fn the_vehicle_encoder_refuses_what_the_decoder_would() {
    let mut f = fused();
    f.tracks.sensor_stamp_ns = Some(vec![vec![1], vec![1]]);
    let r = encode_vehicle_track_frame(&f).unwrap_err();
    assert_eq!(r.reason, ErrorReason::ColumnLength);
    let mut f = fused();
    f.tracks.existence = None;
    assert_eq!(
        encode_vehicle_track_frame(&f).unwrap_err().field.as_deref(),
        Some("tracks.existence")
    );
    let mut f = fused();
    f.sensors[1] = "@vehicle".into();
    assert_eq!(
        encode_vehicle_track_frame(&f).unwrap_err().field.as_deref(),
        Some("sensors.1")
    );
}

fn status(version: u64, vehicles: Option<Value>) -> Vec<u8> {
    let mut pairs: Vec<(Value, Value)> = vec![
        ("schema_version".into(), version.into()),
        ("instance".into(), "svc".into()),
        ("version".into(), "0.1.0".into()),
        ("preset".into(), "kitti".into()),
        ("classes".into(), Value::Array(vec!["Car".into()])),
        ("config_digest".into(), "ab".into()),
        ("started_ns".into(), 1.into()),
        ("ready".into(), true.into()),
        ("queue_depth".into(), 0.into()),
        ("sensors".into(), Value::Array(vec![])),
    ];
    if let Some(v) = vehicles {
        pairs.push(("vehicles".into(), v));
    }
    packed(&Value::Map(pairs))
}

fn vehicle_status() -> Value {
    let sensor = Value::Map(vec![
        ("sensor".into(), "radar".into()),
        ("state".into(), "clock".into()),
        ("last_seq".into(), 7.into()),
        ("last_stamp_ns".into(), Value::Nil),
        ("frames".into(), 7.into()),
        ("idle_s".into(), 0.5.into()),
        ("latency_s".into(), Value::Nil),
        ("clock_offset_s".into(), 2.25.into()),
        (
            "offset_m".into(),
            Value::Array(vec![0.5.into(), (-0.25).into()]),
        ),
        ("flagged_frames".into(), 3.into()),
        ("detail".into(), "stamps 2.3 s ahead".into()),
    ]);
    Value::Array(vec![Value::Map(vec![
        ("vehicle".into(), "veh-1".into()),
        ("seq".into(), 1042.into()),
        ("last_stamp_ns".into(), 5.into()),
        ("active_tracks".into(), 4.into()),
        ("frames".into(), 2000.into()),
        ("late_frames".into(), 2.into()),
        ("reprocessed_frames".into(), 15.into()),
        ("sensors".into(), Value::Array(vec![sensor])),
    ])])
}

#[test]
fn both_status_versions_decode_and_version_1_holds_no_vehicles() {
    let limits = DecodeLimits::default();
    assert!(decode_service_status(&status(1, None), &limits)
        .unwrap()
        .vehicles
        .is_empty());
    assert!(decode_service_status(&status(2, None), &limits)
        .unwrap()
        .vehicles
        .is_empty());
    let s = decode_service_status(&status(2, Some(vehicle_status())), &limits).unwrap();
    let v = &s.vehicles[0];
    assert_eq!(
        (v.vehicle.as_str(), v.seq, v.late_frames),
        ("veh-1", Some(1042), 2)
    );
    let radar = &v.sensors[0];
    assert_eq!(radar.state, SensorCondition::Clock);
    assert_eq!(radar.offset_m, Some([0.5, -0.25]));
    assert_eq!(radar.latency_s, None);
    let r = decode_service_status(&status(1, Some(vehicle_status())), &limits).unwrap_err();
    assert_eq!(
        (r.reason, r.field.as_deref()),
        (ErrorReason::ExtraField, Some("vehicles"))
    );
    let r = decode_service_status(&status(3, None), &limits).unwrap_err();
    assert_eq!(r.reason, ErrorReason::WrongVersion);
}

#[test]
fn the_fusion_reasons_and_keys() {
    assert_eq!(ErrorReason::parse("late"), Some(ErrorReason::Late));
    assert_eq!(
        ErrorReason::parse("sensor_flagged"),
        Some(ErrorReason::SensorFlagged)
    );
    assert!(!ErrorReason::Late.is_drop());
    assert_eq!(
        SensorCondition::parse("unseen"),
        Some(SensorCondition::Unseen)
    );
    let k = Keys::default();
    assert_eq!(k.vehicle_tracks("veh-1"), "fleet/veh-1/@vehicle/tracks");
    assert_eq!(
        k.sensor_of("fleet/veh-1/@vehicle/tracks"),
        Some(("veh-1", VEHICLE_STREAM))
    );
    assert!(!is_name(VEHICLE_STREAM));
}
