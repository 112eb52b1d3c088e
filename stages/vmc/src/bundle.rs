//! One MotionFrame as one VMC bundle (protocol.vmc.info, "Marionette spec": the messages a
//! performer sends to a receiver).
//!
//! In order:
//! - `/VMC/Ext/Root/Pos ("root", 0, 0, 0, 0, 0, 0, 1)`: the avatar's root object stays at the
//!   origin, unturned (as SlimeVR's server sends it); the body moves through its Hips;
//! - `/VMC/Ext/Bone/Pos (name, p.x, p.y, p.z, q.x, q.y, q.z, q.w)` per bone of [`BONES`]:
//!   `Hips`: the root joint's world position and world rotation (the root object is the world);
//!   every other bone: its rest offset from its parent (`localPosition`) and its rotation
//!   relative to its parent (`localRotation`); all in Unity coordinates (`crate::convert`),
//!   quaternions normalized;
//! - `/VMC/Ext/OK (1)`: bone data is being sent;
//! - `/VMC/Ext/T (time)`: seconds since the first frame the stage received (capture times);
//! - with the stage's `capture_time` only, `/imuflow/CaptureTime (ns)`: the frame's
//!   `header.capture_ns` as a decimal string (live: ns since the Unix epoch on the host clock, the
//!   moment the pose describes), so a receiver can measure its latency from capture. VMC receivers
//!   ignore addresses they do not know.
//!
//! The bundle's time tag is 1 ("immediately", OSC 1.0): receivers apply it on arrival.

use imuflow_graph::frames::MotionFrame;
use rosc::{OscBundle, OscMessage, OscPacket, OscTime, OscType};

use crate::bones::{BONES, NUM_BONES};
use crate::convert::{unity_point, unity_rotation_wxyz};

/// OSC address of the root transform.
pub const ROOT_ADDRESS: &str = "/VMC/Ext/Root/Pos";
/// OSC address of a bone's local transform.
pub const BONE_ADDRESS: &str = "/VMC/Ext/Bone/Pos";
/// OSC address of the "bone data available" message.
pub const OK_ADDRESS: &str = "/VMC/Ext/OK";
/// OSC address of the sender's relative time.
pub const TIME_ADDRESS: &str = "/VMC/Ext/T";
/// OSC address of imuflow's capture time (the stage's `capture_time` parameter).
pub const CAPTURE_TIME_ADDRESS: &str = "/imuflow/CaptureTime";

/// OSC 1.0's "immediately" time tag.
const IMMEDIATELY: OscTime = OscTime {
    seconds: 0,
    fractional: 1,
};

/// A frame whose payload is no pose: what is wrong, naming the field.
#[derive(Debug, Clone, PartialEq)]
pub enum Unusable {
    /// A local rotation is no quaternion (zero, or not finite).
    Rotation { joint: usize, wxyz: [f32; 4] },
    /// The root position is not finite.
    Root([f32; 3]),
}

impl std::fmt::Display for Unusable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unusable::Rotation { joint, wxyz } => {
                write!(f, "local_pose_wxyz[{joint}] is not a rotation: {wxyz:?}")
            }
            Unusable::Root(p) => write!(f, "root_position_m is not finite: {p:?}"),
        }
    }
}

/// One bone's transform as VMC sends it (Unity coordinates): position, then rotation `[x, y, z, w]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoneTransform {
    pub position_m: [f32; 3],
    pub rotation_xyzw: [f32; 4],
}

/// The bones of `frame` in [`BONES`] order, in Unity coordinates. `offsets_m` are the bones'
/// rest offsets in Unity axes ([`crate::bones::unity_offsets_m`]).
pub fn bone_transforms(
    frame: &MotionFrame,
    offsets_m: &[[f32; 3]; NUM_BONES],
) -> Result<[BoneTransform; NUM_BONES], Unusable> {
    let root = frame.root_position_m;
    if !root.iter().all(|v| v.is_finite()) {
        return Err(Unusable::Root(root));
    }
    let mut out = [BoneTransform {
        position_m: [0.0; 3],
        rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
    }; NUM_BONES];
    for (k, (joint, _)) in BONES.iter().enumerate() {
        let j = joint.index();
        let q = normalized(frame.local_pose_wxyz[j]).ok_or(Unusable::Rotation {
            joint: j,
            wxyz: frame.local_pose_wxyz[j],
        })?;
        let [w, x, y, z] = unity_rotation_wxyz(q);
        out[k] = BoneTransform {
            position_m: if k == 0 {
                unity_point(root)
            } else {
                offsets_m[k]
            },
            rotation_xyzw: [x, y, z, w],
        };
    }
    Ok(out)
}

/// `q / |q|`, `None` when the norm is not a positive finite number.
fn normalized(q: [f32; 4]) -> Option<[f32; 4]> {
    let n = q.iter().map(|v| f64::from(*v).powi(2)).sum::<f64>().sqrt();
    (n.is_finite() && n > 1e-6).then(|| q.map(|v| (f64::from(v) / n) as f32))
}

/// The frame's VMC bundle: root, bones, OK, time (`time_s`: seconds since the first frame), and
/// with `capture_ns` the capture-time message last.
pub fn bundle(
    bones: &[BoneTransform; NUM_BONES],
    time_s: f32,
    capture_ns: Option<u64>,
) -> OscPacket {
    bundle_of(bones, &[true; NUM_BONES], time_s, capture_ns)
}

/// [`bundle`] with only the bones whose `sent` entry is true (a sensor set that does not observe
/// every joint: the avatar keeps its own pose for the others).
pub fn bundle_of(
    bones: &[BoneTransform; NUM_BONES],
    sent: &[bool; NUM_BONES],
    time_s: f32,
    capture_ns: Option<u64>,
) -> OscPacket {
    let identity = BoneTransform {
        position_m: [0.0; 3],
        rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
    };
    let mut content = Vec::with_capacity(NUM_BONES + 4);
    content.push(transform_message(ROOT_ADDRESS, "root", &identity));
    for (((_, name), bone), _) in BONES.iter().zip(bones).zip(sent).filter(|(_, s)| **s) {
        content.push(transform_message(BONE_ADDRESS, name, bone));
    }
    content.push(message(OK_ADDRESS, vec![OscType::Int(1)]));
    content.push(message(TIME_ADDRESS, vec![OscType::Float(time_s)]));
    if let Some(ns) = capture_ns {
        // A string: OSC 1.0 has no unsigned 64-bit type, and `h` (int64) is optional in 1.0.
        content.push(message(
            CAPTURE_TIME_ADDRESS,
            vec![OscType::String(ns.to_string())],
        ));
    }
    OscPacket::Bundle(OscBundle {
        timetag: IMMEDIATELY,
        content,
    })
}

/// `packet` as the bytes of one UDP datagram, written into `buffer` (cleared first).
pub fn encode(packet: &OscPacket, buffer: &mut Vec<u8>) {
    buffer.clear();
    // Writing into a Vec cannot fail (rosc's Output for Vec has an uninhabited error type).
    let Ok(_) = rosc::encoder::encode_into(packet, buffer);
}

fn transform_message(address: &str, name: &str, t: &BoneTransform) -> OscPacket {
    let mut args = Vec::with_capacity(8);
    args.push(OscType::String(name.to_owned()));
    args.extend(t.position_m.iter().map(|v| OscType::Float(*v)));
    args.extend(t.rotation_xyzw.iter().map(|v| OscType::Float(*v)));
    message(address, args)
}

fn message(address: &str, args: Vec<OscType>) -> OscPacket {
    OscPacket::Message(OscMessage {
        addr: address.to_owned(),
        args,
    })
}

#[cfg(test)]
mod tests {
    use bytemuck::Zeroable;
    use imuflow_body::{BodyModel, BodyParams};

    use super::*;
    use crate::bones::unity_offsets_m;

    fn offsets() -> [[f32; 3]; NUM_BONES] {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        unity_offsets_m(&body.skeleton)
    }

    /// A frame with every joint turned by its own quaternion and the root somewhere off-centre.
    fn frame() -> MotionFrame {
        let mut f = MotionFrame::zeroed();
        for (j, q) in f.local_pose_wxyz.iter_mut().enumerate() {
            let a = 0.05 * j as f32;
            let (s, c) = (a.sin(), a.cos());
            // Unit: an angle 2a about the axis (0.6, 0, 0.8) turned towards y with j.
            *q = [c, 0.6 * s, 0.0, 0.8 * s];
            if j % 3 == 0 {
                *q = [c, 0.0, s, 0.0];
            }
        }
        f.root_position_m = [0.25, 0.93, -1.5];
        f
    }

    fn decode(bytes: &[u8]) -> Vec<OscMessage> {
        let (rest, packet) = rosc::decoder::decode_udp(bytes).unwrap();
        assert!(rest.is_empty());
        let OscPacket::Bundle(b) = packet else {
            panic!("a bundle, not a message")
        };
        assert_eq!((b.timetag.seconds, b.timetag.fractional), (0, 1));
        b.content
            .into_iter()
            .map(|p| match p {
                OscPacket::Message(m) => m,
                OscPacket::Bundle(_) => panic!("no nested bundles"),
            })
            .collect()
    }

    /// Equal up to the rounding of normalizing an f32 quaternion.
    fn assert_close(a: &[f32], b: &[f32]) {
        assert_eq!(a.len(), b.len());
        let worst = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(worst < 1e-6, "{a:?} vs {b:?}");
    }

    fn floats(m: &OscMessage) -> Vec<f32> {
        m.args[1..]
            .iter()
            .map(|a| a.clone().float().expect("a float"))
            .collect()
    }

    #[test]
    fn the_bundle_decodes_to_root_bones_ok_and_time() {
        let f = frame();
        let bones = bone_transforms(&f, &offsets()).unwrap();
        let mut bytes = Vec::new();
        encode(&bundle(&bones, 2.5, None), &mut bytes);
        let messages = decode(&bytes);
        assert_eq!(messages.len(), 1 + 22 + 2);

        let root = &messages[0];
        assert_eq!(root.addr, "/VMC/Ext/Root/Pos");
        assert_eq!(root.args[0], OscType::String("root".into()));
        assert_eq!(floats(root), [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);

        let names: Vec<String> = messages[1..23]
            .iter()
            .map(|m| {
                assert_eq!(m.addr, "/VMC/Ext/Bone/Pos");
                assert_eq!(m.args.len(), 8);
                m.args[0].clone().string().unwrap()
            })
            .collect();
        assert_eq!(names, BONES.map(|(_, n)| n.to_owned()));

        // Hips: the root joint in world, (x, y, z) → (−x, y, z); rotation (w, x, y, z) →
        // (x, −y, −z, w) in VMC's order. Joint 0 turns by 0 here; take joint 3's to see signs.
        assert_close(
            &floats(&messages[1]),
            &[-0.25, 0.93, -1.5, 0.0, 0.0, 0.0, 1.0],
        );
        let spine = floats(&messages[4]);
        let (s, c) = (0.15f32.sin(), 0.15f32.cos());
        assert_close(&spine[3..], &[0.0, -s, 0.0, c]);
        // A bone: its rest offset, and its rotation with y and z negated.
        let left_knee = floats(&messages[5]);
        assert_eq!(&left_knee[..3], &offsets()[4]);
        let (s, c) = (0.2f32.sin(), 0.2f32.cos());
        assert_close(&left_knee[3..], &[0.6 * s, 0.0, -0.8 * s, c]);

        assert_eq!(messages[23].addr, "/VMC/Ext/OK");
        assert_eq!(messages[23].args, [OscType::Int(1)]);
        assert_eq!(messages[24].addr, "/VMC/Ext/T");
        assert_eq!(messages[24].args, [OscType::Float(2.5)]);
    }

    #[test]
    fn a_lower_body_sends_the_bones_it_observes() {
        let bones = bone_transforms(&frame(), &offsets()).unwrap();
        let legs = imuflow_body::SensorSet::builtin("lower-body").unwrap();
        let sent = BONES.map(|(j, _)| legs.observes(j));
        let mut bytes = Vec::new();
        encode(&bundle_of(&bones, &sent, 1.0, None), &mut bytes);
        let names: Vec<String> = decode(&bytes)
            .iter()
            .filter(|m| m.addr == BONE_ADDRESS)
            .map(|m| match &m.args[0] {
                OscType::String(s) => s.clone(),
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(
            names,
            [
                "Hips",
                "LeftUpperLeg",
                "RightUpperLeg",
                "LeftLowerLeg",
                "RightLowerLeg"
            ]
        );
    }

    #[test]
    fn rotations_are_sent_normalized() {
        let mut f = frame();
        f.local_pose_wxyz[18] = [0.0, 0.0, 0.0, 2.0];
        let bones = bone_transforms(&f, &offsets()).unwrap();
        assert_close(&bones[18].rotation_xyzw, &[0.0, 0.0, -1.0, 0.0]);
    }

    #[test]
    fn a_frame_that_is_no_pose_is_refused_naming_the_field() {
        let mut f = frame();
        f.local_pose_wxyz[7] = [0.0; 4];
        let err = bone_transforms(&f, &offsets()).unwrap_err();
        assert_eq!(
            err.to_string(),
            "local_pose_wxyz[7] is not a rotation: [0.0, 0.0, 0.0, 0.0]"
        );
        let mut f = frame();
        f.local_pose_wxyz[2][1] = f32::NAN;
        assert!(matches!(
            bone_transforms(&f, &offsets()),
            Err(Unusable::Rotation { joint: 2, .. })
        ));
        let mut f = frame();
        f.root_position_m[1] = f32::INFINITY;
        assert!(
            bone_transforms(&f, &offsets())
                .unwrap_err()
                .to_string()
                .starts_with("root_position_m is not finite")
        );
        // The hands are not sent, so what they hold does not matter.
        let mut f = frame();
        f.local_pose_wxyz[23] = [0.0; 4];
        assert!(bone_transforms(&f, &offsets()).is_ok());
    }

    /// OSC 1.0 sizes (strings null-terminated and padded to 4 bytes, each element prefixed by
    /// its 4-byte size): "#bundle" 8 + time tag 8; root 4 + 20 ("/VMC/Ext/Root/Pos") + 12
    /// (",sfffffff") + 8 ("root") + 28 (7 floats) = 72; per bone 4 + 20 + 12 + 28 = 64 plus its
    /// padded name (284 for the 22 names); OK 4 + 12 + 4 + 4 = 24; T 24.
    #[test]
    fn the_bundle_has_the_size_osc_gives_it() {
        let bones = bone_transforms(&frame(), &offsets()).unwrap();
        let mut bytes = Vec::new();
        encode(&bundle(&bones, 0.0, None), &mut bytes);
        let names: usize = BONES
            .iter()
            .map(|(_, n)| (n.len() + 1).div_ceil(4) * 4)
            .sum();
        assert_eq!(names, 284);
        assert_eq!(bytes.len(), 16 + 72 + 22 * 64 + names + 24 + 24);
        assert_eq!(bytes.len(), 1828);
        // With the capture time: 4 + 24 ("/imuflow/CaptureTime") + 4 (",s") + 20 (19 digits).
        encode(
            &bundle(&bones, 0.0, Some(1_767_225_600_123_456_789)),
            &mut bytes,
        );
        assert_eq!(bytes.len(), 1828 + 52);
    }

    #[test]
    fn the_capture_time_is_the_last_message_a_decimal_string_of_ns() {
        let bones = bone_transforms(&frame(), &offsets()).unwrap();
        let mut bytes = Vec::new();
        let ns = 1_767_225_600_123_456_789u64;
        encode(&bundle(&bones, 2.5, Some(ns)), &mut bytes);
        let messages = decode(&bytes);
        assert_eq!(messages.len(), 1 + 22 + 3);
        assert_eq!(messages[24].addr, "/VMC/Ext/T");
        let last = &messages[25];
        assert_eq!(last.addr, "/imuflow/CaptureTime");
        let [OscType::String(text)] = &last.args[..] else {
            panic!("{last:?}")
        };
        assert_eq!(text.parse::<u64>().unwrap(), ns);
        // u64::MAX still fits: 20 digits.
        encode(&bundle(&bones, 0.0, Some(u64::MAX)), &mut bytes);
        let messages = decode(&bytes);
        assert_eq!(
            messages[25].args,
            [OscType::String("18446744073709551615".into())]
        );
    }
}
