//! How a stage waits for its next input: block while nothing is due, spin briefly around the
//! moment the next frame is expected.
//!
//! Waking a blocked process costs tens of microseconds per hop (kernel round trip and scheduling),
//! and spinning all the time costs a core per stage. Sources in imuflow graphs are periodic, so
//! each stage learns the interval between its arrivals and the phase of the stream, sleeps until
//! shortly before the next frame is due, then spins (yielding the CPU, so a producer sharing the
//! core still runs) until it arrives or a short tail has passed, then blocks on the wake-up event.
//!
//! The sleep before the spin is `std::thread::sleep` in slices of at most [`SLEEP_SLICE`],
//! checking the inputs between slices: iceoryx2's listener wakes promptly on a notification but
//! its timeouts have a granularity of about 8 ms (measured: `timed_wait(100 µs)` returns after
//! 8 ms), far too coarse to time a spin window. A frame that comes earlier than predicted is
//! therefore seen within one slice.

use std::time::{Duration, Instant};

use crate::transport::WakeListener;

/// Start spinning this long before the expected arrival: covers the jitter of a sleeping source's
/// wake-up and of the hops before this stage.
const SPIN_LEAD: Duration = Duration::from_micros(300);
/// Keep spinning this long after the expected arrival before blocking: a source paced by
/// `sleep` wakes up to a few hundred µs late, and the spin ends as soon as the frame arrives.
const SPIN_TAIL: Duration = Duration::from_micros(800);
/// A stage that warms its working set up ([`ArrivalWaiter::wait_warming`]) does it this long
/// before the expected frame: while the graph is idle (at 60 Hz the previous frame's work ended
/// milliseconds ago), not in the spin window, where it would take memory bandwidth and a core
/// from the stages upstream that are handling the frame.
const WARM_LEAD: Duration = Duration::from_micros(1500);
/// Without a prediction (first frames, irregular streams), spin this long before blocking.
const SHORT_SPIN: Duration = Duration::from_micros(20);
/// Gaps longer than this are pauses, not the stream's rhythm.
const MAX_INTERVAL: Duration = Duration::from_secs(1);
/// Weight of a new interval in the moving average.
const EWMA_WEIGHT: f64 = 0.125;
/// How far a late arrival moves the predicted phase: late frames are mostly jitter (a source
/// paced on an absolute schedule sends the next one on time), early ones reset the phase.
const LATE_PHASE_WEIGHT: f64 = 0.1;
/// How long before a deadline `sleep_until` stops sleeping and spins: about `sleep`'s overshoot.
const SLEEP_MARGIN: Duration = Duration::from_micros(100);
/// Longest sleep between checks of the inputs while waiting for the spin window.
const SLEEP_SLICE: Duration = Duration::from_millis(1);

/// What a waiter blocks on when nothing came in time: the stage's wake-up event.
pub trait Wake {
    /// Blocks until woken or `timeout` passes.
    fn wait(&self, timeout: Duration);
    /// Consumes pending wake-ups.
    fn drain(&self);
}

impl Wake for WakeListener {
    fn wait(&self, timeout: Duration) {
        WakeListener::wait(self, timeout);
    }

    fn drain(&self) {
        WakeListener::drain(self);
    }
}

/// Learns a stage's arrival rhythm and waits accordingly.
#[derive(Debug, Default)]
pub struct ArrivalWaiter {
    /// Where the stream's schedule put the last frame (phase reference).
    last_scheduled: Option<Instant>,
    interval_s: Option<f64>,
}

impl ArrivalWaiter {
    /// Records that a frame (or an aligned set of frames) arrived `now`.
    pub fn arrived(&mut self, now: Instant) {
        let scheduled = match self.expected() {
            Some(p) if now > p && now - p < MAX_INTERVAL => {
                p + (now - p).mul_f64(LATE_PHASE_WEIGHT)
            }
            _ => now,
        };
        // The interval is measured between scheduled times, so one late frame does not
        // stretch the rhythm either.
        if let Some(last) = self.last_scheduled {
            let dt = scheduled.saturating_duration_since(last);
            if dt < MAX_INTERVAL {
                let dt = dt.as_secs_f64();
                self.interval_s = Some(match self.interval_s {
                    Some(avg) => avg + EWMA_WEIGHT * (dt - avg),
                    None => dt,
                });
            }
        }
        self.last_scheduled = Some(scheduled);
    }

    /// When the next arrival is expected, if the stream has a rhythm.
    pub fn expected(&self) -> Option<Instant> {
        Some(self.last_scheduled? + Duration::from_secs_f64(self.interval_s?))
    }

    /// Waits until `ready()` holds, or at most about `poll` (the caller re-checks its inputs and
    /// its stop flag and calls again).
    pub fn wait(&self, listener: &impl Wake, poll: Duration, ready: impl FnMut() -> bool) {
        self.wait_warming(listener, poll, ready, &mut |_| {});
    }

    /// [`ArrivalWaiter::wait`] that calls `warm` once, [`WARM_LEAD`] before the expected frame:
    /// the stage brings its working set back into cache (a live stage idles for most of a frame
    /// period, and the other processes evict it meanwhile). `warm` gets `ready` to stop as soon
    /// as the frame comes.
    pub fn wait_warming(
        &self,
        listener: &impl Wake,
        poll: Duration,
        mut ready: impl FnMut() -> bool,
        warm: &mut dyn FnMut(&mut dyn FnMut() -> bool),
    ) {
        if ready() {
            listener.drain();
            return;
        }
        let now = Instant::now();
        let spin_until = match self.expected() {
            Some(expected) if expected + SPIN_TAIL > now => {
                let spin_from = expected.checked_sub(SPIN_LEAD).unwrap_or(expected);
                let warm_from = expected.checked_sub(WARM_LEAD).unwrap_or(expected);
                let mut warmed = false;
                // Nothing due yet: sleep in slices until the spin window, watching the inputs;
                // warm up on the way.
                loop {
                    let now = Instant::now();
                    if !warmed && now >= warm_from {
                        warm(&mut ready);
                        warmed = true;
                        continue;
                    }
                    if now >= spin_from {
                        break;
                    }
                    let until = if warmed {
                        spin_from
                    } else {
                        warm_from.min(spin_from)
                    };
                    std::thread::sleep(until.saturating_duration_since(now).min(SLEEP_SLICE));
                    if ready() {
                        listener.drain();
                        return;
                    }
                }
                expected + SPIN_TAIL
            }
            // Overdue or no rhythm yet: a short spin, then block on the wake-up event.
            _ => now + SHORT_SPIN,
        };
        while Instant::now() < spin_until {
            if ready() {
                listener.drain();
                return;
            }
            std::thread::yield_now();
        }
        if !ready() {
            listener.wait(poll);
        }
        listener.drain();
    }
}

/// Sleeps until `deadline` with a precision of a few microseconds: `std::thread::sleep` overshoots
/// by about 60-100 µs, so it sleeps until [`SLEEP_MARGIN`] before the deadline and spins (yielding)
/// the rest. Sources use it to pace a stream, so readers can predict the arrivals. The margin is
/// kept short because readers spin around the same moment and every spinner competes for the cores.
pub fn sleep_until(deadline: Instant) {
    let now = Instant::now();
    if let Some(early) = deadline.checked_sub(SLEEP_MARGIN)
        && early > now
    {
        std::thread::sleep(early - now);
    }
    while Instant::now() < deadline {
        std::thread::yield_now();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A wake-up event nobody signals.
    struct Silent;

    impl Wake for Silent {
        fn wait(&self, timeout: Duration) {
            std::thread::sleep(timeout);
        }
        fn drain(&self) {}
    }

    #[test]
    fn the_working_set_is_warmed_ahead_of_the_frame_and_outside_the_spin_window() {
        let mut w = ArrivalWaiter::default();
        let period = Duration::from_millis(10);
        let t0 = Instant::now();
        for k in 0..5u32 {
            w.arrived(t0 + period * k);
        }
        // The frame comes 3 ms late (room for a loaded machine's oversleeping); warm-ups are
        // timed.
        let expected = w.expected().expect("rhythm");
        let comes = expected + Duration::from_millis(3);
        let mut warmed = Vec::new();
        w.wait_warming(
            &Silent,
            Duration::from_millis(50),
            || Instant::now() >= comes,
            &mut |ready| {
                warmed.push(Instant::now());
                assert!(!ready(), "the frame is not there yet");
            },
        );
        assert!(Instant::now() >= comes);
        assert_eq!(warmed.len(), 1, "once per frame");
        // Not earlier than WARM_LEAD before the expected arrival (the graph is busy with the
        // previous frame before that), and before the frame.
        assert!(
            warmed[0] + WARM_LEAD >= expected,
            "{:?} early",
            expected - warmed[0]
        );
        assert!(warmed[0] < comes);
        // Without a rhythm (first frames) nothing is warmed: no prediction to warm before.
        let fresh = ArrivalWaiter::default();
        let mut calls = 0;
        let soon = Instant::now() + Duration::from_millis(2);
        fresh.wait_warming(
            &Silent,
            Duration::from_millis(5),
            || Instant::now() >= soon,
            &mut |_| calls += 1,
        );
        assert_eq!(calls, 0);
    }

    #[test]
    fn sleep_until_is_never_early() {
        for us in [0u64, 50, 400, 2000] {
            let deadline = Instant::now() + Duration::from_micros(us);
            sleep_until(deadline);
            assert!(Instant::now() >= deadline);
        }
    }

    #[test]
    fn learns_a_periodic_rhythm() {
        let mut w = ArrivalWaiter::default();
        let t0 = Instant::now();
        assert!(w.expected().is_none());
        for k in 0..20u32 {
            w.arrived(t0 + Duration::from_millis(10) * k);
        }
        let expected = w.expected().expect("periodic stream has a rhythm");
        let due = t0 + Duration::from_millis(200);
        let off = if expected > due {
            expected - due
        } else {
            due - expected
        };
        assert!(
            off < Duration::from_micros(10),
            "expected arrival off by {off:?}"
        );
    }

    #[test]
    fn pauses_do_not_become_the_rhythm() {
        let mut w = ArrivalWaiter::default();
        let t0 = Instant::now();
        w.arrived(t0);
        w.arrived(t0 + Duration::from_millis(5));
        w.arrived(t0 + Duration::from_secs(10));
        let expected = w.expected().expect("rhythm kept");
        assert_eq!(
            expected - (t0 + Duration::from_secs(10)),
            Duration::from_millis(5)
        );
    }

    #[test]
    fn a_late_frame_does_not_shift_the_schedule() {
        let mut w = ArrivalWaiter::default();
        let t0 = Instant::now();
        let period = Duration::from_millis(10);
        for k in 0..10u32 {
            w.arrived(t0 + period * k);
        }
        // Frame 10 is 2 ms late; frame 11 will come on schedule at t0 + 110 ms.
        w.arrived(t0 + period * 10 + Duration::from_millis(2));
        let expected = w.expected().expect("rhythm");
        let on_schedule = t0 + period * 11;
        let off = if expected > on_schedule {
            expected - on_schedule
        } else {
            on_schedule - expected
        };
        // Without the phase reference it would be predicted 2 ms late and missed by the spin.
        assert!(
            off < Duration::from_micros(300),
            "predicted {off:?} off schedule"
        );
    }
}
