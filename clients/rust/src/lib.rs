//! Rust client of the SimpleTrack tracking service: publish a vehicle's 3D detection frames,
//! receive the tracks (and the errors) the service sends back, over Eclipse Zenoh.
//!
//! - [`wire`]: the messages of schemas/README.md and their msgpack codec, a vehicle's fused
//!   tracks (`VehicleTrackFrame`) included.
//! - [`DetectionPublisher`]: one per vehicle sensor (an advanced publisher with a cache).
//! - [`TrackSubscriber`], [`ErrorSubscriber`]: the planner side.
//! - [`ZenohOptions`]: a session with the service's safe defaults (no multicast scouting).

mod epoch_filter;
mod error;
mod errors;
mod invalid;
mod mailbox;
mod publisher;
mod session;
mod subscriber;
pub mod wire;

pub use epoch_filter::{EpochFilter, MAX_EPOCH_KEYS};
pub use error::{Error, Result};
pub use errors::{ErrorCallback, ErrorSubscriber, ErrorSubscriberOptions};
pub use invalid::InvalidCallback;
pub use publisher::{
    DetectionPublisher, FrameOptions, PublisherOptions, Undelivered, UndeliveredCallback,
    DEFAULT_CACHE_FRAMES, DEFAULT_HEARTBEAT,
};
pub use session::{Mode, ZenohOptions, DEFAULT_ENDPOINT};
pub use subscriber::{
    TrackCallback, TrackMessage, TrackSubscriber, TrackSubscriberOptions, RECENT_FRAMES,
};
pub use zenoh;

// The README's example compiles (it needs a service to run).
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
