//! The dataset builder on copies of the committed Bandai Namco walking fixture (no external data).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use imuflow_body::{BodyModel, BodyParams};
use imuflow_dataset::{
    BuildOptions, DatasetError, FRAME_TENSORS, LICENCE, METADATA_KEY, OFFSETS_TENSOR,
    ShardMetadata, Split, SplitRule, build, fnv1a64, split_of,
};
use imuflow_motion::bvh::Bvh;
use imuflow_motion::retarget::{RetargetOptions, SourceSkeleton, resample, retarget_bvh};
use safetensors::{Dtype, SafeTensors};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../libs/motion/tests/fixtures/bandai-walk-normal-trimmed.bvh")
}

/// Frames of the fixture after retargeting and resampling to 60 Hz, computed with the body crate.
fn fixture_frames_at_60hz() -> usize {
    let bvh = Bvh::read(&fixture()).unwrap();
    let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
    let clip = retarget_bvh(
        &bvh,
        &SourceSkeleton::bandai_namco().unwrap(),
        &body,
        &RetargetOptions::default(),
    )
    .unwrap();
    resample(&clip, 60.0).unwrap().poses.len()
}

/// Chosen so that every split gets clips (hash mod 100: 57, 80, 2, 16, 28, 17, 98; the last one
/// is a held-out content, whatever its hash).
const GOOD: [&str; 8] = [
    "set-a/walk_01.bvh",
    "set-a/walk_02.bvh",
    "set-b/walk_03.bvh",
    "set-b/deep/walk_04.bvh",
    "walk_05.bvh",
    "walk_06.BVH",
    "set-b/walk_07.bvh",
    "x-bandai/dataset-1_kick_normal_001.bvh",
];

fn input_dir(names: &[&str]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    for name in names {
        let p = dir.path().join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::copy(fixture(), &p).unwrap();
    }
    // Not a clip: ignored.
    std::fs::create_dir_all(dir.path().join("set-a")).unwrap();
    std::fs::write(dir.path().join("set-a/walk_01.json"), "{}").unwrap();
    // A malformed clip: reported and skipped.
    std::fs::write(
        dir.path().join("broken.bvh"),
        "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n",
    )
    .unwrap();
    dir
}

fn options(input: &Path, out: &Path) -> BuildOptions {
    let mut o = BuildOptions::new(input, out);
    o.progress = false;
    o.seed = 7;
    o.max_shard_frames = 250; // a few sequences per shard: forces several shards
    o
}

fn split_json(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("split.json")).unwrap()).unwrap()
}

fn clips_by_split(v: &serde_json::Value) -> BTreeMap<String, String> {
    let mut m = BTreeMap::new();
    for s in Split::ALL {
        for c in v[s.name()].as_array().unwrap() {
            m.insert(c.as_str().unwrap().to_string(), s.name().to_string());
        }
    }
    m
}

/// A shard's `imuflow` metadata.
fn shard_metadata(bytes: &[u8]) -> ShardMetadata {
    let (_, metadata) = SafeTensors::read_metadata(bytes).unwrap();
    serde_json::from_str(&metadata.metadata().as_ref().unwrap()[METADATA_KEY]).unwrap()
}

/// A shard tensor's values (the builder writes every float tensor as little-endian f32).
fn f32_tensor(st: &SafeTensors, name: &str) -> Vec<f32> {
    st.tensor(name)
        .unwrap()
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect()
}

fn shard_files(out: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "safetensors"))
        .collect();
    v.sort();
    v
}

#[test]
fn builds_loadable_deterministic_shards_and_skips_bad_clips() {
    let frames = fixture_frames_at_60hz();
    assert!(frames > 48, "resampled to 60 Hz: {frames}");
    let input = input_dir(&GOOD);
    let out = tempfile::tempdir().unwrap();
    let summary = build(&options(input.path(), out.path())).unwrap();

    // Summary numbers add up.
    assert_eq!(summary.found, GOOD.len() + 1);
    assert_eq!(summary.skipped.len(), 1);
    assert_eq!(summary.skipped[0].clip, "broken.bvh");
    assert!(
        summary.skipped[0].error.contains("broken.bvh"),
        "{}",
        summary.skipped[0].error
    );
    assert!(summary.splits.iter().all(|s| s.clips > 0), "{summary:?}");
    let clips: usize = summary.splits.iter().map(|s| s.clips).sum();
    assert_eq!(clips, GOOD.len());
    for s in &summary.splits {
        assert_eq!(s.sequences, 2 * s.clips);
        assert_eq!(s.frames, s.sequences * frames);
        assert_eq!(s.motion_frames, s.clips * frames);
    }
    let shard_bytes: u64 = summary.shards.iter().map(|f| f.bytes).sum();
    let split_len = std::fs::metadata(out.path().join("split.json"))
        .unwrap()
        .len();
    assert_eq!(summary.output_bytes, shard_bytes + split_len);
    assert_eq!(
        summary.shards.len(),
        summary.splits.iter().map(|s| s.shards).sum::<usize>()
    );
    let table = summary.table();
    assert!(
        table.contains("total") && table.contains("skipped broken.bvh"),
        "{table}"
    );

    // The split file lists every written clip once, in the split of its hash.
    let v = split_json(out.path());
    let by_split = clips_by_split(&v);
    assert_eq!(by_split.len(), GOOD.len());
    for name in GOOD {
        assert_eq!(by_split[name], split_of(name).name(), "{name}");
    }
    assert_eq!(v["skipped"][0]["clip"], "broken.bvh");

    // Shards load back with the documented shapes and metadata.
    let files = shard_files(out.path());
    assert_eq!(files.len(), summary.shards.len());
    let mut total_frames = 0;
    let mut total_sequences = 0;
    for path in &files {
        let bytes = std::fs::read(path).unwrap();
        let st = SafeTensors::deserialize(&bytes).unwrap();
        let offsets = st.tensor(OFFSETS_TENSOR).unwrap();
        assert_eq!(offsets.dtype(), Dtype::I64);
        let offsets: Vec<i64> = offsets
            .data()
            .chunks_exact(8)
            .map(|b| i64::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let f = *offsets.last().unwrap() as usize;
        assert_eq!(offsets[0], 0);
        for w in offsets.windows(2) {
            assert_eq!((w[1] - w[0]) as usize, frames, "{}", path.display());
        }
        for (name, dims) in FRAME_TENSORS {
            let t = st.tensor(name).unwrap();
            assert_eq!(t.dtype(), Dtype::F32, "{name}");
            let mut shape = vec![f];
            shape.extend_from_slice(dims);
            assert_eq!(t.shape(), shape.as_slice(), "{name}");
        }
        let (_, header) = SafeTensors::read_metadata(&bytes).unwrap();
        let meta = header.metadata().as_ref().unwrap();
        let m: ShardMetadata = serde_json::from_str(&meta[METADATA_KEY]).unwrap();
        assert_eq!(m.fps, 60.0);
        assert_eq!(m.licence, LICENCE);
        assert_eq!(m.body_model.stature_m, 1.75);
        assert!(
            path.file_name()
                .unwrap()
                .to_str()
                .unwrap()
                .starts_with(&m.split)
        );
        assert_eq!(m.sequences.len() + 1, offsets.len());
        for s in &m.sequences {
            assert_eq!(s.frames, frames);
            assert_eq!(s.augmented, s.copy > 0);
            assert_eq!(s.seed.is_some(), s.augmented);
            assert_eq!(split_of(&s.clip).name(), m.split);
        }
        total_frames += f;
        total_sequences += m.sequences.len();

        // A clip's copies stay together: ideal, then augmented.
        for pair in m.sequences.chunks(2) {
            assert_eq!(pair.len(), 2);
            assert_eq!(pair[0].clip, pair[1].clip);
            assert_eq!((pair[0].copy, pair[1].copy), (0, 1));
        }
        // An ideal copy and its augmented copy share the motion, not the IMU signals.
        let floats = |name: &str| f32_tensor(&st, name);
        let (pose, ori) = (floats("pose_local"), floats("imu_orientation"));
        let (root, joints) = (floats("root_position"), floats("joint_position"));
        let (p, o) = (frames * 24 * 9, frames * 6 * 9);
        assert_eq!(pose[..p], pose[p..2 * p]);
        assert_ne!(ori[..o], ori[o..2 * o]);
        for k in 0..frames {
            // Ideal pelvis IMU (index 5) orientation = the root's global rotation (pose_local[0]).
            for e in 0..9 {
                assert!((ori[k * 54 + 5 * 9 + e] - pose[k * 216 + e]).abs() < 1e-6);
            }
            // root_position = joint_position of the root joint.
            for a in 0..3 {
                assert_eq!(root[k * 3 + a], joints[k * 72 + a]);
            }
        }
    }
    assert_eq!(
        total_frames,
        summary.splits.iter().map(|s| s.frames).sum::<usize>()
    );
    assert_eq!(
        total_sequences,
        summary.splits.iter().map(|s| s.sequences).sum::<usize>()
    );

    // Same input, same output (split and bytes).
    let out2 = tempfile::tempdir().unwrap();
    build(&options(input.path(), out2.path())).unwrap();
    assert_eq!(split_json(out.path()), split_json(out2.path()));
    let files2 = shard_files(out2.path());
    assert_eq!(files.len(), files2.len());
    for (a, b) in files.iter().zip(&files2) {
        let same = std::fs::read(a).unwrap() == std::fs::read(b).unwrap();
        assert!(same, "{} differs between runs", a.display());
    }

    // Adding clips moves no existing clip; rebuilding into the same directory replaces old shards.
    let more = ["set-c/run_01.bvh", "set-c/run_02.bvh", "z.bvh"];
    for name in more {
        let p = input.path().join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::copy(fixture(), &p).unwrap();
    }
    let summary3 = build(&options(input.path(), out2.path())).unwrap();
    let grown = clips_by_split(&split_json(out2.path()));
    assert_eq!(grown.len(), GOOD.len() + more.len());
    for (clip, split) in &by_split {
        assert_eq!(&grown[clip], split, "{clip} moved");
    }
    assert_eq!(shard_files(out2.path()).len(), summary3.shards.len());
}

#[test]
fn limit_takes_the_first_clips_in_sorted_order() {
    let input = input_dir(&GOOD);
    let out = tempfile::tempdir().unwrap();
    let mut o = options(input.path(), out.path());
    o.limit = Some(2);
    o.augment_copies = 0;
    let summary = build(&o).unwrap();
    assert_eq!(summary.found, 2);
    // Sorted keys: "broken.bvh" < "set-a/walk_01.bvh".
    assert_eq!(summary.skipped.len(), 1);
    let by_split = clips_by_split(&split_json(out.path()));
    assert_eq!(by_split.keys().collect::<Vec<_>>(), ["set-a/walk_01.bvh"]);
    for s in &summary.splits {
        assert_eq!(s.sequences, s.clips);
    }
}

#[test]
fn every_content_trains_on_the_held_out_contents_and_moves_no_other_clip() {
    // Three held-out-content clips besides the walks; under the protocol all three are holdout.
    let kicks = [
        "x-bandai/dataset-1_kick_normal_001.bvh",
        "x-bandai/dataset-1_bow_polite_002.bvh",
        "x-bandai/dataset-1_punch_angry_003.bvh",
    ];
    let names: Vec<&str> = GOOD.iter().copied().chain(kicks).collect();
    let input = input_dir(&names);
    let (protocol, every) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let mut o = options(input.path(), protocol.path());
    o.augment_copies = 0;
    build(&o).unwrap();
    o.out_dir = every.path().to_path_buf();
    o.split_rule = SplitRule::EveryContent;
    let summary = build(&o).unwrap();

    let before = clips_by_split(&split_json(protocol.path()));
    let v = split_json(every.path());
    let after = clips_by_split(&v);
    assert!(
        v["rule"].as_str().unwrap().starts_with("every content"),
        "{v}"
    );
    assert_eq!(summary.splits[Split::Holdout.index()].clips, 0);
    assert!(v["holdout"].as_array().unwrap().is_empty());
    for name in &names {
        let held_out = kicks.contains(name);
        assert_eq!(before[*name] == "holdout", held_out, "{name}");
        if held_out {
            // The hash alone decides, as for every other content (tools/dataset/README.md).
            let expected = match fnv1a64(name.as_bytes()) % 100 {
                0..80 => "train",
                80..90 => "validation",
                _ => "test",
            };
            assert_eq!(after[*name], expected, "{name}");
        } else {
            assert_eq!(after[*name], before[*name], "{name} moved");
        }
    }
}

#[test]
fn missing_input_and_all_failing_clips_are_errors() {
    let out = tempfile::tempdir().unwrap();
    let missing = out.path().join("no-such-dir");
    let e = build(&options(&missing, out.path())).unwrap_err();
    assert!(matches!(e, DatasetError::MissingInput { .. }));
    assert!(e.to_string().contains("no-such-dir"), "{e}");

    let empty = tempfile::tempdir().unwrap();
    let e = build(&options(empty.path(), out.path())).unwrap_err();
    assert!(matches!(e, DatasetError::NoClips { .. }), "{e}");

    let bad = input_dir(&[]);
    let e = build(&options(bad.path(), out.path())).unwrap_err();
    assert!(matches!(e, DatasetError::AllFailed { count: 1, .. }), "{e}");
    assert!(e.to_string().contains("broken.bvh"), "{e}");
}

#[test]
fn any_skeleton_builds_with_a_joint_mapping_and_gives_the_same_shards() {
    // The Bandai fixture with every joint renamed is another skeleton: the built-in mapping
    // cannot read it, the same mapping with the new names can, and the motion is the same.
    let renamed = std::fs::read_to_string(fixture())
        .unwrap()
        .lines()
        .map(|line| {
            let t = line.trim_start();
            match t.split_once(' ') {
                Some((kw @ ("ROOT" | "JOINT"), name)) => {
                    format!("{}{kw} mocap:{name}", &line[..line.len() - t.len()])
                }
                _ => line.to_owned(),
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let input = tempfile::tempdir().unwrap();
    std::fs::write(input.path().join("walk.bvh"), &renamed).unwrap();
    let original = input_dir(&["walk.bvh"]);
    std::fs::remove_file(original.path().join("broken.bvh")).unwrap();

    let out = tempfile::tempdir().unwrap();
    let err = build(&options(input.path(), out.path())).unwrap_err();
    assert!(matches!(err, DatasetError::AllFailed { .. }), "{err}");

    let mut section = "";
    let mapping_text = imuflow_motion::retarget::BANDAI_NAMCO_MAPPING_TOML
        .lines()
        .map(|line| {
            if line.starts_with('[') {
                section = line;
            }
            match line.split_once(" = \"") {
                Some((key, name)) if section == "[joints]" && !line.starts_with('#') => {
                    format!("{key} = \"mocap:{name}")
                }
                _ => line.replace("\"joint_Root\"", "\"mocap:joint_Root\""),
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let mapping = input.path().join("mocap.toml");
    std::fs::write(&mapping, mapping_text).unwrap();
    let mut o = options(input.path(), out.path());
    o.mapping = Some(mapping.clone());
    let mapped = build(&o).unwrap();
    assert_eq!(mapped.skipped.len(), 0);
    let reference_out = tempfile::tempdir().unwrap();
    build(&options(original.path(), reference_out.path())).unwrap();
    let names = |dir: &Path| {
        shard_files(dir)
            .iter()
            .map(|p| p.file_name().unwrap().to_owned())
            .collect::<Vec<_>>()
    };
    assert_eq!(names(out.path()), names(reference_out.path()));
    for (a, b) in shard_files(out.path())
        .iter()
        .zip(shard_files(reference_out.path()))
    {
        let (a, b) = (std::fs::read(a).unwrap(), std::fs::read(&b).unwrap());
        let (a, b) = (
            SafeTensors::deserialize(&a).unwrap(),
            SafeTensors::deserialize(&b).unwrap(),
        );
        for (name, _) in FRAME_TENSORS {
            assert_eq!(
                a.tensor(name).unwrap().data(),
                b.tensor(name).unwrap().data(),
                "{name}"
            );
        }
    }

    // A mapping that names a joint we do not have is refused with its file and line.
    std::fs::write(
        &mapping,
        "unit = \"cm\"\nup = \"y\"\n[joints]\ntail = \"Tail\"\n",
    )
    .unwrap();
    let err = build(&o).unwrap_err().to_string();
    assert!(err.contains("mocap.toml") && err.contains(":4"), "{err}");
}

#[test]
fn amass_npz_clips_build_like_the_same_motion_in_bvh() {
    // The fixture's motion, retargeted, written as an AMASS-style .npz at its 30 Hz (with
    // imuflow_motion::npz, which its own tests check against numpy's format), then built from
    // there: the same poses as the BVH build (the floor is re-aligned the same way).
    let bvh = Bvh::read(&fixture()).unwrap();
    let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
    let source = SourceSkeleton::bandai_namco().unwrap();
    let clip = retarget_bvh(&bvh, &source, &body, &RetargetOptions::default()).unwrap();
    let input = tempfile::tempdir().unwrap();
    let options_npz = imuflow_motion::npz::AmassOptions::default();
    imuflow_motion::npz::write_amass_npz(&input.path().join("walk.npz"), &clip, &options_npz)
        .unwrap();
    let out = tempfile::tempdir().unwrap();
    let summary = build(&options(input.path(), out.path())).unwrap();
    assert_eq!(summary.skipped.len(), 0, "{:?}", summary.skipped);
    assert_eq!(summary.found, 1);

    let reference = input_dir(&["walk.bvh"]);
    std::fs::remove_file(reference.path().join("broken.bvh")).unwrap();
    let reference_out = tempfile::tempdir().unwrap();
    build(&options(reference.path(), reference_out.path())).unwrap();
    let read = |dir: &Path| {
        let file = shard_files(dir).into_iter().next().unwrap();
        let bytes = std::fs::read(file).unwrap();
        let t = SafeTensors::deserialize(&bytes).unwrap();
        ["pose_local", "root_position"].map(|name| f32_tensor(&t, name))
    };
    let (npz, bvh) = (read(out.path()), read(reference_out.path()));
    for (name, (a, b)) in ["pose_local", "root_position"]
        .iter()
        .zip(npz.iter().zip(&bvh))
    {
        assert_eq!(a.len(), b.len(), "{name}");
        let worst = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(worst < 1e-4, "{name}: differs by {worst}");
    }
}

#[test]
fn motion_augmentations_add_training_sequences_only() {
    let input = input_dir(&GOOD);
    let (plain_out, augmented_out) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let plain = build(&options(input.path(), plain_out.path())).unwrap();
    let mut o = options(input.path(), augmented_out.path());
    o.mirror = true;
    o.speeds = vec![0.5, 2.0];
    let augmented = build(&o).unwrap();
    let frames = fixture_frames_at_60hz();
    for s in Split::ALL {
        let (p, a) = (&plain.splits[s.index()], &augmented.splits[s.index()]);
        assert_eq!(p.clips, a.clips, "{s}");
        if s == Split::Train {
            // Per clip: recorded + mirrored + two speeds, each ideal + one augmented copy.
            assert_eq!(a.sequences, 4 * p.sequences, "{s}");
            // Half speed lasts twice as long, double speed half (within a frame).
            let expected = 2 * (frames + frames + (2 * frames - 1) + frames.div_ceil(2));
            let per_clip = a.frames / a.clips;
            assert!(per_clip.abs_diff(expected) <= 4, "{per_clip} vs {expected}");
        } else {
            assert_eq!(p, a, "{s} must not change");
        }
    }
    // Each sequence says which motion it carries.
    let shard = shard_files(augmented_out.path())
        .into_iter()
        .find(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("train")
        })
        .unwrap();
    let bytes = std::fs::read(shard).unwrap();
    let meta = shard_metadata(&bytes);
    let motions: Vec<&str> = meta.sequences.iter().map(|s| s.motion.as_str()).collect();
    assert_eq!(
        &motions[..8],
        [
            "",
            "",
            "mirrored",
            "mirrored",
            "speed 0.5",
            "speed 0.5",
            "speed 2",
            "speed 2"
        ]
    );
}

/// Every training sequence of a build, in shard order: (clip, motion, root positions per frame).
fn training_root_paths(out: &Path) -> Vec<(String, String, Vec<[f32; 3]>)> {
    let mut sequences = Vec::new();
    for shard in shard_files(out) {
        let bytes = std::fs::read(&shard).unwrap();
        let meta = shard_metadata(&bytes);
        if meta.split != "train" {
            continue;
        }
        let st = SafeTensors::deserialize(&bytes).unwrap();
        let root = f32_tensor(&st, "root_position");
        let mut start = 0;
        for s in &meta.sequences {
            let path = (start..start + s.frames)
                .map(|k| [root[3 * k], root[3 * k + 1], root[3 * k + 2]])
                .collect();
            sequences.push((s.clip.clone(), s.motion.clone(), path));
            start += s.frames;
        }
    }
    sequences
}

#[test]
fn mirrored_augmentations_balance_the_sides_without_adding_sequences() {
    let input = input_dir(&GOOD);
    let (plain_out, balanced_out) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let mut o = options(input.path(), plain_out.path());
    o.mirror = true;
    o.speeds = vec![0.5, 0.8, 1.25, 2.0];
    o.perturb = true;
    let plain = build(&o).unwrap();
    o.out_dir = balanced_out.path().to_path_buf();
    o.mirror_augmentations = true;
    let balanced = build(&o).unwrap();
    for (a, b) in plain.splits.iter().zip(&balanced.splits) {
        // The bytes differ by the longer motion names in the metadata.
        let counts = |s: &imuflow_dataset::SplitSummary| (s.clips, s.sequences, s.frames, s.shards);
        assert_eq!(counts(a), counts(b), "the same sequences and frames");
    }

    let (before, after) = (
        training_root_paths(plain_out.path()),
        training_root_paths(balanced_out.path()),
    );
    assert_eq!(before.len(), after.len());
    let (mut turned, mut kept) = (0, 0);
    for ((clip_a, motion_a, path_a), (clip_b, motion_b, path_b)) in before.iter().zip(&after) {
        assert_eq!(clip_a, clip_b);
        assert_eq!(path_a.len(), path_b.len(), "{clip_a} {motion_a}");
        // The recorded motion and its mirror image stay as they were; another augmentation
        // either stays or enters as its mirror image (the root's x negated: S = diag(-1, 1, 1)).
        let mirrored = if motion_b == motion_a {
            false
        } else {
            assert!(
                !["", "mirrored"].contains(&motion_a.as_str()),
                "{clip_a}: {motion_a} became {motion_b}"
            );
            assert_eq!(*motion_b, format!("{motion_a}, mirrored"));
            true
        };
        for (a, b) in path_a.iter().zip(path_b) {
            let x = if mirrored { -a[0] } else { a[0] };
            assert!(
                (x - b[0]).abs() < 1e-5 && (a[1] - b[1]).abs() < 1e-5 && (a[2] - b[2]).abs() < 1e-5,
                "{clip_a} {motion_b}: {a:?} vs {b:?}"
            );
        }
        if !["", "mirrored"].contains(&motion_a.as_str()) {
            match mirrored {
                true => turned += 1,
                false => kept += 1,
            }
        }
    }
    // Five augmentations of each training clip, one seeded coin each: both sides must occur.
    assert!(turned > 0 && kept > 0, "{turned} turned, {kept} kept");
}

#[test]
fn recombined_upper_bodies_come_from_other_training_clips_only() {
    let input = input_dir(&GOOD);
    let (plain_out, mixed_out) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let plain = build(&options(input.path(), plain_out.path())).unwrap();
    let mut o = options(input.path(), mixed_out.path());
    o.recombine = true;
    let mixed = build(&o).unwrap();
    let train = &plain.splits[Split::Train.index()];
    assert!(train.clips >= 2, "the fixture set needs two training clips");
    for s in Split::ALL {
        let (p, m) = (&plain.splits[s.index()], &mixed.splits[s.index()]);
        if s == Split::Train {
            // Per clip: recorded + recombined, each ideal + one augmented copy.
            assert_eq!(m.sequences, 2 * p.sequences, "{s}");
        } else {
            assert_eq!(p, m, "{s} must not change");
        }
    }
    let split = split_json(mixed_out.path());
    let by_split = clips_by_split(&split);
    for shard in shard_files(mixed_out.path()) {
        let bytes = std::fs::read(&shard).unwrap();
        let meta = shard_metadata(&bytes);
        for seq in &meta.sequences {
            if let Some(partner) = seq.motion.strip_prefix("upper body of ") {
                assert_ne!(partner, seq.clip, "a clip is not its own partner");
                assert_eq!(
                    by_split.get(partner).map(String::as_str),
                    Some("train"),
                    "{partner} is a training clip"
                );
            }
        }
    }
}

#[test]
fn perturbed_and_standing_idle_motions_enter_training_only() {
    let input = input_dir(&GOOD);
    let (plain_out, more_out) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let plain = build(&options(input.path(), plain_out.path())).unwrap();
    let mut o = options(input.path(), more_out.path());
    o.perturb = true;
    o.standing_idle = true;
    let more = build(&o).unwrap();
    let mut labels: BTreeMap<String, Vec<(String, usize)>> = BTreeMap::new();
    for shard in shard_files(more_out.path()) {
        let bytes = std::fs::read(&shard).unwrap();
        let meta = shard_metadata(&bytes);
        for seq in &meta.sequences {
            labels
                .entry(seq.clip.clone())
                .or_default()
                .push((seq.motion.clone(), seq.frames));
        }
    }
    let by_split = clips_by_split(&split_json(more_out.path()));
    let idle_frames = (imuflow_motion::augment::STANDING_IDLE_S * 60.0) as usize;
    for (clip, motions) in &labels {
        let train = by_split.get(clip).map(String::as_str) == Some("train");
        let perturbed = motions.iter().filter(|(m, _)| m == "perturbed").count();
        // Ideal + one augmented copy of each motion.
        assert_eq!(perturbed, if train { 2 } else { 0 }, "{clip}");
        for (m, frames) in motions.iter().filter(|(m, _)| m == "standing idle") {
            assert!(train, "{clip}: {m} outside training");
            assert_eq!(*frames, idle_frames, "{clip}");
        }
    }
    for s in Split::ALL {
        let (p, m) = (&plain.splits[s.index()], &more.splits[s.index()]);
        if s == Split::Train {
            assert!(
                m.sequences >= 2 * p.sequences,
                "{s}: perturbed copies missing"
            );
        } else {
            assert_eq!(p, m, "{s} must not change");
        }
    }
}

#[test]
fn varied_statures_resize_augmented_training_copies_only() {
    let input = input_dir(&GOOD);
    let out = tempfile::tempdir().unwrap();
    let mut o = options(input.path(), out.path());
    o.max_shard_frames = 100_000; // one shard per split: sequences in order
    o.vary_stature = Some((1.5, 1.95));
    build(&o).unwrap();
    let by_split = clips_by_split(&split_json(out.path()));
    let mut resized = Vec::new();
    for shard in shard_files(out.path()) {
        let bytes = std::fs::read(&shard).unwrap();
        let st = SafeTensors::deserialize(&bytes).unwrap();
        let meta = shard_metadata(&bytes);
        let joints = f32_tensor(&st, "joint_position");
        let mut first = 0;
        let mut ideal_height = 0.0;
        for seq in &meta.sequences {
            let train = by_split.get(&seq.clip).map(String::as_str) == Some("train");
            // Head above the pelvis at the first frame (joint 15 against joint 0).
            let height = f64::from(joints[first * 72 + 15 * 3 + 1] - joints[first * 72 + 1]);
            match seq.stature_m {
                None => {
                    assert!(
                        !(train && seq.augmented),
                        "{}: an augmented training copy",
                        seq.clip
                    );
                    ideal_height = height;
                }
                Some(s) => {
                    assert!(
                        train && seq.augmented,
                        "{}: resized outside training",
                        seq.clip
                    );
                    assert!((1.5..=1.95).contains(&s), "{s}");
                    // The same pose on a body of stature s: every length in proportion.
                    let ratio = height / ideal_height;
                    assert!(
                        (ratio - s / 1.75).abs() < 1e-4,
                        "{ratio} against {}",
                        s / 1.75
                    );
                    resized.push(s);
                }
            }
            first += seq.frames;
        }
    }
    assert!(resized.len() >= 3, "{resized:?}");
    assert!(
        resized.windows(2).any(|w| w[0] != w[1]),
        "statures vary: {resized:?}"
    );
}

#[test]
fn a_sensor_set_builds_its_sites_and_the_ideal_copy_matches_the_six_sites_own() {
    let input = input_dir(&GOOD[..2]);
    let (six_out, legs_out) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    build(&options(input.path(), six_out.path())).unwrap();
    let mut legs = options(input.path(), legs_out.path());
    legs.sensors = imuflow_body::SensorSet::builtin("lower-body").unwrap();
    build(&legs).unwrap();
    let (six_files, legs_files) = (shard_files(six_out.path()), shard_files(legs_out.path()));
    assert_eq!(six_files.len(), legs_files.len());
    // The lower-body set's sites in slot order: left and right lower leg, pelvis, left and right
    // upper leg; the six's: forearms, lower legs, head, pelvis.
    let names = [
        "left_lower_leg",
        "right_lower_leg",
        "pelvis",
        "left_upper_leg",
        "right_upper_leg",
    ];
    for (six_path, legs_path) in six_files.iter().zip(&legs_files) {
        let (six_bytes, legs_bytes) = (
            std::fs::read(six_path).unwrap(),
            std::fs::read(legs_path).unwrap(),
        );
        let legs_meta = shard_metadata(&legs_bytes);
        assert_eq!(legs_meta.sensors, names);
        assert_eq!(shard_metadata(&six_bytes).sensors.len(), 6);
        let (six, legs) = (
            SafeTensors::deserialize(&six_bytes).unwrap(),
            SafeTensors::deserialize(&legs_bytes).unwrap(),
        );
        let frames = six.tensor("root_position").unwrap().shape()[0];
        assert_eq!(
            six.tensor("imu_orientation").unwrap().shape(),
            [frames, 6, 3, 3]
        );
        assert_eq!(
            legs.tensor("imu_orientation").unwrap().shape(),
            [frames, 5, 3, 3]
        );
        assert_eq!(
            legs.tensor("imu_free_accel").unwrap().shape(),
            [frames, 5, 3]
        );
        // The motion is the set's business not at all.
        assert_eq!(
            f32_tensor(&six, "pose_local"),
            f32_tensor(&legs, "pose_local")
        );
        // Ideal signals of a site do not depend on the set: the first sequence is the ideal copy;
        // the six's slots 2, 3, 5 (lower legs, pelvis) are the lower-body's 0, 1, 2.
        let first = legs_meta.sequences[0].frames;
        assert!(!legs_meta.sequences[0].augmented);
        let (o6, o5) = (
            f32_tensor(&six, "imu_orientation"),
            f32_tensor(&legs, "imu_orientation"),
        );
        let (a6, a5) = (
            f32_tensor(&six, "imu_free_accel"),
            f32_tensor(&legs, "imu_free_accel"),
        );
        for f in 0..first {
            for (k6, k5) in [(2, 0), (3, 1), (5, 2)] {
                assert_eq!(o6[(f * 6 + k6) * 9..][..9], o5[(f * 5 + k5) * 9..][..9]);
                assert_eq!(a6[(f * 6 + k6) * 3..][..3], a5[(f * 5 + k5) * 3..][..3]);
            }
        }
    }
}
