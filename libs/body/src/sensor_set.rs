//! Sensor sets: which sites of the site catalogue ([`Imu::CATALOGUE`]) a capture setup wears.
//!
//! A set is data: the shipped ones (`six`, `lower-body`, `full-suit`) come from
//! `models/sensor-sets.toml`, embedded at compile time; a user's own set is a file of the same
//! form. Each site of a set is a site of the body model (its bone and its placement are the body
//! model's `[imus.<site>]`), so a set can only name sites the body model has. The wire carries one
//! slot per catalogue site; a set fills the slots of its sites ([`SiteMask`]).

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;

use serde::Deserialize;

use crate::skeleton::{Imu, JointId, MAX_SITES};

/// The shipped sensor sets (`models/sensor-sets.toml`), embedded at compile time.
pub const BUILTIN_SENSOR_SETS_TOML: &str = include_str!("../../../models/sensor-sets.toml");

/// The set a graph uses when it names none: PIP's and GlobalPose's six.
pub const DEFAULT_SENSOR_SET: &str = "six";

/// The six-site set's site names ([`SensorSet::site_names`]): what weights and shards written
/// before sensor sets mean (their serde default).
pub fn six_site_names() -> Vec<String> {
    SensorSet::six().site_names()
}

/// A set of catalogue sites as a bit mask over wire slots (bit i: [`Imu::index`] i), the form the
/// frames' `valid_mask` has.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct SiteMask(pub u32);

impl SiteMask {
    /// The mask of `sites`.
    pub fn of(sites: impl IntoIterator<Item = Imu>) -> SiteMask {
        SiteMask(sites.into_iter().fold(0, |m, s| m | 1 << s.index()))
    }

    /// Whether `site` is in the mask.
    pub fn contains(self, site: Imu) -> bool {
        self.0 & (1 << site.index()) != 0
    }

    /// Whether wire slot `slot` is in the mask.
    pub fn contains_slot(self, slot: usize) -> bool {
        slot < MAX_SITES && self.0 & (1 << slot) != 0
    }

    /// The sites in the mask, in wire slot order.
    pub fn sites(self) -> impl Iterator<Item = Imu> {
        Imu::CATALOGUE
            .into_iter()
            .filter(move |&s| self.contains(s))
    }

    /// How many sites the mask holds.
    pub fn len(self) -> usize {
        (self.0 & ((1u32 << MAX_SITES) - 1)).count_ones() as usize
    }

    /// Whether the mask holds no site.
    pub fn is_empty(self) -> bool {
        self.len() == 0
    }

    /// The sites of `self` that `other` lacks.
    pub fn missing_from(self, other: SiteMask) -> SiteMask {
        SiteMask(self.0 & !other.0)
    }

    /// The joints whose local rotation sensors on these sites observe, as a mask over joint
    /// indices ([`SensorSet::observed_joints`]).
    pub fn observed_joints(self) -> u32 {
        let mut mask = 0u32;
        for site in self.sites() {
            let mut joint = Some(site.joint());
            while let Some(j) = joint {
                mask |= 1 << j.index();
                joint = j.parent();
            }
        }
        mask
    }

    /// The sites' names, comma-separated (for messages).
    pub fn names(self) -> String {
        let names: Vec<&str> = self.sites().map(Imu::name).collect();
        names.join(", ")
    }
}

/// A sensor set: its name, its sites and the site whose heading the calibration takes as the
/// body's.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SensorSet {
    name: String,
    description: String,
    sites: SiteMask,
    heading_reference: Imu,
}

/// A sensor set file, as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SetEntry {
    #[serde(default)]
    description: String,
    sites: Vec<String>,
    heading_reference: String,
}

/// Failure to find, read or validate a sensor set.
#[derive(Debug, thiserror::Error)]
pub enum SensorSetError {
    /// Neither a shipped set's name nor a readable file.
    #[error(
        "sensor set '{name}': not a shipped set ({shipped}) and not a readable file ({reason})"
    )]
    Unknown {
        name: String,
        shipped: String,
        reason: String,
    },
    /// The file is not valid TOML or a key is missing, unknown or of the wrong type; `detail`
    /// (from the TOML parser) names the line and the key.
    #[error("sensor set file '{file}': {detail}")]
    Parse { file: String, detail: String },
    /// A set's content breaks a rule; `detail` names the set, the key and what was found.
    #[error("sensor set file '{file}': {detail}")]
    Invalid { file: String, detail: String },
}

impl SensorSet {
    /// The set's name (`six`, `lower-body`, `full-suit`, or a user set's table name).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// One line about the set.
    pub fn description(&self) -> &str {
        &self.description
    }

    /// The set's sites as a slot mask.
    pub fn mask(&self) -> SiteMask {
        self.sites
    }

    /// The set's sites, in wire slot order.
    pub fn sites(&self) -> impl Iterator<Item = Imu> {
        self.sites.sites()
    }

    /// How many sites the set has.
    pub fn len(&self) -> usize {
        self.sites.len()
    }

    /// Never true: a set has at least one site.
    pub fn is_empty(&self) -> bool {
        self.sites.is_empty()
    }

    /// Whether the set wears `site`.
    pub fn contains(&self, site: Imu) -> bool {
        self.sites.contains(site)
    }

    /// The site whose heading the calibration takes as the body's.
    pub fn heading_reference(&self) -> Imu {
        self.heading_reference
    }

    /// The joints whose local rotation the set's sensors observe, as a mask over joint indices:
    /// every joint on the kinematic chain from the root to a sensed bone (the joint that turns
    /// a sensed bone included; a sensor sees its bone's turn relative to every sensed or
    /// inferred bone above it). Joints beyond the last sensor of a chain (wrists and hands
    /// without hand sensors, ankles and feet without foot sensors, toes and finger ends always)
    /// are not observed: an estimate for a set leaves them at rest and says so. For the six-site
    /// set the unobserved joints are exactly the ones PIP and GlobalPose do not estimate
    /// (reference §1, "ignored": ankles, feet, wrists, hands).
    pub fn observed_joints(&self) -> u32 {
        self.sites.observed_joints()
    }

    /// Whether the set's sensors observe `joint` ([`SensorSet::observed_joints`]).
    pub fn observes(&self, joint: JointId) -> bool {
        self.observed_joints() & (1 << joint.index()) != 0
    }

    /// The joints [`SensorSet::observed_joints`] leaves out, in joint order.
    pub fn unobserved_joints(&self) -> Vec<JointId> {
        JointId::all().filter(|j| !self.observes(*j)).collect()
    }

    /// The sites' names in wire slot order: what weights and training shards record as the set
    /// they were made for.
    pub fn site_names(&self) -> Vec<String> {
        self.sites().map(|s| s.name().to_owned()).collect()
    }

    /// Whether this is the six-site set of PIP and GlobalPose (whatever its name).
    pub fn is_six(&self) -> bool {
        self.sites == SiteMask::of(Imu::SIX)
    }

    /// PIP's and GlobalPose's six.
    pub fn six() -> SensorSet {
        SensorSet {
            name: DEFAULT_SENSOR_SET.to_owned(),
            description: "PIP's and GlobalPose's six".to_owned(),
            sites: SiteMask::of(Imu::SIX),
            heading_reference: Imu::Pelvis,
        }
    }

    /// Every shipped set, in the file's order of names (sorted).
    pub fn shipped() -> Vec<SensorSet> {
        // The shipped file is checked by this module's tests; a broken one is a build defect.
        parse_sets(BUILTIN_SENSOR_SETS_TOML, "models/sensor-sets.toml").unwrap_or_default()
    }

    /// The shipped set called `name`, if there is one.
    pub fn builtin(name: &str) -> Option<SensorSet> {
        SensorSet::shipped().into_iter().find(|s| s.name == name)
    }

    /// The union of `first` and `others`: every site any of them wears, named `a+b+...`, the
    /// first set's heading reference (the first set itself when the others add no site and
    /// there are none). What one source synthesizes when variants of different sets are compared
    /// on the same input.
    pub fn union(first: &SensorSet, others: &[SensorSet]) -> SensorSet {
        if others.is_empty() {
            return first.clone();
        }
        let names: Vec<&str> = std::iter::once(first)
            .chain(others)
            .map(|s| s.name.as_str())
            .collect();
        SensorSet {
            name: names.join("+"),
            description: format!("the sites of {}", names.join(", ")),
            sites: SiteMask(others.iter().fold(first.sites.0, |m, s| m | s.sites.0)),
            heading_reference: first.heading_reference,
        }
    }

    /// A shipped set by name, the single set of a user's file by its path, or the union of sets
    /// written `a+b` (each a name or a path; [`SensorSet::union`]).
    pub fn resolve(name_or_path: &str) -> Result<SensorSet, SensorSetError> {
        if let Some(set) = SensorSet::builtin(name_or_path) {
            return Ok(set);
        }
        if name_or_path.contains('+') && !Path::new(name_or_path).exists() {
            let (first, others) = name_or_path.split_once('+').unwrap_or((name_or_path, ""));
            let first = SensorSet::resolve(first.trim())?;
            let others = others
                .split('+')
                .map(|part| SensorSet::resolve(part.trim()))
                .collect::<Result<Vec<_>, _>>()?;
            return Ok(SensorSet::union(&first, &others));
        }
        let shipped = || {
            let names: Vec<String> = SensorSet::shipped().into_iter().map(|s| s.name).collect();
            names.join(", ")
        };
        let path = Path::new(name_or_path);
        let text = std::fs::read_to_string(path).map_err(|e| SensorSetError::Unknown {
            name: name_or_path.to_owned(),
            shipped: shipped(),
            reason: e.to_string(),
        })?;
        let file = path.display().to_string();
        let mut sets = parse_sets(&text, &file)?;
        if sets.len() != 1 {
            return Err(SensorSetError::Invalid {
                file,
                detail: format!(
                    "a user's set file holds exactly one set (one table), found {}",
                    sets.len()
                ),
            });
        }
        Ok(sets.remove(0))
    }
}

impl fmt::Display for SensorSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({})", self.name, self.sites.names())
    }
}

/// Every set of a sensor set file (`file` names it in errors), sorted by name.
fn parse_sets(text: &str, file: &str) -> Result<Vec<SensorSet>, SensorSetError> {
    let entries: BTreeMap<String, SetEntry> =
        toml::from_str(text).map_err(|e| SensorSetError::Parse {
            file: file.to_owned(),
            detail: e.to_string(),
        })?;
    let invalid = |detail: String| SensorSetError::Invalid {
        file: file.to_owned(),
        detail,
    };
    let site = |set: &str, key: &str, name: &str| {
        Imu::from_name(name).ok_or_else(|| {
            invalid(format!(
                "[{set}] {key}: '{name}' is not a site of the body model (its sites: {})",
                Imu::NAMES.join(", ")
            ))
        })
    };
    let mut sets = Vec::new();
    for (name, entry) in entries {
        if entry.sites.is_empty() {
            return Err(invalid(format!(
                "[{name}] sites: empty; a set wears at least one site"
            )));
        }
        let mut mask = SiteMask::default();
        for s in &entry.sites {
            let imu = site(&name, "sites", s)?;
            if mask.contains(imu) {
                return Err(invalid(format!("[{name}] sites: '{s}' named twice")));
            }
            mask = SiteMask(mask.0 | 1 << imu.index());
        }
        let reference = site(&name, "heading_reference", &entry.heading_reference)?;
        if !mask.contains(reference) {
            return Err(invalid(format!(
                "[{name}] heading_reference: '{}' is not one of the set's sites ({})",
                entry.heading_reference,
                mask.names()
            )));
        }
        sets.push(SensorSet {
            name,
            description: entry.description,
            sites: mask,
            heading_reference: reference,
        });
    }
    Ok(sets)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_sets_parse_and_six_is_the_first_six_slots() {
        let sets = parse_sets(BUILTIN_SENSOR_SETS_TOML, "models/sensor-sets.toml").unwrap();
        let names: Vec<&str> = sets.iter().map(|s| s.name()).collect();
        assert_eq!(names, ["full-suit", "lower-body", "six"]);
        let six = SensorSet::builtin("six").unwrap();
        assert_eq!(six.mask(), SiteMask(0b11_1111));
        assert_eq!(six.sites().collect::<Vec<_>>(), Imu::SIX);
        assert!(six.is_six());
        assert_eq!(six.mask(), SensorSet::six().mask());
        let suit = SensorSet::builtin("full-suit").unwrap();
        assert_eq!(suit.len(), MAX_SITES);
        let legs = SensorSet::builtin("lower-body").unwrap();
        assert_eq!(
            legs.mask(),
            SiteMask::of([
                Imu::Pelvis,
                Imu::LeftUpperLeg,
                Imu::RightUpperLeg,
                Imu::LeftLowerLeg,
                Imu::RightLowerLeg
            ])
        );
        assert_eq!(legs.heading_reference(), Imu::Pelvis);
        // A set's slots are its own whatever the file's order: slot order.
        assert_eq!(
            suit.sites().map(|s| s.index()).collect::<Vec<_>>(),
            (0..17).collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_set_naming_what_the_body_lacks_is_refused_naming_both() {
        let err = parse_sets(
            "[legs]\nsites = [\"pelvis\", \"left_thigh\"]\nheading_reference = \"pelvis\"\n",
            "my.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("my.toml") && err.contains("[legs] sites: 'left_thigh'"),
            "{err}"
        );
        assert!(err.contains("left_upper_leg"), "{err}");
        let err = parse_sets(
            "[legs]\nsites = [\"pelvis\", \"pelvis\"]\nheading_reference = \"pelvis\"\n",
            "my.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("'pelvis' named twice"), "{err}");
        let err = parse_sets(
            "[legs]\nsites = [\"left_upper_leg\"]\nheading_reference = \"pelvis\"\n",
            "my.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("not one of the set's sites (left_upper_leg)"),
            "{err}"
        );
        let err = parse_sets(
            "[legs]\nsites = []\nheading_reference = \"pelvis\"\n",
            "my.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("empty"), "{err}");
        let err = parse_sets("[legs]\nsite = [\"pelvis\"]\n", "my.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("my.toml") && err.contains("site"), "{err}");
    }

    #[test]
    fn a_users_set_file_resolves_by_path_and_an_unknown_name_lists_the_shipped() {
        let dir = std::env::temp_dir().join(format!("imuflow-sets-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("hips.toml");
        std::fs::write(
            &path,
            "[hips]\nsites = [\"right_upper_leg\", \"pelvis\", \"left_upper_leg\"]\nheading_reference = \"pelvis\"\n",
        )
        .unwrap();
        let set = SensorSet::resolve(path.to_str().unwrap()).unwrap();
        assert_eq!(set.name(), "hips");
        assert_eq!(
            set.sites().collect::<Vec<_>>(),
            [Imu::Pelvis, Imu::LeftUpperLeg, Imu::RightUpperLeg]
        );
        assert!(!set.is_six());
        let err = SensorSet::resolve("legs").unwrap_err().to_string();
        assert!(
            err.contains("'legs'") && err.contains("full-suit, lower-body, six"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_union_of_sets_wears_every_site_of_each_and_keeps_the_first_ones_reference() {
        let union = SensorSet::resolve("six+lower-body").unwrap();
        assert_eq!(union.name(), "six+lower-body");
        // The six's six sites and the lower body's two thighs: slots 0-7.
        assert_eq!(union.mask(), SiteMask(0b1111_1111));
        assert_eq!(union.heading_reference(), Imu::Pelvis);
        assert!(
            SensorSet::six()
                .mask()
                .missing_from(union.mask())
                .is_empty()
        );
        // A set that holds the others is its own union.
        let suit = SensorSet::resolve("full-suit+six").unwrap();
        assert_eq!(suit.mask(), SensorSet::builtin("full-suit").unwrap().mask());
        let err = SensorSet::resolve("six+legs").unwrap_err().to_string();
        assert!(err.contains("'legs'"), "{err}");
    }

    #[test]
    fn the_six_observe_what_pip_estimates_and_the_lower_body_its_legs() {
        let names = |set: &SensorSet| -> Vec<&str> {
            set.unobserved_joints().iter().map(|j| j.name()).collect()
        };
        // PIP's ignored joints (reference §1) but the root, which the pelvis sensor gives.
        let six = SensorSet::six();
        let ignored: Vec<&str> = crate::skeleton::IGNORED_JOINTS[1..]
            .iter()
            .map(|j| j.name())
            .collect();
        assert_eq!(names(&six), ignored);
        let legs = SensorSet::builtin("lower-body").unwrap();
        let observed: Vec<&str> = JointId::all()
            .filter(|j| legs.observes(*j))
            .map(|j| j.name())
            .collect();
        assert_eq!(
            observed,
            ["pelvis", "left_hip", "right_hip", "left_knee", "right_knee"]
        );
        // The full suit: all but the toes' and the fingers' ends.
        let suit = SensorSet::builtin("full-suit").unwrap();
        assert_eq!(
            names(&suit),
            ["left_foot", "right_foot", "left_hand", "right_hand"]
        );
    }

    #[test]
    fn a_mask_lists_what_another_lacks() {
        let six = SensorSet::six().mask();
        let legs = SensorSet::builtin("lower-body").unwrap().mask();
        assert_eq!(
            legs.missing_from(six).names(),
            "left_upper_leg, right_upper_leg"
        );
        assert_eq!(six.missing_from(six), SiteMask::default());
        assert!(six.missing_from(six).is_empty());
    }
}
