//! One JSON shape per message, shared by `echo --json`, `fk --json` and (mirrored) the Python
//! client:
//!
//! - every message: `{"topic": "PSM1/measured_js", "header": {...}, ...body}`; the header has
//!   `seq`, `sample_t_ns`, `sample_realtime_ns`, `publish_t_ns`, `board_timestamp`,
//!   `valid` (a boolean) and `flags` (a list of flag names);
//! - joint states: `name`, `position`, `velocity`, `effort` (lists; the jaw's have one entry);
//! - poses: `position_m` (3), `orientation_xyzw` (4), `rotation` (3×3, a list of rows);
//! - the status: its field names (without `_reserved`).

use dvrk_ipc::{
    CompensationStatusV4, Header, JAW_NAME, JOINT_NAMES, JawStateV1, JointStateV2, PoseV2,
};
use serde_json::{Map, Value, json};

/// The header object.
pub fn header(h: &Header) -> Value {
    json!({
        "seq": h.seq,
        "sample_t_ns": h.sample_t_ns,
        "sample_realtime_ns": h.sample_realtime_ns,
        "publish_t_ns": h.publish_t_ns,
        "board_timestamp": h.board_timestamp,
        "valid": h.valid != 0,
        "flags": dvrk_ipc::flags::names(h.flags).collect::<Vec<_>>(),
    })
}

fn message(topic: &str, h: &Header, body: Value) -> Value {
    let mut m = Map::new();
    m.insert("topic".into(), Value::from(topic));
    m.insert("header".into(), header(h));
    if let Value::Object(b) = body {
        m.extend(b);
    }
    Value::Object(m)
}

/// A pose body without topic and header (what `fk --json` prints).
pub fn pose_body(position_m: [f64; 3], orientation_xyzw: [f64; 4], rotation: &[f64; 9]) -> Value {
    json!({
        "position_m": position_m,
        "orientation_xyzw": orientation_xyzw,
        "rotation": [
            [rotation[0], rotation[1], rotation[2]],
            [rotation[3], rotation[4], rotation[5]],
            [rotation[6], rotation[7], rotation[8]],
        ],
    })
}

pub fn joint_state(topic: &str, m: &JointStateV2) -> Value {
    message(
        topic,
        &m.header,
        json!({ "name": JOINT_NAMES, "position": m.position, "velocity": m.velocity,
                "effort": m.effort }),
    )
}

pub fn jaw_state(topic: &str, m: &JawStateV1) -> Value {
    message(
        topic,
        &m.header,
        json!({ "name": [JAW_NAME], "position": [m.position], "velocity": [m.velocity],
                "effort": [m.effort] }),
    )
}

pub fn pose(topic: &str, m: &PoseV2) -> Value {
    message(
        topic,
        &m.header,
        pose_body(m.position_m, m.orientation_xyzw, &m.rotation),
    )
}

pub fn status(topic: &str, m: &CompensationStatusV4) -> Value {
    message(
        topic,
        &m.header,
        json!({ "tau_ext_nm": m.tau_ext_nm, "delta_rad": m.delta_rad,
                "insertion_m": m.insertion_m, "cycle_period_ns": m.cycle_period_ns,
                "cycle_duration_ns": m.cycle_duration_ns, "cycles_total": m.cycles_total,
                "read_failures_total": m.read_failures_total, "overruns_total": m.overruns_total,
                "consecutive_read_failures": m.consecutive_read_failures,
                "tau_margin_nm": m.tau_margin_nm, "held_sample_age_ns": m.held_sample_age_ns,
                "publish_late_ns": m.publish_late_ns, "implausible_total": m.implausible_total,
                "source_state": m.source_state, "source": source_json(m),
                "bound_rad": m.bound_rad, "tip_bound_m": m.tip_bound_m, "weight": m.weight }),
    )
}

/// `source_state` spelled out: the console's state, the parameter set, the instrument's name.
fn source_json(m: &dvrk_ipc::CompensationStatusV4) -> serde_json::Value {
    let instrument = match m.instrument_code() {
        0 => "not known".to_owned(),
        1 => "removed".to_owned(),
        2 => "not modelled".to_owned(),
        c => dvrk_compliance::instruments()
            .get(usize::from(c - 3))
            .map_or_else(|| format!("#{}", c - 3), |i| i.tool_type().to_string()),
    };
    json!({ "console_state": m.console_state(), "homed": m.console_homed(),
            "console_heard": m.console_heard(), "parameter_set": m.parameter_set(),
            "instrument": instrument })
}

/// The Python client's copy of the instrument catalog's names (python/dvrk_sidecar/instruments.py),
/// in catalog order: what a `source_state` instrument code names.
pub fn python_instruments() -> String {
    let mut s = String::from(
        "\"\"\"The service's instrument catalog, in order: `source_state` instrument code 3 + i names\n\
         INSTRUMENTS[i]. Generated from dvrk_compliance::instruments() (a test of dvrk-sidecar\n\
         checks it; DVRK_REGENERATE=1 rewrites it).\"\"\"\n\nINSTRUMENTS = (\n",
    );
    for i in dvrk_compliance::instruments() {
        s.push_str(&format!("    \"{}\",\n", i.tool_type()));
    }
    s.push_str(")\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_python_client_names_the_instruments_of_the_catalog() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../python/dvrk_sidecar/instruments.py");
        let want = python_instruments();
        if std::env::var_os("DVRK_REGENERATE").is_some() {
            std::fs::write(&path, &want).unwrap();
        }
        assert_eq!(
            std::fs::read_to_string(&path).unwrap_or_default(),
            want,
            "{} is out of date: DVRK_REGENERATE=1 cargo test -p dvrk-sidecar the_python_client",
            path.display()
        );
    }

    #[test]
    fn every_message_has_topic_header_and_its_body() {
        let h = Header {
            seq: 3,
            sample_realtime_ns: 9,
            valid: 1,
            flags: dvrk_ipc::flags::SIMULATED | dvrk_ipc::flags::HELD,
            ..Header::default()
        };
        let p = PoseV2 {
            header: h,
            rotation: [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0],
            ..PoseV2::default()
        };
        let v = pose("PSM1/local/measured_cp", &p);
        assert_eq!(v["topic"], "PSM1/local/measured_cp");
        assert_eq!(v["header"]["valid"], true);
        assert_eq!(v["header"]["sample_realtime_ns"], 9);
        assert_eq!(v["header"]["flags"], json!(["SIMULATED", "HELD"]));
        assert_eq!(
            v["rotation"],
            json!([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]])
        );
        let j = jaw_state(
            "PSM1/jaw/measured_js",
            &JawStateV1 {
                header: h,
                position: 0.5,
                ..Default::default()
            },
        );
        assert_eq!(j["name"], json!(["jaw"]));
        assert_eq!(j["position"], json!([0.5]));
        let js = joint_state(
            "PSM1/measured_js",
            &JointStateV2 {
                header: h,
                ..Default::default()
            },
        );
        assert_eq!(js["name"].as_array().unwrap().len(), 6);
        let st = status("PSM1/compensated/status", &CompensationStatusV4::default());
        assert_eq!(st["header"]["valid"], false);
        assert!(st.get("_reserved").is_none());
        assert!(st.get("implausible_total").is_some());
    }
}
