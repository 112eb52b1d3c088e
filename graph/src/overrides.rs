//! `--set key=value` overrides, applied to the parsed TOML before validation so that overridden
//! values are checked exactly like written ones.

/// Applies one `dotted.key=value` assignment. The value parses as a TOML value (`3`, `true`,
/// `"text"`, `[1, 2]`); anything that does not parse is taken as a plain string, so
/// `--set stages.kin.params.net=globalpose` needs no quotes. Missing tables on the way are created.
pub fn apply(table: &mut toml::Table, assignment: &str) -> Result<(), String> {
    let (key, raw) = assignment
        .split_once('=')
        .ok_or_else(|| "expected KEY=VALUE (e.g. stages.kin.params.net=globalpose)".to_owned())?;
    let path: Vec<&str> = key.trim().split('.').collect();
    if path.iter().any(|p| p.is_empty()) {
        return Err(format!("'{key}' is not a dotted key"));
    }
    let value = parse_value(raw.trim());
    let (last, parents) = path.split_last().ok_or_else(|| "empty key".to_owned())?;
    let mut current = table;
    for (depth, part) in parents.iter().enumerate() {
        let entry = current
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        current = match entry {
            toml::Value::Table(t) => t,
            other => {
                return Err(format!(
                    "'{}' is a {}, not a table",
                    path[..=depth].join("."),
                    other.type_str()
                ));
            }
        };
    }
    current.insert(last.to_string(), value);
    Ok(())
}

/// A `--set` value: a TOML value (`3`, `true`, `"text"`, `[1, 2]`), or the text as a string when it is not one.
pub fn parse_value(raw: &str) -> toml::Value {
    format!("v = {raw}")
        .parse::<toml::Table>()
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_owned()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sets_typed_and_bare_values_creating_tables() {
        let mut t: toml::Table = "[stages.kin]\nkind = \"x\"".parse().expect("valid toml");
        apply(&mut t, "stages.kin.params.net=globalpose").expect("applies");
        apply(&mut t, "stages.kin.params.hidden=256").expect("applies");
        apply(&mut t, "rate_hz = 30.5").expect("applies");
        let params = &t["stages"]["kin"]["params"];
        assert_eq!(params["net"].as_str(), Some("globalpose"));
        assert_eq!(params["hidden"].as_integer(), Some(256));
        assert_eq!(t["rate_hz"].as_float(), Some(30.5));
    }

    #[test]
    fn rejects_bad_assignments() {
        let mut t: toml::Table = "name = \"g\"".parse().expect("valid toml");
        assert!(
            apply(&mut t, "no-equals-sign")
                .unwrap_err()
                .contains("KEY=VALUE")
        );
        assert!(apply(&mut t, "a..b=1").unwrap_err().contains("dotted key"));
        let err = apply(&mut t, "name.inner=1").unwrap_err();
        assert!(err.contains("'name' is a string, not a table"), "{err}");
    }
}
