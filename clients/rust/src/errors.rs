//! `ErrorSubscriber`: the `FrameError`s a service sends on `<prefix>/<vehicle>/<sensor>/errors`
//! (frames refused, shed under load, or lost in transport: `missed`). A publisher holds one
//! for its own sensor; a planner may hold one for the fleet.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};

use crate::error::Result;
use crate::invalid::{InvalidCallback, Invalids};
use crate::mailbox::Mailbox;
use crate::subscriber::sensor_key;
use crate::wire::{
    decode_frame_error, DecodeLimits, ErrorReason, FrameError, Rejection, DEFAULT_PREFIX,
};

pub type ErrorCallback = Arc<dyn Fn(&FrameError) + Send + Sync>;

#[derive(Clone)]
pub struct ErrorSubscriberOptions {
    pub prefix: String,
    pub vehicle: String,
    pub sensor: String,
    pub key_expr: Option<String>,
    /// Notices kept for `recv` (the newest).
    pub buffer: usize,
    /// Called on Zenoh's thread for every notice (keep it short); they are buffered too.
    pub callback: Option<ErrorCallback>,
    pub on_invalid: Option<InvalidCallback>,
}

impl Default for ErrorSubscriberOptions {
    fn default() -> Self {
        Self {
            prefix: DEFAULT_PREFIX.into(),
            vehicle: "*".into(),
            sensor: "*".into(),
            key_expr: None,
            buffer: 1000,
            callback: None,
            on_invalid: None,
        }
    }
}

struct Shared {
    mailbox: Mailbox<FrameError>,
    by_reason: Mutex<HashMap<ErrorReason, u64>>,
    invalid: Invalids,
    callback: Option<ErrorCallback>,
}

impl Shared {
    fn on_sample(&self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        let err = match decode_frame_error(&sample.payload().to_bytes(), &DecodeLimits::default()) {
            Ok(e) => e,
            // A planner built before a new reason refuses it as invalid_value: counted here.
            Err(r) => return self.invalid.record(key, r),
        };
        *self
            .by_reason
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .entry(err.reason)
            .or_insert(0) += 1;
        if let Some(cb) = &self.callback {
            cb(&err);
        }
        self.mailbox.put(err);
    }
}

pub struct ErrorSubscriber {
    shared: Arc<Shared>,
    subscriber: Option<Subscriber<()>>,
}

impl ErrorSubscriber {
    pub fn new(session: &Session, options: ErrorSubscriberOptions) -> Result<Self> {
        let key_expr = match &options.key_expr {
            Some(k) => k.clone(),
            None => sensor_key(&options.prefix, &options.vehicle, &options.sensor, "errors")?,
        };
        let shared = Arc::new(Shared {
            mailbox: Mailbox::new(options.buffer),
            by_reason: Mutex::new(HashMap::new()),
            invalid: Invalids::new("error notice", options.on_invalid.clone()),
            callback: options.callback.clone(),
        });
        let handler = Arc::clone(&shared);
        let subscriber = session
            .declare_subscriber(key_expr)
            .callback(move |sample: Sample| handler.on_sample(&sample))
            .wait()?;
        Ok(Self {
            shared,
            subscriber: Some(subscriber),
        })
    }

    /// The next notice, waiting up to `timeout` (None: until one comes or `close()`).
    pub fn recv(&self, timeout: Option<Duration>) -> Option<FrameError> {
        self.shared.mailbox.get(timeout)
    }

    pub fn try_recv(&self) -> Option<FrameError> {
        self.shared.mailbox.try_get()
    }

    /// Every notice buffered now, oldest first, without waiting.
    pub fn drain(&self) -> Vec<FrameError> {
        std::iter::from_fn(|| self.try_recv()).collect()
    }

    /// Notices received so far.
    pub fn received(&self) -> u64 {
        self.shared.mailbox.put_count()
    }

    /// Notices received so far, by reason (`missed`: frames lost in transport).
    pub fn by_reason(&self) -> HashMap<ErrorReason, u64> {
        self.shared
            .by_reason
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Payloads on an errors key that did not decode.
    pub fn invalid(&self) -> u64 {
        self.shared.invalid.count()
    }

    pub fn last_rejection(&self) -> Option<Rejection> {
        self.shared.invalid.last()
    }

    pub fn close(&mut self) {
        self.shared.mailbox.close();
        if let Some(sub) = self.subscriber.take() {
            let _ = sub.undeclare().wait();
        }
    }
}

impl Drop for ErrorSubscriber {
    fn drop(&mut self) {
        self.close();
    }
}
