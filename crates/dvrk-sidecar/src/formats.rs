//! The text formats of the project's files, parsed here and only here: the library crates take
//! their parsed `*Params` and validate them (ARCHITECTURE.md: no TOML or JSON library in the
//! pure core or the hardware crate). Errors carry the parser's line and column; callers add the
//! file name.

use anyhow::{Context, Result};
use dvrk_compliance::{ComplianceConfig, ComplianceParams};
use dvrk_io::IoConfig;
use dvrk_io::convert::{IoParams, SawFile, strip_json_comments};
use dvrk_sim::{Scenario, ScenarioParams};

/// A compliance parameter file (config/compliance/*.toml).
pub fn compliance_from_toml(text: &str) -> Result<ComplianceConfig> {
    let params: ComplianceParams = crate::files::from_toml(text)?;
    Ok(ComplianceConfig::from_params(params)?)
}

/// This project's actuator conversion file (config/io/*.toml).
pub fn io_from_toml(text: &str) -> Result<IoConfig> {
    let params: IoParams = crate::files::from_toml(text)?;
    Ok(IoConfig::from_params(params)?)
}

/// The dVRK's own sawRobotIO1394 JSON file (version 6, comments allowed); its first robot.
pub fn io_from_saw_json(text: &str) -> Result<IoConfig> {
    let file: SawFile = serde_json::from_str(&strip_json_comments(text))
        .map_err(|e| anyhow::anyhow!("{}", crate::files::quote(&e.to_string())))
        .context("sawRobotIO1394 JSON")?;
    Ok(IoConfig::from_saw_file(file, None)?)
}

/// A simulator scenario (config/sim/*.toml).
pub fn scenario_from_toml(text: &str) -> Result<Scenario> {
    let params: ScenarioParams = crate::files::from_toml(text)?;
    Ok(Scenario::from_params(params)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_errors_carry_line_and_key() {
        let e = format!(
            "{:#}",
            compliance_from_toml("model = \"paper\"\n[[joint]\n").unwrap_err()
        );
        assert!(e.contains("line 2"), "{e}");
        let e = format!(
            "{:#}",
            compliance_from_toml("model = \"paper\"\njoint = []\nextra = 1\n").unwrap_err()
        );
        assert!(e.contains("line 3") && e.contains("extra"), "{e}");
        let e = format!("{:#}", io_from_saw_json("{ \"$version\": ").unwrap_err());
        assert!(
            e.contains("sawRobotIO1394 JSON") && e.contains("line 1"),
            "{e}"
        );
    }

    #[test]
    fn validation_errors_come_through() {
        let text = "[[joint]]\nindex = 3\nbacklash_rad = 0.0\ntau_min_nm = 0.1\n\
                    inverse_compliance_nm_per_rad = [0.0, 0.0, 0.0, 10.0]\n\
                    insertion_range_m = [0.09, 0.22]\n\
                    torque_offset = { position_rad = [0.0], effort_nm = [0.0] }\n";
        let e = format!("{:#}", compliance_from_toml(text).unwrap_err());
        assert!(e.contains("index = 3"), "{e}");
    }
}
