//! Rust client of the SimpleTrack tracking service: publish a vehicle's 3D detection frames,
//! receive the tracks (and the errors) the service sends back, over Eclipse Zenoh.
//!
//! - [`wire`]: the messages of schemas/README.md and their msgpack codec, a vehicle's fused
//!   tracks (`VehicleTrackFrame`) included.
//! - [`DetectionPublisher`]: one per vehicle sensor (an advanced publisher with a cache).
//! - [`TrackSubscriber`] (sensors' tracks), [`VehicleTrackSubscriber`] (a fused vehicle's one
//!   object list), [`ErrorSubscriber`]: the planner side; [`StreamFilter`] is their rule for
//!   repeats and fenced holders.
//! - [`ZenohOptions`]: a session with the service's safe defaults (no multicast scouting).

mod epoch_filter;
mod error;
mod errors;
mod invalid;
mod mailbox;
mod publisher;
mod session;
mod stream_filter;
mod subscriber;
mod vehicle_subscriber;
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
pub use stream_filter::{StreamFilter, Verdict, MAX_STREAM_KEYS, RECENT_FRAMES};
pub use subscriber::{
    Subscription, TrackCallback, TrackMessage, TrackSubscriber, TrackSubscriberOptions,
};
pub use vehicle_subscriber::{
    VehicleTrackCallback, VehicleTrackMessage, VehicleTrackSubscriber,
    VehicleTrackSubscriberOptions,
};
pub use zenoh;

// The README's example compiles (it needs a service to run).
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
