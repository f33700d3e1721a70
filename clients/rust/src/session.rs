//! How to open a Zenoh session, with the service's safe defaults: multicast scouting off and
//! nothing listening unless asked, so peers find each other only through explicit endpoints.

use std::path::PathBuf;

use zenoh::{Config, Session, Wait};

use crate::error::{Error, Result};

/// Where a service listens by default (`simpletrack serve`).
pub const DEFAULT_ENDPOINT: &str = "tcp/127.0.0.1:7447";
/// A lost connection is retried this often at most (Zenoh's own back-off grows to 4 s, which
/// cost seconds of frames after a short router outage).
pub const DEFAULT_RECONNECT_MAX_MS: u64 = 1000;
const RECONNECT_FIRST_MS: u64 = 100;
/// Zenoh closes a link (losing what is queued on it) when a blocking put waited this long; its
/// default of 5 s is shorter than a burst a busy service may need to drain.
const BLOCK_WAIT_BEFORE_CLOSE_KEY: &str =
    "transport/link/tx/queue/congestion_control/block/wait_before_close";
const BLOCK_WAIT_BEFORE_CLOSE_US: u64 = 60_000_000;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Embedded: talks to other peers directly, no router needed.
    Peer,
    /// Talks only through the router(s) given in `connect`.
    Client,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ZenohOptions {
    pub mode: Mode,
    /// Endpoints to listen on (peer mode only); never all interfaces unless named.
    pub listen: Vec<String>,
    /// Endpoints (peers or routers) to connect to, e.g. `tcp/127.0.0.1:7447`.
    pub connect: Vec<String>,
    pub multicast_scouting: bool,
    /// A Zenoh JSON5 config to start from (TLS, access control); the fields above that are
    /// non-empty are laid over it.
    pub config_file: Option<PathBuf>,
    /// -1: a client waits for its router forever.
    pub connect_timeout_ms: Option<i64>,
    pub reconnect_max_ms: u64,
}

impl Default for ZenohOptions {
    /// Peer mode, connecting to a service on this machine (its default listen endpoint).
    fn default() -> Self {
        Self::connect_to([DEFAULT_ENDPOINT])
    }
}

impl ZenohOptions {
    /// Peer mode, connecting to `endpoints`, listening nowhere.
    pub fn connect_to<S: Into<String>>(endpoints: impl IntoIterator<Item = S>) -> Self {
        Self {
            mode: Mode::Peer,
            listen: Vec::new(),
            connect: endpoints.into_iter().map(Into::into).collect(),
            multicast_scouting: false,
            config_file: None,
            connect_timeout_ms: None,
            reconnect_max_ms: DEFAULT_RECONNECT_MAX_MS,
        }
    }

    fn check(&self) -> Result<()> {
        for e in self.listen.iter().chain(&self.connect) {
            let ok = e
                .split_once('/')
                .is_some_and(|(proto, addr)| !proto.is_empty() && !addr.is_empty());
            if !ok {
                return Err(Error::InvalidOption(format!(
                    "endpoint {e:?} must look like PROTO/ADDRESS, e.g. tcp/127.0.0.1:7447"
                )));
            }
        }
        if self.config_file.is_none() && self.mode == Mode::Client {
            if self.connect.is_empty() && !self.multicast_scouting {
                return Err(Error::InvalidOption(
                    "client mode needs at least one connect endpoint (a router)".into(),
                ));
            }
            if !self.listen.is_empty() {
                return Err(Error::InvalidOption(
                    "client mode does not listen; drop listen or use peer mode".into(),
                ));
            }
        }
        if self.reconnect_max_ms < RECONNECT_FIRST_MS {
            return Err(Error::InvalidOption(format!(
                "reconnect_max_ms {} must be at least {RECONNECT_FIRST_MS}",
                self.reconnect_max_ms
            )));
        }
        Ok(())
    }

    pub fn to_config(&self) -> Result<Config> {
        self.check()?;
        let json = |v: &[String]| {
            format!(
                "[{}]",
                v.iter()
                    .map(|s| format!("{s:?}"))
                    .collect::<Vec<_>>()
                    .join(",")
            )
        };
        let mode = match self.mode {
            Mode::Peer => "\"peer\"",
            Mode::Client => "\"client\"",
        };
        let mut config = match &self.config_file {
            Some(path) => {
                let mut c = Config::from_file(path)?;
                if !self.listen.is_empty() {
                    c.insert_json5("listen/endpoints", &json(&self.listen))?;
                }
                if !self.connect.is_empty() {
                    c.insert_json5("connect/endpoints", &json(&self.connect))?;
                }
                c
            }
            None => {
                let mut c = Config::default();
                c.insert_json5("mode", mode)?;
                c.insert_json5("listen/endpoints", &json(&self.listen))?;
                c.insert_json5("connect/endpoints", &json(&self.connect))?;
                c.insert_json5(
                    "scouting/multicast/enabled",
                    &self.multicast_scouting.to_string(),
                )?;
                let retry = format!(
                    "{{period_init_ms: {RECONNECT_FIRST_MS}, period_max_ms: {}, period_increase_factor: 2}}",
                    self.reconnect_max_ms
                );
                c.insert_json5("connect/retry", &retry)?;
                c.insert_json5(
                    BLOCK_WAIT_BEFORE_CLOSE_KEY,
                    &BLOCK_WAIT_BEFORE_CLOSE_US.to_string(),
                )?;
                c
            }
        };
        if let Some(ms) = self.connect_timeout_ms {
            config.insert_json5("connect/timeout_ms", &ms.to_string())?;
        }
        Ok(config)
    }

    pub fn open(&self) -> Result<Session> {
        Ok(zenoh::open(self.to_config()?).wait()?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_connect_to_a_local_service_with_scouting_off_and_no_listener() {
        let c = ZenohOptions::default().to_config().unwrap();
        assert_eq!(
            c.get_json("connect/endpoints").unwrap(),
            r#"["tcp/127.0.0.1:7447"]"#
        );
        assert_eq!(c.get_json("listen/endpoints").unwrap(), "[]");
        assert_eq!(c.get_json("scouting/multicast/enabled").unwrap(), "false");
        assert_eq!(
            c.get_json(BLOCK_WAIT_BEFORE_CLOSE_KEY).unwrap(),
            BLOCK_WAIT_BEFORE_CLOSE_US.to_string()
        );
    }

    #[test]
    fn bad_options_are_refused_naming_the_value() {
        let e = ZenohOptions::connect_to(["127.0.0.1:7447"])
            .to_config()
            .unwrap_err();
        assert!(e.to_string().contains("\"127.0.0.1:7447\""), "{e}");
        let client = ZenohOptions {
            mode: Mode::Client,
            ..ZenohOptions::connect_to(Vec::<String>::new())
        };
        assert!(client
            .to_config()
            .unwrap_err()
            .to_string()
            .contains("router"));
        let listening = ZenohOptions {
            mode: Mode::Client,
            listen: vec!["tcp/127.0.0.1:0".into()],
            ..ZenohOptions::default()
        };
        assert!(listening
            .to_config()
            .unwrap_err()
            .to_string()
            .contains("does not listen"));
    }
}
