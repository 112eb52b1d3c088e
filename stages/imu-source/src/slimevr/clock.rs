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
//!   over twice the median of the rest (the stall before a backlog). A tracker that sends each
//!   sample as several datagrams back to back (SlimeVR's tracker emulator and firmware that does
//!   not bundle: a rotation and an acceleration datagram per sensor) has consecutive intervals of
//!   nothing and of a whole sample in turn, and those left by the backlog rule would make the
//!   pace a whole sample per number: its pace is measured across [`PACE_SPAN`] numbers (a tenth
//!   off each end: the intervals across a stall's edges).
//! - the line `t(n) = n·P + o` touches the earliest-delivered datagram of the last [`WINDOW_NS`]
//!   (`o` is the smallest `a − n·P` there). With a sample sent as several datagrams, that is a
//!   sample's last datagram, and its first lies above the line by the sample's other datagrams'
//!   numbers: `S`, that spread (the 80th percentile of how far each datagram of the pace window
//!   lies above the lowest of the [`PACE_SPAN`] before it, in whole numbers of `P`; 0 for one
//!   datagram per sample), is allowed. A datagram is dated at `min(arrival, t(n) + S)`: a
//!   sample's first datagram on its send, a backlog's back onto the line; a lost datagram leaves
//!   its gap.
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
/// The pace is measured over datagrams this many numbers apart: more than a board sends for one
/// sample unbundled (two sensors' rotation and acceleration: 4), so an interval spans whole
/// samples' time on average.
const PACE_SPAN: usize = 8;

/// One tracker's packet-number clock.
#[derive(Debug, Default, Clone)]
pub struct PacketClock {
    /// The last [`PACE_WINDOW_NS`] of arrivals: (packet number, arrival ns).
    recent: VecDeque<(u64, u64)>,
    /// The time per packet number, ns, and how many datagrams ago it was measured.
    pace: Option<f64>,
    /// How far above the line datagrams that came on time lie, ns (with the pace).
    spread: f64,
    /// The tracker has been seen sending a sample as several datagrams: its firmware keeps doing
    /// so (a window of irregular sends, a loaded sender catching up, does not undo it).
    grouped: bool,
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
            if let Some((pace, grouped)) = pace_ns(&self.recent, self.grouped) {
                self.grouped = grouped;
                self.pace = Some(pace);
                self.spread = if grouped {
                    spread_ns(&self.recent, pace)
                } else {
                    0.0
                };
            }
            self.since_pace = 0;
        }
        let dated = match self.pace {
            // The line through the earliest-delivered recent datagram, at this number.
            // (Relative to this arrival: epoch nanoseconds are beyond f64's integers.)
            Some(pace) => {
                let before_arrival = self
                    .recent
                    .iter()
                    .rev()
                    .take_while(|&&(_, a)| a + WINDOW_NS >= arrival_ns)
                    .map(|&(n, a)| {
                        (arrival_ns as i64 - a as i64) as f64 - (number as f64 - n as f64) * pace
                    })
                    .fold(f64::NEG_INFINITY, f64::max)
                    - self.spread;
                arrival_ns.saturating_sub(before_arrival.max(0.0).round() as u64)
            }
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

/// The time per packet number, ns, and whether the tracker sends each sample as several
/// datagrams (`grouped_before`: it was seen to): the mean of the intervals per number between consecutive datagrams, leaving out
/// those under half the upper quartile (a backlog's, delivered at once) and those over twice the
/// median of the rest (a stall's), once there are [`MIN_INTERVALS`]. A tracker that sends a
/// sample as several datagrams back to back ([`sends_samples_as_groups`]) has consecutive intervals of
/// nothing and of a whole sample in turn, and the rule above would keep only the whole samples':
/// its pace is measured across [`PACE_SPAN`] numbers, and a tenth is taken off each end of the
/// intervals kept (those across a stall's edges, partly delayed).
fn pace_ns(datagrams: &VecDeque<(u64, u64)>, grouped_before: bool) -> Option<(f64, bool)> {
    let consecutive = per_number_ns(datagrams, 1);
    if consecutive.len() < MIN_INTERVALS {
        return None;
    }
    let grouped = grouped_before || sends_samples_as_groups(datagrams, &consecutive);
    // Across PACE_SPAN numbers only for a grouped tracker (and once there are enough of them).
    let across = grouped
        .then(|| per_number_ns(datagrams, PACE_SPAN))
        .filter(|across| across.len() >= MIN_INTERVALS);
    let (intervals, trim) = match across {
        Some(across) => (across, true),
        None => (consecutive, false),
    };
    let upper_quartile = intervals[intervals.len() * 3 / 4];
    let steady: Vec<f64> = intervals
        .into_iter()
        .filter(|&d| d >= 0.5 * upper_quartile)
        .collect();
    // The mean of the steady intervals (a median leans with skewed jitter), a stall's long one
    // left out as its backlog's short ones were.
    let median = *steady.get(steady.len() / 2)?;
    let kept: Vec<f64> = steady.into_iter().filter(|&d| d <= 2.0 * median).collect();
    let cut = if trim { kept.len() / 10 } else { 0 };
    let middle = &kept[cut..kept.len() - cut];
    let mean = middle.iter().sum::<f64>() / middle.len().max(1) as f64;
    (mean > 0.0).then_some((mean, grouped))
}

/// Whether the datagrams come in groups of 2 to 4 numbers sent back to back: for some group size
/// m, the intervals after the datagrams of some numbers mod m are bunched (under half the 90th
/// percentile of `consecutive`, the sorted consecutive intervals per number) at least 4 times in
/// 5, and after those of another at most 1 in 5. A backlog's bunched intervals (a tenth at most)
/// fall on every number alike, as does a loaded sender's catching up, so neither looks like it.
fn sends_samples_as_groups(datagrams: &VecDeque<(u64, u64)>, consecutive: &[f64]) -> bool {
    let Some(&p90) = consecutive.get(consecutive.len() * 9 / 10) else {
        return false;
    };
    (2..=4u64).any(|m| {
        let mut bunched = [0usize; 4];
        let mut total = [0usize; 4];
        for (p, q) in datagrams.iter().zip(datagrams.iter().skip(1)) {
            if q.0 != p.0 + 1 {
                continue;
            }
            let r = (p.0 % m) as usize;
            total[r] += 1;
            if (q.1 as f64) - (p.1 as f64) < 0.5 * p90 {
                bunched[r] += 1;
            }
        }
        let share = |r: usize| bunched[r] as f64 / total[r].max(1) as f64;
        let counted = |r: usize| total[r] >= MIN_INTERVALS / 2;
        let residues = 0..m as usize;
        residues.clone().all(counted)
            && residues.clone().any(|r| share(r) >= 0.8)
            && residues.into_iter().any(|r| share(r) <= 0.2)
    })
}

/// The intervals per number between datagrams `span` apart (numbers increasing), sorted, ns.
fn per_number_ns(datagrams: &VecDeque<(u64, u64)>, span: usize) -> Vec<f64> {
    let mut per_number: Vec<f64> = datagrams
        .iter()
        .zip(datagrams.iter().skip(span))
        .filter(|(p, q)| q.0 > p.0)
        .map(|(p, q)| (q.1 as f64 - p.1 as f64) / (q.0 - p.0) as f64)
        .collect();
    per_number.sort_by(f64::total_cmp);
    per_number
}

/// How far above the line of `pace` datagrams that came on time lie, ns, in whole numbers of the
/// pace: the 80th percentile, over `datagrams`, of each one's `a − n·P` above the lowest of the
/// [`PACE_SPAN`] before it, rounded to a multiple of `P`. A sample sent as m datagrams puts its
/// first (m − 1)·P above its last, a fraction 1/m of them; the percentile finds that for m up to
/// 5 and stays clear of a stall's backlog (a 100 ms stall per second is a tenth of the
/// datagrams). One datagram per sample: 0 (its jitter is under half a number).
fn spread_ns(datagrams: &VecDeque<(u64, u64)>, pace: f64) -> f64 {
    let Some(&(n0, a0)) = datagrams.front() else {
        return 0.0;
    };
    let above_line: Vec<f64> = datagrams
        .iter()
        .map(|&(n, a)| (a - a0) as f64 - (n - n0) as f64 * pace)
        .collect();
    let mut above_lowest: Vec<f64> = above_line
        .windows(PACE_SPAN + 1)
        .map(|w| w[PACE_SPAN] - w.iter().copied().fold(f64::INFINITY, f64::min))
        .collect();
    if above_lowest.is_empty() {
        return 0.0;
    }
    above_lowest.sort_by(f64::total_cmp);
    // Whole numbers of the pace: a sample's datagrams lie whole numbers above one another; what
    // is less than half a number is the delivery's jitter, which the line (the least delayed)
    // already leaves out.
    let spread = above_lowest[above_lowest.len() * 4 / 5];
    (spread / pace).round() * pace
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

    #[test]
    fn a_tracker_sending_each_sample_as_two_datagrams_is_dated_by_its_samples() {
        // SlimeVR's tracker emulator (and firmware that does not bundle): a rotation and an
        // acceleration datagram per 10 ms sample, 20 µs apart, numbers two per sample (5 ms per
        // number on average), arriving 0.3 ms after they were sent. From 2 s a stall, then its
        // 10 samples' 20 datagrams 0.1 ms apart, the last before the next sample's.
        let mut clock = PacketClock::default();
        let t0 = 1_700_000_000_000 * MS;
        let mut dates = Vec::new();
        for k in 0..300u64 {
            for (d, n) in [(0, 2 * k + 1), (20_000, 2 * k + 2)] {
                let sent = t0 + k * 10 * MS + d;
                let arrival = if (200..210).contains(&k) {
                    t0 + 2098 * MS + (n - 401) * MS / 10
                } else {
                    sent + 300_000
                };
                dates.push((n, sent, arrival, clock.date(n, arrival)));
            }
        }
        let pace = clock.pace.expect("measured");
        assert!((pace / (5.0 * MS as f64) - 1.0).abs() < 0.02, "{pace}");
        for &(n, sent, arrival, dated) in &dates[200..] {
            let error = dated as i64 - sent as i64;
            if arrival == sent + 300_000 {
                // On time: its send plus the least delay (0.3 ms), the rotation 20 µs after it
                // (its sample's acceleration's, on the line).
                assert!((300_000..=320_000).contains(&error), "{n}: {error}");
            } else if n % 2 == 1 {
                // The backlog's rotations (whose date a sample takes): back at their sends.
                assert!(error.abs() < 1_000_000, "{n}: {error} ns off");
            } else {
                // Its accelerations: at most a sample after, never after the arrival.
                assert!(
                    (0..11_000_000).contains(&error) && dated <= arrival,
                    "{n}: {error}"
                );
            }
        }
    }
}
