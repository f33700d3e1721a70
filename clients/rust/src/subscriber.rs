//! The planner side: subscriptions to tracks keys that deliver decoded messages as a blocking
//! iterator, by polling, or through a callback.
//!
//! - `TrackSubscriber`: the `TrackFrame`s of one sensor, one vehicle or the whole fleet.
//! - `VehicleTrackSubscriber` (vehicle_subscriber.rs): a fused vehicle's `VehicleTrackFrame`s,
//!   `<prefix>/<vehicle>/@vehicle/tracks`, one track list per vehicle.
//!
//! Both are a `Subscription` and judge each message with a `StreamFilter` per key. A message
//! already delivered (the same key, `seq` and `stamp_ns`: what two instances of a group both
//! send when one died between publishing it and the other hearing of it) is not delivered
//! again; `duplicates()` counts them. Nor is a message of a fenced holder (an instance paused
//! or cut off after another took its stream over): its `epoch` is below the highest its
//! stream has shown; `stale()` counts them.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};

use crate::error::{check_id, Result};
use crate::invalid::{InvalidCallback, Invalids};
use crate::mailbox::Mailbox;
use crate::session::ZenohOptions;
use crate::stream_filter::{StreamFilter, Verdict};
use crate::wire::{
    decode_track_frame, DecodeLimits, ErrorReason, Rejection, TrackFrame, DEFAULT_PREFIX,
};

pub type TrackCallback = Arc<dyn Fn(TrackMessage) + Send + Sync>;

/// One decoded `TrackFrame` and when this client received it.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackMessage {
    pub key: String,
    pub frame: TrackFrame,
    /// This client's wall clock (Unix ns).
    pub received_ns: u64,
}

impl TrackMessage {
    pub fn vehicle(&self) -> &str {
        &self.frame.vehicle
    }

    pub fn sensor(&self) -> &str {
        &self.frame.sensor
    }

    pub fn seq(&self) -> u64 {
        self.frame.seq
    }

    pub fn stamp_ns(&self) -> u64 {
        self.frame.stamp_ns
    }

    /// The stream's custody epoch when the service sent one (version 3), else None.
    pub fn epoch(&self) -> Option<u64> {
        self.frame.epoch
    }

    /// Sensor stamp to arrival here; meaningful when the sensor stamps with wall-clock time.
    pub fn latency_s(&self) -> f64 {
        latency_s(self.received_ns, self.frame.stamp_ns)
    }
}

pub(crate) fn latency_s(received_ns: u64, stamp_ns: u64) -> f64 {
    (received_ns as f64 - stamp_ns as f64) * 1e-9
}

/// `<prefix>/<vehicle>/<sensor>/<leaf>`; `*` selects every vehicle or sensor.
pub(crate) fn sensor_key(prefix: &str, vehicle: &str, sensor: &str, leaf: &str) -> Result<String> {
    for (kind, value) in [("vehicle", vehicle), ("sensor", sensor)] {
        if value != "*" {
            check_id(kind, value)?;
        }
    }
    Ok(format!("{prefix}/{vehicle}/{sensor}/{leaf}"))
}

pub(crate) fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

#[derive(Clone)]
pub struct TrackSubscriberOptions {
    pub prefix: String,
    /// `*` for every vehicle.
    pub vehicle: String,
    /// `*` for every sensor.
    pub sensor: String,
    /// Overrides prefix, vehicle and sensor.
    pub key_expr: Option<String>,
    /// Frames kept for `recv` (the newest; `dropped()` counts the rest).
    pub buffer: usize,
    pub limits: DecodeLimits,
    /// Delivers each frame on Zenoh's thread instead of buffering it (keep it short).
    pub callback: Option<TrackCallback>,
    pub on_invalid: Option<InvalidCallback>,
}

impl Default for TrackSubscriberOptions {
    fn default() -> Self {
        Self {
            prefix: DEFAULT_PREFIX.into(),
            vehicle: "*".into(),
            sensor: "*".into(),
            key_expr: None,
            buffer: 1024,
            limits: DecodeLimits::default(),
            callback: None,
            on_invalid: None,
        }
    }
}

impl TrackSubscriberOptions {
    /// The tracks of one sensor.
    pub fn sensor(vehicle: &str, sensor: &str) -> Self {
        Self {
            vehicle: vehicle.into(),
            sensor: sensor.into(),
            ..Self::default()
        }
    }
}

/// What one kind of tracks message needs from a subscription: how it decodes, and what
/// the stream filter judges it by.
pub(crate) struct Kind<M> {
    /// The message's name in the log line of an invalid payload.
    pub what: &'static str,
    /// (key, payload, limits, received_ns) -> the message
    pub decode: fn(&str, &[u8], &DecodeLimits, u64) -> std::result::Result<M, Rejection>,
    /// (seq, stamp_ns, epoch)
    pub identity: fn(&M) -> (u64, u64, Option<u64>),
}

/// What the Zenoh callback and the consumers share.
struct Shared<M> {
    kind: Kind<M>,
    mailbox: Mailbox<M>,
    filter: Mutex<StreamFilter>,
    duplicates: AtomicU64,
    stale: AtomicU64,
    invalid: Invalids,
    callback: Option<Arc<dyn Fn(M) + Send + Sync>>,
    limits: DecodeLimits,
}

impl<M> Shared<M> {
    fn on_sample(&self, sample: &Sample) {
        let received_ns = now_ns();
        let key = sample.key_expr().as_str();
        let payload = sample.payload().to_bytes();
        let msg = match (self.kind.decode)(key, &payload, &self.limits, received_ns) {
            Ok(m) => m,
            Err(r) => return self.invalid.record(key, r),
        };
        let (seq, stamp_ns, epoch) = (self.kind.identity)(&msg);
        // Verdict and record are one step under the lock: samples of two links come on two
        // threads.
        let verdict = self
            .filter
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .admit(key, seq, stamp_ns, epoch);
        match verdict {
            Verdict::Deliver => {}
            Verdict::Stale => {
                self.stale.fetch_add(1, Ordering::Relaxed);
                return;
            }
            Verdict::Repeat => {
                self.duplicates.fetch_add(1, Ordering::Relaxed);
                return;
            }
        }
        match &self.callback {
            Some(cb) => cb(msg),
            None => self.mailbox.put(msg),
        }
    }
}

/// What both subscribers' options give a subscription.
pub(crate) struct Setup<M> {
    pub key_expr: String,
    pub buffer: usize,
    pub limits: DecodeLimits,
    pub callback: Option<Arc<dyn Fn(M) + Send + Sync>>,
    pub on_invalid: Option<InvalidCallback>,
}

/// A subscription to tracks keys, delivering messages of type `M`: `TrackSubscriber`
/// (sensors' `TrackMessage`s) or `VehicleTrackSubscriber` (fused vehicles'
/// `VehicleTrackMessage`s). Messages are decoded on Zenoh's thread and wait in a bounded
/// buffer (or go to the options' callback); exact repeats and a fenced holder's messages are
/// dropped and counted; payloads that do not decode are counted by reason.
pub struct Subscription<M> {
    key_expr: String,
    shared: Arc<Shared<M>>,
    subscriber: Option<Subscriber<()>>,
    owned_session: Option<Session>,
}

/// The tracks of one sensor, a vehicle's sensors or the fleet's (`TrackFrame`).
pub type TrackSubscriber = Subscription<TrackMessage>;

impl<M: Send + 'static> Subscription<M> {
    pub(crate) fn open(session: &Session, kind: Kind<M>, setup: Setup<M>) -> Result<Self> {
        let shared = Arc::new(Shared {
            invalid: Invalids::new(kind.what, setup.on_invalid),
            kind,
            mailbox: Mailbox::new(setup.buffer),
            filter: Mutex::new(StreamFilter::default()),
            duplicates: AtomicU64::new(0),
            stale: AtomicU64::new(0),
            callback: setup.callback,
            limits: setup.limits,
        });
        let handler = Arc::clone(&shared);
        let subscriber = session
            .declare_subscriber(setup.key_expr.clone())
            .callback(move |sample: Sample| handler.on_sample(&sample))
            .wait()?;
        Ok(Self {
            key_expr: setup.key_expr,
            shared,
            subscriber: Some(subscriber),
            owned_session: None,
        })
    }

    /// `new` on a session of its own, closed by `close()`.
    pub(crate) fn with_own_session(
        zenoh: &ZenohOptions,
        new: impl FnOnce(&Session) -> Result<Self>,
    ) -> Result<Self> {
        let session = zenoh.open()?;
        match new(&session) {
            Ok(mut sub) => {
                sub.owned_session = Some(session);
                Ok(sub)
            }
            Err(e) => {
                let _ = session.close().wait();
                Err(e)
            }
        }
    }
}

impl<M> Subscription<M> {
    pub fn key_expr(&self) -> &str {
        &self.key_expr
    }

    /// The next message, waiting up to `timeout` (None: until one comes or `close()`).
    pub fn recv(&self, timeout: Option<Duration>) -> Option<M> {
        self.shared.mailbox.get(timeout)
    }

    pub fn try_recv(&self) -> Option<M> {
        self.shared.mailbox.try_get()
    }

    /// Blocking iteration; ends on `close()` once drained.
    pub fn iter(&self) -> impl Iterator<Item = M> + '_ {
        std::iter::from_fn(move || self.recv(None))
    }

    /// Messages delivered to the buffer so far.
    pub fn received(&self) -> u64 {
        self.shared.mailbox.put_count()
    }

    /// Messages pushed out of the full buffer before anyone took them.
    pub fn dropped(&self) -> u64 {
        self.shared.mailbox.dropped()
    }

    /// Repeats (same key, seq and stamp, or a new holder's replay) not delivered again.
    pub fn duplicates(&self) -> u64 {
        self.shared.duplicates.load(Ordering::Relaxed)
    }

    /// Messages of a fenced holder (an epoch below its stream's highest), not delivered.
    pub fn stale(&self) -> u64 {
        self.shared.stale.load(Ordering::Relaxed)
    }

    /// Payloads on a subscribed key that did not decode.
    pub fn invalid(&self) -> u64 {
        self.shared.invalid.count()
    }

    pub fn invalid_reasons(&self) -> HashMap<ErrorReason, u64> {
        self.shared.invalid.reasons()
    }

    pub fn last_rejection(&self) -> Option<Rejection> {
        self.shared.invalid.last()
    }

    /// The highest custody epoch `key` (a sample's key) has shown; None when none.
    pub fn highest_epoch(&self, key: &str) -> Option<u64> {
        self.shared
            .filter
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .highest_epoch(key)
    }

    /// Wake every consumer and stop; closes the session if this subscriber opened it.
    pub fn close(&mut self) {
        self.shared.mailbox.close();
        if let Some(sub) = self.subscriber.take() {
            let _ = sub.undeclare().wait();
        }
        if let Some(session) = self.owned_session.take() {
            let _ = session.close().wait();
        }
    }
}

impl<M> Drop for Subscription<M> {
    fn drop(&mut self) {
        self.close();
    }
}

fn track_kind() -> Kind<TrackMessage> {
    Kind {
        what: "track frame",
        decode: |key, payload, limits, received_ns| {
            Ok(TrackMessage {
                key: key.to_owned(),
                frame: decode_track_frame(payload, limits)?,
                received_ns,
            })
        },
        identity: |m| (m.frame.seq, m.frame.stamp_ns, m.frame.epoch),
    }
}

impl Subscription<TrackMessage> {
    pub fn new(session: &Session, options: TrackSubscriberOptions) -> Result<Self> {
        let key_expr = match &options.key_expr {
            Some(k) => k.clone(),
            None => sensor_key(&options.prefix, &options.vehicle, &options.sensor, "tracks")?,
        };
        let setup = Setup {
            key_expr,
            buffer: options.buffer,
            limits: options.limits,
            callback: options
                .callback
                .map(|cb| cb as Arc<dyn Fn(TrackMessage) + Send + Sync>),
            on_invalid: options.on_invalid,
        };
        Self::open(session, track_kind(), setup)
    }

    /// A subscriber with a session of its own, closed by `close()`.
    pub fn connect(zenoh: &ZenohOptions, options: TrackSubscriberOptions) -> Result<Self> {
        Self::with_own_session(zenoh, |session| Self::new(session, options))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_key_of_wildcards_is_built_and_a_bad_id_refused() {
        assert_eq!(
            sensor_key("fleet", "*", "*", "tracks").unwrap(),
            "fleet/*/*/tracks"
        );
        let e = sensor_key("fleet", "veh/1", "*", "tracks").unwrap_err();
        assert!(e.to_string().contains("\"veh/1\""), "{e}");
    }

    fn frame(seq: u64, stamp_ns: u64, epoch: Option<u64>) -> TrackFrame {
        TrackFrame {
            vehicle: "v".into(),
            sensor: "s".into(),
            seq,
            stamp_ns,
            frame_id: "world".into(),
            pose: None,
            key_frame: true,
            instance: "svc".into(),
            received_ns: 0,
            published_ns: 0,
            tracks: crate::wire::TrackColumns {
                age_s: Some(vec![]),
                time_since_update_s: Some(vec![]),
                ..Default::default()
            },
            schema_version: 3,
            epoch,
        }
    }

    #[test]
    fn a_track_messages_identity_is_its_seq_stamp_and_epoch() {
        let kind = track_kind();
        let payload = crate::wire::encode_track_frame(&frame(4, 400, Some(7))).unwrap();
        let msg = (kind.decode)("fleet/v/s/tracks", &payload, &DecodeLimits::default(), 9).unwrap();
        assert_eq!((kind.identity)(&msg), (4, 400, Some(7)));
        assert_eq!(
            (msg.key.as_str(), msg.received_ns, msg.epoch()),
            ("fleet/v/s/tracks", 9, Some(7))
        );
        let err = (kind.decode)("k", b"\xc1", &DecodeLimits::default(), 0).unwrap_err();
        assert_eq!(err.reason, ErrorReason::Malformed);
    }
}
