//! The `vmc` stage process: every MotionFrame on `motion` as one VMC bundle to `host:port`.

use anyhow::{Context, anyhow};
use imuflow_contact::subject::{MASS_PARAM, STATURE_PARAM, subject_body};
use imuflow_graph::frames::{MotionFrame, flags};
use imuflow_graph::params::StageParams;
use imuflow_graph::spec::{InputsSpec, PortSpec, Role, StageSpec};
use imuflow_graph::{FrameType, StageContext, Step};

use crate::bones::{BONES, NUM_BONES, unity_offsets_m};
use crate::bundle::{bone_transforms, bundle_of, encode};
use crate::sender::Sender;

imuflow_graph::stage_params! {
    /// The vmc stage's parameters.
    pub struct VmcParams {
        /// the receiver's host name or address (the avatar app's machine)
        host: String = "127.0.0.1", string;
        /// the receiver's UDP port (39539: the VMC protocol's usual performer-to-marionette port)
        port: u16 = 39539, int(1, 65535);
        /// send every n-th frame (by seq): 1 sends each one; 2 halves a 60 Hz stream to 30 Hz
        send_every: u64 = 1, int(1, 1000);
        stature_m: f64 = use STATURE_PARAM;
        /// append /imuflow/CaptureTime (the frame's capture_ns as a decimal string: live, ns since the Unix epoch) to every bundle, for latency measurements
        capture_time: bool = false, bool;
    }
}

pub const SPEC: StageSpec = StageSpec {
    kind: "vmc",
    role: Role::Sink,
    summary: "streams the motion to avatar apps (VSeeFace, Warudo, VMagicMirror, ...) over the VMC protocol: OSC bundles over UDP",
    inputs: InputsSpec::Fixed(&[PortSpec {
        name: "motion",
        frame: FrameType::Motion,
        required: true,
        doc: "the motion to send (an optimizer's estimate, or an imu-source's truth)",
    }]),
    outputs: &[],
    params: VmcParams::SPECS,
};

/// Runs the vmc stage as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let params =
        VmcParams::try_from_params(ctx.params()).map_err(|e| anyhow!("stage {stage}: {e}"))?;
    let body = subject_body(params.stature_m, MASS_PARAM.default)
        .with_context(|| format!("stage {stage}: the body model"))?;
    let mut sender = Sender::new(&stage, &params.host, params.port)?;
    let motion = ctx.input::<MotionFrame>("motion")?;
    if ctx.ready()? {
        let sensors = imuflow_body::SensorSet::resolve(ctx.sensors())
            .with_context(|| format!("stage {stage}: `sensors`"))?;
        let mut stream = Stream::new(&stage, unity_offsets_m(&body.skeleton), params.send_every)
            .with_capture_time(params.capture_time)
            .for_set(&sensors);
        while let Some(step) = ctx.next()? {
            let Some(datagram) = stream.frame(&step, ctx.get(&motion)) else {
                continue;
            };
            if sender.send(datagram) {
                ctx.count_out(1);
            }
        }
        ctx.set_summary_detail(stream.summary(&sender));
    }
    ctx.finish(&mut [])?;
    Ok(())
}

/// The frames' bundles and what became of each frame.
pub struct Stream {
    stage: String,
    offsets_m: [[f32; 3]; NUM_BONES],
    /// Which bones go out: every one for the six-site set (its networks estimate the whole
    /// body), the joints another set observes for it.
    sent: [bool; NUM_BONES],
    send_every: u64,
    /// Whether bundles carry `/imuflow/CaptureTime`.
    capture_time: bool,
    /// Capture time of the first frame: `/VMC/Ext/T` counts from it.
    first_capture_ns: Option<u64>,
    datagram: Vec<u8>,
    /// Frames that became a bundle.
    pub bundled: u64,
    /// Frames flagged INVALID or CALIBRATING: not sent, the receiver holds its last pose.
    pub flagged: u64,
    /// Frames whose payload is no pose (a zero or non-finite rotation or root): not sent.
    pub unusable: u64,
    /// Frames left out by `send_every`.
    pub thinned: u64,
}

impl Stream {
    pub fn new(stage: &str, offsets_m: [[f32; 3]; NUM_BONES], send_every: u64) -> Stream {
        Stream {
            stage: stage.to_owned(),
            offsets_m,
            sent: [true; NUM_BONES],
            send_every: send_every.max(1),
            capture_time: false,
            first_capture_ns: None,
            datagram: Vec::with_capacity(2048),
            bundled: 0,
            flagged: 0,
            unusable: 0,
            thinned: 0,
        }
    }

    /// Sends only the bones of the joints `set` observes, unless it is the six-site set (whose
    /// networks estimate every joint): the avatar keeps its own pose for the rest.
    pub fn for_set(mut self, set: &imuflow_body::SensorSet) -> Stream {
        if !set.is_six() {
            self.sent = BONES.map(|(j, _)| set.observes(j));
        }
        self
    }

    /// Bundles carry `/imuflow/CaptureTime` (the frame's `capture_ns`) when `on`.
    pub fn with_capture_time(mut self, on: bool) -> Stream {
        self.capture_time = on;
        self
    }

    /// The datagram to send for `frame`, if it is sent.
    pub fn frame(&mut self, step: &Step, frame: &MotionFrame) -> Option<&[u8]> {
        let first = *self.first_capture_ns.get_or_insert(step.capture_ns);
        if step.flags & (flags::INVALID | flags::CALIBRATING) != 0 {
            self.flagged += 1;
            return None;
        }
        if !step.seq.is_multiple_of(self.send_every) {
            self.thinned += 1;
            return None;
        }
        let bones = match bone_transforms(frame, &self.offsets_m) {
            Ok(bones) => bones,
            Err(why) => {
                if self.unusable == 0 {
                    tracing::warn!(
                        stage = self.stage,
                        seq = step.seq,
                        "motion frame not sent: {why} (counting such frames, this is the only warning)"
                    );
                }
                self.unusable += 1;
                return None;
            }
        };
        let time_s = (step.capture_ns.saturating_sub(first) as f64 * 1e-9) as f32;
        let capture_ns = self.capture_time.then_some(step.capture_ns);
        encode(
            &bundle_of(&bones, &self.sent, time_s, capture_ns),
            &mut self.datagram,
        );
        self.bundled += 1;
        Some(&self.datagram)
    }

    /// The stage's line in the run summary.
    pub fn summary(&self, sender: &Sender) -> String {
        let c = sender.counts();
        format!(
            "{} VMC bundles sent to {} ({} failed to send); not sent: {} flagged frames, {} unusable, {} by send_every",
            c.sent,
            sender.target(),
            c.failed,
            self.flagged,
            self.unusable,
            self.thinned
        )
    }
}

#[cfg(test)]
mod tests {
    use std::net::UdpSocket;
    use std::time::Duration;

    use bytemuck::Zeroable;
    use imuflow_body::{BodyModel, BodyParams};
    use rosc::{OscPacket, OscType};

    use super::*;

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<VmcParams>().unwrap();
    }

    fn stream(send_every: u64) -> Stream {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        Stream::new("vmc", unity_offsets_m(&body.skeleton), send_every)
    }

    fn pose() -> MotionFrame {
        let mut f = MotionFrame::zeroed();
        f.local_pose_wxyz = [[1.0, 0.0, 0.0, 0.0]; 24];
        f.root_position_m = [0.0, 0.9, 0.0];
        f
    }

    fn step(seq: u64, flags: u32) -> Step {
        Step {
            seq,
            capture_ns: 1_000_000_000 + seq * 16_666_667,
            flags,
        }
    }

    /// `/VMC/Ext/T` of a datagram.
    fn time_of(datagram: &[u8]) -> f32 {
        let (_, OscPacket::Bundle(b)) = rosc::decoder::decode_udp(datagram).unwrap() else {
            panic!("a bundle")
        };
        let Some(OscPacket::Message(m)) = b
            .content
            .iter()
            .find(|p| matches!(p, OscPacket::Message(m) if m.addr == "/VMC/Ext/T"))
        else {
            panic!("no /VMC/Ext/T")
        };
        let [OscType::Float(t)] = m.args[..] else {
            panic!("{m:?}")
        };
        t
    }

    #[test]
    fn flagged_frames_are_skipped_and_counted_and_time_counts_from_the_first_frame() {
        let mut s = stream(1);
        let f = pose();
        assert!(s.frame(&step(0, flags::CALIBRATING), &f).is_none());
        assert!(s.frame(&step(1, flags::INVALID), &f).is_none());
        assert!(
            s.frame(&step(2, flags::INVALID | flags::FEEDBACK_INITIAL), &f)
                .is_none()
        );
        // PRELUDE and RESTARTED frames carry a pose: sent.
        let t = time_of(s.frame(&step(3, flags::PRELUDE), &f).unwrap());
        assert!((t - 0.05).abs() < 1e-6, "{t}");
        let t = time_of(s.frame(&step(60, flags::RESTARTED), &f).unwrap());
        assert!((t - 1.0).abs() < 1e-6, "{t}");
        assert_eq!((s.bundled, s.flagged, s.unusable, s.thinned), (2, 3, 0, 0));
    }

    /// `/imuflow/CaptureTime` of a datagram, if it has one.
    fn capture_of(datagram: &[u8]) -> Option<u64> {
        let (_, OscPacket::Bundle(b)) = rosc::decoder::decode_udp(datagram).unwrap() else {
            panic!("a bundle")
        };
        b.content.iter().find_map(|p| match p {
            OscPacket::Message(m) if m.addr == "/imuflow/CaptureTime" => match &m.args[..] {
                [OscType::String(s)] => Some(s.parse().unwrap()),
                other => panic!("{other:?}"),
            },
            _ => None,
        })
    }

    #[test]
    fn capture_time_sends_each_frames_capture_ns_only_when_asked() {
        let f = pose();
        let mut plain = stream(1);
        assert_eq!(capture_of(plain.frame(&step(7, 0), &f).unwrap()), None);
        let mut s = stream(1).with_capture_time(true);
        assert!(s.frame(&step(0, flags::CALIBRATING), &f).is_none());
        for seq in [1, 2, 60] {
            let datagram = s.frame(&step(seq, 0), &f).unwrap();
            assert_eq!(capture_of(datagram), Some(step(seq, 0).capture_ns));
            // /VMC/Ext/T still counts from the first frame received.
            let t = time_of(datagram);
            assert!((t - seq as f32 / 60.0).abs() < 1e-5, "{t}");
        }
    }

    #[test]
    fn send_every_keeps_the_frames_whose_seq_it_divides() {
        let mut s = stream(3);
        let f = pose();
        let sent: Vec<u64> = (0..10)
            .filter(|&k| s.frame(&step(k, 0), &f).is_some())
            .collect();
        assert_eq!(sent, [0, 3, 6, 9]);
        assert_eq!((s.bundled, s.thinned), (4, 6));
    }

    #[test]
    fn a_frame_that_is_no_pose_is_counted_not_sent() {
        let mut s = stream(1);
        let mut f = pose();
        f.local_pose_wxyz[5] = [f32::NAN; 4];
        assert!(s.frame(&step(0, 0), &f).is_none());
        assert!(s.frame(&step(1, 0), &pose()).is_some());
        assert_eq!((s.bundled, s.unusable), (1, 1));
    }

    #[test]
    fn frames_reach_a_listening_socket_as_decodable_bundles() {
        let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
        rx.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut sender = Sender::new("vmc", "127.0.0.1", rx.local_addr().unwrap().port()).unwrap();
        let mut s = stream(1);
        for k in 0..5 {
            let datagram = s.frame(&step(k, 0), &pose()).unwrap();
            assert!(sender.send(datagram));
        }
        let mut buf = [0u8; 4096];
        for k in 0..5 {
            let n = rx.recv(&mut buf).unwrap();
            let t = time_of(&buf[..n]);
            assert!((t - k as f32 / 60.0).abs() < 1e-5, "{t}");
        }
        let line = s.summary(&sender);
        assert!(
            line.starts_with("5 VMC bundles sent to 127.0.0.1:"),
            "{line}"
        );
        assert!(line.contains("(0 failed to send)"), "{line}");
    }
}
