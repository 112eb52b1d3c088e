//! [`ContactSet`]: the contacts of one frame, as every method produces them and the optimizer consumes
//! them, and its wire form [`ContactFrame`].

use imuflow_body::{JointId, NUM_JOINTS};
use imuflow_graph::frames::{ContactFrame, MAX_CONTACT_POINTS};
use nalgebra::Vector3;

/// One contact point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactPoint {
    /// The joint (body) the point belongs to.
    pub joint: JointId,
    /// World position of the point (m, frame M).
    pub position: Vector3<f64>,
    /// Contact force acting on the body at the point (N, frame M); zero where the method has none.
    pub force: Vector3<f64>,
}

/// The contacts of one frame. Fixed capacity ([`MAX_CONTACT_POINTS`]): no allocation per frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactSet {
    points: [ContactPoint; MAX_CONTACT_POINTS],
    len: usize,
    /// Bit j set when joint j is in contact.
    pub mask: u32,
    /// Proxy-surface height under each contact joint (m, M's y); 0 where no contact.
    pub surface_height_m: [f64; NUM_JOINTS],
    /// Residual root wrench the contacts did not explain: force (N) then torque (N·m), frame M.
    pub residual_root_wrench: [f64; 6],
}

/// More contact points than a [`ContactFrame`] carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("more than {MAX_CONTACT_POINTS} contact points (the ContactFrame's capacity)")]
pub struct TooManyPoints;

impl Default for ContactSet {
    fn default() -> ContactSet {
        ContactSet::new()
    }
}

impl ContactSet {
    /// No contacts.
    pub fn new() -> ContactSet {
        ContactSet {
            points: [ContactPoint {
                joint: JointId::PELVIS,
                position: Vector3::zeros(),
                force: Vector3::zeros(),
            }; MAX_CONTACT_POINTS],
            len: 0,
            mask: 0,
            surface_height_m: [0.0; NUM_JOINTS],
            residual_root_wrench: [0.0; 6],
        }
    }

    /// Forget every contact.
    pub fn clear(&mut self) {
        *self = ContactSet::new();
    }

    /// The contact points.
    pub fn points(&self) -> &[ContactPoint] {
        &self.points[..self.len]
    }

    /// The contact points, mutable (to set forces).
    pub fn points_mut(&mut self) -> &mut [ContactPoint] {
        &mut self.points[..self.len]
    }

    /// Add a point and mark its joint as in contact.
    pub fn push(&mut self, point: ContactPoint) -> Result<(), TooManyPoints> {
        if self.len == MAX_CONTACT_POINTS {
            return Err(TooManyPoints);
        }
        self.points[self.len] = point;
        self.len += 1;
        self.mask |= 1 << point.joint.index();
        Ok(())
    }

    /// Whether `joint` is in contact.
    pub fn contains(&self, joint: JointId) -> bool {
        self.mask & (1 << joint.index()) != 0
    }

    /// Total contact force per joint (N, frame M): the sum of its points' forces.
    pub fn joint_forces(&self) -> [Vector3<f64>; NUM_JOINTS] {
        let mut out = [Vector3::zeros(); NUM_JOINTS];
        for p in self.points() {
            out[p.joint.index()] += p.force;
        }
        out
    }

    /// Write the set into a wire frame (the header is the caller's).
    pub fn write(&self, out: &mut ContactFrame) {
        out.contact_mask = self.mask;
        out.num_points = self.len as u32;
        out.point_position_m = [[0.0; 3]; MAX_CONTACT_POINTS];
        out.point_joint = [0; MAX_CONTACT_POINTS];
        out.point_force_n = [[0.0; 3]; MAX_CONTACT_POINTS];
        for (i, p) in self.points().iter().enumerate() {
            out.point_position_m[i] = p.position.cast::<f32>().into();
            out.point_joint[i] = p.joint.index() as u32;
            out.point_force_n[i] = p.force.cast::<f32>().into();
        }
        for (j, f) in self.joint_forces().iter().enumerate() {
            out.joint_force_n[j] = f.cast::<f32>().into();
        }
        out.surface_height_m = self.surface_height_m.map(|v| v as f32);
        out.residual_root_wrench = self.residual_root_wrench.map(|v| v as f32);
    }

    /// Read a wire frame. Errors name the field that is out of range or not finite.
    pub fn read(frame: &ContactFrame) -> Result<ContactSet, String> {
        let n = frame.num_points as usize;
        if n > MAX_CONTACT_POINTS {
            return Err(format!(
                "num_points {n} exceeds the capacity {MAX_CONTACT_POINTS}"
            ));
        }
        let mut set = ContactSet::new();
        for i in 0..n {
            let j = frame.point_joint[i] as usize;
            if j >= NUM_JOINTS {
                return Err(format!("point_joint[{i}] = {j} is not a joint (0..23)"));
            }
            let position = Vector3::from(frame.point_position_m[i]).cast::<f64>();
            let force = Vector3::from(frame.point_force_n[i]).cast::<f64>();
            if !position.iter().chain(force.iter()).all(|v| v.is_finite()) {
                return Err(format!("point {i} is not finite"));
            }
            set.points[i] = ContactPoint {
                joint: JointId::from_index(j).expect("checked above"),
                position,
                force,
            };
        }
        set.len = n;
        set.mask = frame.contact_mask & ((1 << NUM_JOINTS) - 1);
        set.surface_height_m = frame.surface_height_m.map(f64::from);
        set.residual_root_wrench = frame.residual_root_wrench.map(f64::from);
        if !set.surface_height_m.iter().all(|v| v.is_finite()) {
            return Err("surface_height_m is not finite".into());
        }
        Ok(set)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bytemuck::Zeroable;

    #[test]
    fn a_set_survives_the_wire_and_sums_forces_per_joint() {
        let mut set = ContactSet::new();
        for (k, x) in [-0.1, 0.1].into_iter().enumerate() {
            set.push(ContactPoint {
                joint: JointId::LEFT_FOOT,
                position: Vector3::new(x, 0.0, 0.2),
                force: Vector3::new(0.0, 100.0 + k as f64, 0.0),
            })
            .unwrap();
        }
        set.surface_height_m[JointId::LEFT_FOOT.index()] = 0.01;
        let mut frame = ContactFrame::zeroed();
        set.write(&mut frame);
        assert_eq!(frame.joint_force_n[10], [0.0, 201.0, 0.0]);
        let back = ContactSet::read(&frame).unwrap();
        assert_eq!(back.points().len(), 2);
        assert!(back.contains(JointId::LEFT_FOOT) && !back.contains(JointId::RIGHT_FOOT));
        assert!((back.points()[0].position.x + 0.1).abs() < 1e-7);
    }

    #[test]
    fn capacity_and_bad_frames_are_errors() {
        let mut set = ContactSet::new();
        let p = ContactPoint {
            joint: JointId::HEAD,
            position: Vector3::zeros(),
            force: Vector3::zeros(),
        };
        for _ in 0..MAX_CONTACT_POINTS {
            set.push(p).unwrap();
        }
        assert_eq!(set.push(p), Err(TooManyPoints));
        let mut frame = ContactFrame::zeroed();
        frame.num_points = 1;
        frame.point_joint[0] = 24;
        assert!(
            ContactSet::read(&frame)
                .unwrap_err()
                .contains("point_joint[0]")
        );
        frame.num_points = 99;
        assert!(ContactSet::read(&frame).unwrap_err().contains("num_points"));
    }
}
