//! How long to wait for an ACK: the round trip estimated as in RFC 6298 (smoothed round
//! trip and its variation, Karn's rule, exponential back-off), with a floor suited to a LAN
//! instead of the RFC's 1 s.
//!
//! A fixed 100 ms wait costs 300 to 1000 round trips of a LAN (0.1-0.3 ms) for every lost
//! datagram; at 20 % loss that starves a streaming run. The estimate starts at the
//! configured ACK timeout (nothing is known yet) and never goes above it, so a host that
//! sets `--ack-timeout-ms` still bounds every wait.

use std::time::Duration;

/// Lowest retransmission timeout by default: a few LAN round trips plus the scheduling
/// jitter of a loaded host (a resend that comes too early is only a duplicate, which the
/// controller ACKs again without executing it).
pub const DEFAULT_MIN_RTO: Duration = Duration::from_millis(3);

/// The controller's duplicate window (docs/PROTOCOL.md, "Ordering, retransmission and
/// duplicates"): a copy of an accepted frame that arrives within 2 s of it is recognised
/// and not executed again.
pub const DUPLICATE_WINDOW: Duration = Duration::from_micros(protocol::limits::DUPLICATE_WINDOW_US);

/// No copy of a command leaves later than this after its first copy: the duplicate window
/// less room for the datagram's way and for the controller's clock running a little fast.
pub const RESEND_HORIZON: Duration = Duration::from_millis(1800);

/// The clock granularity `G` of RFC 6298: the variation term is never below it.
const GRANULARITY: Duration = Duration::from_micros(100);

/// Back-off doublings at most (2^6 = 64 times the estimate, before the ceiling).
const MAX_BACKOFF_SHIFT: u32 = 6;

/// Retransmission timeout estimator (RFC 6298, section 2).
#[derive(Clone, Debug)]
pub struct RttEstimator {
    /// Smoothed round trip, once a sample came.
    srtt: Option<Duration>,
    /// Round-trip variation.
    rttvar: Duration,
    /// Floor of the timeout.
    min: Duration,
    /// Ceiling of the timeout, and its value before the first sample.
    max: Duration,
    /// Doublings since the last valid sample (a timeout doubles the wait).
    backoff: u32,
}

impl RttEstimator {
    /// An estimator that starts at `initial` (also the ceiling) and never goes below `min`.
    pub fn new(initial: Duration, min: Duration) -> RttEstimator {
        let max = initial.max(Duration::from_micros(1));
        RttEstimator {
            srtt: None,
            rttvar: Duration::ZERO,
            min: min.min(max),
            max,
            backoff: 0,
        }
    }

    /// A round trip measured on a frame sent once (Karn's rule: never on a frame that was
    /// sent again, whose ACK may answer either copy). Ends any back-off.
    pub fn sample(&mut self, rtt: Duration) {
        match self.srtt {
            None => {
                self.srtt = Some(rtt);
                self.rttvar = rtt / 2;
            }
            Some(srtt) => {
                let deviation = srtt.abs_diff(rtt);
                self.rttvar = (self.rttvar * 3 + deviation) / 4;
                self.srtt = Some((srtt * 7 + rtt) / 8);
            }
        }
        self.backoff = 0;
    }

    /// An ACK timeout: the next wait is twice as long (up to the ceiling) until a valid
    /// sample arrives.
    pub fn back_off(&mut self) {
        self.backoff = (self.backoff + 1).min(MAX_BACKOFF_SHIFT);
    }

    /// How long to wait for an ACK now.
    pub fn rto(&self) -> Duration {
        self.rto_backed_off(MAX_BACKOFF_SHIFT)
    }

    /// How long to wait for an ACK now, counting at most `max_doublings` of the back-off.
    ///
    /// A stream of frames (an upload) uses a short cap: on a LAN, losses are random rather
    /// than congestion, and a run draining its buffer cannot afford waits that double up
    /// to the ceiling; its own stall timeout bounds how long it keeps trying.
    pub fn rto_backed_off(&self, max_doublings: u32) -> Duration {
        let base = match self.srtt {
            None => self.max,
            Some(srtt) => srtt + (self.rttvar * 4).max(GRANULARITY),
        };
        let doublings = self.backoff.min(max_doublings).min(MAX_BACKOFF_SHIFT);
        (base.max(self.min) * (1 << doublings)).clamp(self.min, self.max)
    }

    /// The smoothed round trip, once measured.
    pub fn srtt(&self) -> Option<Duration> {
        self.srtt
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(v: f64) -> Duration {
        Duration::from_secs_f64(v / 1000.0)
    }

    #[test]
    fn starts_at_the_initial_value() {
        let rtt = RttEstimator::new(ms(100.0), ms(3.0));
        assert_eq!(rtt.rto(), ms(100.0));
        assert_eq!(rtt.srtt(), None);
    }

    #[test]
    fn first_sample_sets_srtt_and_half_of_it_as_variation() {
        let mut rtt = RttEstimator::new(ms(100.0), ms(1.0));
        rtt.sample(ms(10.0));
        // RTO = SRTT + 4 RTTVAR = 10 + 4 * 5.
        assert_eq!(rtt.srtt(), Some(ms(10.0)));
        assert_eq!(rtt.rto(), ms(30.0));
        rtt.sample(ms(10.0));
        // RTTVAR = 3/4 * 5 + 1/4 * 0, SRTT unchanged.
        assert_eq!(rtt.rto(), ms(25.0));
    }

    #[test]
    fn a_lan_round_trip_gives_the_floor() {
        let mut rtt = RttEstimator::new(ms(100.0), DEFAULT_MIN_RTO);
        for _ in 0..20 {
            rtt.sample(Duration::from_micros(200));
        }
        assert_eq!(rtt.rto(), DEFAULT_MIN_RTO);
    }

    #[test]
    fn timeouts_double_the_wait_up_to_the_ceiling_and_a_sample_ends_it() {
        let mut rtt = RttEstimator::new(ms(100.0), ms(3.0));
        for _ in 0..20 {
            rtt.sample(Duration::from_micros(200));
        }
        rtt.back_off();
        assert_eq!(rtt.rto(), ms(6.0));
        rtt.back_off();
        assert_eq!(rtt.rto(), ms(12.0));
        for _ in 0..10 {
            rtt.back_off();
        }
        assert_eq!(rtt.rto(), ms(100.0));
        rtt.sample(Duration::from_micros(200));
        assert_eq!(rtt.rto(), ms(3.0));
    }

    #[test]
    fn a_stream_caps_the_back_off() {
        let mut rtt = RttEstimator::new(ms(100.0), ms(3.0));
        for _ in 0..20 {
            rtt.sample(Duration::from_micros(200));
        }
        for _ in 0..10 {
            rtt.back_off();
        }
        assert_eq!(rtt.rto_backed_off(3), ms(24.0));
        assert_eq!(rtt.rto_backed_off(0), ms(3.0));
        assert_eq!(rtt.rto(), ms(100.0));
    }

    #[test]
    fn a_slow_link_is_followed_up_to_the_ceiling() {
        let mut rtt = RttEstimator::new(ms(100.0), ms(3.0));
        for _ in 0..50 {
            rtt.sample(ms(40.0));
        }
        let rto = rtt.rto();
        assert!(rto > ms(40.0) && rto < ms(50.0), "{rto:?}");
        rtt.sample(ms(400.0));
        assert_eq!(rtt.rto(), ms(100.0));
    }

    #[test]
    fn the_resend_horizon_is_inside_the_duplicate_window() {
        const { assert!(RESEND_HORIZON.as_millis() < DUPLICATE_WINDOW.as_millis()) };
    }
}
