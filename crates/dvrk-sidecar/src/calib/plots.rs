//! The paper's figures from our data, as SVG and PNG (plotters).
//!
//! Text needs a TrueType font registered with plotters; Debian's `fonts-dejavu-core` provides the
//! default [`DEFAULT_FONT`]. A missing font is an error naming the path.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use anyhow::{Context, anyhow};
use dvrk_compliance::fit::{self, Branches};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::fit_cmd::FitOutcome;

/// Default figure font (Debian package fonts-dejavu-core).
pub const DEFAULT_FONT: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";

static FONT: OnceLock<PathBuf> = OnceLock::new();

/// Reads a TTF file into memory that lives for the rest of the process (plotters keeps it).
fn load_font(path: &Path) -> anyhow::Result<&'static [u8]> {
    let mut bytes = Vec::new();
    let read = crate::files::open_regular(path, crate::files::CONFIG_MAX_BYTES)
        .and_then(|mut f| Ok(std::io::Read::read_to_end(&mut f, &mut bytes)?));
    read.map_err(|e| {
        anyhow!(
            "cannot read the figure font {}: {e} (install it with `apt-get install -y fonts-dejavu-core`, or pass --font with a TTF file)",
            path.display()
        )
    })?;
    Ok(Box::leak(bytes.into_boxed_slice()))
}

/// Registers the font for figure text once per process; later calls keep the first font (but
/// still fail for a path that cannot be read). Failures are not remembered, so a later call with
/// a good path still works.
pub fn register_font(path: &Path) -> anyhow::Result<()> {
    if let Some(registered) = FONT.get() {
        // Still report a bad path, so `--font` errors do not depend on what ran before.
        if registered != path {
            std::fs::metadata(path).map_err(|e| {
                anyhow!(
                    "cannot read the figure font {}: {e} (install it with `apt-get install -y fonts-dejavu-core`, or pass --font with a TTF file)",
                    path.display()
                )
            })?;
        }
        return Ok(());
    }
    let bytes = load_font(path)?;
    plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
        .map_err(|_| anyhow!("{} is not a usable TrueType font", path.display()))?;
    let _ = FONT.set(path.to_path_buf());
    Ok(())
}

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Dots,
    Rings,
    Line,
}

/// One data series of a panel.
pub struct Series {
    pub label: Option<String>,
    pub color: RGBColor,
    pub kind: Kind,
    pub points: Vec<(f64, f64)>,
}

/// One chart.
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
}

/// Distinct colour `i` of `n`.
pub fn color(i: usize, n: usize) -> RGBColor {
    let h = i as f64 / n.max(1) as f64 * 0.85;
    let (r, g, b) = hsl_to_rgb(h, 0.75, 0.42);
    RGBColor(r, g, b)
}

fn hsl_to_rgb(h: f64, s: f64, l: f64) -> (u8, u8, u8) {
    let c = (1.0 - (2.0 * l - 1.0).abs()) * s;
    let hp = h * 6.0;
    let x = c * (1.0 - (hp % 2.0 - 1.0).abs());
    let (r, g, b) = match hp as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = l - c / 2.0;
    let to = |v: f64| ((v + m) * 255.0).round().clamp(0.0, 255.0) as u8;
    (to(r), to(g), to(b))
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let span = (hi - lo).max(1e-9 * lo.abs().max(1.0));
    (lo - 0.05 * span, hi + 0.05 * span)
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
) -> anyhow::Result<()> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("drawing `{}`: {e:?}", panel.title);
    let (x0, x1) = range(
        panel
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.0)),
    );
    let (y0, y1) = range(
        panel
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.1)),
    );
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(panel.x_label.as_str())
        .y_desc(panel.y_label.as_str())
        .label_style(("sans-serif", 12))
        .axis_desc_style(("sans-serif", 13))
        .x_labels(6)
        .y_labels(6)
        .draw()
        .map_err(err)?;
    let mut any_label = false;
    for s in &panel.series {
        let color = s.color;
        let drawn = match s.kind {
            Kind::Line => chart
                .draw_series(LineSeries::new(
                    s.points.iter().copied(),
                    color.stroke_width(2),
                ))
                .map_err(err)?,
            Kind::Dots => chart
                .draw_series(s.points.iter().map(|&p| Circle::new(p, 3, color.filled())))
                .map_err(err)?,
            Kind::Rings => chart
                .draw_series(s.points.iter().map(|&p| Circle::new(p, 3, color)))
                .map_err(err)?,
        };
        if let Some(label) = &s.label {
            any_label = true;
            let kind = s.kind;
            drawn
                .label(label.as_str())
                .legend(move |(x, y)| match kind {
                    Kind::Line => {
                        PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2))
                            .into_dyn()
                    }
                    _ => Circle::new((x + 8, y), 3, color.filled()).into_dyn(),
                });
        }
    }
    if any_label {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 11))
            .position(SeriesLabelPosition::UpperLeft)
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

fn draw_all<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    panels: &[Panel],
    cols: usize,
) -> anyhow::Result<()> {
    root.fill(&WHITE)
        .map_err(|e| anyhow!("filling the background: {e:?}"))?;
    let rows = panels.len().div_ceil(cols);
    let areas = root.split_evenly((rows, cols));
    for (area, panel) in areas.iter().zip(panels) {
        draw_panel(area, panel)?;
    }
    root.present()
        .map_err(|e| anyhow!("writing the figure: {e:?}"))?;
    Ok(())
}

/// Renders `panels` in a grid of `cols` columns to `dir/stem.svg` and `dir/stem.png`.
pub fn render(
    dir: &Path,
    stem: &str,
    font: &Path,
    panels: &[Panel],
    cols: usize,
) -> anyhow::Result<[PathBuf; 2]> {
    register_font(font)?;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let cols = cols.clamp(1, panels.len().max(1));
    let rows = panels.len().div_ceil(cols).max(1);
    let size = (cols as u32 * 480, rows as u32 * 340);
    let svg = dir.join(format!("{stem}.svg"));
    let png = dir.join(format!("{stem}.png"));
    draw_all(
        SVGBackend::new(&svg, size).into_drawing_area(),
        panels,
        cols,
    )
    .with_context(|| format!("rendering {}", svg.display()))?;
    draw_all(
        BitMapBackend::new(&png, size).into_drawing_area(),
        panels,
        cols,
    )
    .with_context(|| format!("rendering {}", png.display()))?;
    Ok([svg, png])
}

fn line_points(line: &fit::Line, xs: (f64, f64)) -> Vec<(f64, f64)> {
    vec![(xs.0, line.at(xs.0)), (xs.1, line.at(xs.1))]
}

/// Figures of a fit: Fig. 4 (tau_0 per depth, when a sweep was given), Fig. 5 (clamp data and
/// lines, one panel per depth), Fig. 6 (1/K per depth and the cubic), per joint.
pub fn fit_figures(dir: &Path, font: &Path, o: &FitOutcome) -> anyhow::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    for t in &o.offsets {
        let mut depths: Vec<u32> = o
            .sweep_rows
            .iter()
            .filter(|r| r.joint == t.joint)
            .map(|r| r.depth_index)
            .collect();
        depths.sort_unstable();
        depths.dedup();
        let n = depths.len();
        let mut series: Vec<Series> = depths
            .iter()
            .enumerate()
            .map(|(i, &d)| {
                let rows: Vec<_> = o
                    .sweep_rows
                    .iter()
                    .filter(|r| r.joint == t.joint && r.depth_index == d)
                    .collect();
                let l = rows.iter().map(|r| r.insertion_m).sum::<f64>() / rows.len() as f64;
                Series {
                    label: Some(format!("L = {l:.3} m")),
                    color: color(i, n),
                    kind: Kind::Rings,
                    points: rows
                        .iter()
                        .map(|r| (r.position_rad.to_degrees(), r.effort_nm))
                        .collect(),
                }
            })
            .collect();
        series.push(Series {
            label: Some("tau_0 table (mean)".into()),
            color: BLACK,
            kind: Kind::Line,
            points: t
                .position_rad
                .iter()
                .zip(t.effort_nm.iter())
                .map(|(q, e)| (q.to_degrees(), *e))
                .collect(),
        });
        let panel = Panel {
            title: format!("Torque offset, joint {} (Fig. 4)", t.joint),
            x_label: "joint position (deg)".into(),
            y_label: "effort, no load (N·m)".into(),
            series,
        };
        written.extend(render(
            dir,
            &format!("fig4-torque-offset-joint{}", t.joint),
            font,
            &[panel],
            1,
        )?);
    }
    for j in &o.joints {
        let mut panels = Vec::new();
        for d in &j.depths {
            let rows: Vec<_> = o
                .clamp_rows
                .iter()
                .filter(|r| r.joint == j.joint && r.depth_index == d.depth_index)
                .collect();
            let xs = range(rows.iter().map(|r| r.position_rad));
            let (plus, minus) = match d.branches {
                Branches::Motion => ("moving +", "moving -"),
                Branches::Load | Branches::LoadFriction => ("tau_ext > 0", "tau_ext < 0"),
            };
            // with the motor friction taken out, the lines lie between the rows moving each way
            let friction = if d.branches == Branches::LoadFriction {
                format!(", friction {:.1} mN·m", d.friction_nm * 1e3)
            } else {
                String::new()
            };
            panels.push(Panel {
                title: format!(
                    "L = {:.3} m: K^-1 {:.1} N·m/rad, delta {:.2} mrad{friction}",
                    d.insertion_m,
                    d.stiffness_nm_per_rad,
                    d.backlash_rad * 1e3
                ),
                x_label: "joint position (rad)".into(),
                y_label: "tau_ext (N·m)".into(),
                series: vec![
                    Series {
                        label: None,
                        color: RGBColor(90, 90, 90),
                        kind: Kind::Rings,
                        points: rows
                            .iter()
                            .map(|r| (r.position_rad, r.tau_ext_nm()))
                            .collect(),
                    },
                    Series {
                        label: Some(format!("{plus}: {:.1}", d.lines[0].slope)),
                        color: RGBColor(200, 40, 40),
                        kind: Kind::Line,
                        points: line_points(&d.lines[0], xs),
                    },
                    Series {
                        label: Some(format!("{minus}: {:.1}", d.lines[1].slope)),
                        color: RGBColor(30, 80, 200),
                        kind: Kind::Line,
                        points: line_points(&d.lines[1], xs),
                    },
                ],
            });
        }
        written.extend(render(
            dir,
            &format!("fig5-clamp-joint{}", j.joint),
            font,
            &panels,
            4,
        )?);

        let [lo, hi] = j.insertion_range_m;
        let curve: Vec<(f64, f64)> = (0..=100)
            .map(|i| {
                let l = lo + (hi - lo) * f64::from(i) / 100.0;
                (l, fit::eval_cubic(&j.inverse_compliance_nm_per_rad, l))
            })
            .collect();
        let c = j.inverse_compliance_nm_per_rad;
        let panel = Panel {
            title: format!(
                "Joint {}: 1/K(L) = {:.1}L³ {:+.1}L² {:+.1}L {:+.2} (r² {:.3}) (Fig. 6)",
                j.joint, c[0], c[1], c[2], c[3], j.r_squared
            ),
            x_label: "insertion L (m)".into(),
            y_label: "1/K (N·m/rad)".into(),
            series: vec![
                Series {
                    label: Some("per depth (mean of the two slopes)".into()),
                    color: RGBColor(200, 40, 40),
                    kind: Kind::Dots,
                    points: j
                        .depths
                        .iter()
                        .map(|d| (d.insertion_m, d.stiffness_nm_per_rad))
                        .collect(),
                },
                Series {
                    label: Some("least-squares cubic".into()),
                    color: BLACK,
                    kind: Kind::Line,
                    points: curve,
                },
            ],
        };
        written.extend(render(
            dir,
            &format!("fig6-inverse-compliance-joint{}", j.joint),
            font,
            &[panel],
            1,
        )?);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_font_is_a_clear_error() {
        let err = load_font(Path::new("/nonexistent/font.ttf"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nonexistent/font.ttf"), "{err}");
        assert!(err.contains("fonts-dejavu-core"), "{err}");
    }

    #[test]
    fn not_a_font_is_a_clear_error() {
        let p =
            std::env::temp_dir().join(format!("dvrk-calib-notafont-{}.ttf", std::process::id()));
        std::fs::write(&p, b"hello").unwrap();
        let bytes = load_font(&p).unwrap();
        assert!(
            plotters::style::register_font("test-not-a-font", FontStyle::Normal, bytes).is_err()
        );
    }
}
