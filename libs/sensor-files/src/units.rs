//! Units a recording may be written in, and their conversion to imuflow's SI units.

use serde::Deserialize;

/// Standard gravity, the definition of the unit g: 9.80665 m/s² (3rd CGPM, 1901). Used only to
/// convert values written in g; the gravity added back to free acceleration is the layout's
/// `gravity_mps2` (default [`GRAVITY_MPS2`]).
pub const STANDARD_GRAVITY_MPS2: f64 = 9.80665;

/// Gravity the model frame uses (docs/architecture.md, "Conventions": (0, −9.81, 0) in M); the
/// default magnitude added back to free acceleration.
pub const GRAVITY_MPS2: f64 = 9.81;

/// The field magnitude a magnetometer in arbitrary units is scaled to, µT: the order of the
/// Earth's field, whose total intensity at the surface lies between about 25 and 65 µT (World
/// Magnetic Model). Only the direction of such a reading is known; see [`MagnetometerUnit::Arbitrary`].
pub const NOMINAL_FIELD_UT: f64 = 50.0;

/// Unit of a time column.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum TimeUnit {
    #[serde(rename = "s")]
    Seconds,
    #[serde(rename = "ms")]
    Milliseconds,
    #[serde(rename = "us", alias = "µs")]
    Microseconds,
    #[serde(rename = "ns")]
    Nanoseconds,
}

impl TimeUnit {
    /// Nanoseconds per unit.
    pub fn ns(self) -> f64 {
        match self {
            TimeUnit::Seconds => 1e9,
            TimeUnit::Milliseconds => 1e6,
            TimeUnit::Microseconds => 1e3,
            TimeUnit::Nanoseconds => 1.0,
        }
    }
}

/// Unit of accelerometer (and free-acceleration) columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
pub enum AccelerometerUnit {
    #[default]
    #[serde(rename = "m/s2", alias = "m/s^2", alias = "m/s²")]
    MetresPerSecondSquared,
    #[serde(rename = "g")]
    G,
    /// Thousandths of g (Noraxon writes "mG").
    #[serde(rename = "mg", alias = "mG")]
    MilliG,
}

impl AccelerometerUnit {
    /// m/s² per unit.
    pub fn mps2(self) -> f64 {
        match self {
            AccelerometerUnit::MetresPerSecondSquared => 1.0,
            AccelerometerUnit::G => STANDARD_GRAVITY_MPS2,
            AccelerometerUnit::MilliG => STANDARD_GRAVITY_MPS2 / 1000.0,
        }
    }
}

/// Unit of gyroscope columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
pub enum GyroscopeUnit {
    #[default]
    #[serde(rename = "rad/s")]
    RadiansPerSecond,
    #[serde(rename = "deg/s")]
    DegreesPerSecond,
}

impl GyroscopeUnit {
    /// rad/s per unit.
    pub fn radps(self) -> f64 {
        match self {
            GyroscopeUnit::RadiansPerSecond => 1.0,
            GyroscopeUnit::DegreesPerSecond => std::f64::consts::PI / 180.0,
        }
    }
}

/// Unit of magnetometer columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
pub enum MagnetometerUnit {
    #[default]
    #[serde(rename = "uT", alias = "µT")]
    Microtesla,
    #[serde(rename = "nT")]
    Nanotesla,
    /// 1 G = 100 µT.
    #[serde(rename = "gauss", alias = "G")]
    Gauss,
    #[serde(rename = "mgauss", alias = "mG")]
    Milligauss,
    /// Units only the vendor knows (Xsens writes its field normalised to the field at calibration):
    /// each sensor's readings are scaled so that their median magnitude over the recording is
    /// [`NOMINAL_FIELD_UT`]. Directions are kept, magnitudes relative to each other are kept, the
    /// absolute magnitude is not known.
    #[serde(rename = "arbitrary", alias = "a.u.")]
    Arbitrary,
}

impl MagnetometerUnit {
    /// µT per unit; `None` for arbitrary units (normalised per sensor instead).
    pub fn ut(self) -> Option<f64> {
        match self {
            MagnetometerUnit::Microtesla => Some(1.0),
            MagnetometerUnit::Nanotesla => Some(1e-3),
            MagnetometerUnit::Gauss => Some(100.0),
            MagnetometerUnit::Milligauss => Some(0.1),
            MagnetometerUnit::Arbitrary => None,
        }
    }
}

/// Unit of Euler-angle columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
pub enum AngleUnit {
    #[default]
    #[serde(rename = "deg")]
    Degrees,
    #[serde(rename = "rad")]
    Radians,
}

impl AngleUnit {
    /// Radians per unit.
    pub fn rad(self) -> f64 {
        match self {
            AngleUnit::Degrees => std::f64::consts::PI / 180.0,
            AngleUnit::Radians => 1.0,
        }
    }
}

/// Order of a quaternion's four components in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
pub enum QuaternionOrder {
    #[default]
    #[serde(rename = "wxyz")]
    Wxyz,
    #[serde(rename = "xyzw")]
    Xyzw,
}

impl QuaternionOrder {
    /// The components as `[w, x, y, z]`.
    pub fn wxyz(self, q: [f64; 4]) -> [f64; 4] {
        match self {
            QuaternionOrder::Wxyz => q,
            QuaternionOrder::Xyzw => [q[3], q[0], q[1], q[2]],
        }
    }
}

/// A signed axis, for the inertial frame's up direction and for sensor axis remaps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum SignedAxis {
    #[serde(rename = "+x", alias = "x")]
    PlusX,
    #[serde(rename = "-x")]
    MinusX,
    #[serde(rename = "+y", alias = "y")]
    PlusY,
    #[serde(rename = "-y")]
    MinusY,
    #[serde(rename = "+z", alias = "z")]
    PlusZ,
    #[serde(rename = "-z")]
    MinusZ,
}

impl SignedAxis {
    /// The unit vector.
    pub fn vector(self) -> [f64; 3] {
        match self {
            SignedAxis::PlusX => [1.0, 0.0, 0.0],
            SignedAxis::MinusX => [-1.0, 0.0, 0.0],
            SignedAxis::PlusY => [0.0, 1.0, 0.0],
            SignedAxis::MinusY => [0.0, -1.0, 0.0],
            SignedAxis::PlusZ => [0.0, 0.0, 1.0],
            SignedAxis::MinusZ => [0.0, 0.0, -1.0],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversion_factors() {
        assert_eq!(AccelerometerUnit::G.mps2(), 9.80665);
        assert!((AccelerometerUnit::MilliG.mps2() - 0.00980665).abs() < 1e-15);
        assert!(
            (GyroscopeUnit::DegreesPerSecond.radps() * 180.0 - std::f64::consts::PI).abs() < 1e-15
        );
        assert_eq!(MagnetometerUnit::Gauss.ut(), Some(100.0));
        assert_eq!(MagnetometerUnit::Arbitrary.ut(), None);
        assert_eq!(TimeUnit::Microseconds.ns(), 1000.0);
        assert_eq!(
            QuaternionOrder::Xyzw.wxyz([0.1, 0.2, 0.3, 0.9]),
            [0.9, 0.1, 0.2, 0.3]
        );
    }
}
