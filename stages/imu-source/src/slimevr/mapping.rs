//! The `trackers` file of the `slimevr` mode: which tracker (MAC address) and which IMU on it
//! (sensor id) is worn on which site of the body model.
//!
//! ```toml
//! [[tracker]]
//! mac = "aa:bb:cc:dd:ee:01"
//! site = "left_forearm"
//!
//! [[tracker]]
//! mac = "aa:bb:cc:dd:ee:05"
//! sensor = 1            # optional: the IMU's sensor id on that tracker board (default 0)
//! site = "head"
//! ```
//!
//! Sites: the body model's (`left_forearm`, ..., `pelvis`, `left_upper_leg`, ..., `right_hand`;
//! `imuflow_body::Imu::NAMES`); the graph's sensor set says which are read. Every problem (unknown key or site, malformed MAC, a site or a tracker's sensor
//! given twice) is an error naming the file and the line.

use std::collections::BTreeMap;
use std::path::Path;

use imuflow_body::skeleton::Imu;
use imuflow_body::{MAX_SITES, SiteMask};
use serde::Deserialize;
use toml::Spanned;

use super::packets::Mac;

/// Which tracker sensor is worn on which site.
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    sites: BTreeMap<(Mac, u8), usize>,
}

/// Why a trackers file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum MappingError {
    #[error("cannot read trackers file '{file}': {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
    #[error("trackers file '{file}': {detail}")]
    Parse { file: String, detail: String },
    #[error("trackers file '{file}', line {line}: {detail}")]
    Invalid {
        file: String,
        line: usize,
        detail: String,
    },
    #[error(
        "trackers file '{file}' maps no tracker (expected [[tracker]] tables with `mac` and `site`)"
    )]
    Empty { file: String },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    tracker: Vec<Entry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    mac: Spanned<String>,
    sensor: Option<Spanned<i64>>,
    site: Spanned<String>,
}

/// Names of the sites, in wire slot order.
pub fn site_names() -> [&'static str; MAX_SITES] {
    Imu::NAMES
}

impl Mapping {
    /// Reads and checks a trackers file.
    pub fn load(path: &Path) -> Result<Mapping, MappingError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| MappingError::Io {
            file: file.clone(),
            source,
        })?;
        Mapping::parse(&text, &file)
    }

    /// Parses and checks the text of a trackers file; `file` names it in errors.
    pub fn parse(text: &str, file: &str) -> Result<Mapping, MappingError> {
        let parsed: File = toml::from_str(text).map_err(|e| MappingError::Parse {
            file: file.to_owned(),
            detail: e.to_string().trim_end().to_owned(),
        })?;
        if parsed.tracker.is_empty() {
            return Err(MappingError::Empty {
                file: file.to_owned(),
            });
        }
        let invalid = |span: std::ops::Range<usize>, detail: String| MappingError::Invalid {
            file: file.to_owned(),
            line: line_of(text, span.start),
            detail,
        };
        let mut sites = BTreeMap::new();
        // Where each site and each (tracker, sensor) was given, for the duplicate errors.
        let mut site_lines: [Option<usize>; MAX_SITES] = [None; MAX_SITES];
        let mut key_lines = BTreeMap::new();
        for entry in &parsed.tracker {
            let mac: Mac = entry
                .mac
                .get_ref()
                .parse()
                .map_err(|e| invalid(entry.mac.span(), e))?;
            let sensor = match &entry.sensor {
                None => 0,
                Some(s) => u8::try_from(*s.get_ref()).map_err(|_| {
                    invalid(
                        s.span(),
                        format!("sensor must be 0 to 255 (got {})", s.get_ref()),
                    )
                })?,
            };
            let name = entry.site.get_ref().as_str();
            let Some(site) = site_names().iter().position(|n| *n == name) else {
                return Err(invalid(
                    entry.site.span(),
                    format!("unknown site '{name}' ({})", site_names().join(", ")),
                ));
            };
            let line = line_of(text, entry.site.span().start);
            if let Some(first) = site_lines[site] {
                return Err(invalid(
                    entry.site.span(),
                    format!("site '{name}' is already given on line {first}"),
                ));
            }
            if let Some(first) = key_lines.insert((mac, sensor), line) {
                return Err(invalid(
                    entry.mac.span(),
                    format!("tracker {mac} sensor {sensor} is already mapped on line {first}"),
                ));
            }
            site_lines[site] = Some(line);
            sites.insert((mac, sensor), site);
        }
        Ok(Mapping { sites })
    }

    /// The site (IMU index) of sensor `sensor_id` on tracker `mac`, if mapped.
    pub fn site(&self, mac: Mac, sensor_id: u8) -> Option<usize> {
        self.sites.get(&(mac, sensor_id)).copied()
    }

    /// Whether any sensor of tracker `mac` is mapped.
    pub fn knows(&self, mac: Mac) -> bool {
        self.sites.keys().any(|(m, _)| *m == mac)
    }

    /// The sites of `set` no tracker is mapped to, by name.
    pub fn missing_sites(&self, set: SiteMask) -> Vec<&'static str> {
        set.sites()
            .filter(|site| !self.sites.values().any(|s| *s == site.index()))
            .map(Imu::name)
            .collect()
    }

    /// Forgets the trackers mapped to sites outside `set`; their sites, by name.
    pub fn keep_only(&mut self, set: SiteMask) -> Vec<&'static str> {
        let names = site_names();
        let mut left_out: Vec<&'static str> = self
            .sites
            .values()
            .filter(|&&s| !set.contains_slot(s))
            .map(|&s| names[s])
            .collect();
        left_out.sort_by_key(|name| Imu::from_name(name).map(Imu::index));
        self.sites.retain(|_, s| set.contains_slot(*s));
        left_out
    }

    /// Every mapped (tracker, sensor) with its site, ordered by tracker.
    pub fn entries(&self) -> impl Iterator<Item = (Mac, u8, usize)> + '_ {
        self.sites
            .iter()
            .map(|(&(mac, sensor), &site)| (mac, sensor, site))
    }
}

/// 1-based line of byte `offset` in `text`.
fn line_of(text: &str, offset: usize) -> usize {
    text.get(..offset).unwrap_or(text).matches('\n').count() + 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_simulator_mapping_covers_every_site() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/trackers/slimevr-sim.toml");
        let mapping = Mapping::load(&path).expect("configs/trackers/slimevr-sim.toml loads");
        assert!(mapping.missing_sites(SiteMask::of(Imu::SIX)).is_empty());
        assert_eq!(mapping.entries().count(), imuflow_body::NUM_IMUS);
    }

    fn error(text: &str) -> String {
        Mapping::parse(text, "trackers.toml")
            .expect_err("should be rejected")
            .to_string()
    }

    #[test]
    fn a_mapping_gives_each_tracker_sensor_its_site() {
        let text = "\
[[tracker]]
mac = \"AA:bb:cc:dd:ee:01\"
site = \"pelvis\"

[[tracker]]
mac = \"aa:bb:cc:dd:ee:02\"
sensor = 1
site = \"left_forearm\"
";
        let m = Mapping::parse(text, "trackers.toml").unwrap();
        let mac = |last| Mac([0xaa, 0xbb, 0xcc, 0xdd, 0xee, last]);
        assert_eq!(m.site(mac(1), 0), Some(5));
        assert_eq!(m.site(mac(2), 1), Some(0));
        assert_eq!(m.site(mac(2), 0), None);
        assert!(m.knows(mac(2)) && !m.knows(mac(3)));
        assert_eq!(
            m.missing_sites(SiteMask::of(Imu::SIX)),
            ["right_forearm", "left_lower_leg", "right_lower_leg", "head"]
        );
    }

    #[test]
    fn a_lower_body_mapping_reads_its_sites_and_leaves_the_others_out() {
        // SlimeVR's five-tracker lower body (hip, thighs, ankles) and a chest tracker.
        let entry = |last: u8, site: &str| {
            format!("[[tracker]]\nmac = \"aa:bb:cc:dd:ee:{last:02x}\"\nsite = \"{site}\"\n")
        };
        let text: String = [
            (1, "pelvis"),
            (2, "left_upper_leg"),
            (3, "right_upper_leg"),
            (4, "left_lower_leg"),
            (5, "right_lower_leg"),
            (6, "sternum"),
        ]
        .iter()
        .map(|(last, site)| entry(*last, site))
        .collect();
        let mut m = Mapping::parse(&text, "trackers.toml").unwrap();
        let legs = imuflow_body::SensorSet::builtin("lower-body")
            .unwrap()
            .mask();
        assert!(m.missing_sites(legs).is_empty());
        assert_eq!(m.site(Mac([0xaa, 0xbb, 0xcc, 0xdd, 0xee, 2]), 0), Some(6));
        assert_eq!(m.keep_only(legs), ["sternum"]);
        assert!(!m.knows(Mac([0xaa, 0xbb, 0xcc, 0xdd, 0xee, 6])));
        assert_eq!(m.entries().count(), 5);
        assert_eq!(
            m.missing_sites(SiteMask::of(Imu::SIX)),
            ["left_forearm", "right_forearm", "head"]
        );
    }

    #[test]
    fn bad_files_name_the_file_and_line() {
        let entry =
            |mac: &str, site: &str| format!("[[tracker]]\nmac = \"{mac}\"\nsite = \"{site}\"\n");
        let ok = entry("aa:bb:cc:dd:ee:01", "head");
        assert_eq!(
            error(&format!("{ok}{}", entry("aa:bb:cc:dd:ee:02", "knee"))),
            format!(
                "trackers file 'trackers.toml', line 6: unknown site 'knee' ({})",
                Imu::NAMES.join(", ")
            )
        );
        assert_eq!(
            error(&format!("{ok}{}", entry("aa:bb:cc:dd:ee", "pelvis"))),
            "trackers file 'trackers.toml', line 5: 'aa:bb:cc:dd:ee' is not a MAC address \
             (expected six hex bytes: aa:bb:cc:dd:ee:ff)"
        );
        assert_eq!(
            error(&format!("{ok}{}", entry("aa:bb:cc:dd:ee:02", "head"))),
            "trackers file 'trackers.toml', line 6: site 'head' is already given on line 3"
        );
        assert_eq!(
            error(&format!("{ok}{}", entry("AA:BB:CC:DD:EE:01", "pelvis"))),
            "trackers file 'trackers.toml', line 5: tracker aa:bb:cc:dd:ee:01 sensor 0 is \
             already mapped on line 3"
        );
        assert_eq!(
            error(&format!(
                "{ok}[[tracker]]\nmac = \"aa:bb:cc:dd:ee:03\"\nsensor = 300\nsite = \"pelvis\"\n"
            )),
            "trackers file 'trackers.toml', line 6: sensor must be 0 to 255 (got 300)"
        );
        assert_eq!(
            error(""),
            "trackers file 'trackers.toml' maps no tracker (expected [[tracker]] tables with \
             `mac` and `site`)"
        );
        // Syntax and unknown keys: the toml parser's message, which has the line.
        let unknown = error(&format!(
            "{ok}[[tracker]]\nmac = \"aa:bb:cc:dd:ee:03\"\nslot = 1\n"
        ));
        assert!(
            unknown.starts_with("trackers file 'trackers.toml': "),
            "{unknown}"
        );
        assert!(
            unknown.contains("line 6") && unknown.contains("slot"),
            "{unknown}"
        );
        let syntax = error("[[tracker]\nmac = 1\n");
        assert!(syntax.contains("line 1"), "{syntax}");
        let missing = Mapping::load(Path::new("/nonexistent/trackers.toml"))
            .unwrap_err()
            .to_string();
        assert!(missing.starts_with("cannot read trackers file '/nonexistent/trackers.toml'"));
    }
}
