//! Print the msgpack of the cross-language fixture frame as one line of hex.
//!
//! The fixture is tests/native/fixture_boxes.json, the same boxes for every client language
//! (Rust, C++, ROS 2): a test decodes each language's bytes in Python and compares them with
//! the Python encoder's. Its values are written out here rather than read from that file so
//! that the comparison also checks that this crate and the file agree.

use simpletrack_client::wire::{encode_detection_frame, BoxColumns, DetectionFrame};

/// The fixture: 3 boxes of classes Car / Pedestrian, with velocity, no pose, no session id.
fn fixture() -> DetectionFrame {
    DetectionFrame {
        vehicle: "veh-fixture".into(),
        sensor: "lidar".into(),
        seq: 7,
        stamp_ns: 1_700_000_000_000_000_000,
        frame_id: "base_link".into(),
        pose: None,
        key_frame: true,
        session_id: None,
        extrinsic: None,
        boxes: BoxColumns {
            classes: vec!["Car".into(), "Pedestrian".into()],
            class_index: vec![0, 1, 0],
            center: vec![[10.0, 2.0, 0.8], [6.0, -3.0, 0.9], [25.0, 4.0, 0.8]],
            size: vec![[4.5, 1.9, 1.6], [0.8, 0.7, 1.8], [4.2, 1.8, 1.5]],
            yaw: vec![0.1, 1.5, -0.2],
            score: vec![0.9, 0.7, 0.6],
            velocity: Some(vec![[5.0, 0.0], [1.0, 0.5], [-3.0, 0.2]]),
        },
    }
}

fn main() {
    match encode_detection_frame(&fixture()) {
        Ok(bytes) => println!(
            "{}",
            bytes.iter().map(|b| format!("{b:02x}")).collect::<String>()
        ),
        Err(r) => {
            eprintln!("error: the fixture frame was refused: {r}");
            std::process::exit(1);
        }
    }
}
