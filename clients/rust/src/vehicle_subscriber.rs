//! `VehicleTrackSubscriber`: a planner's one object list per vehicle. Receives the decoded
//! `VehicleTrackFrame`s of a fused vehicle (or of every one) on
//! `<prefix>/<vehicle>/@vehicle/tracks` (docs/VEHICLES.md, "One object list per vehicle").
//! `@vehicle` is a verbatim chunk: no `TrackSubscriber` key matches it, and `*` stands for
//! the vehicle only.
//!
//! The same subscription as `TrackSubscriber`'s (subscriber.rs): a bounded buffer or a
//! callback, the exact repeat (same vehicle, `seq` and `stamp_ns`: a member taking the
//! vehicle over publishes the last message it heard once more) and a fenced holder's
//! messages (an `epoch` below the stream's highest) dropped and counted, invalid payloads
//! counted by reason.

use std::sync::Arc;

use zenoh::Session;

use crate::error::{check_id, Result};
use crate::invalid::InvalidCallback;
use crate::session::ZenohOptions;
use crate::subscriber::{latency_s, Kind, Setup, Subscription};
use crate::wire::{
    decode_vehicle_track_frame, DecodeLimits, Keys, SensorCondition, VehicleTrackFrame,
    DEFAULT_PREFIX,
};

pub type VehicleTrackCallback = Arc<dyn Fn(VehicleTrackMessage) + Send + Sync>;

/// One decoded `VehicleTrackFrame`, a vehicle's fused track list at `stamp_ns`, and when this
/// client received it. The columns are `frame.tracks` (a sensor's `TrackFrame` version 2's,
/// plus `existence` and `sensor_stamp_ns`).
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleTrackMessage {
    pub key: String,
    pub frame: VehicleTrackFrame,
    /// This client's wall clock (Unix ns).
    pub received_ns: u64,
}

impl VehicleTrackMessage {
    pub fn vehicle(&self) -> &str {
        &self.frame.vehicle
    }

    /// The vehicle stream's message counter.
    pub fn seq(&self) -> u64 {
        self.frame.seq
    }

    /// The time every box is at: the stamp of the input frame that produced the message.
    pub fn stamp_ns(&self) -> u64 {
        self.frame.stamp_ns
    }

    /// The stream's custody epoch when the service sent one (version 2), else None.
    pub fn epoch(&self) -> Option<u64> {
        self.frame.epoch
    }

    /// Stamp to arrival here; meaningful when the sensors stamp with wall-clock time.
    pub fn latency_s(&self) -> f64 {
        latency_s(self.received_ns, self.frame.stamp_ns)
    }

    /// (sensor, seq) of the input frame this message answers.
    pub fn source(&self) -> (&str, u64) {
        (&self.frame.sensor, self.frame.sensor_seq)
    }

    /// The number of tracks.
    pub fn count(&self) -> usize {
        self.frame.count()
    }

    /// Track `i`'s fleet-unique id `<vehicle>/@vehicle/<id>`: the same for as long as the
    /// track lives, never given to another one; None when `i` is out of range.
    pub fn global_id(&self, i: usize) -> Option<String> {
        self.frame.global_id(i)
    }

    /// Every track's `global_id`, in column order.
    pub fn global_ids(&self) -> Vec<String> {
        self.frame.global_ids()
    }

    /// The probability in [0, 1] that track `i` is a real object.
    pub fn existence(&self, i: usize) -> Option<f64> {
        self.frame.existence(i)
    }

    /// The sensors that updated track `i`, each with the stamp of its last update.
    pub fn contributors(&self, i: usize) -> Vec<(&str, u64)> {
        self.frame.contributors(i)
    }

    /// The stamp of `sensor`'s last update of track `i`; None when it never updated it.
    pub fn last_update_ns(&self, i: usize, sensor: &str) -> Option<u64> {
        self.frame.last_update_ns(i, sensor)
    }

    /// The fused sensors, in the vehicle's order.
    pub fn sensors(&self) -> &[String] {
        &self.frame.sensors
    }

    /// Each fused sensor's condition (ok, probation, silent, clock, extrinsic, unseen).
    pub fn sensor_state(&self) -> Vec<(&str, SensorCondition)> {
        let sensors = self.frame.sensors.iter().map(String::as_str);
        sensors
            .zip(self.frame.sensor_state.iter().copied())
            .collect()
    }
}

#[derive(Clone)]
pub struct VehicleTrackSubscriberOptions {
    pub prefix: String,
    /// `*` for every vehicle.
    pub vehicle: String,
    /// Overrides prefix and vehicle.
    pub key_expr: Option<String>,
    /// Messages kept for `recv` (the newest; `dropped()` counts the rest).
    pub buffer: usize,
    pub limits: DecodeLimits,
    /// Delivers each message on Zenoh's thread instead of buffering it (keep it short).
    pub callback: Option<VehicleTrackCallback>,
    pub on_invalid: Option<InvalidCallback>,
}

impl Default for VehicleTrackSubscriberOptions {
    /// Every vehicle's fused tracks under the default prefix.
    fn default() -> Self {
        Self {
            prefix: DEFAULT_PREFIX.into(),
            vehicle: "*".into(),
            key_expr: None,
            buffer: 1024,
            limits: DecodeLimits::default(),
            callback: None,
            on_invalid: None,
        }
    }
}

impl VehicleTrackSubscriberOptions {
    /// One vehicle's fused tracks.
    pub fn vehicle(vehicle: &str) -> Self {
        Self {
            vehicle: vehicle.into(),
            ..Self::default()
        }
    }

    /// Every vehicle's fused tracks.
    pub fn all() -> Self {
        Self::default()
    }

    /// `<prefix>/<vehicle>/@vehicle/tracks`, or `key_expr`.
    pub fn key(&self) -> Result<String> {
        if let Some(k) = &self.key_expr {
            return Ok(k.clone());
        }
        if self.vehicle != "*" {
            check_id("vehicle", &self.vehicle)?;
        }
        Ok(Keys::new(self.prefix.as_str()).vehicle_tracks(&self.vehicle))
    }
}

/// Fused vehicles' tracks (`VehicleTrackFrame`): one track list per vehicle, one id per
/// object.
pub type VehicleTrackSubscriber = Subscription<VehicleTrackMessage>;

fn vehicle_kind() -> Kind<VehicleTrackMessage> {
    Kind {
        what: "vehicle track frame",
        decode: |key, payload, limits, received_ns| {
            Ok(VehicleTrackMessage {
                key: key.to_owned(),
                frame: decode_vehicle_track_frame(payload, limits)?,
                received_ns,
            })
        },
        identity: |m| (m.frame.seq, m.frame.stamp_ns, m.frame.epoch),
    }
}

impl Subscription<VehicleTrackMessage> {
    pub fn new(session: &Session, options: VehicleTrackSubscriberOptions) -> Result<Self> {
        let setup = Setup {
            key_expr: options.key()?,
            buffer: options.buffer,
            limits: options.limits,
            callback: options
                .callback
                .map(|cb| cb as Arc<dyn Fn(VehicleTrackMessage) + Send + Sync>),
            on_invalid: options.on_invalid,
        };
        Self::open(session, vehicle_kind(), setup)
    }

    /// A subscriber with a session of its own, closed by `close()`.
    pub fn connect(zenoh: &ZenohOptions, options: VehicleTrackSubscriberOptions) -> Result<Self> {
        Self::with_own_session(zenoh, |session| Self::new(session, options))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stream_filter::{StreamFilter, Verdict};
    use crate::wire::{encode_vehicle_track_frame, ErrorReason, TrackColumns, NEVER_UPDATED};

    fn frame(seq: u64, stamp_ns: u64, epoch: Option<u64>) -> VehicleTrackFrame {
        VehicleTrackFrame {
            vehicle: "veh01".into(),
            seq,
            stamp_ns,
            sensor: "camera".into(),
            sensor_seq: 812,
            frame_id: "base_link".into(),
            pose: None,
            instance: "svc".into(),
            received_ns: stamp_ns + 5,
            published_ns: stamp_ns + 9,
            sensors: vec!["lidar".into(), "camera".into()],
            sensor_state: vec![SensorCondition::Ok, SensorCondition::Silent],
            tracks: TrackColumns {
                classes: vec!["Car".into()],
                id: vec![17],
                class_index: vec![0],
                center: vec![[10.0, 2.0, 0.8]],
                size: vec![[4.5, 1.9, 1.6]],
                yaw: vec![0.1],
                score: vec![0.9],
                velocity: vec![[5.0, 0.0, 0.0]],
                state: vec![1],
                hits: vec![4],
                age: vec![5],
                time_since_update: vec![0],
                covariance: None,
                age_s: Some(vec![0.5]),
                time_since_update_s: Some(vec![0.0]),
                existence: Some(vec![0.875]),
                sensor_stamp_ns: Some(vec![vec![NEVER_UPDATED, stamp_ns as i64]]),
            },
            epoch,
        }
    }

    fn decoded(f: &VehicleTrackFrame) -> VehicleTrackMessage {
        let payload = encode_vehicle_track_frame(f).unwrap();
        (vehicle_kind().decode)(KEY, &payload, &DecodeLimits::default(), 42).unwrap()
    }

    const KEY: &str = "fleet/veh01/@vehicle/tracks";

    #[test]
    fn the_key_is_the_vehicles_fused_stream_and_a_bad_id_is_refused() {
        let one = VehicleTrackSubscriberOptions::vehicle("veh01");
        assert_eq!(one.key().unwrap(), KEY);
        let all = VehicleTrackSubscriberOptions::all();
        assert_eq!(all.key().unwrap(), "fleet/*/@vehicle/tracks");
        let other = VehicleTrackSubscriberOptions {
            prefix: "lab".into(),
            ..VehicleTrackSubscriberOptions::vehicle("v")
        };
        assert_eq!(other.key().unwrap(), "lab/v/@vehicle/tracks");
        let e = VehicleTrackSubscriberOptions::vehicle("veh/1")
            .key()
            .unwrap_err();
        assert!(e.to_string().contains("\"veh/1\""), "{e}");
        let given = VehicleTrackSubscriberOptions {
            key_expr: Some("fleet/**".into()),
            ..Default::default()
        };
        assert_eq!(given.key().unwrap(), "fleet/**");
    }

    #[test]
    fn a_message_walks_its_tracks_by_global_id_contributors_and_sensor_state() {
        let m = decoded(&frame(3, 1_000, Some(5)));
        assert_eq!((m.key.as_str(), m.received_ns), (KEY, 42));
        assert_eq!(
            (m.vehicle(), m.seq(), m.stamp_ns(), m.epoch()),
            ("veh01", 3, 1_000, Some(5))
        );
        assert_eq!(m.source(), ("camera", 812));
        assert_eq!(m.count(), 1);
        assert_eq!(m.global_id(0).as_deref(), Some("veh01/@vehicle/17"));
        assert_eq!(m.global_ids(), ["veh01/@vehicle/17"]);
        assert_eq!(m.existence(0), Some(0.875));
        assert_eq!(m.contributors(0), [("camera", 1_000)]);
        assert_eq!(m.last_update_ns(0, "lidar"), None);
        assert_eq!(m.sensors(), ["lidar", "camera"]);
        assert_eq!(
            m.sensor_state(),
            [
                ("lidar", SensorCondition::Ok),
                ("camera", SensorCondition::Silent)
            ]
        );
        assert!(m.latency_s() < 0.0); // stamped after "arrival" at 42 ns
    }

    #[test]
    fn the_filter_judges_a_vehicle_message_by_its_seq_stamp_and_epoch() {
        let kind = vehicle_kind();
        let mut f = StreamFilter::default();
        let mut verdict = |fr: &VehicleTrackFrame| {
            let (seq, stamp, epoch) = (kind.identity)(&decoded(fr));
            f.admit(KEY, seq, stamp, epoch)
        };
        assert_eq!(verdict(&frame(0, 100, Some(5))), Verdict::Deliver);
        assert_eq!(verdict(&frame(1, 200, Some(5))), Verdict::Deliver);
        assert_eq!(verdict(&frame(1, 200, Some(5))), Verdict::Repeat);
        assert_eq!(verdict(&frame(2, 300, Some(3))), Verdict::Stale);
        assert_eq!(verdict(&frame(2, 300, Some(5))), Verdict::Deliver);
        assert_eq!(verdict(&frame(3, 400, None)), Verdict::Deliver); // version 1
    }

    #[test]
    fn a_payload_that_does_not_decode_is_refused_with_its_reason() {
        let err = (vehicle_kind().decode)(KEY, b"\x80", &DecodeLimits::default(), 0).unwrap_err();
        assert_eq!(err.reason, ErrorReason::MissingField);
    }
}
