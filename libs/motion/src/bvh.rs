//! BVH (Biovision Hierarchy) reading and writing for any skeleton.
//!
//! Semantics (as in Blender's and most importers): a joint's rotation is the product of its rotation
//! channels in the listed order, R = R_c1·R_c2·R_c3 acting on column vectors (so `Zrotation Xrotation
//! Yrotation` means R = Rz·Rx·Ry); angles are in degrees. A joint's translation from its parent is its
//! OFFSET, except that components given by position channels replace the OFFSET's component. Values stay
//! in the file's units; [`crate::retarget`] converts units and axes.
//!
//! Parsing never panics: every malformed input gives a [`BvhError`] naming the file and line.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Rotation3, Vector3};

use imuflow_body::rotation::Axis;

/// Maximum joint nesting depth accepted (guards the recursive parser against hostile input; real
/// skeletons, fingers included, stay below 20).
const MAX_DEPTH: usize = 64;

/// One BVH channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    Xposition,
    Yposition,
    Zposition,
    Xrotation,
    Yrotation,
    Zrotation,
}

impl Channel {
    fn parse(token: &str) -> Option<Channel> {
        Some(match token {
            "Xposition" => Channel::Xposition,
            "Yposition" => Channel::Yposition,
            "Zposition" => Channel::Zposition,
            "Xrotation" => Channel::Xrotation,
            "Yrotation" => Channel::Yrotation,
            "Zrotation" => Channel::Zrotation,
            _ => return None,
        })
    }

    /// The channel's name as written in BVH files.
    pub fn name(self) -> &'static str {
        match self {
            Channel::Xposition => "Xposition",
            Channel::Yposition => "Yposition",
            Channel::Zposition => "Zposition",
            Channel::Xrotation => "Xrotation",
            Channel::Yrotation => "Yrotation",
            Channel::Zrotation => "Zrotation",
        }
    }

    /// Rotation axis for rotation channels.
    pub fn rotation_axis(self) -> Option<Axis> {
        match self {
            Channel::Xrotation => Some(Axis::X),
            Channel::Yrotation => Some(Axis::Y),
            Channel::Zrotation => Some(Axis::Z),
            _ => None,
        }
    }

    /// Component index (0 = x) for position channels.
    pub fn position_component(self) -> Option<usize> {
        match self {
            Channel::Xposition => Some(0),
            Channel::Yposition => Some(1),
            Channel::Zposition => Some(2),
            _ => None,
        }
    }
}

/// A joint of a BVH hierarchy.
#[derive(Clone, Debug, PartialEq)]
pub struct BvhJoint {
    /// Joint name as in the file.
    pub name: String,
    /// Index of the parent joint in [`Bvh::joints`]; `None` for a root.
    pub parent: Option<usize>,
    /// Rest offset from the parent joint (file units), in the parent's frame (= world axes at rest).
    pub offset: Vector3<f64>,
    /// Channels in file order.
    pub channels: Vec<Channel>,
    /// Offsets of `End Site` children (file units).
    pub end_sites: Vec<Vector3<f64>>,
    /// 1-based line of the joint's declaration.
    pub line: usize,
}

/// A parsed BVH file: hierarchy and motion.
#[derive(Clone, Debug, PartialEq)]
pub struct Bvh {
    /// The file's name, used in error messages.
    pub file: String,
    /// Joints in file order; every parent precedes its children.
    pub joints: Vec<BvhJoint>,
    /// Seconds between frames.
    pub frame_time_s: f64,
    /// Channel values, frame-major: frame f, channel c at `values[f * num_channels + c]`; angles in
    /// degrees, positions in file units.
    pub values: Vec<f64>,
    /// Index of each joint's first channel within a frame.
    channel_start: Vec<usize>,
    num_channels: usize,
    /// 1-based line of each frame (for error messages downstream).
    frame_lines: Vec<usize>,
}

/// A BVH parse failure, located in the file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}:{line}: {kind}")]
pub struct BvhError {
    /// File name as passed to the parser.
    pub file: String,
    /// 1-based line number of the offending token (the last line for a truncated file).
    pub line: usize,
    /// What is wrong.
    pub kind: BvhErrorKind,
}

/// What is wrong with a BVH file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BvhErrorKind {
    /// The file ends early (truncated). Fix: re-export or re-download the file.
    #[error("unexpected end of file, expected {expected}")]
    UnexpectedEof { expected: String },
    /// A keyword or brace is missing or misplaced.
    #[error("expected {expected}, found '{found}'")]
    Unexpected { expected: String, found: String },
    /// A token that should be a number is not.
    #[error("{field}: '{token}' is not a number")]
    InvalidNumber { field: String, token: String },
    /// A number is NaN or infinite.
    #[error("{field}: value '{token}' is not finite")]
    NonFinite { field: String, token: String },
    /// A `CHANNELS` count that is not an integer in 0..=6.
    #[error("joint '{joint}': channel count '{count}' must be an integer from 0 to 6")]
    ChannelCount { joint: String, count: String },
    /// Fewer channel names than declared, or an unknown channel name.
    #[error(
        "joint '{joint}': CHANNELS declares {declared} channels, but '{found}' is not a channel name"
    )]
    BadChannel {
        joint: String,
        declared: usize,
        found: String,
    },
    /// The same channel listed twice for one joint.
    #[error("joint '{joint}': channel {channel} listed twice")]
    DuplicateChannel {
        joint: String,
        channel: &'static str,
    },
    /// Two joints share a name (names must be unique for mapping).
    #[error("duplicate joint name '{joint}'")]
    DuplicateJoint { joint: String },
    /// A frame line holds the wrong number of values.
    #[error("frame {frame}: expected {expected} values (one per channel), found {found}")]
    FrameLength {
        frame: usize,
        expected: usize,
        found: usize,
    },
    /// The number of frame lines differs from `Frames:`.
    #[error("header declares {declared} frames but the file has {found}")]
    FrameCount { declared: usize, found: usize },
    /// `Frame Time` not positive.
    #[error("Frame Time must be a positive number of seconds (got {value})")]
    FrameTime { value: f64 },
    /// Joints nested deeper than the parser accepts.
    #[error("joints nested deeper than {max} levels")]
    TooDeep { max: usize },
}

/// Failure to read a BVH file from disk.
#[derive(Debug, thiserror::Error)]
pub enum BvhReadError {
    /// The file could not be read.
    #[error("cannot read BVH file '{file}': {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
    /// The file is malformed.
    #[error(transparent)]
    Parse(#[from] BvhError),
}

struct Tokens<'a> {
    file: &'a str,
    tokens: Vec<(&'a str, usize)>,
    pos: usize,
    last_line: usize,
}

impl<'a> Tokens<'a> {
    fn new(text: &'a str, file: &'a str) -> Tokens<'a> {
        let mut tokens = Vec::new();
        let mut last_line = 1;
        for (i, line) in text.lines().enumerate() {
            last_line = i + 1;
            for t in line.split_whitespace() {
                // Braces glued to other text ("{" at the end of "ROOT Hips{") become their own tokens.
                let mut rest = t;
                while !rest.is_empty() {
                    let cut = rest.find(['{', '}']).unwrap_or(rest.len());
                    if cut == 0 {
                        tokens.push((&rest[..1], i + 1));
                        rest = &rest[1..];
                    } else {
                        tokens.push((&rest[..cut], i + 1));
                        rest = &rest[cut..];
                    }
                }
            }
        }
        Tokens {
            file,
            tokens,
            pos: 0,
            last_line,
        }
    }

    fn err(&self, line: usize, kind: BvhErrorKind) -> BvhError {
        BvhError {
            file: self.file.to_owned(),
            line,
            kind,
        }
    }

    fn peek(&self) -> Option<(&'a str, usize)> {
        self.tokens.get(self.pos).copied()
    }

    fn next(&mut self, expected: &str) -> Result<(&'a str, usize), BvhError> {
        match self.tokens.get(self.pos).copied() {
            Some(t) => {
                self.pos += 1;
                Ok(t)
            }
            None => Err(self.err(
                self.last_line,
                BvhErrorKind::UnexpectedEof {
                    expected: expected.to_owned(),
                },
            )),
        }
    }

    fn expect(&mut self, keyword: &str) -> Result<usize, BvhError> {
        let (t, line) = self.next(&format!("'{keyword}'"))?;
        if t == keyword {
            Ok(line)
        } else {
            Err(self.err(
                line,
                BvhErrorKind::Unexpected {
                    expected: format!("'{keyword}'"),
                    found: t.to_owned(),
                },
            ))
        }
    }

    fn number(&mut self, field: &str) -> Result<f64, BvhError> {
        let (t, line) = self.next(field)?;
        parse_number(t, field).map_err(|kind| self.err(line, kind))
    }
}

fn parse_number(token: &str, field: &str) -> Result<f64, BvhErrorKind> {
    match token.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(BvhErrorKind::NonFinite {
            field: field.to_owned(),
            token: token.to_owned(),
        }),
        Err(_) => Err(BvhErrorKind::InvalidNumber {
            field: field.to_owned(),
            token: token.to_owned(),
        }),
    }
}

impl Bvh {
    /// Parse BVH text; `file` names the source in errors.
    pub fn parse(text: &str, file: &str) -> Result<Bvh, BvhError> {
        let mut tk = Tokens::new(text, file);
        tk.expect("HIERARCHY")?;
        let mut joints: Vec<BvhJoint> = Vec::new();
        loop {
            match tk.peek() {
                Some(("ROOT", _)) => {
                    tk.pos += 1;
                    parse_joint(&mut tk, &mut joints, None, 0)?;
                }
                Some(("MOTION", _)) if !joints.is_empty() => break,
                Some((t, line)) => {
                    let expected = if joints.is_empty() {
                        "'ROOT'"
                    } else {
                        "'ROOT' or 'MOTION'"
                    };
                    return Err(tk.err(
                        line,
                        BvhErrorKind::Unexpected {
                            expected: expected.to_owned(),
                            found: t.to_owned(),
                        },
                    ));
                }
                None => {
                    return Err(tk.err(
                        tk.last_line,
                        BvhErrorKind::UnexpectedEof {
                            expected: "'ROOT' or 'MOTION'".to_owned(),
                        },
                    ));
                }
            }
        }
        tk.expect("MOTION")?;
        tk.expect("Frames:")?;
        let (t, line) = tk.next("frame count")?;
        let declared: usize = t.parse().map_err(|_| {
            tk.err(
                line,
                BvhErrorKind::InvalidNumber {
                    field: "Frames".to_owned(),
                    token: t.to_owned(),
                },
            )
        })?;
        tk.expect("Frame")?;
        let line = tk.expect("Time:")?;
        let frame_time_s = tk.number("Frame Time")?;
        if frame_time_s <= 0.0 {
            return Err(tk.err(
                line,
                BvhErrorKind::FrameTime {
                    value: frame_time_s,
                },
            ));
        }

        let mut channel_start = Vec::with_capacity(joints.len());
        let mut num_channels = 0;
        for j in &joints {
            channel_start.push(num_channels);
            num_channels += j.channels.len();
        }

        // Frames: one per line, so a wrong count is caught on the line where it happens.
        // Capacity hints are capped: `Frames:` is untrusted input.
        let mut values = Vec::with_capacity(declared.saturating_mul(num_channels).min(1 << 22));
        let mut frame_lines = Vec::with_capacity(declared.min(1 << 16));
        let rest = &tk.tokens[tk.pos..];
        let mut i = 0;
        while i < rest.len() {
            let line = rest[i].1;
            let mut end = i;
            while end < rest.len() && rest[end].1 == line {
                end += 1;
            }
            let frame = frame_lines.len();
            if frame >= declared {
                return Err(tk.err(
                    line,
                    BvhErrorKind::FrameCount {
                        declared,
                        found: frame + 1,
                    },
                ));
            }
            if end - i != num_channels {
                return Err(tk.err(
                    line,
                    BvhErrorKind::FrameLength {
                        frame,
                        expected: num_channels,
                        found: end - i,
                    },
                ));
            }
            for (c, (t, _)) in rest[i..end].iter().enumerate() {
                let v = parse_number(t, "").map_err(|kind| {
                    let field = channel_field(&joints, &channel_start, frame, c);
                    tk.err(line, with_field(kind, field))
                })?;
                values.push(v);
            }
            frame_lines.push(line);
            i = end;
        }
        if frame_lines.len() != declared {
            return Err(tk.err(
                tk.last_line,
                BvhErrorKind::FrameCount {
                    declared,
                    found: frame_lines.len(),
                },
            ));
        }
        Ok(Bvh {
            file: file.to_owned(),
            joints,
            frame_time_s,
            values,
            channel_start,
            num_channels,
            frame_lines,
        })
    }

    /// Read and parse a BVH file.
    pub fn read(path: &Path) -> Result<Bvh, BvhReadError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| BvhReadError::Io {
            file: file.clone(),
            source,
        })?;
        Ok(Bvh::parse(&text, &file)?)
    }

    /// Build a BVH from parts (for export). Joints must be in depth-first order (each joint's parent is
    /// on the path from the root to the previous joint), as BVH nesting requires; `values` is frame-major
    /// with one value per channel. Returns `None` when either condition fails.
    pub fn from_parts(
        file: &str,
        joints: Vec<BvhJoint>,
        frame_time_s: f64,
        values: Vec<f64>,
    ) -> Option<Bvh> {
        let mut channel_start = Vec::with_capacity(joints.len());
        let mut num_channels = 0;
        let mut path: Vec<usize> = Vec::new();
        for (i, j) in joints.iter().enumerate() {
            while path.last().is_some_and(|&top| Some(top) != j.parent) {
                path.pop();
            }
            if j.parent.is_some() && path.is_empty() {
                return None;
            }
            path.push(i);
            channel_start.push(num_channels);
            num_channels += j.channels.len();
        }
        let frames = values.len().checked_div(num_channels)?;
        if !values.len().is_multiple_of(num_channels) {
            return None;
        }
        Some(Bvh {
            file: file.to_owned(),
            joints,
            frame_time_s,
            values,
            channel_start,
            num_channels,
            frame_lines: vec![0; frames],
        })
    }

    /// Number of channels per frame.
    pub fn num_channels(&self) -> usize {
        self.num_channels
    }

    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        self.values
            .len()
            .checked_div(self.num_channels)
            .unwrap_or(0)
    }

    /// Channel values of frame `f`, or `None` past the end.
    pub fn frame(&self, f: usize) -> Option<&[f64]> {
        let start = f.checked_mul(self.num_channels)?;
        self.values.get(start..start + self.num_channels)
    }

    /// 1-based line of frame `f` in the source file (0 for BVHs not read from text).
    pub fn frame_line(&self, f: usize) -> usize {
        self.frame_lines.get(f).copied().unwrap_or(0)
    }

    /// Index of the joint called `name`.
    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// Local rotation (parent_from_joint) and translation from the parent (file units) of `joint` in
    /// frame values `frame` (as returned by [`Bvh::frame`]).
    pub fn local_transform(&self, frame: &[f64], joint: usize) -> (Rotation3<f64>, Vector3<f64>) {
        let mut r = Rotation3::identity();
        let Some(j) = self.joints.get(joint) else {
            return (r, Vector3::zeros());
        };
        let mut t = j.offset;
        let start = self.channel_start.get(joint).copied().unwrap_or(0);
        for (k, ch) in j.channels.iter().enumerate() {
            let v = frame.get(start + k).copied().unwrap_or(0.0);
            if let Some(axis) = ch.rotation_axis() {
                r *= axis.rotation(v.to_radians());
            } else if let Some(c) = ch.position_component() {
                t[c] = v;
            }
        }
        (r, t)
    }

    /// World rotation and position (file units, file axes) of every joint for frame values `frame`.
    /// `rot` and `pos` must have `joints.len()` entries (extra entries are left alone).
    pub fn global_transforms(
        &self,
        frame: &[f64],
        rot: &mut [Rotation3<f64>],
        pos: &mut [Vector3<f64>],
    ) {
        for (i, j) in self.joints.iter().enumerate() {
            if i >= rot.len() || i >= pos.len() {
                return;
            }
            let (r, t) = self.local_transform(frame, i);
            match j.parent {
                Some(p) if p < i => {
                    rot[i] = rot[p] * r;
                    pos[i] = pos[p] + rot[p] * t;
                }
                _ => {
                    rot[i] = r;
                    pos[i] = t;
                }
            }
        }
    }

    /// Rest (all channels zero, offsets only) joint positions in file units and axes.
    pub fn rest_positions(&self) -> Vec<Vector3<f64>> {
        let mut p = vec![Vector3::zeros(); self.joints.len()];
        for (i, j) in self.joints.iter().enumerate() {
            p[i] = match j.parent {
                Some(q) if q < i => p[q] + j.offset,
                _ => j.offset,
            };
        }
        p
    }

    /// Serialize to BVH text. Numbers use Rust's shortest round-trip formatting, so parsing the output
    /// gives back exactly the same values.
    pub fn to_bvh_string(&self) -> String {
        let mut s = String::from("HIERARCHY\n");
        // Depth-first in file order: close braces when the next joint is not a descendant.
        let mut stack: Vec<usize> = Vec::new();
        for (i, j) in self.joints.iter().enumerate() {
            while let Some(&top) = stack.last() {
                if Some(top) == j.parent {
                    break;
                }
                close_joint(&mut s, &self.joints[top], stack.len() - 1);
                stack.pop();
            }
            let ind = "  ".repeat(stack.len());
            let kw = if j.parent.is_none() { "ROOT" } else { "JOINT" };
            let _ = writeln!(s, "{ind}{kw} {}", j.name);
            let _ = writeln!(s, "{ind}{{");
            let _ = writeln!(
                s,
                "{ind}  OFFSET {} {} {}",
                j.offset.x, j.offset.y, j.offset.z
            );
            let names: Vec<&str> = j.channels.iter().map(|c| c.name()).collect();
            let _ = writeln!(
                s,
                "{ind}  CHANNELS {} {}",
                j.channels.len(),
                names.join(" ")
            );
            stack.push(i);
        }
        while let Some(top) = stack.pop() {
            close_joint(&mut s, &self.joints[top], stack.len());
        }
        let _ = writeln!(
            s,
            "MOTION\nFrames: {}\nFrame Time: {}",
            self.num_frames(),
            self.frame_time_s
        );
        for f in 0..self.num_frames() {
            if let Some(vals) = self.frame(f) {
                let line: Vec<String> = vals.iter().map(|v| v.to_string()).collect();
                let _ = writeln!(s, "{}", line.join(" "));
            }
        }
        s
    }
}

fn close_joint(s: &mut String, j: &BvhJoint, depth: usize) {
    let ind = "  ".repeat(depth);
    for e in &j.end_sites {
        let _ = writeln!(
            s,
            "{ind}  End Site\n{ind}  {{\n{ind}    OFFSET {} {} {}\n{ind}  }}",
            e.x, e.y, e.z
        );
    }
    let _ = writeln!(s, "{ind}}}");
}

fn channel_field(joints: &[BvhJoint], starts: &[usize], frame: usize, c: usize) -> String {
    let j = starts.iter().rposition(|&s| s <= c).unwrap_or(0);
    let (name, ch) = joints
        .get(j)
        .and_then(|jt| {
            jt.channels
                .get(c - starts[j])
                .map(|ch| (jt.name.as_str(), ch.name()))
        })
        .unwrap_or(("?", "?"));
    format!("frame {frame}, joint '{name}' {ch}")
}

fn with_field(kind: BvhErrorKind, field: String) -> BvhErrorKind {
    match kind {
        BvhErrorKind::InvalidNumber { token, .. } => BvhErrorKind::InvalidNumber { field, token },
        BvhErrorKind::NonFinite { token, .. } => BvhErrorKind::NonFinite { field, token },
        other => other,
    }
}

fn parse_joint(
    tk: &mut Tokens<'_>,
    joints: &mut Vec<BvhJoint>,
    parent: Option<usize>,
    depth: usize,
) -> Result<(), BvhError> {
    let (name, line) = tk.next("joint name")?;
    if depth > MAX_DEPTH {
        return Err(tk.err(line, BvhErrorKind::TooDeep { max: MAX_DEPTH }));
    }
    if name == "{" || name == "}" {
        return Err(tk.err(
            line,
            BvhErrorKind::Unexpected {
                expected: "joint name".to_owned(),
                found: name.to_owned(),
            },
        ));
    }
    if joints.iter().any(|j| j.name == name) {
        return Err(tk.err(
            line,
            BvhErrorKind::DuplicateJoint {
                joint: name.to_owned(),
            },
        ));
    }
    tk.expect("{")?;
    tk.expect("OFFSET")?;
    let offset = read_vec3(tk, &format!("joint '{name}' OFFSET"))?;
    tk.expect("CHANNELS")?;
    let (count_tok, count_line) = tk.next("channel count")?;
    let count = match count_tok.parse::<usize>() {
        Ok(n) if n <= 6 => n,
        _ => {
            return Err(tk.err(
                count_line,
                BvhErrorKind::ChannelCount {
                    joint: name.to_owned(),
                    count: count_tok.to_owned(),
                },
            ));
        }
    };
    let mut channels = Vec::with_capacity(count);
    for _ in 0..count {
        let (t, l) = tk.next("channel name")?;
        let Some(ch) = Channel::parse(t) else {
            return Err(tk.err(
                l,
                BvhErrorKind::BadChannel {
                    joint: name.to_owned(),
                    declared: count,
                    found: t.to_owned(),
                },
            ));
        };
        if channels.contains(&ch) {
            return Err(tk.err(
                l,
                BvhErrorKind::DuplicateChannel {
                    joint: name.to_owned(),
                    channel: ch.name(),
                },
            ));
        }
        channels.push(ch);
    }
    let index = joints.len();
    joints.push(BvhJoint {
        name: name.to_owned(),
        parent,
        offset,
        channels,
        end_sites: Vec::new(),
        line,
    });
    loop {
        let (t, l) = tk.next("'JOINT', 'End Site' or '}'")?;
        match t {
            "JOINT" => parse_joint(tk, joints, Some(index), depth + 1)?,
            "End" => {
                tk.expect("Site")?;
                tk.expect("{")?;
                tk.expect("OFFSET")?;
                let e = read_vec3(tk, &format!("joint '{name}' End Site OFFSET"))?;
                tk.expect("}")?;
                joints[index].end_sites.push(e);
            }
            "}" => return Ok(()),
            other => {
                // A number here usually means CHANNELS declared fewer channels than listed.
                return Err(tk.err(
                    l,
                    BvhErrorKind::Unexpected {
                        expected: format!("'JOINT', 'End Site' or '}}' in joint '{name}'"),
                        found: other.to_owned(),
                    },
                ));
            }
        }
    }
}

fn read_vec3(tk: &mut Tokens<'_>, field: &str) -> Result<Vector3<f64>, BvhError> {
    let x = tk.number(&format!("{field} x"))?;
    let y = tk.number(&format!("{field} y"))?;
    let z = tk.number(&format!("{field} z"))?;
    Ok(Vector3::new(x, y, z))
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    const SMALL: &str = "HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Leg
  {
    OFFSET 10 0 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {
      OFFSET 0 -40 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
1 2 3 0 0 0 0 0 0
1 2 3 90 0 0 0 90 0
";

    #[test]
    fn parses_hierarchy_channels_and_frames() {
        let b = Bvh::parse(SMALL, "small.bvh").unwrap();
        assert_eq!(b.joints.len(), 2);
        assert_eq!(b.joints[1].parent, Some(0));
        assert_eq!(b.joints[1].line, 6);
        assert_eq!(b.joints[1].end_sites, vec![Vector3::new(0.0, -40.0, 0.0)]);
        assert_eq!(b.num_channels(), 9);
        assert_eq!(b.num_frames(), 2);
        assert_eq!(b.frame_line(1), 20);
        assert_relative_eq!(b.frame_time_s, 0.0333333);
    }

    #[test]
    fn global_transforms_follow_channel_order() {
        let b = Bvh::parse(SMALL, "small.bvh").unwrap();
        let mut rot = vec![Rotation3::identity(); 2];
        let mut pos = vec![Vector3::zeros(); 2];
        let f1 = b.frame(1).unwrap();
        b.global_transforms(f1, &mut rot, &mut pos);
        // Root: position channels replace the offset; Rz(90°) maps the leg offset x -> y.
        assert_relative_eq!(pos[0], Vector3::new(1.0, 2.0, 3.0), epsilon = 1e-12);
        assert_relative_eq!(pos[1], Vector3::new(1.0, 12.0, 3.0), epsilon = 1e-12);
        // Leg: Rz(90°)·Ry(90°) (Xrotation 0, Yrotation 90, Zrotation 0 in the leg's own order).
        // The End Site (0,−40,0): Ry leaves y; Rz(90°) maps −y to +x.
        let tip = pos[1] + rot[1] * Vector3::new(0.0, -40.0, 0.0);
        assert_relative_eq!(tip, Vector3::new(41.0, 12.0, 3.0), epsilon = 1e-9);
        // A ZXY order with only X non-zero equals a plain X rotation.
        let (r, _) = b.local_transform(&[0.0, 0.0, 0.0, 0.0, 30.0, 0.0, 0.0, 0.0, 0.0], 0);
        assert!(
            imuflow_body::rotation::angle_between(&r, &Axis::X.rotation(30f64.to_radians()))
                < 1e-12
        );
    }

    #[test]
    fn write_then_parse_is_the_identity() {
        let b = Bvh::parse(SMALL, "small.bvh").unwrap();
        let text = b.to_bvh_string();
        let c = Bvh::parse(&text, "again.bvh").unwrap();
        assert_eq!(b.joints.len(), c.joints.len());
        for (x, y) in b.joints.iter().zip(&c.joints) {
            assert_eq!(
                (&x.name, x.parent, x.offset, &x.channels, &x.end_sites),
                (&y.name, y.parent, y.offset, &y.channels, &y.end_sites)
            );
        }
        assert_eq!(b.values, c.values);
        assert_eq!(b.frame_time_s, c.frame_time_s);
    }

    /// Parse `text` and return the error, asserting it names the file and the expected line.
    fn error_at(text: &str, line: usize) -> BvhError {
        let e = Bvh::parse(text, "bad.bvh").expect_err("malformed input must fail");
        assert_eq!(e.line, line, "{e}");
        let msg = e.to_string();
        assert!(msg.starts_with(&format!("bad.bvh:{line}: ")), "{msg}");
        e
    }

    #[test]
    fn truncated_hierarchy_names_file_and_last_line() {
        let text: String = SMALL.lines().take(9).collect::<Vec<_>>().join("\n");
        let e = error_at(&text, 9);
        assert!(matches!(e.kind, BvhErrorKind::UnexpectedEof { .. }));
    }

    #[test]
    fn truncated_motion_reports_missing_frames() {
        let text: String = SMALL.lines().take(19).collect::<Vec<_>>().join("\n");
        let e = error_at(&text, 19);
        assert_eq!(
            e.kind,
            BvhErrorKind::FrameCount {
                declared: 2,
                found: 1
            }
        );
    }

    #[test]
    fn wrong_channel_count_is_reported_at_the_channel_line() {
        // Declares 4 channels but lists 3, so 'End' is read as a channel name.
        let text = SMALL.replace(
            "CHANNELS 3 Xrotation Yrotation Zrotation\n    End",
            "CHANNELS 4 Xrotation Yrotation Zrotation\n    End",
        );
        let e = error_at(&text, 10);
        assert!(
            matches!(&e.kind, BvhErrorKind::BadChannel { joint, declared: 4, found } if joint == "Leg" && found == "End"),
            "{e}"
        );
        // Declares 2 but lists 3: the extra name is left where a JOINT/End Site/'}' should be.
        let text = SMALL.replace("CHANNELS 3 Xrotation", "CHANNELS 2 Xrotation");
        let e = error_at(&text, 9);
        assert!(
            e.to_string().contains("Zrotation") && e.to_string().contains("Leg"),
            "{e}"
        );
        let text = SMALL.replace("CHANNELS 3", "CHANNELS 9");
        let e = error_at(&text, 9);
        assert!(matches!(e.kind, BvhErrorKind::ChannelCount { .. }));
        let text = SMALL.replace(
            "Xrotation Yrotation Zrotation",
            "Xrotation Xrotation Zrotation",
        );
        let e = error_at(&text, 9);
        assert!(matches!(e.kind, BvhErrorKind::DuplicateChannel { .. }));
    }

    #[test]
    fn frame_with_wrong_value_count_is_reported_at_its_line() {
        let text = SMALL.replace("1 2 3 90 0 0 0 90 0", "1 2 3 90 0 0 0 90");
        let e = error_at(&text, 20);
        assert_eq!(
            e.kind,
            BvhErrorKind::FrameLength {
                frame: 1,
                expected: 9,
                found: 8
            }
        );
    }

    #[test]
    fn nan_and_non_numeric_values_name_the_joint_and_channel() {
        let text = SMALL.replace("1 2 3 90 0 0 0 90 0", "1 2 3 90 0 0 0 NaN 0");
        let e = error_at(&text, 20);
        assert!(
            matches!(&e.kind, BvhErrorKind::NonFinite { field, .. } if field == "frame 1, joint 'Leg' Yrotation"),
            "{e}"
        );
        let text = SMALL.replace("1 2 3 90 0 0 0 90 0", "1 2 abc 90 0 0 0 90 0");
        let e = error_at(&text, 20);
        assert!(
            matches!(&e.kind, BvhErrorKind::InvalidNumber { field, token } if field == "frame 1, joint 'Hips' Zposition" && token == "abc"),
            "{e}"
        );
        let text = SMALL.replace("OFFSET 10 0 0", "OFFSET 10 x 0");
        let e = error_at(&text, 8);
        assert!(e.to_string().contains("joint 'Leg' OFFSET y"), "{e}");
        let text = SMALL.replace("OFFSET 0 -40 0", "OFFSET 0 inf 0");
        let e = error_at(&text, 12);
        assert!(matches!(e.kind, BvhErrorKind::NonFinite { .. }));
    }

    #[test]
    fn structural_errors_name_the_line() {
        let e = error_at(&SMALL.replace("HIERARCHY", "HIERARCHIE"), 1);
        assert!(matches!(e.kind, BvhErrorKind::Unexpected { .. }));
        let e = error_at(&SMALL.replace("JOINT Leg", "JOINT Hips"), 6);
        assert!(matches!(e.kind, BvhErrorKind::DuplicateJoint { .. }));
        let e = error_at(&SMALL.replace("Frame Time: 0.0333333", "Frame Time: 0"), 18);
        assert!(matches!(e.kind, BvhErrorKind::FrameTime { .. }));
        let e = error_at(&SMALL.replace("Frames: 2", "Frames: two"), 17);
        assert!(matches!(e.kind, BvhErrorKind::InvalidNumber { .. }));
        let e = error_at(&format!("{SMALL}1 2 3 0 0 0 0 0 0\n"), 21);
        assert_eq!(
            e.kind,
            BvhErrorKind::FrameCount {
                declared: 2,
                found: 3
            }
        );
        let e = error_at("", 1);
        assert!(matches!(e.kind, BvhErrorKind::UnexpectedEof { .. }));
        // Deep nesting is refused, not a stack overflow.
        let mut deep = String::from("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 0\n");
        for i in 0..600 {
            deep.push_str(&format!("JOINT j{i}\n{{\nOFFSET 0 0 0\nCHANNELS 0\n"));
        }
        let e = Bvh::parse(&deep, "deep.bvh").unwrap_err();
        assert!(matches!(e.kind, BvhErrorKind::TooDeep { .. }), "{e}");
    }

    #[test]
    fn missing_file_names_the_path() {
        let e = Bvh::read(Path::new("/nonexistent/x.bvh")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/x.bvh"));
    }
}
