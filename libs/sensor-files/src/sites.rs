//! Which file or folder of a recording holds each site's sensor when the export names them by
//! sensor id (Xsens MT Manager: `<prefix>_<id>.txt`) or by the vendor's name of the body part
//! (x-IMU3: "Left Lower Leg 64F61CB3 (UDP)"), as `[files]` in the layout says.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use quick_xml::Reader;
use quick_xml::events::Event;

use crate::error::{Error, read_text};
use crate::layout::{FilesLayout, Layout};
use crate::{MAX_SITES, SITES};

/// A name reduced for comparison: lower case, letters and digits only, a trailing "imu" (OpenSim's
/// `tibia_r_imu`) or "sensor" dropped.
pub fn normalise(name: &str) -> String {
    let s: String = name
        .chars()
        .filter(char::is_ascii_alphanumeric)
        .map(|c| c.to_ascii_lowercase())
        .collect();
    for suffix in ["imu", "sensor"] {
        if let Some(stem) = s.strip_suffix(suffix)
            && !stem.is_empty()
        {
            return stem.to_owned();
        }
    }
    s
}

/// The site a body-part name means, if it is one of the catalogue's: imuflow's names and the
/// ones vendors and labs use for the same places (MVN's `LeftForeArm`, OpenSim's `tibia_l` and
/// `femur_r`, "Left Lower Leg", `LShank`, `LFemur`, ...). Sides are left/right or l/r before or
/// after the part.
pub fn site_of(name: &str) -> Option<usize> {
    let n = normalise(name);
    // Parts per limb site; a sensor on the wrist or ankle sits on the forearm or shank, one on
    // the heel or toes on the foot.
    const FOREARM: [&str; 5] = ["forearm", "lowerarm", "wrist", "radius", "ulna"];
    const SHANK: [&str; 6] = ["lowerleg", "shank", "tibia", "shin", "ankle", "calf"];
    const THIGH: [&str; 4] = ["upperleg", "thigh", "femur", "femoral"];
    const FOOT: [&str; 5] = ["foot", "heel", "calcn", "toes", "midfoot"];
    const UPPER_ARM: [&str; 3] = ["upperarm", "humerus", "arm"];
    const SHOULDER: [&str; 3] = ["shoulder", "scapula", "clavicle"];
    const HAND: [&str; 2] = ["hand", "metacarpal"];
    let sided = |parts: &[&str], side: &str, s: &str| {
        parts.iter().any(|p| {
            n == format!("{side}{p}")
                || n == format!("{s}{p}")
                || n == format!("{p}{side}")
                || n == format!("{p}{s}")
        })
    };
    let limbs: [(&[&str], &str, &str); 7] = [
        (&FOREARM, "left_forearm", "right_forearm"),
        (&SHANK, "left_lower_leg", "right_lower_leg"),
        (&THIGH, "left_upper_leg", "right_upper_leg"),
        (&FOOT, "left_foot", "right_foot"),
        (&UPPER_ARM, "left_upper_arm", "right_upper_arm"),
        (&SHOULDER, "left_shoulder", "right_shoulder"),
        (&HAND, "left_hand", "right_hand"),
    ];
    let limb = limbs.iter().find_map(|(parts, left, right)| {
        if sided(parts, "left", "l") {
            Some(*left)
        } else if sided(parts, "right", "r") {
            Some(*right)
        } else {
            None
        }
    });
    let site = match limb {
        Some(site) => site,
        None if n == "head" => "head",
        None if ["pelvis", "sacrum", "lumbar", "lowerback"].contains(&n.as_str()) => "pelvis",
        // OpenSense's torso sensor and MVN's T8 sit on the sternum (the chest's front).
        None if ["sternum", "stern", "chest", "torso", "t8", "thorax"].contains(&n.as_str()) => {
            "sternum"
        }
        None => return None,
    };
    SITES.iter().position(|s| *s == site)
}

/// One piece of a `[files] match` pattern.
#[derive(Debug, Clone, PartialEq)]
enum Token {
    Literal(String),
    Star,
    /// `{site}` or `{id}`: any non-empty text the caller accepts.
    Capture,
}

fn tokens(pattern: &str) -> Vec<Token> {
    let mut out = Vec::new();
    let mut literal = String::new();
    let mut rest = pattern;
    while let Some(c) = rest.chars().next() {
        let (token, len) = if rest.starts_with("{site}") {
            (Some(Token::Capture), 6)
        } else if rest.starts_with("{id}") {
            (Some(Token::Capture), 4)
        } else if c == '*' {
            (Some(Token::Star), 1)
        } else {
            literal.extend(c.to_lowercase());
            (None, c.len_utf8())
        };
        if let Some(t) = token {
            if !literal.is_empty() {
                out.push(Token::Literal(std::mem::take(&mut literal)));
            }
            out.push(t);
        }
        rest = &rest[len..];
    }
    if !literal.is_empty() {
        out.push(Token::Literal(literal));
    }
    out
}

/// Whether `name` (lower case) matches `tokens` with a capture that `accept` takes.
fn matches(tokens: &[Token], name: &str, accept: &dyn Fn(&str) -> bool) -> bool {
    let cuts = |from: usize| (from..=name.len()).filter(|i| name.is_char_boundary(*i));
    match tokens.first() {
        None => name.is_empty(),
        Some(Token::Literal(l)) => name
            .strip_prefix(l.as_str())
            .is_some_and(|r| matches(&tokens[1..], r, accept)),
        Some(Token::Star) => cuts(0).any(|i| matches(&tokens[1..], &name[i..], accept)),
        Some(Token::Capture) => {
            cuts(1).any(|i| accept(&name[..i]) && matches(&tokens[1..], &name[i..], accept))
        }
    }
}

/// Each listed site's file or folder in `folder`, found by `[files] match`. A site whose entry is
/// not there is `None`; two entries for one site are an error naming both.
pub fn find(
    folder: &Path,
    files: &FilesLayout,
    layout: &Layout,
) -> Result<[Option<PathBuf>; MAX_SITES], Error> {
    let by_id = files.pattern.contains("{id}");
    let mut ids: [Option<String>; MAX_SITES] = Default::default();
    if by_id {
        let listed = files.ids.as_ref().map_or(&[][..], |p| p.list());
        if let Some(table) = listed.iter().map(|t| folder.join(t)).find(|t| t.exists()) {
            for (site, id) in read_ids(&table)? {
                ids[site] = Some(id);
            }
        }
        for (i, sensor) in layout.sites() {
            if let Some(id) = &sensor.id {
                ids[i] = Some(normalise_id(id));
            }
        }
        if layout.sites().all(|(i, _)| ids[i].is_none()) {
            let names: Vec<String> = listed.iter().map(|p| p.display().to_string()).collect();
            return Err(Error::file(
                folder,
                format!(
                    "no sensor ids: none of the mapping files ({}) is in the folder and the layout gives no `id`; map each site's sensor id to its site there",
                    if names.is_empty() {
                        "none named".to_owned()
                    } else {
                        names.join(", ")
                    }
                ),
            ));
        }
    }
    let mut names: Vec<String> = std::fs::read_dir(folder)
        .map_err(|e| Error::io(folder, e))?
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let tokens = tokens(&files.pattern);
    let mut found: [Option<PathBuf>; MAX_SITES] = Default::default();
    for (i, _) in layout.sites() {
        let accept = |capture: &str| {
            if by_id {
                ids[i].as_deref() == Some(normalise_id(capture).as_str())
            } else {
                site_of(capture) == Some(i)
            }
        };
        if by_id && ids[i].is_none() {
            continue;
        }
        let hits: Vec<&String> = names
            .iter()
            .filter(|n| {
                // A gzip-compressed file matches as the file it holds.
                let n = n.to_lowercase();
                let plain = n.strip_suffix(".gz").unwrap_or(&n);
                matches(&tokens, plain, &accept)
            })
            .collect();
        match hits.as_slice() {
            [] => {}
            [one] => found[i] = Some(folder.join(one)),
            [a, b, ..] => {
                return Err(Error::file(
                    folder,
                    format!(
                        "both '{a}' and '{b}' match [files] match = \"{}\" for {}: keep one",
                        files.pattern, SITES[i]
                    ),
                ));
            }
        }
    }
    Ok(found)
}

/// A sensor id for comparison: lower case, without the separator OpenSim puts in front.
fn normalise_id(id: &str) -> String {
    id.trim().trim_start_matches('_').to_ascii_lowercase()
}

/// The sensor ids of the sites a mapping file names: a CSV/TSV with an id column and a site
/// column, or an OpenSense `<ExperimentalSensor name="_ID"><name_in_model>` XML. Rows for other
/// body parts are skipped; a site given two ids is an error.
pub fn read_ids(path: &Path) -> Result<Vec<(usize, String)>, Error> {
    let text = read_text(path)?;
    let pairs = if text.trim_start().starts_with('<') {
        ids_from_xml(path, &text)?
    } else {
        ids_from_table(path, &text)?
    };
    let mut seen: BTreeMap<usize, (String, usize)> = BTreeMap::new();
    let mut out = Vec::new();
    for (line, id, name) in pairs {
        let Some(site) = site_of(&name) else { continue };
        if let Some((other, _)) = seen.get(&site) {
            return Err(Error::line(
                path,
                line,
                format!("{} is mapped twice: sensors {other} and {id}", SITES[site]),
            ));
        }
        seen.insert(site, (id.clone(), line));
        out.push((site, normalise_id(&id)));
    }
    Ok(out)
}

/// (line, id, body part) per row of a CSV/TSV mapping.
fn ids_from_table(path: &Path, text: &str) -> Result<Vec<(usize, String, String)>, Error> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l))
        .filter(|(_, l)| !l.trim().is_empty());
    let Some((_, header)) = lines.next() else {
        return Err(Error::file(path, "empty: no header row"));
    };
    let delimiter = ['\t', ';', ',']
        .into_iter()
        .find(|c| header.contains(*c))
        .unwrap_or(',');
    let cells = |l: &str| -> Vec<String> {
        l.split(delimiter)
            .map(|c| c.trim().trim_matches('"').to_owned())
            .collect()
    };
    let header = cells(header);
    let column = |names: &[&str], what: &str| {
        header
            .iter()
            .position(|h| names.contains(&normalise(h).as_str()))
            .ok_or_else(|| {
                Error::line(
                    path,
                    1,
                    format!(
                        "no {what} column (one of {}; columns: {})",
                        names.join(", "),
                        header.join(", ")
                    ),
                )
            })
    };
    let id = column(
        &["sensorid", "id", "sensor", "deviceid", "device"],
        "sensor id",
    )?;
    let part = column(
        &["segment", "site", "bodypart", "location", "nameinmodel"],
        "site",
    )?;
    lines
        .map(|(n, l)| {
            let c = cells(l);
            match (c.get(id), c.get(part)) {
                (Some(i), Some(p)) => Ok((n, i.clone(), p.clone())),
                _ => Err(Error::line(
                    path,
                    n,
                    format!(
                        "short row: {} cells, the header has {}",
                        c.len(),
                        header.len()
                    ),
                )),
            }
        })
        .collect()
}

/// (line, id, body part) per `<ExperimentalSensor>` of an OpenSense mapping.
fn ids_from_xml(path: &Path, text: &str) -> Result<Vec<(usize, String, String)>, Error> {
    let mut reader = Reader::from_str(text);
    reader.config_mut().trim_text(true);
    let mut out = Vec::new();
    let mut sensor: Option<(usize, String)> = None;
    let mut in_name = false;
    loop {
        let at = reader.buffer_position() as usize;
        let line = || crate::layout::line_of(text, at);
        match reader.read_event() {
            Err(e) => return Err(Error::line(path, line(), format!("broken XML: {e}"))),
            Ok(Event::Eof) => break,
            Ok(Event::Start(e)) => match e.name().as_ref() {
                b"ExperimentalSensor" => {
                    let name = e
                        .try_get_attribute("name")
                        .ok()
                        .flatten()
                        .and_then(|a| a.unescape_value().ok().map(|v| v.into_owned()))
                        .ok_or_else(|| {
                            Error::line(path, line(), "ExperimentalSensor without a name")
                        })?;
                    sensor = Some((line(), name));
                }
                b"name_in_model" => in_name = true,
                _ => {}
            },
            Ok(Event::Text(t)) if in_name => {
                let part = t
                    .decode()
                    .map_err(|e| Error::line(path, line(), format!("name_in_model: {e}")))?;
                if let Some((n, id)) = sensor.take() {
                    out.push((n, id, part.into_owned()));
                }
            }
            Ok(Event::End(e)) if e.name().as_ref() == b"name_in_model" => in_name = false,
            Ok(_) => {}
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn site(name: &str) -> Option<&'static str> {
        site_of(name).map(|i| SITES[i])
    }

    #[test]
    fn vendors_names_of_the_sites() {
        assert_eq!(site("left_forearm"), Some("left_forearm"));
        assert_eq!(site("LeftForeArm"), Some("left_forearm"));
        assert_eq!(site("Left Lower Leg"), Some("left_lower_leg"));
        assert_eq!(site("tibia_r_imu"), Some("right_lower_leg"));
        assert_eq!(site("LTibia"), Some("left_lower_leg"));
        assert_eq!(site("RTibia"), Some("right_lower_leg"));
        assert_eq!(site("Pelvis"), Some("pelvis"));
        assert_eq!(site("head"), Some("head"));
        // The lower-body sets' and the full suit's (Movella DOT tags, OpenSense's model bodies,
        // x-IMU3 folder names, MVN labels).
        assert_eq!(site("LFemur"), Some("left_upper_leg"));
        assert_eq!(site("femur_r_imu"), Some("right_upper_leg"));
        assert_eq!(site("Left Upper Leg"), Some("left_upper_leg"));
        assert_eq!(site("calcn_l_imu"), Some("left_foot"));
        assert_eq!(site("Right Foot"), Some("right_foot"));
        assert_eq!(site("torso_imu"), Some("sternum"));
        assert_eq!(site("T8"), Some("sternum"));
        // The Palermo MTw trial's sensors.csv.
        assert_eq!(site("stern"), Some("sternum"));
        assert_eq!(site("RightShoulder"), Some("right_shoulder"));
        assert_eq!(site("humerus_l_imu"), Some("left_upper_arm"));
        assert_eq!(site("right_hand"), Some("right_hand"));
        for (k, name) in SITES.iter().enumerate() {
            assert_eq!(site_of(name), Some(k), "{name}");
        }
        for other in ["sternal", "neck", "Left", "spine", "hips"] {
            assert_eq!(site(other), None, "{other}");
        }
    }

    #[test]
    fn patterns_capture_sites_and_ids() {
        let t = tokens("{site} *");
        let leg = |c: &str| site_of(c) == Some(2);
        assert!(matches(
            &t,
            &"Left Lower Leg 64F61CB3 (UDP)".to_lowercase(),
            &leg
        ));
        assert!(!matches(
            &t,
            &"Left Upper Leg 64F61CC4 (UDP)".to_lowercase(),
            &leg
        ));
        let t = tokens("*_{id}.csv");
        let id = |c: &str| c == "00b45c27";
        assert!(matches(&t, "example_calibration_xsens_00b45c27.csv", &id));
        assert!(!matches(
            &t,
            "example_calibration_xsens_00b45c27.csv.bak",
            &id
        ));
        assert!(!matches(&t, "example_calibration_xsens_00b45c28.csv", &id));
    }
}
