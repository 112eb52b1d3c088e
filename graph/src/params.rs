//! A stage's parameters as a typed struct, declared once with [`stage_params!`]: each field's
//! name, Rust type, default, [`ParamType`] and doc comment give both the struct (with `Default`
//! and `from_params`) and the [`ParamSpec`]s the validator and `imuflow stage --list` read, so a
//! default is written once, as a literal, and its text in the spec is that literal.
//!
//! ```
//! imuflow_graph::stage_params! {
//!     /// The parameters of a stage.
//!     pub struct ExampleParams {
//!         /// how many frames to emit
//!         frames: u64 = 600, int(0, 1 << 40);
//!         /// gain of the filter
//!         gain: f64 = 1.5, float(0.0, 10.0);
//!         /// which filter
//!         filter: String = "median", choice(&["median", "mean"]);
//!         /// the file to write
//!         path: Option<std::path::PathBuf> = required, path;
//!         /// a calibration file to load (none: calibrate)
//!         from_file: Option<std::path::PathBuf>, path;
//!         /// pace the frames in real time
//!         realtime: Option<bool> = computed("false offline, true live"), bool;
//!     }
//! }
//!
//! let p = ExampleParams::default();
//! assert_eq!((p.frames, p.gain, p.filter.as_str()), (600, 1.5, "median"));
//! assert_eq!(ExampleParams::SPECS[1].default, "1.5");
//! let mut table = toml::Table::new();
//! table.insert("gain".into(), toml::Value::Integer(2));
//! assert_eq!(ExampleParams::from_params(&table).gain, 2.0);
//! ```
//!
//! A field is one of:
//! - `name: T = LITERAL, KIND;` a default stated by the literal; the spec's default text is the
//!   literal as written (`8` for a float stays "8", a string loses its quotes).
//! - `name: Option<T>, KIND;` optional without a default (`None` when the graph does not set it).
//! - `name: Option<T> = computed("TEXT"), KIND;` optional; the stage computes the default when it
//!   is `None` (from another parameter or the graph), and TEXT says how in the spec.
//! - `name: Option<T> = required, KIND;` the graph must set it; the validator guarantees `Some`.
//! - `name: T = use PARAM;` a [`Param`] defined once with [`param!`] elsewhere: shared by several
//!   stages, or by a stage and its library's own defaults. Its spec (doc included) is PARAM's.
//!
//! KIND is the [`ParamType`]: `float(min, max)`, `int(min, max)`, `bool`, `string`, `path` or
//! `choice(&NAMES)`. A literal outside its range or choices does not compile. T is anything serde
//! deserializes from the TOML value: numbers, `bool`, `String`, `PathBuf`, an enum whose serde
//! names are the choices. The struct derives `Debug`, `Clone` and `PartialEq`.

use serde::de::DeserializeOwned;

use crate::spec::{ParamSpec, ParamType};

/// The TOML crate the stage parameter tables are made of (for [`stage_params!`]'s expansion, so a
/// stage crate needs no dependency of its own).
pub use toml;

/// A parameter with its typed default, defined once with [`param!`] and used by several stages'
/// [`stage_params!`] (`name: T = use PARAM;`) or by a library's own defaults (`PARAM.default`).
#[derive(Debug, Clone, Copy)]
pub struct Param<T> {
    pub spec: ParamSpec,
    pub default: T,
}

/// A default as its literal states it, in the form [`ParamType::check`] and the TOML table share.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Literal {
    Float(f64),
    Int(i64),
    Bool(bool),
    Str(&'static str),
}

impl Literal {
    /// Whether the value passes `ty`'s check, at compile time (as [`ParamType::check`] would).
    pub const fn fits(&self, ty: &ParamType) -> bool {
        match (ty, self) {
            (ParamType::Float { min, max }, Literal::Float(x)) => {
                x.is_finite() && *min <= *x && *x <= *max
            }
            (ParamType::Int { min, max }, Literal::Int(i)) => *min <= *i && *i <= *max,
            (ParamType::Bool, Literal::Bool(_)) => true,
            (ParamType::String | ParamType::Path, Literal::Str(_)) => true,
            (ParamType::Choice(options), Literal::Str(s)) => {
                let mut k = 0;
                while k < options.len() {
                    if str_eq(options[k], s) {
                        return true;
                    }
                    k += 1;
                }
                false
            }
            _ => false,
        }
    }

    /// The value as a graph file would write it.
    pub fn to_toml(&self) -> toml::Value {
        match *self {
            Literal::Float(x) => toml::Value::Float(x),
            Literal::Int(i) => toml::Value::Integer(i),
            Literal::Bool(b) => toml::Value::Boolean(b),
            Literal::Str(s) => toml::Value::String(s.to_owned()),
        }
    }
}

/// What [`stage_params!`] implements besides the inherent `SPECS`, `from_params` and `Default`, for
/// code generic over stages (the default checks in tests).
pub trait StageParams: Default + std::fmt::Debug + PartialEq + Sized {
    /// The parameters' declarations, in field order (a `StageSpec`'s `params`).
    const SPECS: &'static [ParamSpec];

    /// The parameters from a stage's table, which the graph validator checked; a missing key, or a
    /// value that does not convert to its field's type, takes the default.
    fn from_params(table: &toml::Table) -> Self;

    /// Like `from_params`, but a value that does not convert to its field's type is an error
    /// naming the key.
    fn try_from_params(table: &toml::Table) -> Result<Self, String>;

    /// The defaults stated by literals or shared [`Param`]s, as a graph file would write them (the
    /// optional, computed and required parameters have none).
    fn stated_defaults() -> toml::Table;
}

/// `table[name]` as a `T`; `None` when missing, `Some(Err)` when it does not convert.
pub fn read<T: DeserializeOwned>(table: &toml::Table, name: &str) -> Option<Result<T, String>> {
    table.get(name).map(|value| {
        T::deserialize(value.clone()).map_err(|e| format!("params.{name} = {value}: {e}"))
    })
}

/// The default value `value` of parameter `name` as its field's type. A stated default always
/// converts (the stage's tests check it with [`check_defaults`]); one that does not is a bug in the
/// declaration.
#[doc(hidden)]
pub fn stated<T: DeserializeOwned>(value: toml::Value, name: &str) -> T {
    match T::deserialize(value.clone()) {
        Ok(v) => v,
        Err(e) => panic!(
            "stage_params!: the default {value} of `{name}` is not a value of its field's type: {e}"
        ),
    }
}

/// Byte-wise string equality, usable in constants.
pub const fn str_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut k = 0;
    while k < a.len() {
        if a[k] != b[k] {
            return false;
        }
        k += 1;
    }
    true
}

/// A spec's default text read back as the value a graph file would write: `None` where the text is
/// empty or does not read as its type (a computed default's description).
pub fn parse_default(spec: &ParamSpec) -> Option<toml::Value> {
    let text = spec.default;
    if text.is_empty() {
        return None;
    }
    match spec.ty {
        ParamType::Float { .. } => text.parse().ok().map(toml::Value::Float),
        ParamType::Int { .. } => text.parse().ok().map(toml::Value::Integer),
        ParamType::Bool => text.parse().ok().map(toml::Value::Boolean),
        ParamType::String | ParamType::Path | ParamType::Choice(_) => {
            Some(toml::Value::String(text.to_owned()))
        }
    }
}

/// Checks a stage's declaration, for its tests: every stated default's text reads back as the
/// stated value and passes [`ParamType::check`], the stated defaults read through `from_params`
/// give `Default`, a required parameter has no default text, and every choice of a choice
/// parameter converts to its field's type.
pub fn check_defaults<P: StageParams>() -> Result<(), String> {
    let stated = P::stated_defaults();
    for spec in P::SPECS {
        match stated.get(spec.name) {
            Some(value) => {
                let text = parse_default(spec);
                if text.as_ref() != Some(value) {
                    return Err(format!(
                        "{}: default text '{}' reads as {text:?}, the literal is {value}",
                        spec.name, spec.default
                    ));
                }
                spec.ty
                    .check(value)
                    .map_err(|e| format!("{}: default {e}", spec.name))?;
            }
            None if spec.required && !spec.default.is_empty() => {
                return Err(format!("{}: required, yet has a default text", spec.name));
            }
            None => {}
        }
        if let ParamType::Choice(options) = spec.ty {
            for option in options {
                let mut table = toml::Table::new();
                table.insert(spec.name.into(), toml::Value::String((*option).into()));
                P::try_from_params(&table)
                    .map_err(|e| format!("{}: choice '{option}': {e}", spec.name))?;
            }
        }
    }
    let read = P::try_from_params(&stated)?;
    if read != P::default() {
        return Err(format!(
            "the stated defaults read as {read:?}, Default is {:?}",
            P::default()
        ));
    }
    Ok(())
}

/// One parameter with its typed default, for a [`Param`] constant (see the module docs for KIND):
///
/// ```
/// use imuflow_graph::params::Param;
///
/// pub const STATURE_PARAM: Param<f64> = imuflow_graph::param! {
///     /// subject stature (m): scales the body model
///     stature_m: f64 = 1.75, float(1.0, 2.5)
/// };
/// assert_eq!(STATURE_PARAM.default, 1.75);
/// assert_eq!(STATURE_PARAM.spec.default, "1.75");
/// ```
///
/// The default's type is `f64` or another number type for `float` and `int`, `bool`, and
/// `&'static str` for `string`, `path` and `choice`.
#[macro_export]
macro_rules! param {
    (
        $(#[doc = $doc:literal])*
        $name:ident : $ty:ty = $lit:literal , $kind:ident $(( $($arg:expr),* $(,)? ))? $(;)?
    ) => {{
        let spec = $crate::spec::ParamSpec {
            name: stringify!($name),
            ty: $crate::__param_kind!(ty $kind $(($($arg),*))?),
            required: false,
            default: $crate::__param_kind!(text $kind $lit),
            doc: concat!($($doc),*).trim_ascii_start(),
        };
        assert!(
            $crate::__param_kind!(literal $kind $lit).fits(&spec.ty),
            concat!("the default of `", stringify!($name), "` is outside its range or choices")
        );
        $crate::params::Param {
            spec,
            default: $crate::__param_kind!(typed $kind $lit $ty),
        }
    }};
}

/// A stage's parameters as a struct with `pub` fields, `Default`, `SPECS` and `from_params` (see
/// the module docs, [`crate::params`], for the field forms).
///
/// A default outside its range does not compile:
///
/// ```compile_fail
/// imuflow_graph::stage_params! {
///     struct Gains {
///         /// gain
///         gain: f64 = 11, float(0.0, 10.0);
///     }
/// }
/// ```
///
/// nor does one outside its choices:
///
/// ```compile_fail
/// imuflow_graph::stage_params! {
///     struct Filters {
///         /// which filter
///         filter: String = "mode", choice(&["median", "mean"]);
///     }
/// }
/// ```
#[macro_export]
macro_rules! stage_params {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident { $($fields:tt)* }
    ) => {
        $crate::stage_params!(@munch [$(#[$meta])* $vis struct $name] [] $($fields)*);
    };

    // A field's ParamSpec: its name, kind, docs, whether required, and the default as stated.
    (@spec $field:ident [$($doc:literal)*] $kind:ident $(( $($arg:expr),* ))?,
        required: $required:expr, default: $text:expr
    ) => {
        $crate::spec::ParamSpec {
            name: stringify!($field),
            ty: $crate::__param_kind!(ty $kind $(($($arg),*))?),
            required: $required,
            default: $text,
            doc: concat!($($doc),*).trim_ascii_start(),
        }
    };

    // `name: T = use PARAM;`
    (@munch $head:tt [$($acc:tt)*]
        $(#[doc = $doc:literal])* $field:ident : $ty:ty = use $param:path ; $($rest:tt)*
    ) => {
        $crate::stage_params!(@munch $head [$($acc)* {
            [$($doc)*] $field : $ty,
            spec: $param.spec,
            check: $crate::params::str_eq($param.spec.name, stringify!($field)),
            why: "the shared parameter has another name",
            stated: ::core::option::Option::Some($crate::params::toml::Value::from($param.default)),
            default: $crate::params::stated::<$ty>(
                $crate::params::toml::Value::from($param.default),
                stringify!($field),
            ),
        }] $($rest)*);
    };

    // `name: Option<T> = required, KIND;`
    (@munch $head:tt [$($acc:tt)*]
        $(#[doc = $doc:literal])* $field:ident : $ty:ty = required ,
        $kind:ident $(( $($arg:expr),* $(,)? ))? ; $($rest:tt)*
    ) => {
        $crate::stage_params!(@munch $head [$($acc)* {
            [$($doc)*] $field : $ty,
            spec: $crate::stage_params!(@spec $field [$($doc)*] $kind $(($($arg),*))?,
                required: true, default: ""),
            check: true,
            why: "",
            stated: ::core::option::Option::None,
            default: ::core::option::Option::None,
        }] $($rest)*);
    };

    // `name: Option<T> = computed("TEXT"), KIND;`
    (@munch $head:tt [$($acc:tt)*]
        $(#[doc = $doc:literal])* $field:ident : $ty:ty = computed($text:literal) ,
        $kind:ident $(( $($arg:expr),* $(,)? ))? ; $($rest:tt)*
    ) => {
        $crate::stage_params!(@munch $head [$($acc)* {
            [$($doc)*] $field : $ty,
            spec: $crate::stage_params!(@spec $field [$($doc)*] $kind $(($($arg),*))?,
                required: false, default: $text),
            check: !$crate::params::str_eq($text, ""),
            why: "the computed default has no text",
            stated: ::core::option::Option::None,
            default: ::core::option::Option::None,
        }] $($rest)*);
    };

    // `name: T = LITERAL, KIND;`
    (@munch $head:tt [$($acc:tt)*]
        $(#[doc = $doc:literal])* $field:ident : $ty:ty = $lit:literal ,
        $kind:ident $(( $($arg:expr),* $(,)? ))? ; $($rest:tt)*
    ) => {
        $crate::stage_params!(@munch $head [$($acc)* {
            [$($doc)*] $field : $ty,
            spec: $crate::stage_params!(@spec $field [$($doc)*] $kind $(($($arg),*))?,
                required: false, default: $crate::__param_kind!(text $kind $lit)),
            check: $crate::__param_kind!(literal $kind $lit)
                .fits(&$crate::__param_kind!(ty $kind $(($($arg),*))?)),
            why: "the default is outside its range or choices",
            stated: ::core::option::Option::Some(
                $crate::__param_kind!(literal $kind $lit).to_toml()
            ),
            default: $crate::params::stated::<$ty>(
                $crate::__param_kind!(literal $kind $lit).to_toml(),
                stringify!($field),
            ),
        }] $($rest)*);
    };

    // `name: Option<T>, KIND;`
    (@munch $head:tt [$($acc:tt)*]
        $(#[doc = $doc:literal])* $field:ident : $ty:ty ,
        $kind:ident $(( $($arg:expr),* $(,)? ))? ; $($rest:tt)*
    ) => {
        $crate::stage_params!(@munch $head [$($acc)* {
            [$($doc)*] $field : $ty,
            spec: $crate::stage_params!(@spec $field [$($doc)*] $kind $(($($arg),*))?,
                required: false, default: ""),
            check: true,
            why: "",
            stated: ::core::option::Option::None,
            default: ::core::option::Option::None,
        }] $($rest)*);
    };

    // Every field read: the struct and its impls.
    (@munch [$(#[$meta:meta])* $vis:vis struct $name:ident] [$({
        [$($doc:literal)*] $field:ident : $ty:ty,
        spec: $spec:expr,
        check: $check:expr,
        why: $why:literal,
        stated: $stated:expr,
        default: $default:expr,
    })*]) => {
        $(#[$meta])*
        #[derive(Debug, Clone, PartialEq)]
        $vis struct $name {
            $($(#[doc = $doc])* pub $field: $ty,)*
        }

        // A default outside its range or choices, a computed default without its text, or a
        // shared parameter under another name is a compile error.
        const _: () = {
            $(assert!($check, concat!("stage_params!: `", stringify!($field), "`: ", $why));)*
        };

        impl $name {
            /// The parameters' declarations, in field order (the stage's `StageSpec::params`).
            pub const SPECS: &'static [$crate::spec::ParamSpec] = &[$($spec),*];

            /// The parameters from the stage's table, which the graph validator checked; a missing
            /// key takes the default.
            pub fn from_params(table: &$crate::params::toml::Table) -> Self {
                let defaults = <Self as ::core::default::Default>::default();
                Self {
                    $($field: match $crate::params::read::<$ty>(table, stringify!($field)) {
                        ::core::option::Option::Some(::core::result::Result::Ok(value)) => value,
                        _ => defaults.$field,
                    },)*
                }
            }
        }

        impl ::core::default::Default for $name {
            fn default() -> Self {
                Self { $($field: $default,)* }
            }
        }

        impl $crate::params::StageParams for $name {
            const SPECS: &'static [$crate::spec::ParamSpec] = <$name>::SPECS;

            fn from_params(table: &$crate::params::toml::Table) -> Self {
                <$name>::from_params(table)
            }

            fn try_from_params(
                table: &$crate::params::toml::Table,
            ) -> ::core::result::Result<Self, ::std::string::String> {
                let defaults = <Self as ::core::default::Default>::default();
                ::core::result::Result::Ok(Self {
                    $($field: match $crate::params::read::<$ty>(table, stringify!($field)) {
                        ::core::option::Option::Some(value) => value?,
                        ::core::option::Option::None => defaults.$field,
                    },)*
                })
            }

            fn stated_defaults() -> $crate::params::toml::Table {
                let mut table = $crate::params::toml::Table::new();
                $(
                    let stated: ::core::option::Option<$crate::params::toml::Value> = $stated;
                    if let ::core::option::Option::Some(value) = stated {
                        table.insert(stringify!($field).into(), value);
                    }
                )*
                table
            }
        }
    };
}

/// The per-KIND pieces of [`param!`] and [`stage_params!`].
#[doc(hidden)]
#[macro_export]
macro_rules! __param_kind {
    (ty float($min:expr, $max:expr)) => {
        $crate::spec::ParamType::Float {
            min: $min,
            max: $max,
        }
    };
    (ty int($min:expr, $max:expr)) => {
        $crate::spec::ParamType::Int {
            min: $min,
            max: $max,
        }
    };
    (ty bool) => {
        $crate::spec::ParamType::Bool
    };
    (ty string) => {
        $crate::spec::ParamType::String
    };
    (ty path) => {
        $crate::spec::ParamType::Path
    };
    (ty choice($names:expr)) => {
        $crate::spec::ParamType::Choice($names)
    };

    // The literal as the check and the table see it. `as f64`: a float parameter's literal may be
    // written as an integer (`8`), which is how its text reads.
    (literal float $lit:literal) => {
        $crate::params::Literal::Float($lit as f64)
    };
    (literal int $lit:literal) => {
        $crate::params::Literal::Int($lit)
    };
    (literal bool $lit:literal) => {
        $crate::params::Literal::Bool($lit)
    };
    (literal $kind:ident $lit:literal) => {
        $crate::params::Literal::Str($lit)
    };

    // The spec's default text: the literal as written, a string without its quotes.
    (text float $lit:literal) => {
        stringify!($lit)
    };
    (text int $lit:literal) => {
        stringify!($lit)
    };
    (text bool $lit:literal) => {
        stringify!($lit)
    };
    (text $kind:ident $lit:literal) => {
        $lit
    };

    // A `Param`'s typed default.
    (typed float $lit:literal $ty:ty) => {
        $lit as $ty
    };
    (typed int $lit:literal $ty:ty) => {
        $lit as $ty
    };
    (typed $kind:ident $lit:literal $ty:ty) => {
        $lit
    };
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;

    const SHARED: Param<f64> = crate::param! {
        /// a shared parameter
        /// over two lines
        shared_m: f64 = 1.75, float(1.0, 2.5)
    };

    #[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
    #[serde(rename_all = "kebab-case")]
    enum Shape {
        Round,
        FlatTop,
    }

    crate::stage_params! {
        /// Every field form.
        struct Example {
            /// a count
            count: u64 = 600, int(0, 1 << 40);
            /// a gain written as an integer
            gain: f64 = 8, float(0.0, 10.0);
            /// a fraction
            fraction: f64 = 1.0, float(0.0, 1.0);
            /// a switch
            switch: bool = true, bool;
            /// a name
            label: String = "a b", string;
            /// a typed choice
            shape: Shape = "flat-top", choice(&["round", "flat-top"]);
            /// a plain choice
            mode: String = "x", choice(&["x", "y"]);
            /// an output file
            out: Option<PathBuf> = required, path;
            /// an input file
            input: Option<PathBuf>, path;
            /// computed from the mode
            rate: Option<f64> = computed("x 1, y 2"), float(0.0, 5.0);
            shared_m: f64 = use SHARED;
        }
    }

    #[test]
    fn the_specs_state_the_literals_as_written() {
        let texts: Vec<(&str, &str, bool)> = Example::SPECS
            .iter()
            .map(|s| (s.name, s.default, s.required))
            .collect();
        assert_eq!(
            texts,
            [
                ("count", "600", false),
                ("gain", "8", false),
                ("fraction", "1.0", false),
                ("switch", "true", false),
                ("label", "a b", false),
                ("shape", "flat-top", false),
                ("mode", "x", false),
                ("out", "", true),
                ("input", "", false),
                ("rate", "x 1, y 2", false),
                ("shared_m", "1.75", false),
            ]
        );
        assert_eq!(Example::SPECS[0].doc, "a count");
        assert_eq!(Example::SPECS[10].doc, "a shared parameter over two lines");
        assert!(matches!(
            Example::SPECS[0].ty,
            ParamType::Int { min: 0, max } if max == 1 << 40
        ));
        assert!(matches!(
            Example::SPECS[5].ty,
            ParamType::Choice(["round", "flat-top"])
        ));
    }

    #[test]
    fn the_defaults_are_the_literals() {
        let d = Example::default();
        assert_eq!(
            d,
            Example {
                count: 600,
                gain: 8.0,
                fraction: 1.0,
                switch: true,
                label: "a b".into(),
                shape: Shape::FlatTop,
                mode: "x".into(),
                out: None,
                input: None,
                rate: None,
                shared_m: 1.75,
            }
        );
        assert_eq!(SHARED.default, 1.75);
    }

    #[test]
    fn the_derived_specs_defaults_parse_back_to_the_default_values() {
        check_defaults::<Example>().unwrap();
        let stated = Example::stated_defaults();
        assert_eq!(stated.len(), 8, "{stated:?}");
        assert!(!stated.contains_key("rate") && !stated.contains_key("out"));
    }

    #[test]
    fn from_params_reads_set_keys_and_defaults_the_rest() {
        let table: toml::Table = toml::from_str(
            r#"
            count = 5
            gain = 2
            shape = "round"
            out = "rec.mcap"
            rate = 1.5
            shared_m = 2.0
            "#,
        )
        .unwrap();
        let p = Example::from_params(&table);
        assert_eq!(p.count, 5);
        assert_eq!(p.gain, 2.0);
        assert_eq!(p.shape, Shape::Round);
        assert_eq!(p.out, Some(PathBuf::from("rec.mcap")));
        assert_eq!(p.rate, Some(1.5));
        assert_eq!(p.shared_m, 2.0);
        assert_eq!((p.fraction, p.switch, p.input), (1.0, true, None));
    }

    #[test]
    fn a_value_of_another_type_takes_the_default_or_is_an_error_when_asked() {
        let table: toml::Table = toml::from_str("count = -1\nshape = \"square\"").unwrap();
        assert_eq!(Example::from_params(&table), Example::default());
        let err = Example::try_from_params(&table).unwrap_err();
        assert!(err.contains("params.count"), "{err}");
    }

    #[test]
    fn a_wrong_declaration_fails_the_check() {
        crate::stage_params! {
            struct Wrong {
                /// the serde name is not the choice's
                shape: Shape = "round", choice(&["round", "flat_top"]);
            }
        }
        let err = check_defaults::<Wrong>().unwrap_err();
        assert!(err.contains("flat_top"), "{err}");
    }

    #[test]
    fn literals_fit_like_the_validator_checks() {
        let float = ParamType::Float { min: 0.0, max: 1.0 };
        assert!(Literal::Float(1.0).fits(&float));
        assert!(!Literal::Float(1.5).fits(&float));
        assert!(!Literal::Float(f64::NAN).fits(&float));
        assert!(!Literal::Int(1).fits(&float));
        let choice = ParamType::Choice(&["a", "bc"]);
        assert!(Literal::Str("bc").fits(&choice));
        assert!(!Literal::Str("b").fits(&choice));
        for (literal, ty) in [
            (Literal::Float(0.5), float),
            (Literal::Int(3), ParamType::Int { min: 0, max: 3 }),
            (Literal::Bool(false), ParamType::Bool),
            (Literal::Str("bc"), choice),
        ] {
            assert!(ty.check(&literal.to_toml()).is_ok(), "{literal:?}");
        }
    }
}
