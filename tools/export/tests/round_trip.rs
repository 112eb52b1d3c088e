//! The round trip through the synthesizer: a recording's motion exported as npz
//! (`imuflow export --format npz`) and read by the imu-source stage's `synthesize` mode
//! (`imuflow_synth::Motion::load`, which takes a `.npz` as its motion) gives back, as the truth it
//! publishes, the motion that was exported: the same frames, poses within 1e-4 rad and 0.1 mm.

mod common;

use common::{sample, truth_after_prelude};

use imuflow_body::JointId;
use imuflow_body::rotation::{angle_between, rotation_from_quat_wxyz};
use imuflow_export::{ExportOptions, Format, export};
use imuflow_graph::frames::flags;
use imuflow_motion::retarget::LengthUnit;
use imuflow_synth::{Motion, Options};

fn rotation(q: &[f32; 4]) -> nalgebra::Rotation3<f64> {
    rotation_from_quat_wxyz(&q.map(f64::from)).expect("a rotation")
}

#[test]
fn the_synthesizer_reads_an_exported_npz_as_the_exported_motion() {
    let dir = tempfile::tempdir().expect("temp dir");
    let npz = dir.path().join("walk.npz");
    let done = export(&ExportOptions {
        input: sample(),
        channel: "source.truth".into(),
        format: Format::Npz,
        out: npz.clone(),
        unit: LengthUnit::Metre,
        keep_all: false,
        stature_m: 1.75,
        all_joints: false,
    })
    .expect("exports");
    let truth = truth_after_prelude();
    assert_eq!(done.frames, truth.len());

    // The stage's defaults: no prelude, the graph's 60 Hz (the rate the sample was recorded at).
    let motion = Motion::load(&npz, &Options::default(), 60.0).expect("the synthesizer reads it");
    assert_eq!(motion.prelude_frames, 0);
    assert_eq!(
        motion.len(),
        truth.len(),
        "one synthesized frame per exported frame"
    );
    let (mut worst_rad, mut worst_m) = (0.0f64, 0.0f64);
    for (seq, want) in truth.iter().enumerate() {
        let got = motion.truth_frame(seq).expect("a truth frame");
        assert_eq!(got.header.seq, seq as u64);
        assert_eq!(got.header.flags & flags::PRELUDE, 0);
        for j in JointId::all() {
            let i = j.index();
            let e = angle_between(
                &rotation(&want.local_pose_wxyz[i]),
                &rotation(&got.local_pose_wxyz[i]),
            );
            worst_rad = worst_rad.max(e);
        }
        let d = (0..3)
            .map(|i| f64::from(want.root_position_m[i] - got.root_position_m[i]).abs())
            .fold(0.0, f64::max);
        worst_m = worst_m.max(d);
    }
    assert!(
        worst_rad <= 1e-4,
        "a joint's rotation is {worst_rad} rad off"
    );
    assert!(worst_m <= 1e-4, "the root is {worst_m} m off");
}
