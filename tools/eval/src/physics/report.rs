//! The text `imuflow eval-physics` prints: a table of the methods and, with validation, a second
//! table of the simulation's scores.

use std::fmt;

use super::{MethodTotals, PhysicsReport};

impl fmt::Display for PhysicsReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "test split of {} (augmented copies), {} kinematics, {} sequences",
            self.data.display(),
            self.net.name(),
            self.sequences
        )?;
        f.write_str(&table(&self.methods, self.mass_kg))?;
        if let Some(truth) = &self.truth_validation {
            writeln!(
                f,
                "\nvalidation (rapier3d simulation tracking each output; torques mode unless noted)\n{:<11} {:>10} {:>10} {:>10} {:>11} {:>10}",
                "motion", "falls/min", "track cm", "skate m/s", "resid. mg", "support %"
            )?;
            writeln!(f, "{:<11} {}", "truth", truth.columns())?;
            for (name, totals) in &self.methods {
                if let Some(v) = &totals.validation {
                    writeln!(f, "{:<11} {}", name, v.columns())?;
                }
            }
            writeln!(
                f,
                "track: mean joint distance simulation-estimate; skate: simulated feet in contact; resid.: residual mode's mean root force / body weight; support: judged frames whose needed centre of pressure is > 3 cm outside the feet or unsupported (no simulation)"
            )?;
        }
        Ok(())
    }
}

fn table(methods: &[(String, MethodTotals)], mass_kg: f64) -> String {
    let mut out = format!(
        "{:<11} {:>8} {:>9} {:>9} {:>9} {:>11} {:>9} {:>16} {:>9} {:>9}\n",
        "method",
        "frames",
        "jitter",
        "root jit",
        "skate m/s",
        "penetr. cm",
        "TE@2m cm",
        "standing GRF/mg",
        "fallbacks",
        "µs/frame"
    );
    for (name, s) in methods {
        let n = s.frames.max(1) as f64;
        let standing = if s.standing_frames > 0 {
            format!(
                "{:.2} ({:.0}%≤10%)",
                s.standing_ratio_sum / s.standing_frames as f64,
                100.0 * s.standing_within_10 as f64 / s.standing_frames as f64
            )
        } else {
            "-".into()
        };
        let te = if s.translation_sequences > 0 {
            format!(
                "{:.1}",
                100.0 * s.translation_sum / s.translation_sequences as f64
            )
        } else {
            "-".into()
        };
        out.push_str(&format!(
            "{:<11} {:>8} {:>9.3} {:>9.3} {:>9.3} {:>11.2} {:>9} {:>16} {:>9} {:>9.0}\n",
            name,
            s.frames,
            s.jitter / n,
            s.root_jitter / n,
            s.skating / n,
            100.0 * s.penetration / n,
            te,
            standing,
            s.fallbacks,
            s.seconds * 1e6 / n,
        ));
    }
    out.push_str(&format!(
        "jitter in km/s³ (world joint positions; root: translation only); body mass {mass_kg} kg\n"
    ));
    out
}
