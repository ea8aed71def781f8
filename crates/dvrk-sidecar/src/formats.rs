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

/// One parameter set of a compliance file: the instrument it was fitted for (`None`: not
/// recorded, used for any instrument) and its parameters.
#[derive(Debug, Clone)]
pub struct ParamSet {
    pub instrument: Option<&'static dvrk_compliance::Instrument>,
    pub config: ComplianceConfig,
}

/// A compliance file with one set (the project's parameter file, its instrument on fit's
/// `# instrument:` line) or several (`[[set]]` tables, each with `instrument = "NAME:MODEL"` and
/// the keys of a one-set file, as `fit --add` writes them). Errors name the set.
pub fn compliance_sets_from_toml(text: &str) -> Result<Vec<ParamSet>> {
    let table: toml::Table = crate::files::from_toml(text)?;
    let Some(sets) = table.get("set") else {
        let instrument = text
            .lines()
            .take_while(|l| l.starts_with('#') || l.trim().is_empty())
            .find_map(|l| l.strip_prefix("# instrument:"))
            .map(str::trim)
            .filter(|s| !s.is_empty() && *s != "not recorded")
            .map(|s| crate::config::find_instrument(s).context("its `# instrument:` line"))
            .transpose()?;
        return Ok(vec![ParamSet {
            instrument,
            config: compliance_from_toml(text)?,
        }]);
    };
    if table.len() != 1 {
        anyhow::bail!("a file of `[[set]]` tables has nothing else at its top level");
    }
    let Some(sets) = sets.as_array() else {
        anyhow::bail!("`set` must be an array of tables (`[[set]]`)");
    };
    if sets.is_empty() {
        anyhow::bail!("`[[set]]`: no parameter set");
    }
    let mut out: Vec<ParamSet> = Vec::new();
    for (i, s) in sets.iter().enumerate() {
        let Some(t) = s.as_table() else {
            anyhow::bail!("set {}: not a table", i + 1);
        };
        let mut t = t.clone();
        let name = match t.remove("instrument") {
            Some(toml::Value::String(n)) => n,
            _ => anyhow::bail!("set {}: `instrument = \"NAME:MODEL\"` is required", i + 1),
        };
        let inst = crate::config::find_instrument(&name)
            .with_context(|| format!("set {}: instrument = \"{name}\"", i + 1))?;
        if out
            .iter()
            .any(|o| o.instrument.is_some_and(|x| x.model == inst.model))
        {
            anyhow::bail!("set {}: a second set for instrument {name}", i + 1);
        }
        let text = toml::to_string(&t).context("re-reading a set")?;
        let config = compliance_from_toml(&text)
            .with_context(|| format!("set {} (instrument {name})", i + 1))?;
        out.push(ParamSet {
            instrument: Some(inst),
            config,
        });
    }
    Ok(out)
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

#[cfg(test)]
mod sets_tests {
    use super::*;

    fn sim_params() -> String {
        std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../config/compliance/sim-psm.toml"),
        )
        .unwrap()
    }

    #[test]
    fn sets_per_instrument_and_one_set_files_read() {
        let text = sim_params();
        let one = compliance_sets_from_toml(&text).unwrap();
        assert_eq!(one.len(), 1);
        assert!(one[0].instrument.is_none());
        let tagged = format!("# instrument: CADIERE_FORCEPS:400049\n{text}");
        let one = compliance_sets_from_toml(&tagged).unwrap();
        assert_eq!(one[0].instrument.unwrap().model, 400049);
        let body = text
            .replace("[[joint]]", "[[set.joint]]")
            .replace("[joint.", "[set.joint.");
        let two = format!(
            "[[set]]\ninstrument = \"LARGE_NEEDLE_DRIVER:400006\"\n{body}\n\
             [[set]]\ninstrument = \"CADIERE_FORCEPS:400049\"\n{body}\n"
        );
        let sets = compliance_sets_from_toml(&two).unwrap();
        let models: Vec<u32> = sets.iter().map(|s| s.instrument.unwrap().model).collect();
        assert_eq!(models, [400006, 400049]);
        // the same instrument twice, or a set without one: refused, naming the set
        let dup = two.replace("CADIERE_FORCEPS:400049", "LARGE_NEEDLE_DRIVER:400006");
        let e = format!("{:#}", compliance_sets_from_toml(&dup).unwrap_err());
        assert!(e.contains("set 2") && e.contains("a second set"), "{e}");
        let none = two.replace("instrument = \"CADIERE_FORCEPS:400049\"\n", "");
        let e = format!("{:#}", compliance_sets_from_toml(&none).unwrap_err());
        assert!(e.contains("set 2") && e.contains("required"), "{e}");
    }
}
