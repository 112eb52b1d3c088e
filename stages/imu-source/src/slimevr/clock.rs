//! When a tracker sent each datagram, from its packet numbers and their arrival times.
//!
//! SlimeVR packets carry no sample time, and arrival times lie in a burst: a tracker whose Wi-Fi
//! stalled 100 ms delivers its backlog within a millisecond, so ten samples taken 10 ms apart
//! would look simultaneous, and an angular rate derived from them would spike (171 rad/s against
//! a true peak of 6 were measured so). The firmware numbers every datagram it sends (one counter
//! per tracker, `Connection::sendPacketNumber`), at a steady pace while it streams. So a
//! datagram's send time is modelled as a line in its packet number,
//! `t(n) = a₀ + (n − n₀)·P + o`, fitted under the arrivals (a datagram never arrives before it
//! is sent):
//!
//! - `(n₀, a₀)`, the anchor: the least delayed of the first [`ANCHOR_SPAN_NS`] of datagrams.
//! - `P`, the time per packet number: the smallest slope from the anchor to one of the last
//!   [`WINDOW_NS`] of arrivals (the least delayed of them), at least [`MIN_SPAN_NS`] after it.
//! - `o`, the offset: the smallest `a − (a₀ + (n − n₀)·P)` over the last [`WINDOW_NS`] of
//!   arrivals, i.e. the line touches the earliest-delivered recent datagram. A backlog's
//!   datagrams lie above it, and are dated back onto it, `P` apart per number.
//! - Each date is kept within `[a − MAX_BACKDATE_NS, a]` and after the previous one.
//!
//! Until the slope is measured (about 0.4 s) a datagram is dated at its arrival. A tracker that pauses (the
//! firmware skips rotations that did not change) resumes with numbers that advanced less than
//! the time: its datagrams are dated up to the pause (at most `MAX_BACKDATE`) early until the
//! datagrams before the pause leave the window, while the tracker was still, so the orientation
//! hardly moved.

use std::collections::VecDeque;

/// How far back the fit looks: longer than the stalls it dates back (100 ms), short enough to
/// follow a tracker that paused.
pub const WINDOW_NS: u64 = 500_000_000;
/// The first arrivals, over this long, give the line's anchor: the least delayed of them, ns.
pub const ANCHOR_SPAN_NS: u64 = 150_000_000;
/// The slope is measured over at least this long after the anchor; before, datagrams are dated
/// at their arrival, ns.
pub const MIN_SPAN_NS: u64 = 250_000_000;
/// A datagram is dated at most this long before its arrival, ns.
pub const MAX_BACKDATE_NS: u64 = 200_000_000;

/// One tracker's packet-number clock.
#[derive(Debug, Default, Clone)]
pub struct PacketClock {
    /// The first [`ANCHOR_SPAN_NS`] of arrivals: (packet number, arrival ns).
    first: Vec<(u64, u64)>,
    /// The least delayed of `first`: where the line is anchored.
    anchor: Option<(u64, u64)>,
    /// The last [`WINDOW_NS`] of arrivals: (packet number, arrival ns).
    recent: VecDeque<(u64, u64)>,
    last_dated: u64,
}

impl PacketClock {
    /// Dates datagram `number`, which arrived at `arrival_ns`: when it was sent, on the arrival
    /// clock. Numbers must not repeat or go back (the receiver drops those before).
    pub fn date(&mut self, number: u64, arrival_ns: u64) -> u64 {
        self.recent.push_back((number, arrival_ns));
        while self
            .recent
            .front()
            .is_some_and(|&(_, a)| a + WINDOW_NS < arrival_ns)
        {
            self.recent.pop_front();
        }
        let dated = match self.line(number, arrival_ns) {
            Some((anchor, period)) => {
                let line = |n: u64| anchor.1 as f64 + (n as f64 - anchor.0 as f64) * period;
                let offset = self
                    .recent
                    .iter()
                    .map(|&(n, a)| a as f64 - line(n))
                    .fold(f64::INFINITY, f64::min);
                (line(number) + offset).round() as u64
            }
            None => arrival_ns,
        };
        let dated = dated
            .clamp(arrival_ns.saturating_sub(MAX_BACKDATE_NS), arrival_ns)
            .max(self.last_dated + 1)
            .min(arrival_ns);
        self.last_dated = dated;
        dated
    }

    /// The anchor and the time per packet number (ns) once the arrivals span [`MIN_SPAN_NS`]:
    /// the smallest slope from the anchor to a recent datagram (the least delayed of them).
    fn line(&mut self, number: u64, arrival_ns: u64) -> Option<((u64, u64), f64)> {
        let anchor = match self.anchor {
            Some(anchor) => anchor,
            None => {
                let start = self.first.first().map_or(arrival_ns, |f| f.1);
                if arrival_ns < start + ANCHOR_SPAN_NS {
                    self.first.push((number, arrival_ns));
                    return None;
                }
                *self.anchor.insert(least_delayed(&self.first)?)
            }
        };
        self.recent
            .iter()
            .filter(|&&(n, a)| n > anchor.0 && a >= anchor.1 + MIN_SPAN_NS)
            .map(|&(n, a)| (a - anchor.1) as f64 / (n - anchor.0) as f64)
            .reduce(f64::min)
            .map(|period| (anchor, period))
    }
}

/// Of datagrams spanning a short time, the one delivered with the least delay: the smallest
/// `a − n·p` with `p` the median time per number between consecutive ones.
fn least_delayed(datagrams: &[(u64, u64)]) -> Option<(u64, u64)> {
    let mut per_number: Vec<f64> = datagrams
        .windows(2)
        .map(|w| (w[1].1 as f64 - w[0].1 as f64) / (w[1].0 - w[0].0) as f64)
        .collect();
    per_number.sort_by(f64::total_cmp);
    let p = *per_number.get(per_number.len() / 2)?;
    let (n0, a0) = *datagrams.first()?;
    datagrams.iter().copied().min_by(|x, y| {
        let below = |&(n, a): &(u64, u64)| (a - a0) as f64 - (n - n0) as f64 * p;
        below(x).total_cmp(&below(y))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn a_backlog_is_dated_back_onto_the_pace_of_the_numbers() {
        // 200 datagrams a second (numbers 5 ms apart), 0.2..1.2 ms of delivery jitter; from 2 s a
        // 100 ms stall, then the 20 datagrams of the stall arrive 0.05 ms apart.
        let mut clock = PacketClock::default();
        let t0 = 1_700_000_000_000 * MS;
        let mut dates = Vec::new();
        for n in 1..=600u64 {
            let sent = t0 + n * 5 * MS;
            let jitter = (n * 7919 % 11) * MS / 10 + MS / 5;
            let stalled = (400..420).contains(&n);
            let arrival = if stalled {
                t0 + 420 * 5 * MS + (n - 400) * MS / 20
            } else {
                sent + jitter
            };
            dates.push((n, sent, arrival, clock.date(n, arrival)));
        }
        for &(n, sent, arrival, dated) in &dates[100..] {
            assert!(dated <= arrival, "{n}: dated after arrival");
            // The line touches the least delayed datagram (0.2 ms): within a millisecond of the
            // send, also for the backlog.
            let error = dated as i64 - sent as i64;
            assert!((0..1_000_000).contains(&error), "{n}: {error} ns off");
        }
        // Dates increase, by about the numbers' pace.
        for w in dates[100..].windows(2) {
            let step = w[1].3 - w[0].3;
            assert!((4 * MS..6 * MS).contains(&step), "{}: {step}", w[1].0);
        }
    }

    #[test]
    fn lost_numbers_leave_gaps_and_a_pause_is_bounded() {
        let mut clock = PacketClock::default();
        let t0 = 10_000 * MS;
        for n in 1..=100u64 {
            clock.date(n, t0 + n * 10 * MS);
        }
        // Numbers 101..=104 lost: 105 is dated 50 ms after 100.
        let d100 = t0 + 1000 * MS;
        assert_eq!(clock.date(105, t0 + 1050 * MS), d100 + 50 * MS);
        // A 300 ms pause (numbers did not advance): the next number is dated at most
        // MAX_BACKDATE before its arrival while the datagrams before the pause are in the window.
        let arrival = t0 + 1350 * MS;
        assert_eq!(clock.date(106, arrival), arrival - MAX_BACKDATE_NS);
        // Once they left it, at the pace after the pause.
        let arrival = t0 + 1900 * MS;
        assert_eq!(clock.date(107, arrival), arrival);
        // Before MIN_SPAN: at arrival.
        let mut fresh = PacketClock::default();
        assert_eq!(fresh.date(7, 5 * MS), 5 * MS);
        assert_eq!(fresh.date(9, 30 * MS), 30 * MS);
    }
}
