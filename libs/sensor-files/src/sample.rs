//! One sensor's samples in SI units and its own frame, and the conversions every reader shares:
//! free acceleration to specific force, axis remaps, angular rate from orientations, magnetometers
//! in arbitrary units.

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};

use crate::units::{NOMINAL_FIELD_UT, SignedAxis};

/// One sample of one sensor, in SI units, vectors in the sensor frame S. `None` where the file
/// has no value (an empty or NaN cell) or no column for the quantity.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sample {
    /// Time on the sensor's own clock (the file's time column), ns.
    pub time_ns: i64,
    /// Specific force (includes −gravity) in S, m/s².
    pub accelerometer_mps2: Option<Vector3<f64>>,
    /// Angular rate in S, rad/s.
    pub gyroscope_radps: Option<Vector3<f64>>,
    /// Magnetic field in S, µT.
    pub magnetometer_ut: Option<Vector3<f64>>,
    /// On-board orientation R_IS (S to the sensor's inertial frame I).
    pub orientation: Option<UnitQuaternion<f64>>,
}

/// The vendor's gravity vector in its inertial frame: `gravity` m/s² along the down axis.
pub fn gravity_in_inertial(up: SignedAxis, gravity_mps2: f64) -> Vector3<f64> {
    -Vector3::from(up.vector()) * gravity_mps2
}

/// Specific force in S from free acceleration (gravity removed) in the inertial frame I:
/// f_S = R_ISᵀ·(a_free_I − g_I). A resting sensor has a_free = 0 and reads −g, i.e. `gravity`
/// m/s² along up.
pub fn specific_force_from_free_acceleration(
    free_acceleration_in_inertial: &Vector3<f64>,
    orientation: &UnitQuaternion<f64>,
    gravity_in_inertial: &Vector3<f64>,
) -> Vector3<f64> {
    orientation.inverse_transform_vector(&(free_acceleration_in_inertial - gravity_in_inertial))
}

/// The matrix P with v_S = P·v_F for a remap `axes` (our x, y, z as signed axes of the file's
/// sensor frame F); an error unless P is a rotation (each axis once, right-handed).
pub fn axis_matrix(axes: [SignedAxis; 3]) -> Result<Matrix3<f64>, String> {
    let rows = axes.map(|a| Vector3::from(a.vector()).transpose());
    let p = Matrix3::from_rows(&rows);
    if (p.determinant() - 1.0).abs() > 1e-9 {
        return Err(format!(
            "axes {axes:?}: must name each axis once and keep the frame right-handed (a rotation)"
        ));
    }
    Ok(p)
}

/// Re-expresses a sample read in the file's sensor frame F in our sensor frame S, with
/// v_S = P·v_F: vectors are multiplied by P, and R_IS = R_IF·Pᵀ.
pub fn remap_axes(sample: &mut Sample, p: &Matrix3<f64>) {
    let rotate = |v: &mut Option<Vector3<f64>>| {
        if let Some(v) = v {
            *v = p * *v;
        }
    };
    rotate(&mut sample.accelerometer_mps2);
    rotate(&mut sample.gyroscope_radps);
    rotate(&mut sample.magnetometer_ut);
    if let Some(q) = &mut sample.orientation {
        let r_fs = Rotation3::from_matrix_unchecked(p.transpose());
        *q *= UnitQuaternion::from_rotation_matrix(&r_fs);
    }
}

/// A unit quaternion from `[w, x, y, z]`; `None` for non-finite or zero components (a missing
/// sample), `Err` with the norm for one far from unit length (a wrong column or scaling).
pub fn unit_quaternion(wxyz: [f64; 4]) -> Result<Option<UnitQuaternion<f64>>, String> {
    if wxyz.iter().any(|v| !v.is_finite()) {
        return Ok(None);
    }
    let q = Quaternion::new(wxyz[0], wxyz[1], wxyz[2], wxyz[3]);
    let norm = q.norm();
    if norm == 0.0 {
        return Ok(None);
    }
    // Exports round to a few digits; a norm this far off means the columns are not a quaternion.
    if (norm - 1.0).abs() > 0.1 {
        return Err(format!(
            "quaternion {wxyz:?} has norm {norm:.3}, not 1: are these the quaternion's columns?"
        ));
    }
    Ok(Some(UnitQuaternion::from_quaternion(q)))
}

/// R_IS from Euler angles about x, y and z (rad), the Xsens convention: R = Rz(z)·Ry(y)·Rx(x)
/// (rotations about the fixed axes x, then y, then z; "XYZ Earth fixed", Xsens MTi manual
/// MT0100P, "Euler angles orientation output mode").
pub fn quaternion_from_euler_xyz(angles_rad: [f64; 3]) -> UnitQuaternion<f64> {
    let [x, y, z] = angles_rad;
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), z)
        * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), y)
        * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), x)
}

/// Fills the angular rate of samples that have none from their orientations (for exports with
/// an on-board orientation but no gyroscope): the body-frame rate ω with Ṙ = R·[ω]×, averaged
/// over the intervals before and after a sample, log(R_{k−1}ᵀR_k)/Δt and log(R_kᵀR_{k+1})/Δt
/// (both already in S_k: a rotation's axis is fixed by it). One-sided at the ends and next to
/// a sample without orientation. Returns how many samples got a rate.
///
/// Deliberately not left to the fusion stage, which derives a rate for live streams without a
/// gyroscope (SlimeVR, `no_gyroscope_mask`) from the turn since the previous sample only: a file
/// has every sample's successor, and the centred rate lags its sample by nothing instead of half
/// an interval.
pub fn derive_gyroscope(samples: &mut [Sample]) -> usize {
    let rate = |a: &Sample, b: &Sample| -> Option<Vector3<f64>> {
        let (qa, qb) = (a.orientation?, b.orientation?);
        let dt = (b.time_ns - a.time_ns) as f64 * 1e-9;
        (dt > 0.0).then(|| (qa.inverse() * qb).scaled_axis() / dt)
    };
    let rates: Vec<Option<Vector3<f64>>> = (0..samples.len())
        .map(|k| {
            samples[k].orientation?;
            let before = (k > 0)
                .then(|| rate(&samples[k - 1], &samples[k]))
                .flatten();
            let after = samples.get(k + 1).and_then(|next| rate(&samples[k], next));
            match (before, after) {
                (Some(b), Some(a)) => Some((a + b) * 0.5),
                (one, other) => one.or(other),
            }
        })
        .collect();
    let mut filled = 0;
    for (s, w) in samples.iter_mut().zip(rates) {
        if s.gyroscope_radps.is_none() && w.is_some() {
            s.gyroscope_radps = w;
            filled += 1;
        }
    }
    filled
}

/// Scales magnetometer readings in arbitrary units so that their median magnitude is
/// [`NOMINAL_FIELD_UT`] (see [`crate::units::MagnetometerUnit::Arbitrary`]).
pub fn normalise_arbitrary_magnetometer(samples: &mut [Sample]) {
    let mut norms: Vec<f64> = samples
        .iter()
        .filter_map(|s| s.magnetometer_ut.map(|m| m.norm()))
        .filter(|n| *n > 0.0)
        .collect();
    if norms.is_empty() {
        return;
    }
    norms.sort_by(f64::total_cmp);
    let scale = NOMINAL_FIELD_UT / norms[norms.len() / 2];
    for m in samples
        .iter_mut()
        .filter_map(|s| s.magnetometer_ut.as_mut())
    {
        *m *= scale;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_resting_sensor_reads_gravity_up_in_its_own_frame() {
        // Sensor turned 90° about x (z-up inertial frame): its y axis points up.
        let q = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2);
        let g = gravity_in_inertial(SignedAxis::PlusZ, 9.81);
        let f = specific_force_from_free_acceleration(&Vector3::zeros(), &q, &g);
        assert!((f - Vector3::new(0.0, 9.81, 0.0)).norm() < 1e-12, "{f}");
    }

    #[test]
    fn remapping_keeps_the_inertial_direction_of_a_vector() {
        let p = axis_matrix([SignedAxis::MinusY, SignedAxis::PlusX, SignedAxis::PlusZ]).unwrap();
        let q = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
        let v_f = Vector3::new(0.5, -1.0, 2.0);
        let mut s = Sample {
            accelerometer_mps2: Some(v_f),
            orientation: Some(q),
            ..Sample::default()
        };
        remap_axes(&mut s, &p);
        let (v_s, q_s) = (s.accelerometer_mps2.unwrap(), s.orientation.unwrap());
        assert_eq!(v_s, Vector3::new(1.0, 0.5, 2.0), "x_S = -y_F, y_S = x_F");
        assert!((q_s * v_s - q * v_f).norm() < 1e-12);
    }

    #[test]
    fn a_reflection_is_not_a_remap() {
        assert!(axis_matrix([SignedAxis::PlusY, SignedAxis::PlusX, SignedAxis::PlusZ]).is_err());
        assert!(axis_matrix([SignedAxis::PlusX, SignedAxis::PlusX, SignedAxis::PlusZ]).is_err());
    }

    #[test]
    fn euler_angles_follow_the_xsens_convention() {
        // Yaw 90° alone turns x to y.
        let q = quaternion_from_euler_xyz([0.0, 0.0, std::f64::consts::FRAC_PI_2]);
        assert!((q * Vector3::x() - Vector3::y()).norm() < 1e-12);
        // Roll then yaw (fixed axes): y goes to z by the roll, z stays z under the yaw.
        let q = quaternion_from_euler_xyz([std::f64::consts::FRAC_PI_2, 0.0, 0.4]);
        assert!((q * Vector3::y() - Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn a_constant_rotation_rate_is_recovered_from_orientations() {
        let w = Vector3::new(0.4, -1.2, 2.0);
        let q0 = UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3);
        let mut samples: Vec<Sample> = (0..6)
            .map(|k| {
                let t = k as f64 * 0.01;
                Sample {
                    time_ns: (t * 1e9) as i64,
                    orientation: Some(q0 * UnitQuaternion::from_scaled_axis(w * t)),
                    ..Sample::default()
                }
            })
            .collect();
        samples[3].orientation = None;
        assert_eq!(derive_gyroscope(&mut samples), 5);
        assert!(samples[3].gyroscope_radps.is_none());
        for s in samples.iter().filter_map(|s| s.gyroscope_radps) {
            assert!((s - w).norm() < 1e-9, "{s} vs {w}");
        }
    }

    #[test]
    fn arbitrary_units_are_scaled_to_the_nominal_field() {
        let mut samples: Vec<Sample> = [0.9, 1.0, 1.2]
            .iter()
            .map(|n| Sample {
                magnetometer_ut: Some(Vector3::new(0.0, *n, 0.0)),
                ..Sample::default()
            })
            .collect();
        normalise_arbitrary_magnetometer(&mut samples);
        let got: Vec<f64> = samples
            .iter()
            .map(|s| s.magnetometer_ut.unwrap().y)
            .collect();
        assert!((got[1] - 50.0).abs() < 1e-12 && (got[0] - 45.0).abs() < 1e-12);
    }

    #[test]
    fn quaternions_far_from_unit_length_are_rejected_zeros_are_missing() {
        assert!(unit_quaternion([2.0, 0.0, 0.0, 0.0]).is_err());
        assert_eq!(unit_quaternion([0.0; 4]), Ok(None));
        assert_eq!(unit_quaternion([f64::NAN, 0.0, 0.0, 1.0]), Ok(None));
        assert!(unit_quaternion([0.0, 0.0, 0.0, 1.0]).unwrap().is_some());
    }
}
