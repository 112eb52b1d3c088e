//! What a stage kind declares about itself: its ports and its parameters. The validator checks
//! graph files against these declarations; `imuflow stage --list` prints them.

use crate::frames::FrameType;

/// How a stage relates to the flow of frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Produces frames from outside the graph (files, sensors); has no inputs.
    Source,
    /// Reads frames and writes frames.
    Transform,
    /// Reads frames and writes none (files, viewers); nobody needs to read it.
    Sink,
}

/// One port of a stage kind.
#[derive(Debug, Clone, Copy)]
pub struct PortSpec {
    pub name: &'static str,
    pub frame: FrameType,
    /// For inputs: whether the graph must connect it.
    pub required: bool,
    pub doc: &'static str,
}

/// Which inputs a kind accepts.
#[derive(Debug, Clone, Copy)]
pub enum InputsSpec {
    /// Exactly these named ports.
    Fixed(&'static [PortSpec]),
    /// Any number of inputs, any names, any frame types (recorders, loggers).
    Any,
}

/// The type of a parameter value.
#[derive(Debug, Clone, Copy)]
pub enum ParamType {
    /// Any string.
    String,
    /// A file system path; relative paths are relative to the working directory.
    Path,
    Bool,
    /// An integer within the inclusive range.
    Int {
        min: i64,
        max: i64,
    },
    /// A finite float within the inclusive range.
    Float {
        min: f64,
        max: f64,
    },
    /// One of the listed strings.
    Choice(&'static [&'static str]),
}

impl ParamType {
    /// What a valid value looks like, for error messages.
    pub fn expected(&self) -> String {
        match self {
            ParamType::String => "a string".into(),
            ParamType::Path => "a path (string)".into(),
            ParamType::Bool => "true or false".into(),
            ParamType::Int { min, max } => format!("an integer in {min}..={max}"),
            ParamType::Float { min, max } => format!("a finite number in {min}..={max}"),
            ParamType::Choice(options) => format!("one of {}", options.join(", ")),
        }
    }

    /// Checks a value; `Err` says what is wrong.
    pub fn check(&self, value: &toml::Value) -> Result<(), String> {
        let ok = match (self, value) {
            (ParamType::String | ParamType::Path, toml::Value::String(_)) => true,
            (ParamType::Bool, toml::Value::Boolean(_)) => true,
            (ParamType::Int { min, max }, toml::Value::Integer(i)) => (*min..=*max).contains(i),
            (ParamType::Float { min, max }, toml::Value::Float(x)) => {
                x.is_finite() && *min <= *x && *x <= *max
            }
            (ParamType::Float { min, max }, toml::Value::Integer(i)) => {
                let x = *i as f64;
                *min <= x && x <= *max
            }
            (ParamType::Choice(options), toml::Value::String(s)) => options.contains(&s.as_str()),
            _ => false,
        };
        if ok {
            Ok(())
        } else {
            Err(format!("must be {} (got {value})", self.expected()))
        }
    }
}

/// One parameter of a stage kind.
#[derive(Debug, Clone, Copy)]
pub struct ParamSpec {
    pub name: &'static str,
    pub ty: ParamType,
    /// Whether the graph must set it.
    pub required: bool,
    /// The default as the user would write it (for `--help`-style listings), or "" for none.
    pub default: &'static str,
    pub doc: &'static str,
}

impl ParamSpec {
    /// An optional float parameter within `min..=max` (the common case for gains and sizes).
    pub const fn float(
        name: &'static str,
        min: f64,
        max: f64,
        default: &'static str,
        doc: &'static str,
    ) -> ParamSpec {
        ParamSpec {
            name,
            ty: ParamType::Float { min, max },
            required: false,
            default,
            doc,
        }
    }
}

/// Everything a built-in stage kind declares.
#[derive(Debug, Clone, Copy)]
pub struct StageSpec {
    /// The `kind` string in graph files.
    pub kind: &'static str,
    pub role: Role,
    pub summary: &'static str,
    pub inputs: InputsSpec,
    pub outputs: &'static [PortSpec],
    pub params: &'static [ParamSpec],
}

impl StageSpec {
    pub fn output(&self, name: &str) -> Option<&PortSpec> {
        self.outputs.iter().find(|p| p.name == name)
    }

    pub fn param(&self, name: &str) -> Option<&ParamSpec> {
        self.params.iter().find(|p| p.name == name)
    }
}

/// The stage kinds a launcher knows. The `imuflow` binary builds one from every built-in stage crate.
#[derive(Debug, Clone, Default)]
pub struct Registry {
    specs: Vec<StageSpec>,
}

impl Registry {
    pub fn new(specs: impl IntoIterator<Item = StageSpec>) -> Self {
        Self {
            specs: specs.into_iter().collect(),
        }
    }

    pub fn get(&self, kind: &str) -> Option<&StageSpec> {
        self.specs.iter().find(|s| s.kind == kind)
    }

    pub fn kinds(&self) -> impl Iterator<Item = &StageSpec> {
        self.specs.iter()
    }
}
