//! `TrackSubscriber`: the planner side. Receives decoded `TrackFrame`s of one sensor, one
//! vehicle or the whole fleet, as a blocking iterator, by polling, or through a callback.
//!
//! A frame already delivered (the same key, `seq` and `stamp_ns`: what two instances of a
//! group both send when one died between publishing a frame and the other hearing of it) is
//! not delivered again; `duplicates()` counts them. Nor is a frame of a fenced holder (an
//! instance paused or cut off after another took its stream over): its `epoch` is below the
//! highest its stream has shown (`EpochFilter`); `stale()` counts them.

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};

use crate::epoch_filter::EpochFilter;
use crate::error::{check_id, Result};
use crate::invalid::{InvalidCallback, Invalids};
use crate::mailbox::Mailbox;
use crate::session::ZenohOptions;
use crate::wire::{
    decode_track_frame, DecodeLimits, ErrorReason, Rejection, TrackFrame, DEFAULT_PREFIX,
};

/// Per key: a repeat comes within a takeover, a few frames at most.
pub const RECENT_FRAMES: usize = 16;
const MAX_KEYS: usize = 100_000;

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

    /// Sensor stamp to arrival here; meaningful when the sensor stamps with wall-clock time.
    pub fn latency_s(&self) -> f64 {
        (self.received_ns as f64 - self.frame.stamp_ns as f64) * 1e-9
    }
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

/// The last (seq, stamp_ns) delivered per key: an exact repeat is not delivered again.
#[derive(Default)]
pub(crate) struct Recent {
    keys: HashMap<String, VecDeque<(u64, u64)>>,
}

impl Recent {
    /// True when (seq, stamp_ns) was delivered on `key` within the last `RECENT_FRAMES`;
    /// otherwise records it. Check and record are one step under the caller's lock.
    pub fn is_repeat(&mut self, key: &str, seq: u64, stamp_ns: u64) -> bool {
        if !self.keys.contains_key(key) && self.keys.len() >= MAX_KEYS {
            self.keys.clear();
        }
        let recent = self.keys.entry(key.to_owned()).or_default();
        if recent.contains(&(seq, stamp_ns)) {
            return true;
        }
        if recent.len() == RECENT_FRAMES {
            recent.pop_front();
        }
        recent.push_back((seq, stamp_ns));
        false
    }
}

/// What a subscriber keeps per stream key to decide whether to deliver a frame.
#[derive(Default)]
struct Streams {
    epochs: EpochFilter,
    recent: Recent,
}

/// Why a frame was not delivered.
enum Refused {
    Stale,
    Repeat,
}

impl Streams {
    /// Fenced first: a stale holder's frame is no repeat to remember. Check and record are
    /// one step under the caller's lock (samples of two links come on two threads).
    fn admit(&mut self, key: &str, frame: &TrackFrame) -> std::result::Result<(), Refused> {
        if !self.epochs.accept(key, frame.epoch) {
            return Err(Refused::Stale);
        }
        if self.recent.is_repeat(key, frame.seq, frame.stamp_ns) {
            return Err(Refused::Repeat);
        }
        Ok(())
    }
}

struct Shared {
    mailbox: Mailbox<TrackMessage>,
    streams: Mutex<Streams>,
    duplicates: AtomicU64,
    stale: AtomicU64,
    invalid: Invalids,
    callback: Option<TrackCallback>,
    limits: DecodeLimits,
}

impl Shared {
    fn on_sample(&self, sample: &Sample) {
        let received_ns = now_ns();
        let key = sample.key_expr().as_str();
        let frame = match decode_track_frame(&sample.payload().to_bytes(), &self.limits) {
            Ok(f) => f,
            Err(r) => return self.invalid.record(key, r),
        };
        let verdict = self
            .streams
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .admit(key, &frame);
        match verdict {
            Ok(()) => {}
            Err(Refused::Stale) => {
                self.stale.fetch_add(1, Ordering::Relaxed);
                return;
            }
            Err(Refused::Repeat) => {
                self.duplicates.fetch_add(1, Ordering::Relaxed);
                return;
            }
        }
        let msg = TrackMessage {
            key: key.to_owned(),
            frame,
            received_ns,
        };
        match &self.callback {
            Some(cb) => cb(msg),
            None => self.mailbox.put(msg),
        }
    }
}

pub struct TrackSubscriber {
    key_expr: String,
    shared: Arc<Shared>,
    subscriber: Option<Subscriber<()>>,
    owned_session: Option<Session>,
}

impl TrackSubscriber {
    pub fn new(session: &Session, options: TrackSubscriberOptions) -> Result<Self> {
        let key_expr = match &options.key_expr {
            Some(k) => k.clone(),
            None => sensor_key(&options.prefix, &options.vehicle, &options.sensor, "tracks")?,
        };
        let shared = Arc::new(Shared {
            mailbox: Mailbox::new(options.buffer),
            streams: Mutex::new(Streams::default()),
            duplicates: AtomicU64::new(0),
            stale: AtomicU64::new(0),
            invalid: Invalids::new("track frame", options.on_invalid.clone()),
            callback: options.callback.clone(),
            limits: options.limits,
        });
        let handler = Arc::clone(&shared);
        let subscriber = session
            .declare_subscriber(key_expr.clone())
            .callback(move |sample: Sample| handler.on_sample(&sample))
            .wait()?;
        Ok(Self {
            key_expr,
            shared,
            subscriber: Some(subscriber),
            owned_session: None,
        })
    }

    /// A subscriber with a session of its own, closed by `close()`.
    pub fn connect(zenoh: &ZenohOptions, options: TrackSubscriberOptions) -> Result<Self> {
        let session = zenoh.open()?;
        match Self::new(&session, options) {
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

    pub fn key_expr(&self) -> &str {
        &self.key_expr
    }

    /// The next frame, waiting up to `timeout` (None: until one comes or `close()`).
    pub fn recv(&self, timeout: Option<Duration>) -> Option<TrackMessage> {
        self.shared.mailbox.get(timeout)
    }

    pub fn try_recv(&self) -> Option<TrackMessage> {
        self.shared.mailbox.try_get()
    }

    /// Blocking iteration; ends on `close()` once drained.
    pub fn iter(&self) -> impl Iterator<Item = TrackMessage> + '_ {
        std::iter::from_fn(move || self.recv(None))
    }

    /// Frames delivered to the buffer so far.
    pub fn received(&self) -> u64 {
        self.shared.mailbox.put_count()
    }

    /// Frames pushed out of the full buffer before anyone took them.
    pub fn dropped(&self) -> u64 {
        self.shared.mailbox.dropped()
    }

    /// Exact repeats (same key, seq and stamp) not delivered again.
    pub fn duplicates(&self) -> u64 {
        self.shared.duplicates.load(Ordering::Relaxed)
    }

    /// Frames of a fenced holder (an epoch below its stream's highest), not delivered.
    pub fn stale(&self) -> u64 {
        self.shared.stale.load(Ordering::Relaxed)
    }

    /// Payloads on a tracks key that did not decode.
    pub fn invalid(&self) -> u64 {
        self.shared.invalid.count()
    }

    pub fn invalid_reasons(&self) -> HashMap<ErrorReason, u64> {
        self.shared.invalid.reasons()
    }

    pub fn last_rejection(&self) -> Option<Rejection> {
        self.shared.invalid.last()
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

impl Drop for TrackSubscriber {
    fn drop(&mut self) {
        self.close();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_exact_repeat_is_caught_per_key_and_a_new_stamp_is_not() {
        let mut r = Recent::default();
        assert!(!r.is_repeat("fleet/v/s/tracks", 3, 100));
        assert!(r.is_repeat("fleet/v/s/tracks", 3, 100));
        assert!(!r.is_repeat("fleet/v/s/tracks", 3, 200)); // a restarted publisher's seq 3
        assert!(!r.is_repeat("fleet/v/t/tracks", 3, 100)); // another sensor
    }

    #[test]
    fn the_window_is_the_last_recent_frames() {
        let mut r = Recent::default();
        for seq in 0..=RECENT_FRAMES as u64 {
            assert!(!r.is_repeat("k", seq, seq));
        }
        assert!(!r.is_repeat("k", 0, 0)); // pushed out by the newer ones
        assert!(r.is_repeat("k", RECENT_FRAMES as u64, RECENT_FRAMES as u64));
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
            tracks: crate::wire::TrackColumns::default(),
            schema_version: 3,
            epoch,
        }
    }

    #[test]
    fn a_fenced_holders_frame_is_stale_and_an_equal_epoch_follows_the_repeat_rule() {
        let mut s = Streams::default();
        let k = "fleet/v/s/tracks";
        assert!(s.admit(k, &frame(0, 100, Some(1))).is_ok());
        assert!(s.admit(k, &frame(1, 200, Some(2))).is_ok());
        assert!(matches!(
            s.admit(k, &frame(2, 300, Some(1))),
            Err(Refused::Stale)
        ));
        assert!(matches!(
            s.admit(k, &frame(1, 200, Some(2))),
            Err(Refused::Repeat)
        ));
        assert!(s.admit(k, &frame(3, 400, None)).is_ok()); // a service of before epochs
        assert!(s.admit(k, &frame(4, 500, Some(2))).is_ok());
    }

    #[test]
    fn a_key_of_wildcards_is_built_and_a_bad_id_refused() {
        assert_eq!(
            sensor_key("fleet", "*", "*", "tracks").unwrap(),
            "fleet/*/*/tracks"
        );
        let e = sensor_key("fleet", "veh/1", "*", "tracks").unwrap_err();
        assert!(e.to_string().contains("\"veh/1\""), "{e}");
    }
}
