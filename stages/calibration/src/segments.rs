//! Calibration phases from the stream of per-frame stillness: a hold is a still run that lasted
//! long enough. Each hold is reported once, when it reaches that length, together with the previous
//! hold (if any), so the caller sees stand–motion–stand patterns: the motion is the gap between them.
//!
//! Frame indices are absolute (0 = the first frame seen); ranges are half-open.

use std::ops::Range;

/// A still run that just reached the hold length.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Hold {
    /// The run so far (it may go on).
    pub hold: Range<u64>,
    /// The hold before it, complete, if one ended since the last report.
    pub previous: Option<Range<u64>>,
}

impl Hold {
    /// Frames of motion between the previous hold and this one.
    pub fn motion_frames(&self) -> Option<u64> {
        self.previous.as_ref().map(|p| self.hold.start - p.end)
    }
}

/// Finds holds, one frame at a time.
#[derive(Debug)]
pub struct Segmenter {
    hold_frames: u64,
    /// First frame of the current still run.
    run_start: Option<u64>,
    /// The last still run that lasted at least the hold length and has ended.
    last_hold: Option<Range<u64>>,
}

impl Segmenter {
    /// `hold_frames`: how long a still run must last to count.
    pub fn new(hold_frames: u64) -> Segmenter {
        Segmenter {
            hold_frames: hold_frames.max(1),
            run_start: None,
            last_hold: None,
        }
    }

    /// Takes frame `index`'s stillness; `Some` when a hold reaches the hold length at this frame.
    pub fn push(&mut self, index: u64, still: bool) -> Option<Hold> {
        if !still {
            if let Some(start) = self.run_start.take()
                && index - start >= self.hold_frames
            {
                self.last_hold = Some(start..index);
            }
            return None;
        }
        let start = *self.run_start.get_or_insert(index);
        (index + 1 - start == self.hold_frames).then(|| Hold {
            hold: start..index + 1,
            previous: self.last_hold.take(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn feed(seg: &mut Segmenter, i: &mut u64, pattern: &[(bool, u64)]) -> Vec<(u64, Hold)> {
        let mut out = Vec::new();
        for &(still, n) in pattern {
            for _ in 0..n {
                if let Some(h) = seg.push(*i, still) {
                    out.push((*i, h));
                }
                *i += 1;
            }
        }
        out
    }

    #[test]
    fn stand_step_stand_is_reported_once_the_second_stand_is_long_enough() {
        let mut seg = Segmenter::new(10);
        let events = feed(&mut seg, &mut 0, &[(true, 15), (false, 20), (true, 12)]);
        assert_eq!(
            events,
            vec![
                (
                    9,
                    Hold {
                        hold: 0..10,
                        previous: None
                    }
                ),
                (
                    44,
                    Hold {
                        hold: 35..45,
                        previous: Some(0..15)
                    }
                ),
            ]
        );
        assert_eq!(events[1].1.motion_frames(), Some(20));
    }

    #[test]
    fn short_still_runs_are_not_holds() {
        let mut seg = Segmenter::new(10);
        let mut i = 0;
        // A 5-frame pause inside the motion is not a stand: the motion spans it.
        let events = feed(
            &mut seg,
            &mut i,
            &[(true, 10), (false, 10), (true, 5), (false, 25), (true, 10)],
        );
        assert_eq!(events.len(), 2);
        assert_eq!(events[1].1.motion_frames(), Some(40));
        // The previous hold is reported once; the next hold pairs with the one just seen.
        let more = feed(&mut seg, &mut i, &[(false, 3), (true, 10)]);
        assert_eq!(more[0].1.previous, Some(50..60));
    }
}
