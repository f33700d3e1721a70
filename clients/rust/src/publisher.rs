//! `DetectionPublisher`: the vehicle side of the service. One per vehicle sensor.
//!
//! Frames are stamped with a per-sensor `seq` (increasing), the wall-clock `stamp_ns` unless
//! one is given, and the publisher's `session_id` (63 random bits per publisher: the service
//! knows a restarted publisher by it and tracks it from its first frame). `resume()` asks the
//! service for the last seq it processed and continues after it.
//!
//! Delivery: detections go out through Zenoh's advanced publisher, declared as the Python
//! client declares it: a cache of the last `cache_frames` frames (100: 10 s at 10 Hz), sample
//! miss detection with a heartbeat every 0.5 s, and publisher detection (a liveliness token the
//! service's `subscribe = "owned"` mode finds sensors by). A service that lost frames in a
//! router outage asks the cache for them; frames the cache no longer holds come back as a
//! `missed` notice on the errors key. A frame published while no service is reachable is
//! reported to `on_undelivered` as held and, if the outage outlasts the cache, again as lost.
//!
//! A sensor of a vehicle whose sensors the service fuses gives its mounting,
//! `PublisherOptions::extrinsic` (sensor→vehicle): every frame then carries it
//! (`DetectionFrame` version 2). A vehicle without poses must give it (docs/VEHICLES.md).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use zenoh::bytes::Encoding;
use zenoh::matching::{MatchingListener, MatchingStatus};
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};
use zenoh_ext::{AdvancedPublisher, AdvancedPublisherBuilderExt, CacheConfig, MissDetectionConfig};

use crate::error::{check_id, Error, Result};
use crate::errors::{ErrorCallback, ErrorSubscriber, ErrorSubscriberOptions};
use crate::session::ZenohOptions;
use crate::subscriber::now_ns;
use crate::wire::detection::{encode_parts, Header};
use crate::wire::header::check_transform;
use crate::wire::{
    decode_service_status, BoxColumns, DecodeLimits, Keys, SensorStatus, DEFAULT_PREFIX, ENCODING,
};

pub const DEFAULT_CACHE_FRAMES: usize = 100;
/// Lets a service notice the last frames it missed even when the vehicle stops publishing.
pub const DEFAULT_HEARTBEAT: Duration = Duration::from_millis(500);
/// How long `wait_for_service` waits past the first matching subscriber (the Python
/// client's `SETTLE_S`).
pub const SETTLE: Duration = Duration::from_millis(250);

/// A frame published while no service was reachable. `lost` false: it is in the cache and
/// goes out when a service asks for it after reconnecting; true: the outage outlasted the
/// cache and the frame is gone.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Undelivered {
    pub seq: u64,
    pub lost: bool,
}

pub type UndeliveredCallback = Arc<dyn Fn(Undelivered) + Send + Sync>;

#[derive(Clone)]
pub struct PublisherOptions {
    pub prefix: String,
    /// Coordinate frame of the boxes; default: the sensor's name.
    pub frame_id: Option<String>,
    /// `Block` (default) never drops a frame silently; `Drop` sheds under congestion.
    pub congestion: CongestionControl,
    pub first_seq: u64,
    /// Default: 63 random bits.
    pub session_id: Option<u64>,
    pub cache_frames: usize,
    pub heartbeat: Duration,
    /// Error notices kept for `errors().recv()`.
    pub error_buffer: usize,
    /// Called on Zenoh's thread for each error notice of this sensor (keep it short).
    pub on_error: Option<ErrorCallback>,
    /// Called from `publish` (the caller's thread) for frames sent while no service listens.
    pub on_undelivered: Option<UndeliveredCallback>,
    /// The sensor's mounting, sensor→vehicle 4×4 row-major, sent with every frame; checked
    /// once, by `new` (`Error::Invalid`, field `extrinsic`). None: frames carry none.
    pub extrinsic: Option<[f64; 16]>,
}

impl Default for PublisherOptions {
    fn default() -> Self {
        Self {
            prefix: DEFAULT_PREFIX.into(),
            frame_id: None,
            congestion: CongestionControl::Block,
            first_seq: 0,
            session_id: None,
            cache_frames: DEFAULT_CACHE_FRAMES,
            heartbeat: DEFAULT_HEARTBEAT,
            error_buffer: 1000,
            on_error: None,
            on_undelivered: None,
            extrinsic: None,
        }
    }
}

/// What one frame carries besides its boxes.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameOptions {
    /// Default: the wall clock now (Unix ns).
    pub stamp_ns: Option<u64>,
    /// Sensor→world, 4×4 row-major: with it the service tracks in the world frame.
    pub pose: Option<[f64; 16]>,
    pub key_frame: bool,
    /// Default: one more than the last; may skip ahead, never go back.
    pub seq: Option<u64>,
    /// Sensor→vehicle for this frame alone, in place of `PublisherOptions::extrinsic`.
    pub extrinsic: Option<[f64; 16]>,
}

impl Default for FrameOptions {
    fn default() -> Self {
        Self {
            stamp_ns: None,
            pose: None,
            key_frame: true,
            seq: None,
            extrinsic: None,
        }
    }
}

impl FrameOptions {
    pub fn at(stamp_ns: u64) -> Self {
        Self {
            stamp_ns: Some(stamp_ns),
            ..Self::default()
        }
    }
}

#[derive(Default)]
struct Held {
    seqs: VecDeque<u64>, // in the cache, not yet seen by a service
    held: u64,
    lost: u64,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Publishes one vehicle sensor's detection frames on `<prefix>/<vehicle>/<sensor>/detections`.
pub struct DetectionPublisher {
    vehicle: String,
    sensor: String,
    frame_id: String,
    keys: Keys,
    next_seq: u64,
    session_id: u64,
    sent: u64,
    cache_frames: usize,
    extrinsic: Option<[f64; 16]>,
    session: Session,
    owns_session: bool,
    publisher: Option<AdvancedPublisher<'static>>,
    matching: Option<MatchingListener<()>>,
    held: Arc<Mutex<Held>>,
    on_undelivered: Option<UndeliveredCallback>,
    errors: ErrorSubscriber,
    closed: bool,
}

impl DetectionPublisher {
    pub fn new(
        session: &Session,
        vehicle: &str,
        sensor: &str,
        options: PublisherOptions,
    ) -> Result<Self> {
        check_id("vehicle", vehicle)?;
        check_id("sensor", sensor)?;
        if options.cache_frames < 1 {
            return Err(Error::InvalidOption(
                "cache_frames must be at least 1".into(),
            ));
        }
        if options.heartbeat.is_zero() {
            return Err(Error::InvalidOption("heartbeat must be positive".into()));
        }
        if let Some(e) = &options.extrinsic {
            check_transform(e, "extrinsic").map_err(|e| e.into_rejection(None, None))?;
        }
        let keys = Keys::new(options.prefix.clone());
        let key = keys.detections(vehicle, sensor);
        let publisher = session
            .declare_publisher(key)
            .encoding(Encoding::from(ENCODING))
            .congestion_control(options.congestion)
            .cache(CacheConfig::default().max_samples(options.cache_frames))
            .sample_miss_detection(MissDetectionConfig::default().heartbeat(options.heartbeat))
            .publisher_detection()
            .wait()?;
        let held = Arc::new(Mutex::new(Held::default()));
        let on_match = Arc::clone(&held);
        let matching = publisher
            .matching_listener()
            .callback(move |status: MatchingStatus| {
                if status.matching() {
                    // A service is back: what is still cached is its to ask for.
                    lock(&on_match).seqs.clear();
                }
            })
            .wait()?;
        let errors = ErrorSubscriber::new(
            session,
            ErrorSubscriberOptions {
                prefix: options.prefix.clone(),
                vehicle: vehicle.into(),
                sensor: sensor.into(),
                buffer: options.error_buffer,
                callback: options.on_error.clone(),
                ..ErrorSubscriberOptions::default()
            },
        )?;
        Ok(Self {
            vehicle: vehicle.into(),
            sensor: sensor.into(),
            frame_id: options.frame_id.clone().unwrap_or_else(|| sensor.into()),
            keys,
            next_seq: options.first_seq,
            session_id: options
                .session_id
                .unwrap_or_else(|| rand::random::<u64>() >> 1),
            sent: 0,
            cache_frames: options.cache_frames,
            extrinsic: options.extrinsic,
            session: session.clone(),
            owns_session: false,
            publisher: Some(publisher),
            matching: Some(matching),
            held,
            on_undelivered: options.on_undelivered,
            errors,
            closed: false,
        })
    }

    /// A publisher with a session of its own (closed by `close()`).
    pub fn connect(
        zenoh: &ZenohOptions,
        vehicle: &str,
        sensor: &str,
        options: PublisherOptions,
    ) -> Result<Self> {
        let session = zenoh.open()?;
        match Self::new(&session, vehicle, sensor, options) {
            Ok(mut p) => {
                p.owns_session = true;
                Ok(p)
            }
            Err(e) => {
                let _ = session.close().wait();
                Err(e)
            }
        }
    }

    pub fn vehicle(&self) -> &str {
        &self.vehicle
    }

    pub fn sensor(&self) -> &str {
        &self.sensor
    }

    pub fn session_id(&self) -> u64 {
        self.session_id
    }

    /// The seq the next frame gets by default.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// Frames published so far.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// Send one frame stamped now; returns its seq.
    pub fn publish(&mut self, boxes: &BoxColumns) -> Result<u64> {
        self.publish_with(boxes, &FrameOptions::default())
    }

    /// Send one frame; returns its seq. A frame the service would refuse as malformed (bad
    /// column lengths, NaN, sizes ≤ 0, values beyond the bounds, a pose that is not rigid) is
    /// refused here instead (`Error::Invalid`, the service's reason and field) and not sent.
    pub fn publish_with(&mut self, boxes: &BoxColumns, frame: &FrameOptions) -> Result<u64> {
        let publisher = self
            .publisher
            .as_ref()
            .ok_or_else(|| Error::InvalidOption("publisher is closed".into()))?;
        let seq = match frame.seq {
            None => self.next_seq,
            Some(seq) if seq < self.next_seq => {
                return Err(Error::SeqBackwards {
                    seq,
                    next: self.next_seq,
                })
            }
            Some(seq) => seq,
        };
        let header = Header {
            vehicle: &self.vehicle,
            sensor: &self.sensor,
            seq,
            stamp_ns: frame.stamp_ns.unwrap_or_else(now_ns),
            frame_id: &self.frame_id,
            pose: frame.pose.as_ref(),
            key_frame: frame.key_frame,
            session_id: Some(self.session_id),
            extrinsic: frame.extrinsic.as_ref().or(self.extrinsic.as_ref()),
        };
        let payload = encode_parts(&header, boxes)?;
        publisher.put(payload).wait()?;
        self.next_seq = seq + 1;
        self.sent += 1;
        if !self.delivering() {
            self.report_held(seq);
        }
        Ok(seq)
    }

    /// True while some subscriber (a service) is reachable on this sensor's key.
    pub fn delivering(&self) -> bool {
        self.publisher
            .as_ref()
            .and_then(|p| p.matching_status().wait().ok())
            .is_some_and(|s| s.matching())
    }

    /// True once some subscriber matches this sensor's detections key, and `SETTLE` more
    /// has passed (false after `timeout`). Any subscriber counts: a recorder, a viewer or a
    /// group's scout already listening makes this true before the sensor's owner subscribes;
    /// the owner subscribes on seeing this publisher's token, within milliseconds, and
    /// `SETTLE` covers that (its history query could otherwise race the first frames), as
    /// the Python `DetectionPublisher.wait_for_service` does.
    pub fn wait_for_service(&self, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        loop {
            if self.delivering() {
                std::thread::sleep(SETTLE);
                return true;
            }
            if Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Frames published while no service was reachable, and of those the ones pushed out of
    /// the cache before a service came back.
    pub fn held(&self) -> u64 {
        lock(&self.held).held
    }

    pub fn lost(&self) -> u64 {
        lock(&self.held).lost
    }

    fn report_held(&self, seq: u64) {
        let mut reports = vec![Undelivered { seq, lost: false }];
        {
            let mut h = lock(&self.held);
            h.held += 1;
            h.seqs.push_back(seq);
            while h.seqs.len() > self.cache_frames {
                if let Some(old) = h.seqs.pop_front() {
                    reports.push(Undelivered {
                        seq: old,
                        lost: true,
                    });
                    h.lost += 1;
                }
            }
        }
        if let Some(cb) = &self.on_undelivered {
            reports.into_iter().for_each(|r| cb(r));
        }
    }

    /// What the service last tracked of this sensor (`last_seq`, `last_stamp_ns`), from the
    /// status queryable of every instance that answers within `timeout`; the latest stamp
    /// wins. None when no service holds the sensor.
    pub fn last_processed(&self, timeout: Duration) -> Result<Option<SensorStatus>> {
        let selector = format!(
            "{}?vehicle={};sensor={}",
            self.keys.status("*"),
            self.vehicle,
            self.sensor
        );
        let replies = self.session.get(selector).timeout(timeout).wait()?;
        let mut best: Option<SensorStatus> = None;
        while let Ok(reply) = replies.recv() {
            let Ok(sample) = reply.result() else { continue };
            let Ok(status) =
                decode_service_status(&sample.payload().to_bytes(), &DecodeLimits::default())
            else {
                continue;
            };
            for st in status.sensors {
                if st.vehicle != self.vehicle || st.sensor != self.sensor {
                    continue;
                }
                let stamp = |s: &SensorStatus| s.last_stamp_ns.map_or(-1, i128::from);
                if best.as_ref().is_none_or(|b| stamp(&st) > stamp(b)) {
                    best = Some(st);
                }
            }
        }
        Ok(best)
    }

    /// Continue the stream after the last seq the service processed: the next frame gets
    /// that seq + 1 (never less than this publisher's own next one). Returns the service's
    /// last seq, or None (nothing known: numbering goes on unchanged).
    pub fn resume(&mut self, timeout: Duration) -> Result<Option<u64>> {
        let last = self.last_processed(timeout)?.and_then(|s| s.last_seq);
        if let Some(last) = last {
            self.next_seq = self.next_seq.max(last + 1);
        }
        Ok(last)
    }

    /// The error notices of this sensor (`recv`, `drain`, counts by reason).
    pub fn errors(&self) -> &ErrorSubscriber {
        &self.errors
    }

    /// Stop; closes the session if this publisher opened it. Idempotent.
    pub fn close(&mut self) {
        if self.closed {
            return;
        }
        self.closed = true;
        self.errors.close();
        if let Some(m) = self.matching.take() {
            let _ = m.undeclare().wait();
        }
        if let Some(p) = self.publisher.take() {
            let _ = p.undeclare().wait();
        }
        if self.owns_session {
            let _ = self.session.close().wait();
        }
    }
}

impl Drop for DetectionPublisher {
    fn drop(&mut self) {
        self.close();
    }
}
