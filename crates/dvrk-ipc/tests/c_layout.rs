//! `include/dvrk_ipc.h` describes the same bytes as the Rust types: a C (and a C++) program
//! compiled against the header prints sizeof/alignof/offsetof of every type and field and the
//! value of every constant, and the test compares them with the Rust side.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use dvrk_ipc::{
    CompensationStatusV4, Header, JOINT_NAMES, JawStateV1, JointStateV2, Message, NUM_JOINTS,
    PoseV2, Topic, flags, qos,
};

/// `(type, field)` of every field, in declaration order.
const FIELDS: &[(&str, &str)] = &[
    ("dvrk_Header", "seq"),
    ("dvrk_Header", "sample_t_ns"),
    ("dvrk_Header", "sample_realtime_ns"),
    ("dvrk_Header", "board_timestamp"),
    ("dvrk_Header", "publish_t_ns"),
    ("dvrk_Header", "valid"),
    ("dvrk_Header", "flags"),
    ("dvrk_JointStateV2", "header"),
    ("dvrk_JointStateV2", "position"),
    ("dvrk_JointStateV2", "velocity"),
    ("dvrk_JointStateV2", "effort"),
    ("dvrk_JawStateV1", "header"),
    ("dvrk_JawStateV1", "position"),
    ("dvrk_JawStateV1", "velocity"),
    ("dvrk_JawStateV1", "effort"),
    ("dvrk_PoseV2", "header"),
    ("dvrk_PoseV2", "position_m"),
    ("dvrk_PoseV2", "orientation_xyzw"),
    ("dvrk_PoseV2", "rotation"),
    ("dvrk_CompensationStatusV4", "header"),
    ("dvrk_CompensationStatusV4", "tau_ext_nm"),
    ("dvrk_CompensationStatusV4", "delta_rad"),
    ("dvrk_CompensationStatusV4", "insertion_m"),
    ("dvrk_CompensationStatusV4", "cycle_period_ns"),
    ("dvrk_CompensationStatusV4", "cycle_duration_ns"),
    ("dvrk_CompensationStatusV4", "cycles_total"),
    ("dvrk_CompensationStatusV4", "read_failures_total"),
    ("dvrk_CompensationStatusV4", "overruns_total"),
    ("dvrk_CompensationStatusV4", "consecutive_read_failures"),
    ("dvrk_CompensationStatusV4", "source_state"),
    ("dvrk_CompensationStatusV4", "tau_margin_nm"),
    ("dvrk_CompensationStatusV4", "held_sample_age_ns"),
    ("dvrk_CompensationStatusV4", "publish_late_ns"),
    ("dvrk_CompensationStatusV4", "implausible_total"),
    ("dvrk_CompensationStatusV4", "bound_rad"),
    ("dvrk_CompensationStatusV4", "tip_bound_m"),
    ("dvrk_CompensationStatusV4", "weight"),
    ("dvrk_CompensationStatusV4", "_reserved"),
];

const TYPES: &[&str] = &[
    "dvrk_Header",
    "dvrk_JointStateV2",
    "dvrk_JawStateV1",
    "dvrk_PoseV2",
    "dvrk_CompensationStatusV4",
];

/// Integer constants of the header and their Rust values.
fn int_constants() -> Vec<(&'static str, u64)> {
    let mut v: Vec<(&'static str, u64)> = vec![
        ("DVRK_IPC_NUM_JOINTS", NUM_JOINTS as u64),
        ("DVRK_IPC_QOS_MAX_PUBLISHERS", qos::MAX_PUBLISHERS as u64),
        ("DVRK_IPC_QOS_MAX_SUBSCRIBERS", qos::MAX_SUBSCRIBERS as u64),
        (
            "DVRK_IPC_QOS_SUBSCRIBER_MAX_BUFFER_SIZE",
            qos::SUBSCRIBER_MAX_BUFFER_SIZE as u64,
        ),
        (
            "DVRK_IPC_QOS_SUBSCRIBER_MAX_BORROWED_SAMPLES",
            qos::SUBSCRIBER_MAX_BORROWED_SAMPLES as u64,
        ),
        ("DVRK_IPC_QOS_HISTORY_SIZE", qos::HISTORY_SIZE as u64),
        (
            "DVRK_IPC_QOS_ENABLE_SAFE_OVERFLOW",
            qos::ENABLE_SAFE_OVERFLOW as u64,
        ),
        ("DVRK_IPC_QOS_MAX_NODES", qos::MAX_NODES as u64),
        (
            "DVRK_IPC_QOS_EVENT_MAX_NOTIFIERS",
            qos::EVENT_MAX_NOTIFIERS as u64,
        ),
        (
            "DVRK_IPC_QOS_EVENT_MAX_LISTENERS",
            qos::EVENT_MAX_LISTENERS as u64,
        ),
        (
            "DVRK_IPC_DEADLINE_PERIODS",
            dvrk_ipc::DEADLINE_PERIODS as u64,
        ),
        (
            "DVRK_IPC_NOMINAL_PERIOD_NS",
            dvrk_ipc::NOMINAL_PERIOD.as_nanos() as u64,
        ),
        ("DVRK_IPC_FLAG_FAULT_MASK", flags::FAULT_MASK as u64),
    ];
    let flag_macros = [
        "DVRK_IPC_FLAG_BOARD_TIMEOUT",
        "DVRK_IPC_FLAG_BOARD_ERROR",
        "DVRK_IPC_FLAG_WATCHDOG_TIMEOUT",
        "DVRK_IPC_FLAG_POWER_OFF",
        "DVRK_IPC_FLAG_ENCODER_ERROR",
        "DVRK_IPC_FLAG_AMP_FAULT",
        "DVRK_IPC_FLAG_INSERTION_CLAMPED",
        "DVRK_IPC_FLAG_CORRECTION_ACTIVE_J1",
        "DVRK_IPC_FLAG_CORRECTION_ACTIVE_J2",
        "DVRK_IPC_FLAG_SIMULATED",
        "DVRK_IPC_FLAG_OVERRUN",
        "DVRK_IPC_FLAG_IMPLAUSIBLE",
        "DVRK_IPC_FLAG_NO_SOURCE",
        "DVRK_IPC_FLAG_HELD",
        "DVRK_IPC_FLAG_NOT_HOMED",
        "DVRK_IPC_FLAG_ARM_NOT_ENABLED",
        "DVRK_IPC_FLAG_CONSOLE_UNKNOWN",
        "DVRK_IPC_FLAG_NO_INSTRUMENT",
        "DVRK_IPC_FLAG_INSTRUMENT_UNSUPPORTED",
        "DVRK_IPC_FLAG_NO_CALIBRATION",
        "DVRK_IPC_FLAG_BASE_FRAME_STALE",
        "DVRK_IPC_FLAG_WARMUP",
        "DVRK_IPC_FLAG_GAP",
        "DVRK_IPC_FLAG_TRANSIENT",
        "DVRK_IPC_FLAG_ACCEL_OUT_OF_RANGE",
        "DVRK_IPC_FLAG_INSERTION_EXTRAPOLATED",
        "DVRK_IPC_FLAG_INSERTION_OUT_OF_RANGE",
        "DVRK_IPC_FLAG_STILL_ONLY",
        "DVRK_IPC_FLAG_REDUCED",
        "DVRK_IPC_FLAG_POT_MISMATCH",
        "DVRK_IPC_FLAG_POSITION_OUT_OF_RANGE",
    ];
    assert_eq!(flag_macros.len(), flags::TABLE.len(), "a flag is missing");
    for (mac, (bit, name)) in flag_macros.iter().zip(flags::TABLE) {
        assert!(mac.ends_with(name), "{mac} vs {name}");
        v.push((mac, bit as u64));
    }
    v
}

/// String constants of the header and their Rust values.
fn string_constants() -> Vec<(&'static str, String)> {
    vec![
        ("DVRK_IPC_DEFAULT_PREFIX", dvrk_ipc::DEFAULT_PREFIX.into()),
        (
            "DVRK_IPC_SUFFIX_MEASURED_JS",
            Topic::MeasuredJs.suffix().into(),
        ),
        (
            "DVRK_IPC_SUFFIX_JAW_MEASURED_JS",
            Topic::JawMeasuredJs.suffix().into(),
        ),
        (
            "DVRK_IPC_SUFFIX_LOCAL_MEASURED_CP",
            Topic::LocalMeasuredCp.suffix().into(),
        ),
        (
            "DVRK_IPC_SUFFIX_MEASURED_CP",
            Topic::MeasuredCp.suffix().into(),
        ),
        (
            "DVRK_IPC_SUFFIX_COMPENSATED_MEASURED_JS",
            Topic::CompensatedMeasuredJs.suffix().into(),
        ),
        (
            "DVRK_IPC_SUFFIX_COMPENSATED_JAW_MEASURED_JS",
            Topic::CompensatedJawMeasuredJs.suffix().into(),
        ),
        (
            "DVRK_IPC_SUFFIX_COMPENSATED_LOCAL_MEASURED_CP",
            Topic::CompensatedLocalMeasuredCp.suffix().into(),
        ),
        (
            "DVRK_IPC_SUFFIX_COMPENSATED_MEASURED_CP",
            Topic::CompensatedMeasuredCp.suffix().into(),
        ),
        (
            "DVRK_IPC_SUFFIX_COMPENSATED_STATUS",
            Topic::CompensatedStatus.suffix().into(),
        ),
        ("DVRK_IPC_SUFFIX_CYCLE", dvrk_ipc::CYCLE_SUFFIX.into()),
        (
            "DVRK_IPC_SUFFIX_CYCLE_FIRST",
            dvrk_ipc::CYCLE_FIRST_SUFFIX.into(),
        ),
        (
            "DVRK_IPC_TYPE_NAME_JOINT_STATE_V2",
            JointStateV2::TYPE_NAME.into(),
        ),
        (
            "DVRK_IPC_TYPE_NAME_JAW_STATE_V1",
            JawStateV1::TYPE_NAME.into(),
        ),
        ("DVRK_IPC_TYPE_NAME_POSE_V2", PoseV2::TYPE_NAME.into()),
        (
            "DVRK_IPC_TYPE_NAME_COMPENSATION_STATUS_V4",
            CompensationStatusV4::TYPE_NAME.into(),
        ),
        ("DVRK_IPC_JAW_NAME", dvrk_ipc::JAW_NAME.into()),
    ]
}

/// What the Rust types say, as `key -> value` lines identical in format to the C program's.
fn rust_layout() -> BTreeMap<String, String> {
    use core::mem::{align_of, offset_of, size_of, size_of_val};
    let mut m = BTreeMap::new();
    let mut put = |k: String, v: String| {
        assert!(m.insert(k.clone(), v).is_none(), "duplicate key {k}");
    };
    macro_rules! ty {
        ($c:literal, $t:ty, [$($f:ident),+]) => {
            put(format!("sizeof {}", $c), size_of::<$t>().to_string());
            put(format!("alignof {}", $c), align_of::<$t>().to_string());
            let v: $t = unsafe { core::mem::zeroed() };
            $(
                put(format!("offsetof {}.{}", $c, stringify!($f)), offset_of!($t, $f).to_string());
                put(format!("sizeof {}.{}", $c, stringify!($f)), size_of_val(&v.$f).to_string());
            )+
        };
    }
    ty!(
        "dvrk_Header",
        Header,
        [
            seq,
            sample_t_ns,
            sample_realtime_ns,
            board_timestamp,
            publish_t_ns,
            valid,
            flags
        ]
    );
    ty!(
        "dvrk_JointStateV2",
        JointStateV2,
        [header, position, velocity, effort]
    );
    ty!(
        "dvrk_JawStateV1",
        JawStateV1,
        [header, position, velocity, effort]
    );
    ty!(
        "dvrk_PoseV2",
        PoseV2,
        [header, position_m, orientation_xyzw, rotation]
    );
    ty!(
        "dvrk_CompensationStatusV4",
        CompensationStatusV4,
        [
            header,
            tau_ext_nm,
            delta_rad,
            insertion_m,
            cycle_period_ns,
            cycle_duration_ns,
            cycles_total,
            read_failures_total,
            overruns_total,
            consecutive_read_failures,
            source_state,
            tau_margin_nm,
            held_sample_age_ns,
            publish_late_ns,
            implausible_total,
            bound_rad,
            tip_bound_m,
            weight,
            _reserved
        ]
    );
    for (name, value) in int_constants() {
        put(format!("const {name}"), value.to_string());
    }
    for (name, value) in string_constants() {
        put(format!("str {name}"), value);
    }
    for (i, name) in JOINT_NAMES.iter().enumerate() {
        put(format!("joint {i}"), (*name).to_owned());
    }
    m
}

/// The C program: one `key value` line per Rust entry.
fn c_source() -> String {
    let mut s = String::from(
        "#include <stdio.h>\n#include <stddef.h>\n#include \"dvrk_ipc.h\"\n\
         #define SIZEOF_FIELD(t, f) sizeof(((t*)0)->f)\n\
         #ifdef __cplusplus\n#define ALIGNOF(t) alignof(t)\n#else\n#define ALIGNOF(t) _Alignof(t)\n#endif\n\
         int main(void) {\n",
    );
    for t in TYPES {
        s += &format!("  printf(\"sizeof {t} %zu\\n\", sizeof({t}));\n");
        s += &format!("  printf(\"alignof {t} %zu\\n\", (size_t)ALIGNOF({t}));\n");
    }
    for (t, f) in FIELDS {
        s += &format!("  printf(\"offsetof {t}.{f} %zu\\n\", offsetof({t}, {f}));\n");
        s += &format!("  printf(\"sizeof {t}.{f} %zu\\n\", SIZEOF_FIELD({t}, {f}));\n");
    }
    for (name, _) in int_constants() {
        s += &format!("  printf(\"const {name} %llu\\n\", (unsigned long long)({name}));\n");
    }
    for (name, _) in string_constants() {
        s += &format!("  printf(\"str {name} %s\\n\", {name});\n");
    }
    s += "  { const char* names[] = DVRK_IPC_JOINT_NAMES;\n";
    s += "    for (size_t i = 0; i < sizeof(names) / sizeof(names[0]); ++i)\n";
    s += "      printf(\"joint %zu %s\\n\", i, names[i]); }\n";
    s += "  return 0;\n}\n";
    s
}

fn find_compiler(candidates: &[&str]) -> Option<String> {
    candidates
        .iter()
        .find(|c| Command::new(c).arg("--version").output().is_ok())
        .map(|c| (*c).to_owned())
}

fn include_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("include")
}

fn scratch_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dvrk_ipc_{tag}_{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scratch dir");
    dir
}

/// Compiles `src` with `compiler args`, runs it, parses `key value` lines.
fn compile_and_run(compiler: &str, args: &[&str], tag: &str) -> BTreeMap<String, String> {
    let dir = scratch_dir(tag);
    let src = dir.join("layout.c");
    let exe = dir.join("layout");
    std::fs::write(&src, c_source()).expect("write C source");
    let out = Command::new(compiler)
        .args(args)
        .arg("-I")
        .arg(include_dir())
        .arg(&src)
        .arg("-o")
        .arg(&exe)
        .output()
        .expect("run compiler");
    assert!(
        out.status.success(),
        "{compiler} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let run = Command::new(&exe).output().expect("run layout program");
    assert!(run.status.success());
    let _ = std::fs::remove_dir_all(&dir);
    let mut m = BTreeMap::new();
    for line in String::from_utf8(run.stdout).expect("utf8").lines() {
        // Keys have one space ("sizeof T", "joint 3"); the value is the rest.
        let mut parts = line.splitn(3, ' ');
        let (a, b, v) = (
            parts.next().unwrap(),
            parts.next().unwrap(),
            parts.next().unwrap_or(""),
        );
        m.insert(format!("{a} {b}"), v.to_owned());
    }
    m
}

fn assert_same(c: &BTreeMap<String, String>, what: &str) {
    let rust = rust_layout();
    let mut diffs = Vec::new();
    for (k, v) in &rust {
        match c.get(k) {
            Some(cv) if cv == v => {}
            other => diffs.push(format!("{k}: rust {v}, {what} {other:?}")),
        }
    }
    for k in c.keys() {
        if !rust.contains_key(k) {
            diffs.push(format!("{k}: only in {what}"));
        }
    }
    assert!(
        diffs.is_empty(),
        "header and Rust differ:\n{}",
        diffs.join("\n")
    );
    // Sanity: the comparison covered every field.
    assert_eq!(
        c.keys().filter(|k| k.starts_with("offsetof ")).count(),
        FIELDS.len()
    );
}

#[test]
fn c_header_matches_rust_layouts() {
    let Some(cc) = find_compiler(&["cc", "gcc", "clang"]) else {
        common::skip_unless_ci("no C compiler (cc, gcc, clang) found");
        return;
    };
    let c = compile_and_run(
        &cc,
        &["-std=c11", "-Wall", "-Wextra", "-Werror", "-pedantic"],
        "c",
    );
    assert_same(&c, "C");
}

#[test]
fn cxx_header_matches_rust_layouts() {
    let Some(cxx) = find_compiler(&["c++", "g++", "clang++"]) else {
        common::skip_unless_ci("no C++ compiler (c++, g++, clang++) found");
        return;
    };
    // The same program as C++17 (the header adds IOX2_TYPE_NAME members there).
    let c = compile_and_run(
        &cxx,
        &[
            "-x",
            "c++",
            "-std=c++17",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-Wno-invalid-offsetof",
        ],
        "cxx",
    );
    assert_same(&c, "C++");
}

#[test]
fn the_comparison_detects_a_wrong_header() {
    // Compile against a header with one field moved: the test machinery must notice.
    let Some(cc) = find_compiler(&["cc", "gcc", "clang"]) else {
        common::skip_unless_ci("no C compiler found");
        return;
    };
    let dir = scratch_dir("bad");
    let good = std::fs::read_to_string(include_dir().join("dvrk_ipc.h")).unwrap();
    let bad = good
        .replace(
            "    uint32_t valid;\n    uint32_t flags;",
            "    uint32_t flags;\n    uint32_t valid;",
        )
        .replace(
            "DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_Header, valid) == 40, \"dvrk_Header.valid offset\");",
            "",
        )
        .replace(
            "DVRK_IPC_STATIC_ASSERT(offsetof(dvrk_Header, flags) == 44, \"dvrk_Header.flags offset\");",
            "",
        );
    assert_ne!(good, bad, "the swap applied");
    std::fs::write(dir.join("dvrk_ipc.h"), bad).unwrap();
    std::fs::write(dir.join("layout.c"), c_source()).unwrap();
    let out = Command::new(&cc)
        .args(["-std=c11", "-I"])
        .arg(&dir)
        .arg(dir.join("layout.c"))
        .arg("-o")
        .arg(dir.join("layout"))
        .output()
        .unwrap();
    assert!(out.status.success());
    let run = Command::new(dir.join("layout")).output().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let text = String::from_utf8(run.stdout).unwrap();
    let valid_line = text
        .lines()
        .find(|l| l.starts_with("offsetof dvrk_Header.valid "))
        .unwrap();
    assert_eq!(valid_line, "offsetof dvrk_Header.valid 44");
    assert_eq!(
        rust_layout()["offsetof dvrk_Header.valid"],
        "40",
        "so assert_same would report the difference"
    );
}
