//! Which recorded frames are scored, and how two streams line up.
//!
//! Streams are paired by `header.seq` (every stage copies it from the source, so the frames of one
//! sensor sample share it across the graph). A frame is left out when its header carries any of
//! [`SKIPPED_FLAGS`] or its pose does not decode ([`Pose::from_wire`]); a pair is left out when
//! either side is. Sequence metrics (jitter, skating, travel) are computed per run of consecutive
//! seqs, never across a gap, so a dropped or skipped frame cannot fake a jump.

use std::collections::BTreeMap;
use std::ops::Range;

use imuflow_body::Pose;
use imuflow_graph::frames::{FrameHeader, MotionFrame, flags};

/// Header flags that keep a frame out of every score: INVALID (the producer does not trust the
/// payload), CALIBRATING (not yet a pose of the subject), END_OF_STREAM (no payload) and PRELUDE
/// (a truth frame of the calibration prelude a synthesizing source put before the clip: the scores
/// are the clip's, and a few seconds of standing per clip would dilute them).
pub const SKIPPED_FLAGS: u32 =
    flags::INVALID | flags::CALIBRATING | flags::END_OF_STREAM | flags::PRELUDE;

/// Whether a frame with this header is scored (none of [`SKIPPED_FLAGS`] set).
pub fn is_scored(header: &FrameHeader) -> bool {
    header.flags & SKIPPED_FLAGS == 0
}

/// A scored motion frame with its decoded pose.
pub(crate) struct Usable<'a> {
    pub seq: u64,
    pub pose: Pose,
    pub frame: &'a MotionFrame,
}

/// The scored frames of one stream by seq. A seq recorded twice keeps its last frame.
pub(crate) fn usable(frames: &[MotionFrame]) -> BTreeMap<u64, Usable<'_>> {
    frames
        .iter()
        .filter(|f| is_scored(&f.header))
        .filter_map(|frame| {
            let pose = Pose::from_wire(&frame.local_pose_wxyz, &frame.root_position_m).ok()?;
            Some((
                frame.header.seq,
                Usable {
                    seq: frame.header.seq,
                    pose,
                    frame,
                },
            ))
        })
        .collect()
}

/// The frames of `a` that have a scored partner of the same seq in `b`, in seq order.
pub(crate) fn pairs<'m, 'f>(
    a: &'m BTreeMap<u64, Usable<'f>>,
    b: &'m BTreeMap<u64, Usable<'f>>,
) -> Vec<(&'m Usable<'f>, &'m Usable<'f>)> {
    a.values()
        .filter_map(|x| b.get(&x.seq).map(|y| (x, y)))
        .collect()
}

/// Index ranges of the runs of consecutive seqs in an ascending list.
pub(crate) fn contiguous_runs(seqs: &[u64]) -> Vec<Range<usize>> {
    let mut runs = Vec::new();
    let mut start = 0;
    for i in 1..=seqs.len() {
        if i == seqs.len() || seqs[i] != seqs[i - 1] + 1 {
            if i > start {
                runs.push(start..i);
            }
            start = i;
        }
    }
    runs
}

/// A mean of per-run values weighted by the runs' frame counts (how `imuflow eval-physics`
/// combines sequences).
#[derive(Default)]
pub(crate) struct FrameWeighted {
    sum: f64,
    frames: usize,
}

impl FrameWeighted {
    pub fn add(&mut self, value: f64, frames: usize) {
        self.sum += value * frames as f64;
        self.frames += frames;
    }

    /// `None` when no run contributed.
    pub fn mean(&self) -> Option<f64> {
        (self.frames > 0).then(|| self.sum / self.frames as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_split_at_gaps() {
        assert_eq!(contiguous_runs(&[]), Vec::<Range<usize>>::new());
        assert_eq!(contiguous_runs(&[7]), vec![0..1]);
        assert_eq!(
            contiguous_runs(&[3, 4, 5, 9, 10, 12]),
            vec![0..3, 3..5, 5..6]
        );
    }

    #[test]
    fn flagged_and_undecodable_frames_are_not_usable() {
        let mut frames = vec![MotionFrame::default(); 5];
        for (k, f) in frames.iter_mut().enumerate() {
            f.header.seq = k as u64;
            f.local_pose_wxyz = [[1.0, 0.0, 0.0, 0.0]; 24];
        }
        frames[1].header.flags = flags::CALIBRATING;
        frames[2].local_pose_wxyz[5] = [0.0; 4];
        frames[4].header.flags = flags::PRELUDE;
        let kept: Vec<u64> = usable(&frames).keys().copied().collect();
        assert_eq!(kept, vec![0, 3]);
        assert!(!is_scored(&frames[1].header));
        assert!(!is_scored(&frames[4].header));
    }
}
