//! The inertial frame a sensor reports its orientation in, and how it relates to the model frame:
//! one definition for the sources that synthesize sensors and the calibration that undoes them.

use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

use crate::rotation::Axis;

/// How a sensor's inertial frame I (the frame its orientation `R_IS` is reported in) relates to the
/// model frame M (x = left, y = up, z = forward), up to the heading, which no convention fixes.
///
/// At heading 0 the subject faces the convention's reference forward axis:
/// - `model`: I is M (x left, y up, z forward): what imu-source's synthesize mode emits by default.
/// - `z-up` (Xsens-like, x/y horizontal, z up): forward = +x_I, left = +y_I, up = +z_I. This is the
///   reference's PIP/Xsens DOT placement matrix C (§4).
/// - `z-down` (Noitom-like, NED: x/y horizontal, z down): forward = +x_I, left = −y_I, up = −z_I.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum InertialFrame {
    #[default]
    Model,
    ZUp,
    ZDown,
}

impl InertialFrame {
    /// The names used in graph files and calibration files.
    pub const NAMES: [&'static str; 3] = ["model", "z-up", "z-down"];

    /// Parses a name of [`InertialFrame::NAMES`].
    pub fn parse(name: &str) -> Option<InertialFrame> {
        match name {
            "model" => Some(InertialFrame::Model),
            "z-up" => Some(InertialFrame::ZUp),
            "z-down" => Some(InertialFrame::ZDown),
            _ => None,
        }
    }

    /// The name as written in graph files.
    pub fn name(self) -> &'static str {
        match self {
            InertialFrame::Model => "model",
            InertialFrame::ZUp => "z-up",
            InertialFrame::ZDown => "z-down",
        }
    }

    /// `R_MI` at heading 0: its rows are M's axes (left, up, forward) written in I.
    pub fn model_from_inertial_at_zero_heading(self) -> Rotation3<f64> {
        let m = match self {
            InertialFrame::Model => Matrix3::identity(),
            InertialFrame::ZUp => Matrix3::new(0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0),
            InertialFrame::ZDown => Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0),
        };
        Rotation3::from_matrix_unchecked(m)
    }

    /// `R_MI` when the subject faces `heading_rad` (right-handed about up, measured in I from the
    /// convention's reference forward axis): `R_MI = R_y(−heading)·R_MI(0)`.
    pub fn model_from_inertial(self, heading_rad: f64) -> Rotation3<f64> {
        Axis::Y.rotation(-heading_rad) * self.model_from_inertial_at_zero_heading()
    }

    /// The up direction (against gravity) in I.
    pub fn up_in_inertial(self) -> Unit<Vector3<f64>> {
        Unit::new_unchecked(self.model_from_inertial_at_zero_heading().transpose() * Vector3::y())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conventions_are_proper_rotations_with_the_stated_axes() {
        for name in InertialFrame::NAMES {
            let f = InertialFrame::parse(name).expect("known");
            assert_eq!(f.name(), name);
            let r = f.model_from_inertial_at_zero_heading();
            assert!((r.matrix().determinant() - 1.0).abs() < 1e-12, "{name}");
            assert!((r * f.up_in_inertial().into_inner() - Vector3::y()).norm() < 1e-12);
        }
        let zup = InertialFrame::ZUp.model_from_inertial_at_zero_heading();
        assert!(
            (zup * Vector3::z() - Vector3::y()).norm() < 1e-12,
            "z-up: y_M = z_I"
        );
        assert!(
            (zup * Vector3::x() - Vector3::z()).norm() < 1e-12,
            "forward = x_I"
        );
        let zdown = InertialFrame::ZDown.model_from_inertial_at_zero_heading();
        assert!(
            (zdown * Vector3::z() + Vector3::y()).norm() < 1e-12,
            "z-down: y_M = −z_I"
        );
        assert!(InertialFrame::parse("y-up").is_none());
    }

    #[test]
    fn heading_turns_the_forward_axis_about_up() {
        let h = 0.6;
        for f in [
            InertialFrame::Model,
            InertialFrame::ZUp,
            InertialFrame::ZDown,
        ] {
            let r = f.model_from_inertial(h);
            let zero = f.model_from_inertial_at_zero_heading();
            // The subject faces the reference forward axis turned by `h` about up.
            let up = f.up_in_inertial();
            let facing = Rotation3::from_axis_angle(&up, h) * (zero.transpose() * Vector3::z());
            assert!((r * facing - Vector3::z()).norm() < 1e-12, "{f:?}");
        }
    }
}
