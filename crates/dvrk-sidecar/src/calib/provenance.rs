//! Where a calibration file came from: the arm, the instrument (the console's `tool_type`), the
//! date and the command, as `# key: value` comment lines at the top of every data file the
//! procedures write, and carried by `fit` into the parameter file's header. `fit` refuses to mix
//! files of different instruments.
//!
//! The readers of the data files skip lines that start with `#`, so files with a provenance
//! block and files without one (the 2017 recordings, files of earlier versions) read the same.

use std::io::Read;
use std::path::Path;

/// The provenance of one file; fields absent from the file are `None`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Provenance {
    pub arm: Option<String>,
    pub instrument: Option<String>,
    pub date: Option<String>,
    pub command: Option<String>,
    /// `calibrate dynamics --robot`: the rate (Hz) at which the excitation was commanded in
    /// steps (one `servo_jp` per console `measured_js`), which `fit --dynamics` needs when the
    /// rows are faster (`--measure sidecar`). Absent: the motion is smooth at the rows' rate.
    pub commanded_hz: Option<String>,
}

impl Provenance {
    /// This process's provenance: the command line as typed and the current date.
    pub fn now(arm: &str, instrument: Option<&str>) -> Self {
        Self {
            arm: Some(arm.to_owned()),
            instrument: instrument.map(str::to_owned),
            date: Some(utc_now()),
            command: Some(command_line()),
            commanded_hz: None,
        }
    }

    /// The `# key: value` lines (each value on one line).
    pub fn lines(&self) -> String {
        let mut s = String::new();
        for (k, v) in [
            ("arm", &self.arm),
            ("instrument", &self.instrument),
            ("date", &self.date),
            ("command", &self.command),
            ("commanded_hz", &self.commanded_hz),
        ] {
            if let Some(v) = v {
                let v: String = v.chars().map(|c| if c == '\n' { ' ' } else { c }).collect();
                s.push_str(&format!("# {k}: {v}\n"));
            }
        }
        s
    }

    /// The instrument without the console's version range (`NAME:MODEL[..]` -> `NAME:MODEL`),
    /// for comparing two files.
    pub fn instrument_model(&self) -> Option<&str> {
        self.instrument
            .as_deref()
            .map(|s| s.split('[').next().unwrap_or(s).trim())
    }
}

/// Reads the provenance block of `path` (its leading `#` lines, within the first 64 kB).
pub fn read(path: &Path) -> anyhow::Result<Provenance> {
    let mut head = Vec::new();
    crate::files::open_regular(path, crate::files::DATA_MAX_BYTES)?
        .take(64 * 1024)
        .read_to_end(&mut head)?;
    let text = String::from_utf8_lossy(&head);
    let mut p = Provenance::default();
    for line in text.lines() {
        let Some(rest) = line.strip_prefix('#') else {
            break;
        };
        let Some((k, v)) = rest.split_once(':') else {
            continue;
        };
        let v = Some(v.trim().to_owned());
        match k.trim() {
            "arm" => p.arm = v,
            "instrument" => p.instrument = v,
            "date" => p.date = v,
            "command" => p.command = v,
            "commanded_hz" => p.commanded_hz = v,
            _ => {}
        }
    }
    Ok(p)
}

/// Checks that the files name one instrument (files that name none are accepted); returns it.
pub fn one_instrument<'a>(
    files: impl IntoIterator<Item = (&'a Path, &'a Provenance)>,
) -> anyhow::Result<Option<String>> {
    let mut seen: Option<(String, &Path)> = None;
    for (path, p) in files {
        let Some(model) = p.instrument_model() else {
            continue;
        };
        match &seen {
            None => seen = Some((model.to_owned(), path)),
            Some((first, first_path)) if first != model => anyhow::bail!(
                "{} was recorded with instrument {model}, {} with {first}: one parameter set is \
                 for one instrument; fit each instrument's files separately",
                path.display(),
                first_path.display()
            ),
            Some(_) => {}
        }
    }
    Ok(seen.map(|(m, _)| m))
}

/// The command line, arguments with spaces or quotes quoted.
pub fn command_line() -> String {
    std::env::args()
        .enumerate()
        .map(|(i, a)| {
            let a = if i == 0 {
                Path::new(&a)
                    .file_name()
                    .map_or(a.clone(), |n| n.to_string_lossy().into_owned())
            } else {
                a
            };
            if a.is_empty() || a.contains([' ', '\'', '"', '\t']) {
                format!("'{}'", a.replace('\'', "'\\''"))
            } else {
                a
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// The current UTC time as `YYYY-MM-DDTHH:MM:SSZ`.
pub fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    utc(secs)
}

/// `secs` since the Unix epoch as `YYYY-MM-DDTHH:MM:SSZ` (proleptic Gregorian calendar).
pub fn utc(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    // Days since 1970-01-01 to a civil date, by 400-year eras starting on March 1st.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_dates() {
        assert_eq!(utc(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(utc(1_795_564_800 + 3_661), "2026-11-25T01:01:01Z");
    }

    #[test]
    fn lines_read_back_and_instruments_compare_without_their_range() {
        let dir = std::env::temp_dir().join(format!("dvrk-prov-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let a = Provenance {
            arm: Some("PSM1".into()),
            instrument: Some("LARGE_NEEDLE_DRIVER:400006[..]".into()),
            date: Some("2026-11-25T01:01:01Z".into()),
            command: Some("dvrk-sidecar calibrate clamp --robot ros2:PSM1".into()),
            commanded_hz: Some("99.8".into()),
        };
        let pa = dir.join("a.csv");
        std::fs::write(&pa, format!("{}joint,x\n1,2\n", a.lines())).unwrap();
        assert_eq!(read(&pa).unwrap(), a);
        let b = Provenance {
            instrument: Some("LARGE_NEEDLE_DRIVER:400006".into()),
            ..Provenance::default()
        };
        let c = Provenance {
            instrument: Some("CADIERE_FORCEPS:400049[..]".into()),
            ..Provenance::default()
        };
        let none = Provenance::default();
        let (p1, p2) = (Path::new("a.csv"), Path::new("b.csv"));
        assert_eq!(
            one_instrument([(p1, &a), (p2, &b), (p2, &none)])
                .unwrap()
                .as_deref(),
            Some("LARGE_NEEDLE_DRIVER:400006")
        );
        let e = one_instrument([(p1, &a), (p2, &c)])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("CADIERE_FORCEPS:400049") && e.contains("a.csv"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
