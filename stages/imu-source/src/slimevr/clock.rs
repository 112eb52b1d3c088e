//! When a tracker sent each datagram, from its packet numbers and their arrival times.
//!
//! SlimeVR packets carry no sample time, and arrival times lie in a burst: a tracker whose Wi-Fi
//! stalled 100 ms delivers its backlog within a millisecond, so ten samples taken 10 ms apart
//! would look simultaneous, and an angular rate derived from them would spike (171 rad/s against
//! a true peak of 6 were measured so). The firmware numbers every datagram it sends (one counter
//! per tracker, `Connection::sendPacketNumber`), at a steady pace while it streams; the receiver
//! takes the datagrams without sample data (heartbeat answers, battery) out of the count and hands
//! this clock the data datagrams' numbers. A datagram's send time lies on a line in its number
//! fitted under the arrivals (a datagram never arrives before it is sent):
//!
//! - `P`, the time per packet number: the mean of the intervals per number between consecutive
//!   datagrams of the last [`PACE_WINDOW_NS`], leaving out those under half their upper quartile
//!   (a backlog's datagrams, delivered back to back, would make the pace look faster) and those
//!   over twice the median of the rest (the stall before a backlog).
//! - the line `t(n) = n·P + o` touches the earliest-delivered datagram of the last [`WINDOW_NS`]
//!   (`o` is the smallest `a − n·P` there). A backlog's datagrams lie above it and are dated back
//!   onto it, `P` apart per number; a lost datagram leaves its gap.
//! - Each date is at or before the arrival and after the previous date by at least 3/4 of the
//!   pace per number (where the line moves back, a less delayed datagram or a new pace, the
//!   dates rejoin it without bunching), and so at most [`WINDOW_NS`] before the arrival.
//!
//! Until [`MIN_INTERVALS`] intervals are seen a datagram is dated at its arrival. A tracker that
//! pauses (the firmware skips rotations that did not change) resumes with numbers that advanced
//! less than the time: its datagrams are dated up to the pause early until the datagrams before
//! the pause leave the window (at most [`WINDOW_NS`]); it was still then, so its orientation
//! hardly moved.

use std::collections::VecDeque;

/// The line touches the earliest-delivered datagram of this long: longer than the stalls it
/// dates back (100 ms), short enough to follow a tracker that paused or slowed down (its dates
/// lag its sends by what it lost against the line in this long), ns.
pub const WINDOW_NS: u64 = 150_000_000;
/// The pace is measured over this long of arrivals, ns.
pub const PACE_WINDOW_NS: u64 = 1_000_000_000;
/// Intervals needed before the pace is measured; until then datagrams are dated at arrival.
pub const MIN_INTERVALS: usize = 16;
/// The pace is measured again every this many datagrams.
const REPACE_EVERY: u32 = 16;

/// One tracker's packet-number clock.
#[derive(Debug, Default, Clone)]
pub struct PacketClock {
    /// The last [`PACE_WINDOW_NS`] of arrivals: (packet number, arrival ns).
    recent: VecDeque<(u64, u64)>,
    /// The time per packet number, ns, and how many datagrams ago it was measured.
    pace: Option<f64>,
    since_pace: u32,
    last_dated: u64,
    last_number: Option<u64>,
}

impl PacketClock {
    /// Dates datagram `number`, which arrived at `arrival_ns`: when it was sent, on the arrival
    /// clock. Numbers must not repeat or go back (the receiver drops those before).
    pub fn date(&mut self, number: u64, arrival_ns: u64) -> u64 {
        self.recent.push_back((number, arrival_ns));
        while self
            .recent
            .front()
            .is_some_and(|&(_, a)| a + PACE_WINDOW_NS < arrival_ns)
        {
            self.recent.pop_front();
        }
        self.since_pace += 1;
        if self.pace.is_none() || self.since_pace >= REPACE_EVERY {
            self.pace = pace_ns(&self.recent).or(self.pace);
            self.since_pace = 0;
        }
        let dated = match self.pace {
            // The line through the earliest-delivered recent datagram, at this number.
            Some(pace) => self
                .recent
                .iter()
                .rev()
                .take_while(|&&(_, a)| a + WINDOW_NS >= arrival_ns)
                .map(|&(n, a)| a as f64 + (number as f64 - n as f64) * pace)
                .fold(f64::INFINITY, f64::min)
                .round() as u64,
            None => arrival_ns,
        };
        // Never after the arrival; after the previous date by at least 3/4 of the pace per number
        // (when the line moves back, a less delayed datagram or a new pace, the dates rejoin it
        // without bunching, rates derived across them at most 4/3 too high); and so (numbers
        // increase) at most the window before the arrival.
        let spacing = match (self.pace, self.last_number) {
            (Some(pace), Some(n)) => (0.75 * pace * number.saturating_sub(n) as f64) as u64,
            _ => 1,
        };
        let dated = dated.max(self.last_dated + spacing.max(1)).min(arrival_ns);
        self.last_dated = dated;
        self.last_number = Some(number);
        dated
    }
}

/// The time per packet number, ns: the mean of the intervals per number between consecutive
/// datagrams, leaving out those under half the upper quartile (a backlog's, delivered at once) and
/// those over twice the median of the rest (a stall's), once there are [`MIN_INTERVALS`].
fn pace_ns(datagrams: &VecDeque<(u64, u64)>) -> Option<f64> {
    let mut per_number: Vec<f64> = datagrams
        .iter()
        .zip(datagrams.iter().skip(1))
        .filter(|(p, q)| q.0 > p.0)
        .map(|(p, q)| (q.1 as f64 - p.1 as f64) / (q.0 - p.0) as f64)
        .collect();
    if per_number.len() < MIN_INTERVALS {
        return None;
    }
    per_number.sort_by(f64::total_cmp);
    let upper_quartile = per_number[per_number.len() * 3 / 4];
    let steady: Vec<f64> = per_number
        .into_iter()
        .filter(|&d| d >= 0.5 * upper_quartile)
        .collect();
    // The mean of the steady intervals (a median leans with skewed jitter), a stall's long one
    // left out as its backlog's short ones were.
    let median = *steady.get(steady.len() / 2)?;
    let kept: Vec<f64> = steady.into_iter().filter(|&d| d <= 2.0 * median).collect();
    let mean = kept.iter().sum::<f64>() / kept.len() as f64;
    (mean > 0.0).then_some(mean)
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
            // The line touches the least delayed datagram (0.2 ms late), its pace measured over
            // jitter that comes in a sawtooth: within 1.5 ms of the send, the backlog too.
            let error = dated as i64 - sent as i64;
            assert!(error.abs() < 1_500_000, "{n}: {error} ns off");
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
        // A 100 ms pause (numbers did not advance): the next number is dated by the pace, the
        // pause early, while the datagrams before the pause are in the window...
        assert_eq!(clock.date(106, t0 + 1150 * MS), t0 + 1060 * MS);
        // ... and at its arrival once they left it.
        let arrival = t0 + 1400 * MS;
        assert_eq!(clock.date(107, arrival), arrival);

        // Before MIN_INTERVALS: at arrival.
        let mut fresh = PacketClock::default();
        assert_eq!(fresh.date(7, 5 * MS), 5 * MS);
        assert_eq!(fresh.date(9, 30 * MS), 30 * MS);
    }

    #[test]
    fn a_backlog_at_the_start_does_not_set_the_pace() {
        // 50 datagrams at once, then one every 10 ms: the pace is 10 ms once the steady ones are
        // over a quarter of the intervals, and a later backlog is dated back onto it.
        let mut clock = PacketClock::default();
        let t0 = 10_000 * MS;
        for n in 1..=50u64 {
            assert_eq!(clock.date(n, t0 + n * 1000), t0 + n * 1000);
        }
        for n in 51..=200u64 {
            clock.date(n, t0 + (n - 50) * 10 * MS);
        }
        let pace = clock.pace.expect("measured");
        assert!((pace / (10.0 * MS as f64) - 1.0).abs() < 1e-3, "{pace}");
        let stall_end = t0 + 1600 * MS;
        for n in 201..=210u64 {
            let error =
                clock.date(n, stall_end + n * 1000) as i64 - (t0 + (n - 50) * 10 * MS) as i64;
            assert!(error.abs() < 200_000, "{n}: {error} ns off");
        }
    }
}
