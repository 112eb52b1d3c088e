//! Naming conventions shared by every graph and every sink: how a grouped input (one variant of a
//! comparison, or any group a graph author chooses) is named on a sink, and the entity path a
//! viewer shows it at.
//!
//! A sink input named `<group>__<what>` (e.g. `pip__motion`) carries `<what>` of `<group>`; the rerun
//! logger draws it at the entity path `<group>/<what>` (`pip/motion`), one entity root per group.
//! `imuflow compare` names each variant's inputs on its recorder and logger so; a hand-written graph
//! may do the same to group its own inputs. docs/architecture.md ("Conventions") states the rule.

/// Separator in a sink input name between the group and what it carries (`pip__motion`).
pub const GROUP_SEPARATOR: &str = "__";

/// The sink input name of `what` in `group`: `grouped("pip", "motion")` is `pip__motion`.
pub fn grouped(group: &str, what: &str) -> String {
    format!("{group}{GROUP_SEPARATOR}{what}")
}

/// The entity path of a sink input: `<group>__<what>` becomes `<group>/<what>`; an input without
/// a group keeps its name.
pub fn entity_of(input: &str) -> String {
    input.replace(GROUP_SEPARATOR, "/")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grouped_input_becomes_an_entity_under_its_group() {
        assert_eq!(grouped("pip", "motion"), "pip__motion");
        assert_eq!(entity_of(&grouped("pip", "motion")), "pip/motion");
        assert_eq!(entity_of("motion"), "motion");
        assert_eq!(entity_of("no-physics__body_imu"), "no-physics/body_imu");
    }
}
