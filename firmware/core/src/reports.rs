//! Where reports go: the owner endpoints that get LOCATION ([`LOCATION_LISTENERS`] of
//! them) and the settings the upload and network tasks read ([`ReportSettings`]), copied
//! out of the [`crate::Controller`] after every change (see "Who gets which report" in
//! [`crate::controller`]).

use protocol::{State, limits};

use crate::config::OWNER_TIMEOUT_US;
use crate::hw::Endpoint;

/// Owner endpoints that get the LOCATION reports at once: a few tools on the owner's
/// machine (an uploader, a watcher, a poller, one more), each a socket of its own.
pub const LOCATION_LISTENERS: usize = 4;

/// An owner endpoint that gets LOCATION reports (see "Who gets which report" in
/// [`crate::controller`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub(crate) struct Listener {
    /// The endpoint.
    pub(crate) to: Endpoint,
    /// When it last sent a CRC-valid frame, microseconds: silent
    /// [`crate::config::OWNER_TIMEOUT_US`], it stops getting reports (unless it started
    /// the upload or run under way).
    pub(crate) heard_us: u64,
}

/// How long the endpoint heard most recently keeps its LOCATION reports while nothing
/// runs and it is silent: a host with one socket that turned reports on and only listens
/// keeps them (as under the manual) for a minute, not for ever, so that one datagram, a
/// forged one too, buys a bounded volume of reports (issue 21 F6: at the default 10 ms
/// period at most 6,000 LOCATION datagrams; docs/PROTOCOL.md section 1 gives the bound).
pub const KEEPER_SILENCE_US: u64 = 60_000_000;

/// How long a [`Listener`] keeps its reports without being heard.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Keep {
    /// It started the upload or run under way: for as long as that lasts.
    Running,
    /// Nothing runs and it was heard most recently: [`KEEPER_SILENCE_US`].
    Keeper,
    /// Any other: [`OWNER_TIMEOUT_US`].
    Other,
}

impl Listener {
    /// When it stops getting LOCATION reports unless heard from again.
    pub(crate) fn until_us(&self, keep: Keep) -> u64 {
        match keep {
            Keep::Running => u64::MAX,
            Keep::Keeper => self.heard_us.saturating_add(KEEPER_SILENCE_US),
            Keep::Other => self.heard_us.saturating_add(OWNER_TIMEOUT_US),
        }
    }
}

/// Settings the location upload needs, copied out after every change.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReportSettings {
    /// Where LOCATION reports go: each of these owner endpoints (none before any host
    /// spoke) until its time in `location_until_us`.
    pub location_to: [Option<Endpoint>; LOCATION_LISTENERS],
    /// When each of `location_to` stops getting LOCATION reports unless it is heard from
    /// again, microseconds: 5 s after its last CRC-valid frame, or `u64::MAX` for the
    /// endpoint that started the upload or run under way (or, when nothing runs, the one
    /// heard most recently). Checked when a report is sent,
    /// so a tool that went away stops getting reports even if no later command comes.
    pub location_until_us: [u64; LOCATION_LISTENERS],
    /// Where USART_RECV reports go (`None` before any host spoke).
    pub serial_to: Option<Endpoint>,
    /// LOCATION reports on.
    pub reports_on: bool,
    /// LOCATION period, microseconds.
    pub upload_period_us: u32,
    /// The trajectory state.
    pub state: State,
    /// With a key: which endpoints hold a session, and what sealing needs (reports go to
    /// those endpoints only, sealed).
    pub seal: crate::auth::SealRoutes,
}

impl ReportSettings {
    /// The endpoints a LOCATION report sent at `now_us` goes to.
    pub fn location_destinations(&self, now_us: u64) -> impl Iterator<Item = Endpoint> + '_ {
        self.location_to
            .iter()
            .zip(self.location_until_us)
            .filter_map(move |(to, until_us)| to.filter(|_| now_us < until_us))
    }

    /// Whether a LOCATION report sent at `now_us` has anywhere to go.
    pub fn has_location_listener(&self, now_us: u64) -> bool {
        self.location_destinations(now_us).next().is_some()
    }

    /// Whether a LOCATION report sent at `now_us` goes to `endpoint`.
    pub fn location_goes_to(&self, endpoint: Endpoint, now_us: u64) -> bool {
        self.location_destinations(now_us).any(|to| to == endpoint)
    }

    /// Before the trajectory task first publishes the controller's: no report anywhere,
    /// period 0 (the upload task waits for the first publication). All zero bytes, so that
    /// a [`crate::Bus`] in a `static` is zero-initialised (`.bss`, not a flash copy).
    pub const UNPUBLISHED: ReportSettings = ReportSettings {
        location_to: [None; LOCATION_LISTENERS],
        location_until_us: [0; LOCATION_LISTENERS],
        serial_to: None,
        reports_on: false,
        upload_period_us: 0,
        state: State::New,
        seal: crate::auth::SealRoutes::NONE,
    };

    /// Boot values: reports on at the default period, nobody to send them to yet.
    pub const BOOT: ReportSettings = ReportSettings {
        reports_on: true,
        upload_period_us: limits::DEFAULT_UPLOAD_PERIOD_US,
        state: State::Stopped,
        ..ReportSettings::UNPUBLISHED
    };
}
