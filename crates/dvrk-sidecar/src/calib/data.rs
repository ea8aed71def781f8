//! Calibration data files: the project's CSV layout and import of the dVRK 2017 layouts.
//!
//! Project layout (one averaged step per row, units in the header):
//! `joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction`
//! with `joint` 1 (yaw) or 2 (pitch) and `direction` +1, -1 or 0.
//!
//! dVRK 2017 layouts, recognised by their header line (they do not say which joint they hold, so
//! the caller must):
//! - clamp: `pos index,depth index,depth,current joint position,current joint effort,current torque offset`
//! - torque-offset sweep: `position index,depth index,current depth,current joint position,current torque offset`
//!   (the last column is the unloaded effort; it becomes `effort_nm`, with `torque_offset_nm` 0).
//!
//! The 2017 rows carry no direction (0): the fit derives it from the order of the rows.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use dvrk_compliance::fit::DataRow;

use crate::files::{Bounded, DATA_MAX_BYTES, open_regular, quote};

/// Header of the project's calibration CSV.
pub const HEADER: [&str; 7] = [
    "joint",
    "depth_index",
    "insertion_m",
    "position_rad",
    "effort_nm",
    "torque_offset_nm",
    "direction",
];

const DVRK2017_CLAMP: [&str; 6] = [
    "pos index",
    "depth index",
    "depth",
    "current joint position",
    "current joint effort",
    "current torque offset",
];

const DVRK2017_TORQUE_OFFSET: [&str; 5] = [
    "position index",
    "depth index",
    "current depth",
    "current joint position",
    "current torque offset",
];

/// Which layout a file has, from its header line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    Project,
    Dvrk2017Clamp,
    Dvrk2017TorqueOffset,
}

impl Layout {
    /// Whether rows of this layout need the joint from the command line.
    pub fn needs_joint(self) -> bool {
        !matches!(self, Layout::Project)
    }

    fn detect(header: &csv::StringRecord) -> Option<Self> {
        let names: Vec<&str> = header.iter().map(str::trim).collect();
        if names == HEADER {
            Some(Layout::Project)
        } else if names == DVRK2017_CLAMP {
            Some(Layout::Dvrk2017Clamp)
        } else if names == DVRK2017_TORQUE_OFFSET {
            Some(Layout::Dvrk2017TorqueOffset)
        } else {
            None
        }
    }
}

fn reader(path: &Path) -> anyhow::Result<csv::Reader<Bounded>> {
    let file = open_regular(path, DATA_MAX_BYTES)?;
    Ok(csv::ReaderBuilder::new()
        .has_headers(true)
        // the provenance block (`# arm: ...`, see provenance.rs)
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_reader(file))
}

/// Reads the header line of `path` and says which layout it is.
pub fn detect_layout(path: &Path) -> anyhow::Result<Layout> {
    let mut rdr = reader(path)?;
    let header = rdr
        .headers()
        .with_context(|| format!("{}: reading the header line", path.display()))?
        .clone();
    Layout::detect(&header).with_context(|| {
        format!(
            "{}: unknown header `{}`; expected `{}`, or the dVRK 2017 clamp header `{}`, or the dVRK 2017 torque-offset header `{}`",
            path.display(),
            quote(&header.iter().collect::<Vec<_>>().join(",")),
            HEADER.join(","),
            DVRK2017_CLAMP.join(","),
            DVRK2017_TORQUE_OFFSET.join(",")
        )
    })
}

fn field<'a>(
    rec: &'a csv::StringRecord,
    i: usize,
    name: &str,
    path: &Path,
    line: u64,
) -> anyhow::Result<&'a str> {
    rec.get(i)
        .with_context(|| format!("{} line {line}: missing column `{name}`", path.display()))
}

fn number(
    rec: &csv::StringRecord,
    i: usize,
    name: &str,
    path: &Path,
    line: u64,
) -> anyhow::Result<f64> {
    let s = field(rec, i, name, path, line)?;
    let v: f64 = s.parse().with_context(|| {
        format!(
            "{} line {line}: column `{name}` = `{}` is not a number",
            path.display(),
            quote(s)
        )
    })?;
    if !v.is_finite() {
        bail!(
            "{} line {line}: column `{name}` = `{}` is not finite",
            path.display(),
            quote(s)
        );
    }
    Ok(v)
}

/// A number of column `name` within `[lo, hi]` (`unit` for the message): the physical bounds
/// of [`dvrk_compliance::bounds`], so that 1e308 rad cannot become a data point (issue 22).
#[allow(clippy::too_many_arguments)]
fn bounded(
    rec: &csv::StringRecord,
    i: usize,
    name: &str,
    path: &Path,
    line: u64,
    [lo, hi]: [f64; 2],
    unit: &str,
) -> anyhow::Result<f64> {
    let v = number(rec, i, name, path, line)?;
    within(
        v,
        [lo, hi],
        unit,
        path,
        line,
        format_args!("column `{name}`"),
    )
}

/// `v` if it lies within `[lo, hi]`, else an error naming the file, the line, the value (`what`,
/// e.g. a column) and the physical range: the one check of every data file's bounds (the CSV
/// layouts here, the dynamics file of `calibrate dynamics`).
pub(crate) fn within(
    v: f64,
    [lo, hi]: [f64; 2],
    unit: &str,
    path: &Path,
    line: u64,
    what: std::fmt::Arguments<'_>,
) -> anyhow::Result<f64> {
    if !(lo..=hi).contains(&v) {
        bail!(
            "{} line {line}: {what} = {v:?} {unit} is outside the physical range [{lo}, {hi}] {unit}",
            path.display()
        );
    }
    Ok(v)
}

/// The bounds of a data file's columns: position of `joint` (1 or 2), insertion, effort.
fn ranges(joint: u8) -> ([f64; 2], [f64; 2], [f64; 2]) {
    let range = dvrk_compliance::bounds::PSM_JOINT_RANGE;
    let e = dvrk_compliance::bounds::MAX_ABS_EFFORT;
    (range[usize::from(joint == 2)], range[2], [-e, e])
}

fn integer<T: std::str::FromStr>(
    rec: &csv::StringRecord,
    i: usize,
    name: &str,
    path: &Path,
    line: u64,
) -> anyhow::Result<T> {
    let s = field(rec, i, name, path, line)?;
    s.parse().ok().with_context(|| {
        format!(
            "{} line {line}: column `{name}` = `{}` is not a valid integer here",
            path.display(),
            quote(s)
        )
    })
}

/// Reads every row of a calibration file. `joint` (1 or 2) is required for the 2017 layouts and
/// must be `None` for the project layout, whose rows name their joint.
pub fn read_rows(path: &Path, joint: Option<u8>) -> anyhow::Result<(Layout, Vec<DataRow>)> {
    let layout = detect_layout(path)?;
    if layout.needs_joint() && joint.is_none() {
        bail!(
            "{} is in the dVRK 2017 layout, which does not say which joint it holds: pass --joint 1 or --joint 2",
            path.display()
        );
    }
    if let Some(j) = joint
        && j != 1
        && j != 2
    {
        bail!("--joint {j}: the joint must be 1 (yaw) or 2 (pitch)");
    }
    let mut rdr = reader(path)?;
    let mut rows = Vec::new();
    for rec in rdr.records() {
        let rec = rec.with_context(|| format!("reading {}", path.display()))?;
        let line = rec.position().map_or(0, |p| p.line());
        let row = match layout {
            Layout::Project => {
                let j: u8 = integer(&rec, 0, "joint", path, line)?;
                if j != 1 && j != 2 {
                    bail!(
                        "{} line {line}: joint = {j}; must be 1 (yaw) or 2 (pitch)",
                        path.display()
                    );
                }
                let direction: i8 = integer(&rec, 6, "direction", path, line)?;
                if !(-1..=1).contains(&direction) {
                    bail!(
                        "{} line {line}: direction = {direction}; must be -1, 0 or 1",
                        path.display()
                    );
                }
                let (q, l, e) = ranges(j);
                DataRow {
                    joint: j,
                    depth_index: integer(&rec, 1, "depth_index", path, line)?,
                    insertion_m: bounded(&rec, 2, "insertion_m", path, line, l, "m")?,
                    position_rad: bounded(&rec, 3, "position_rad", path, line, q, "rad")?,
                    effort_nm: bounded(&rec, 4, "effort_nm", path, line, e, "N·m")?,
                    torque_offset_nm: bounded(&rec, 5, "torque_offset_nm", path, line, e, "N·m")?,
                    direction,
                }
            }
            Layout::Dvrk2017Clamp => {
                let (q, l, e) = ranges(joint.unwrap_or(0));
                DataRow {
                    joint: joint.unwrap_or(0),
                    depth_index: integer(&rec, 1, "depth index", path, line)?,
                    insertion_m: bounded(&rec, 2, "depth", path, line, l, "m")?,
                    position_rad: bounded(&rec, 3, "current joint position", path, line, q, "rad")?,
                    effort_nm: bounded(&rec, 4, "current joint effort", path, line, e, "N·m")?,
                    torque_offset_nm: bounded(
                        &rec,
                        5,
                        "current torque offset",
                        path,
                        line,
                        e,
                        "N·m",
                    )?,
                    direction: 0,
                }
            }
            Layout::Dvrk2017TorqueOffset => {
                let (q, l, e) = ranges(joint.unwrap_or(0));
                DataRow {
                    joint: joint.unwrap_or(0),
                    depth_index: integer(&rec, 1, "depth index", path, line)?,
                    insertion_m: bounded(&rec, 2, "current depth", path, line, l, "m")?,
                    position_rad: bounded(&rec, 3, "current joint position", path, line, q, "rad")?,
                    effort_nm: bounded(&rec, 4, "current torque offset", path, line, e, "N·m")?,
                    torque_offset_nm: 0.0,
                    direction: 0,
                }
            }
        };
        rows.push(row);
    }
    if rows.is_empty() {
        bail!("{}: no data rows after the header", path.display());
    }
    Ok((layout, rows))
}

/// Writes rows in the project layout to `out`.
pub fn write_rows<W: Write>(out: W, rows: &[DataRow]) -> anyhow::Result<()> {
    let mut w = csv::Writer::from_writer(out);
    w.write_record(HEADER)?;
    for r in rows {
        w.write_record([
            r.joint.to_string(),
            r.depth_index.to_string(),
            format!("{:?}", r.insertion_m),
            format!("{:?}", r.position_rad),
            format!("{:?}", r.effort_nm),
            format!("{:?}", r.torque_offset_nm),
            r.direction.to_string(),
        ])?;
    }
    w.flush()?;
    Ok(())
}

/// Checks that `path` can be an output file: a new path or an existing regular file, with a
/// parent directory that exists. The CLI runs it on every `--out` before any work starts, and
/// [`write_atomically`] again just before it writes.
///
/// Anything else that exists is refused, naming it: the write goes to a temporary file that is
/// then renamed onto `path`, which would replace a device node such as `/dev/null` (run as
/// root) or a FIFO with a regular file (issue 22). A symbolic link is refused too, even to a
/// regular file: the rename would replace the link itself and leave the file it points to
/// unchanged, the opposite of what the user asked; the message names the target to give
/// instead.
pub fn check_output_path(path: &Path) -> anyhow::Result<()> {
    if path.as_os_str().is_empty() {
        anyhow::bail!("the output path is empty");
    }
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        let ft = meta.file_type();
        if ft.is_symlink() {
            let target = std::fs::read_link(path)
                .map(|t| t.display().to_string())
                .unwrap_or_else(|_| "?".to_owned());
            anyhow::bail!(
                "{} is a symbolic link (to {target}); --out replaces the path given, so name the \
                 file itself",
                path.display()
            );
        }
        if !ft.is_file() && !ft.is_dir() {
            anyhow::bail!(
                "{} exists and is {}, not a regular file; --out writes only a regular file or a \
                 new path",
                path.display(),
                crate::files::kind(ft)
            );
        }
    }
    if path.is_dir() {
        anyhow::bail!(
            "{} is a directory; give a file path inside it, e.g. {}",
            path.display(),
            path.join("NAME").display()
        );
    }
    if path.file_name().is_none() {
        anyhow::bail!("{}: not a file path", path.display());
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !parent.is_dir() {
        anyhow::bail!(
            "{}: the directory {} does not exist",
            path.display(),
            parent.display()
        );
    }
    Ok(())
}

/// Writes `bytes` to `path` through a temporary file beside it (same directory, so the rename
/// is atomic) and a rename, so a reader never sees a half-written file. The temporary file is
/// removed on every error path, and a directory is refused before anything is written.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    check_output_path(path)?;
    let name = path
        .file_name()
        .with_context(|| format!("{}: not a file path", path.display()))?;
    let tmp = path.with_file_name(format!(".{}.partial", name.to_string_lossy()));
    // A stale temporary file (or a link planted in its place) is removed, and the new one is
    // created exclusively, so the write never follows a link to somewhere else.
    let _ = std::fs::remove_file(&tmp);
    let result = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&tmp)
        .and_then(|mut f| f.write_all(bytes).and_then(|()| f.sync_all()))
        .with_context(|| format!("writing {}", tmp.display()))
        .and_then(|()| {
            std::fs::rename(&tmp, path)
                .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
        });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Reads several files; `joints` gives the joint of each 2017-layout file: either one value for
/// all of them, or one per 2017 file in command-line order. Depth indices of later files that
/// repeat a joint are shifted past the earlier ones, so that two recordings of one depth index
/// are never merged into one (the fit reads each depth's rows in recorded order).
pub fn read_files(
    paths: &[PathBuf],
    joints: &[u8],
    legacy_seen: &mut usize,
) -> anyhow::Result<Vec<DataRow>> {
    let mut all: Vec<DataRow> = Vec::new();
    for path in paths {
        let layout = detect_layout(path)?;
        let joint = if layout.needs_joint() {
            let j = match joints {
                [] => None,
                [one] => Some(*one),
                many => Some(*many.get(*legacy_seen).with_context(|| {
                    format!(
                        "{}: {} --joint values given, but this is dVRK 2017 file number {}; give one --joint for all or one per 2017 file",
                        path.display(),
                        many.len(),
                        *legacy_seen + 1
                    )
                })?),
            };
            *legacy_seen += 1;
            j
        } else {
            None
        };
        let (_, mut rows) = read_rows(path, joint)?;
        for j in [1u8, 2] {
            let shift = all
                .iter()
                .filter(|r| r.joint == j)
                .map(|r| r.depth_index + 1)
                .max()
                .unwrap_or(0);
            rows.iter_mut()
                .filter(|r| r.joint == j)
                .for_each(|r| r.depth_index += shift);
        }
        all.extend(rows);
    }
    Ok(all)
}

#[cfg(test)]
mod output_tests {
    use super::*;

    #[test]
    fn a_directory_is_refused_and_nothing_is_left_behind() {
        let dir = std::env::temp_dir().join(format!("dvrk-out-{}", std::process::id()));
        let target = dir.join("params");
        std::fs::create_dir_all(&target).unwrap();
        let e = write_atomically(&target, b"x").unwrap_err().to_string();
        assert!(e.contains("is a directory"), "{e}");
        assert!(
            std::fs::read_dir(&dir).unwrap().count() == 1,
            "only the directory itself is there"
        );
        let e = check_output_path(&dir.join("missing/p.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("does not exist"), "{e}");
        // Issue 22: a FIFO, a device and a symbolic link are refused, and stay what they were.
        let fifo = dir.join("fifo");
        let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: mkfifo(3) with a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = write_atomically(&fifo, b"x").unwrap_err().to_string();
        assert!(e.contains("fifo") && e.contains("named pipe"), "{e}");
        assert!(std::os::unix::fs::FileTypeExt::is_fifo(
            &std::fs::metadata(&fifo).unwrap().file_type()
        ));
        let e = check_output_path(Path::new("/dev/null"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("/dev/null") && e.contains("character device"),
            "{e}"
        );
        let link = dir.join("link.toml");
        std::os::unix::fs::symlink(dir.join("p.toml"), &link).unwrap();
        let e = write_atomically(&link, b"x").unwrap_err().to_string();
        assert!(
            e.contains("link.toml") && e.contains("symbolic link"),
            "{e}"
        );
        std::fs::remove_file(&fifo).unwrap();
        std::fs::remove_file(&link).unwrap();
        // A good path: written, no temporary file left.
        let f = dir.join("p.toml");
        write_atomically(&f, b"ok").unwrap();
        assert_eq!(std::fs::read(&f).unwrap(), b"ok");
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 2, "{names:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str, text: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("dvrk-calib-data-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn project_layout_round_trip() {
        let rows = vec![
            DataRow {
                joint: 2,
                depth_index: 3,
                insertion_m: 0.12,
                position_rad: -0.001,
                effort_nm: 0.3,
                torque_offset_nm: 0.1,
                direction: -1,
            };
            2
        ];
        let mut buf = Vec::new();
        write_rows(&mut buf, &rows).unwrap();
        let text = String::from_utf8(buf).unwrap();
        assert!(text.starts_with(
            "joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction\n"
        ));
        let p = tmp("round.csv", &text);
        let (layout, back) = read_rows(&p, None).unwrap();
        assert_eq!(layout, Layout::Project);
        assert_eq!(back, rows);
    }

    #[test]
    fn dvrk2017_needs_joint() {
        let p = tmp(
            "legacy.csv",
            "pos index,depth index,depth,current joint position,current joint effort,current torque offset\n0,0,0.1,0.0,0.2,0.1\n",
        );
        let err = read_rows(&p, None).unwrap_err().to_string();
        assert!(err.contains("--joint"), "{err}");
        let (layout, rows) = read_rows(&p, Some(2)).unwrap();
        assert_eq!(layout, Layout::Dvrk2017Clamp);
        assert_eq!(rows[0].joint, 2);
        assert!((rows[0].tau_ext_nm() - 0.1).abs() < 1e-12);
        assert!(read_rows(&p, Some(3)).is_err());
    }

    #[test]
    fn dvrk2017_sweep_effort_is_the_offset_column() {
        let p = tmp(
            "sweep.csv",
            "position index,depth index,current depth,current joint position,current torque offset\n1,0,0.09,-0.002,0.092\n",
        );
        let (layout, rows) = read_rows(&p, Some(1)).unwrap();
        assert_eq!(layout, Layout::Dvrk2017TorqueOffset);
        assert_eq!(rows[0].effort_nm, 0.092);
        assert_eq!(rows[0].torque_offset_nm, 0.0);
    }

    #[test]
    fn bad_files_name_line_and_column() {
        let p = tmp("bad-header.csv", "a,b,c\n1,2,3\n");
        let err = format!("{:#}", read_rows(&p, None).unwrap_err());
        assert!(err.contains("unknown header `a,b,c`"), "{err}");
        let p = tmp(
            "bad-number.csv",
            "joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction\n1,0,0.1,abc,0,0,1\n",
        );
        let err = format!("{:#}", read_rows(&p, None).unwrap_err());
        assert!(
            err.contains("line 2") && err.contains("position_rad") && err.contains("abc"),
            "{err}"
        );
        let p = tmp(
            "bad-joint.csv",
            "joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction\n3,0,0.1,0,0,0,1\n",
        );
        assert!(format!("{:#}", read_rows(&p, None).unwrap_err()).contains("joint = 3"));
        let p = tmp(
            "nan.csv",
            "joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction\n1,0,0.1,NaN,0,0,1\n",
        );
        assert!(format!("{:#}", read_rows(&p, None).unwrap_err()).contains("not finite"));
        let p = tmp(
            "short.csv",
            "joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction\n1,0,0.1\n",
        );
        assert!(read_rows(&p, None).is_err());
    }

    #[test]
    fn unphysical_numbers_are_refused_naming_file_line_column_and_value() {
        let project =
            "joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction\n";
        for (row, column, value) in [
            ("1,0,0.1,1e308,0,0,1", "position_rad", "1e308 rad"),
            ("2,0,0.1,-1.3,0,0,1", "position_rad", "-1.3 rad"),
            ("1,0,0.5,0,0,0,1", "insertion_m", "0.5 m"),
            ("1,0,-0.01,0,0,0,1", "insertion_m", "-0.01 m"),
            ("1,0,0.1,0,51,0,1", "effort_nm", "51.0 N·m"),
            ("1,0,0.1,0,0,-1e300,1", "torque_offset_nm", "-1e300 N·m"),
        ] {
            let p = tmp("unphysical.csv", &format!("{project}{row}\n"));
            let err = format!("{:#}", read_rows(&p, None).unwrap_err());
            assert!(
                err.contains("unphysical.csv line 2")
                    && err.contains(&format!("`{column}` = {value}"))
                    && err.contains("physical range"),
                "{row}: {err}"
            );
        }
        // The range's ends pass.
        let p = tmp("ends.csv", &format!("{project}2,0,0.29,1.301,-50,50,1\n"));
        assert!(read_rows(&p, None).is_ok());
        // The 2017 layout and divot files too.
        let p = tmp(
            "legacy-unphysical.csv",
            "pos index,depth index,depth,current joint position,current joint effort,current torque offset\n0,0,0.1,1e308,0.2,0.1\n",
        );
        let err = format!("{:#}", read_rows(&p, Some(1)).unwrap_err());
        assert!(
            err.contains("line 2") && err.contains("`current joint position` = 1e308 rad"),
            "{err}"
        );
        let mut row = DivotRow {
            push_index: 0,
            joint: 1,
            direction: 1,
            t_s: 0.0,
            position: [0.1, -0.2, 0.12, 0.0, 0.1, -0.1],
            effort: [0.2, -0.9, 1.0],
            truth: None,
        };
        let mut buf = Vec::new();
        write_divot(&mut buf, &[row]).unwrap();
        let p = tmp("divot-ok.csv", std::str::from_utf8(&buf).unwrap());
        assert!(read_divot(&p).is_ok());
        row.position[0] = 1e308;
        let mut buf = Vec::new();
        write_divot(&mut buf, &[row]).unwrap();
        let p = tmp("divot-1e308.csv", std::str::from_utf8(&buf).unwrap());
        let err = format!("{:#}", read_divot(&p).unwrap_err());
        assert!(
            err.contains("divot-1e308.csv line 2") && err.contains("= 1e308 rad"),
            "{err}"
        );
    }

    #[test]
    fn divot_round_trip_with_and_without_truth() {
        let mut row = DivotRow {
            push_index: 3,
            joint: 2,
            direction: -1,
            t_s: 1.5,
            position: [0.1, -0.2, 0.12, 0.0, 0.1, -0.1],
            effort: [0.2, -0.9, 1.0],
            truth: None,
        };
        for truth in [
            None,
            Some(DivotTruth {
                position_rad: [0.1, -0.19],
                tip_m: [0.01, 0.02, -0.12],
            }),
        ] {
            row.truth = truth;
            let mut buf = Vec::new();
            write_divot(&mut buf, &[row, row]).unwrap();
            let p = tmp("divot.csv", &String::from_utf8(buf).unwrap());
            assert_eq!(read_divot(&p).unwrap(), vec![row, row]);
        }
        let p = tmp("divot-bad.csv", "push_index,joint\n0,1\n");
        assert!(format!("{:#}", read_divot(&p).unwrap_err()).contains("a divot file has"));
    }

    #[test]
    fn repeated_depths_of_a_joint_are_kept_apart() {
        let text = "joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction\n1,0,0.1,0,0,0,1\n1,1,0.11,0,0,0,1\n";
        let a = tmp("a.csv", text);
        let b = tmp("b.csv", text);
        let mut seen = 0;
        let rows = read_files(&[a, b], &[], &mut seen).unwrap();
        let idx: Vec<u32> = rows.iter().map(|r| r.depth_index).collect();
        assert_eq!(idx, vec![0, 1, 2, 3]);
    }
}

/// Header of the divot-push data file (one averaged step per row). Positions of joints 1-6 are
/// recorded so that the tip can be computed with the instrument's kinematics.
pub const DIVOT_HEADER: [&str; 13] = [
    "push_index",
    "joint",
    "direction",
    "t_s",
    "position_1_rad",
    "position_2_rad",
    "insertion_m",
    "position_4_rad",
    "position_5_rad",
    "position_6_rad",
    "effort_1_nm",
    "effort_2_nm",
    "effort_3_n",
];

/// Ground-truth columns a simulator adds after [`DIVOT_HEADER`]: the true (shaft-side) angles of
/// joints 1 and 2 and the true tip position in the RCM frame.
pub const DIVOT_TRUTH_HEADER: [&str; 5] = [
    "true_position_1_rad",
    "true_position_2_rad",
    "true_tip_x_m",
    "true_tip_y_m",
    "true_tip_z_m",
];

/// Ground truth of one divot row (simulator data only).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DivotTruth {
    pub position_rad: [f64; 2],
    pub tip_m: [f64; 3],
}

/// One row of a divot-push file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DivotRow {
    /// 0 = joint 1 pushed +, 1 = joint 1 -, 2 = joint 2 +, 3 = joint 2 -.
    pub push_index: u32,
    /// Joint pushed, 1 or 2.
    pub joint: u8,
    /// Direction of the step that led here (+1, -1, 0 at the start).
    pub direction: i8,
    pub t_s: f64,
    /// Joints 1-6 (rad, rad, m, rad, rad, rad).
    pub position: [f64; 6],
    /// Joints 1-3 (N·m, N·m, N).
    pub effort: [f64; 3],
    pub truth: Option<DivotTruth>,
}

/// Reads a divot-push file (with or without the truth columns).
pub fn read_divot(path: &Path) -> anyhow::Result<Vec<DivotRow>> {
    let mut rdr = reader(path)?;
    let header = rdr
        .headers()
        .with_context(|| format!("{}: reading the header line", path.display()))?
        .clone();
    let names: Vec<&str> = header.iter().map(str::trim).collect();
    let with_truth: Vec<&str> = DIVOT_HEADER
        .iter()
        .chain(DIVOT_TRUTH_HEADER.iter())
        .copied()
        .collect();
    let truth = if names == with_truth {
        true
    } else if names == DIVOT_HEADER {
        false
    } else {
        bail!(
            "{}: unknown header `{}`; a divot file has `{}`, optionally followed by `{}`",
            path.display(),
            quote(&names.join(",")),
            DIVOT_HEADER.join(","),
            DIVOT_TRUTH_HEADER.join(",")
        );
    };
    let mut rows = Vec::new();
    for rec in rdr.records() {
        let rec = rec.with_context(|| format!("reading {}", path.display()))?;
        let line = rec.position().map_or(0, |p| p.line());
        let joint: u8 = integer(&rec, 1, "joint", path, line)?;
        if joint != 1 && joint != 2 {
            bail!(
                "{} line {line}: joint = {joint}; must be 1 or 2",
                path.display()
            );
        }
        let direction: i8 = integer(&rec, 2, "direction", path, line)?;
        if !(-1..=1).contains(&direction) {
            bail!(
                "{} line {line}: direction = {direction}; must be -1, 0 or 1",
                path.display()
            );
        }
        // Physical bounds (issue 22): joints 1-2 and insertion within the PSM's range, the
        // wrist within a turn, efforts within MAX_ABS_EFFORT.
        let (q1, l, e) = ranges(1);
        let (q2, _, _) = ranges(2);
        let wrist = [-std::f64::consts::PI, std::f64::consts::PI];
        let b = |i: usize, range: [f64; 2], unit: &str| {
            bounded(&rec, i, with_truth[i], path, line, range, unit)
        };
        let time = dvrk_compliance::bounds::MAX_ABS_TIME_S;
        let tip = dvrk_compliance::bounds::MAX_TIP_COORDINATE_M;
        rows.push(DivotRow {
            push_index: integer(&rec, 0, "push_index", path, line)?,
            joint,
            direction,
            t_s: b(3, [-time, time], "s")?,
            position: [
                b(4, q1, "rad")?,
                b(5, q2, "rad")?,
                b(6, l, "m")?,
                b(7, wrist, "rad")?,
                b(8, wrist, "rad")?,
                b(9, wrist, "rad")?,
            ],
            effort: [b(10, e, "N·m")?, b(11, e, "N·m")?, b(12, e, "N")?],
            truth: if truth {
                Some(DivotTruth {
                    position_rad: [b(13, q1, "rad")?, b(14, q2, "rad")?],
                    tip_m: [
                        b(15, [-tip, tip], "m")?,
                        b(16, [-tip, tip], "m")?,
                        b(17, [-tip, tip], "m")?,
                    ],
                })
            } else {
                None
            },
        });
    }
    if rows.is_empty() {
        bail!("{}: no data rows after the header", path.display());
    }
    Ok(rows)
}

/// Writes divot rows; the truth columns are written when every row has truth.
pub fn write_divot<W: Write>(out: W, rows: &[DivotRow]) -> anyhow::Result<()> {
    let truth = !rows.is_empty() && rows.iter().all(|r| r.truth.is_some());
    let mut w = csv::Writer::from_writer(out);
    let mut header: Vec<&str> = DIVOT_HEADER.to_vec();
    if truth {
        header.extend(DIVOT_TRUTH_HEADER);
    }
    w.write_record(&header)?;
    for r in rows {
        let mut rec = vec![
            r.push_index.to_string(),
            r.joint.to_string(),
            r.direction.to_string(),
            format!("{:?}", r.t_s),
        ];
        rec.extend(r.position.iter().map(|v| format!("{v:?}")));
        rec.extend(r.effort.iter().map(|v| format!("{v:?}")));
        if let (true, Some(t)) = (truth, r.truth) {
            rec.extend(t.position_rad.iter().map(|v| format!("{v:?}")));
            rec.extend(t.tip_m.iter().map(|v| format!("{v:?}")));
        }
        w.write_record(&rec)?;
    }
    w.flush()?;
    Ok(())
}
