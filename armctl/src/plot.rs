//! SVG and PNG plots (drawn with plotters) of a recorded run (LOCATION reports, or a
//! simulator trace): joint positions (steps) over time, one colour per joint, with the
//! commanded trajectory dashed when given. A PNG's text is drawn with DejaVu Sans, built in
//! (`assets/`, its licence beside it): a bitmap has no viewer to pick a font.

use std::ops::Range;

use plotters::element::DashedPathElement;
use plotters::prelude::*;

use crate::record::Sample;
use crate::trajectory::Waypoints;
use crate::vcd::Trace;

/// Plot size in pixels.
const WIDTH: u32 = 960;
const HEIGHT: u32 = 540;
/// Space around the chart, and for the tick labels and axis names below and left of it.
const MARGIN: u32 = 15;
const X_LABEL_AREA: u32 = 45;
const Y_LABEL_AREA: u32 = 75;
/// About this many labelled ticks per axis (plotters picks round values).
const TICKS: usize = 8;
/// A generic family: the SVG names it and the viewer picks the font; for a PNG it is
/// [`FONT_FILE`], registered under this name.
const FONT: &str = "sans-serif";
/// The font a PNG's text is drawn with.
static FONT_FILE: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
/// Line widths (px): the recording over its commanded trajectory.
const JOINT_WIDTH: u32 = 2;
const COMMANDED_WIDTH: u32 = 1;
/// Dash and gap of the commanded trajectory (px).
const DASH: u32 = 6;
const GAP: u32 = 4;
/// One colour per joint (8 joints at most), as 0xRRGGBB.
const COLOURS: [u32; 8] = [
    0x1f77b4, 0xd62728, 0x2ca02c, 0xff7f0e, 0x9467bd, 0x8c564b, 0xe377c2, 0x17becf,
];

/// A commanded trajectory to draw under the recording: time (s) and positions (steps).
#[derive(Clone, Debug, Default)]
pub struct Commanded {
    /// Seconds from the start of the trajectory.
    pub times_s: Vec<f64>,
    /// Steps per joint at each time.
    pub positions: Vec<Vec<f64>>,
    /// Seconds to add to line it up with the recording's clock.
    pub offset_s: f64,
}

impl Commanded {
    /// From trajectory file waypoints (joints the file leaves out are not drawn).
    pub fn from_waypoints(waypoints: &Waypoints) -> Commanded {
        Commanded {
            times_s: waypoints.times_us.iter().map(|&t| t as f64 / 1e6).collect(),
            positions: waypoints
                .positions
                .iter()
                .map(|row| row.iter().map(|p| p.unwrap_or(f64::NAN)).collect())
                .collect(),
            offset_s: 0.0,
        }
    }

    /// Seconds into the trajectory at which some joint is first half a step away from its
    /// start: about when its first STEP pulse comes, to line it up with a trace.
    pub fn first_step_s(&self) -> Option<f64> {
        let start = self.positions.first()?;
        let mut first: Option<f64> = None;
        for (j, &p0) in start.iter().enumerate() {
            let mut previous = (self.times_s.first().copied()?, p0);
            for (&t, row) in self.times_s.iter().zip(&self.positions).skip(1) {
                let Some(&p) = row.get(j) else { break };
                if !(p.is_finite() && p0.is_finite()) {
                    break;
                }
                if (p - p0).abs() >= 0.5 {
                    // Linear between waypoints: where |position - p0| reaches 0.5.
                    let (t_prev, p_prev) = previous;
                    let target = p0 + 0.5 * (p - p0).signum();
                    let f = if (p - p_prev).abs() > f64::EPSILON {
                        ((target - p_prev) / (p - p_prev)).clamp(0.0, 1.0)
                    } else {
                        0.0
                    };
                    let t_step = t_prev + f * (t - t_prev);
                    first = Some(first.map_or(t_step, |f: f64| f.min(t_step)));
                    break;
                }
                previous = (t, p);
            }
        }
        first
    }
}

/// One joint's line: `(seconds, steps)` corners.
struct Line {
    joint: usize,
    points: Vec<(f64, f64)>,
}

/// Draws the recording (and the commanded trajectory) as an SVG document.
pub fn svg(samples: &[Sample], commanded: Option<&Commanded>, title: &str) -> String {
    svg_named(samples, commanded, title, &[])
}

/// As [`svg`], the legend naming joint `j` `names[j]` where given (a joint config's
/// names), else `joint j`.
pub fn svg_named(
    samples: &[Sample],
    commanded: Option<&Commanded>,
    title: &str,
    names: &[String],
) -> String {
    draw(&sample_lines(samples), commanded, title, names)
}

/// One line per joint of a recording.
fn sample_lines(samples: &[Sample]) -> Vec<Line> {
    let joints = samples.iter().map(|s| s.position.len()).max().unwrap_or(0);
    (0..joints)
        .map(|joint| Line {
            joint,
            points: samples
                .iter()
                .filter_map(|s| s.position.get(joint).map(|&p| (s.time_s, f64::from(p))))
                .collect(),
        })
        .collect()
}

/// As [`svg_named`], a PNG written to `path`.
pub fn png_named(
    path: &std::path::Path,
    samples: &[Sample],
    commanded: Option<&Commanded>,
    title: &str,
    names: &[String],
) -> Result<(), String> {
    render_png(path, &sample_lines(samples), commanded, title, names)
}

/// Draws a simulator trace (and the commanded trajectory) as an SVG document: the joints
/// that stepped or are commanded (joint 0 when none did), each at most about two corners
/// per bucket of its [`crate::vcd::Track`], ending exactly at its final position.
pub fn trace_svg(trace: &Trace, commanded: Option<&Commanded>, title: &str) -> String {
    trace_svg_named(trace, commanded, title, &[])
}

/// As [`trace_svg`], with joint names as [`svg_named`] takes them.
pub fn trace_svg_named(
    trace: &Trace,
    commanded: Option<&Commanded>,
    title: &str,
    names: &[String],
) -> String {
    draw(&trace_lines(trace, commanded), commanded, title, names)
}

/// As [`trace_svg_named`], a PNG written to `path`.
pub fn trace_png_named(
    path: &std::path::Path,
    trace: &Trace,
    commanded: Option<&Commanded>,
    title: &str,
    names: &[String],
) -> Result<(), String> {
    render_png(
        path,
        &trace_lines(trace, commanded),
        commanded,
        title,
        names,
    )
}

/// The lines of a trace: the joints that stepped or are commanded.
fn trace_lines(trace: &Trace, commanded: Option<&Commanded>) -> Vec<Line> {
    let commanded_joints = commanded.map_or(0, |c| {
        c.positions
            .iter()
            .map(|row| row.iter().rposition(|p| p.is_finite()).map_or(0, |j| j + 1))
            .max()
            .unwrap_or(0)
    });
    let mut lines: Vec<Line> = trace
        .joints
        .iter()
        .enumerate()
        .filter(|(j, joint)| joint.steps > 0 || *j < commanded_joints)
        .map(|(joint, jt)| Line {
            joint,
            points: jt
                .track
                .points(trace.end_tick)
                .into_iter()
                .map(|(tick, p)| (tick as f64 * trace.seconds_per_tick, p as f64))
                .collect(),
        })
        .collect();
    if lines.is_empty() {
        lines.push(Line {
            joint: 0,
            points: vec![
                (0.0, 0.0),
                (trace.end_tick as f64 * trace.seconds_per_tick, 0.0),
            ],
        });
    }
    lines
}

fn draw(lines: &[Line], commanded: Option<&Commanded>, title: &str, names: &[String]) -> String {
    render(lines, commanded, title, names).unwrap_or_else(|e| {
        // Drawing into a String has no I/O; only a layout error could get here.
        format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{WIDTH}\" height=\"{HEIGHT}\"><text x=\"20\" y=\"40\">plot failed: {}</text></svg>\n",
            escape(&e.to_string())
        )
    })
}

/// The plot's extent: time (s) and position (steps), widened so that neither is empty.
fn bounds(lines: &[Line], commanded: Option<&Commanded>) -> (Range<f64>, Range<f64>) {
    let mut t_min = f64::INFINITY;
    let mut t_max = f64::NEG_INFINITY;
    let mut p_min = f64::INFINITY;
    let mut p_max = f64::NEG_INFINITY;
    let mut widen = |t: f64, p: f64| {
        if t.is_finite() && p.is_finite() {
            t_min = t_min.min(t);
            t_max = t_max.max(t);
            p_min = p_min.min(p);
            p_max = p_max.max(p);
        }
    };
    for line in lines {
        for &(t, p) in &line.points {
            widen(t, p);
        }
    }
    if let Some(c) = commanded {
        for (t, row) in c.times_s.iter().zip(&c.positions) {
            for &p in row {
                widen(t + c.offset_s, p);
            }
        }
    }
    if !t_min.is_finite() {
        (t_min, t_max, p_min, p_max) = (0.0, 1.0, 0.0, 1.0);
    }
    if t_max - t_min < 1e-9 {
        t_max = t_min + 1.0;
    }
    if p_max - p_min < 1.0 {
        p_min -= 1.0;
        p_max += 1.0;
    }
    (t_min..t_max, p_min..p_max)
}

/// An axis label: plotters puts ticks on round values (1, 2 or 5 times a power of ten), so
/// the shortest decimal of the value rounded to a nanounit is exact and has no float noise.
fn tick_label(value: f64) -> String {
    let rounded = (value * 1e9).round() / 1e9;
    // No "-0".
    format!("{}", rounded + 0.0)
}

fn render(
    lines: &[Line],
    commanded: Option<&Commanded>,
    title: &str,
    names: &[String],
) -> Result<String, Box<dyn std::error::Error>> {
    let mut out = String::new();
    render_on(
        SVGBackend::with_string(&mut out, (WIDTH, HEIGHT)).into_drawing_area(),
        lines,
        commanded,
        title,
        names,
    )?;
    Ok(out)
}

/// Draws the plot as PNG into `path` ([`FONT_FILE`] for its text).
fn render_png(
    path: &std::path::Path,
    lines: &[Line],
    commanded: Option<&Commanded>,
    title: &str,
    names: &[String],
) -> Result<(), String> {
    render_on(
        BitMapBackend::new(path, (WIDTH, HEIGHT)).into_drawing_area(),
        lines,
        commanded,
        title,
        names,
    )
    .map_err(|e| format!("{}: {e}", path.display()))
}

fn render_on<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    lines: &[Line],
    commanded: Option<&Commanded>,
    title: &str,
    names: &[String],
) -> Result<(), Box<dyn std::error::Error>>
where
    DB::ErrorType: 'static,
{
    // Text is laid out with the font's metrics, for the SVG too (it names the family).
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let registered = *REGISTERED
        .get_or_init(|| plotters::style::register_font(FONT, FontStyle::Normal, FONT_FILE).is_ok());
    if !registered {
        return Err("the built-in font cannot be read".into());
    }
    let (times, positions) = bounds(lines, commanded);
    {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (FONT, 20))
            .margin(MARGIN)
            .x_label_area_size(X_LABEL_AREA)
            .y_label_area_size(Y_LABEL_AREA)
            .build_cartesian_2d(times, positions)?;
        chart
            .configure_mesh()
            .x_desc("time (s)")
            .y_desc("position (steps)")
            .x_labels(TICKS)
            .y_labels(TICKS)
            .max_light_lines(0)
            .x_label_formatter(&|t| tick_label(*t))
            .y_label_formatter(&|p| tick_label(*p))
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 15))
            .draw()?;
        for line in lines {
            let j = line.joint;
            let colour = colour(j);
            if let Some(c) = commanded {
                let corners: Vec<(f64, f64)> = c
                    .times_s
                    .iter()
                    .zip(&c.positions)
                    .filter_map(|(t, row)| row.get(j).map(|&p| (t + c.offset_s, p)))
                    .filter(|(_, p)| p.is_finite())
                    .collect();
                if corners.len() > 1 {
                    chart.draw_series(DashedLineSeries::new(
                        corners,
                        DASH,
                        GAP,
                        colour.mix(0.7).stroke_width(COMMANDED_WIDTH),
                    ))?;
                }
            }
            // Corners that fall on the same pixel are one corner.
            let mut corners: Vec<(f64, f64)> = Vec::with_capacity(line.points.len());
            let mut last_pixel = None;
            for &(t, p) in &line.points {
                let pixel = chart.backend_coord(&(t, p));
                if last_pixel != Some(pixel) {
                    corners.push((t, p));
                    last_pixel = Some(pixel);
                }
            }
            chart
                .draw_series(LineSeries::new(corners, colour.stroke_width(JOINT_WIDTH)))?
                .label(
                    names
                        .get(j)
                        .cloned()
                        .unwrap_or_else(|| format!("joint {j}")),
                )
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(3))
                });
        }
        if commanded.is_some() {
            // A legend entry only: the dashed lines themselves are drawn in each joint's colour.
            chart
                .draw_series(std::iter::empty::<PathElement<(f64, f64)>>())?
                .label("commanded")
                .legend(|(x, y)| {
                    DashedPathElement::new([(x, y), (x + 20, y)], 5, 3, BLACK.stroke_width(1))
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font((FONT, 14))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        root.present()?;
    }
    Ok(())
}

/// The colour of a joint's lines.
fn colour(joint: usize) -> RGBColor {
    let [_, r, g, b] = COLOURS[joint % COLOURS.len()].to_be_bytes();
    RGBColor(r, g, b)
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The joints' solid lines (plotters writes a series as one `<polyline>`).
    fn joint_lines(svg: &str) -> Vec<&str> {
        svg.lines()
            .filter(|l| l.starts_with("<polyline") && l.contains("stroke-width=\"2\""))
            .collect()
    }

    /// Dashes of the commanded trajectory, in the colour of joint `j`.
    fn dashes(svg: &str, joint: usize) -> usize {
        let c = colour(joint);
        let stroke = format!(
            "stroke=\"#{:02X}{:02X}{:02X}\" stroke-width=\"1\"",
            c.0, c.1, c.2
        );
        svg.lines()
            .filter(|l| l.starts_with("<polyline") && l.contains(&stroke))
            .count()
    }

    /// The text of the `<text>` elements (plotters puts it on its own line).
    fn texts(svg: &str) -> Vec<&str> {
        let lines: Vec<&str> = svg.lines().collect();
        lines
            .windows(2)
            .filter(|w| w[0].starts_with("<text"))
            .map(|w| w[1])
            .collect()
    }

    #[test]
    fn svg_has_one_line_per_joint_and_the_commanded_dashed() {
        let samples: Vec<Sample> = (0..10)
            .map(|k| Sample {
                time_s: f64::from(k) * 0.1,
                state: 2,
                position: vec![k * 10, -k],
            })
            .collect();
        let commanded = Commanded {
            times_s: vec![0.0, 1.0],
            positions: vec![vec![0.0, 0.0], vec![100.0, -10.0]],
            offset_s: 0.0,
        };
        let svg = svg(&samples, Some(&commanded), "run <1>");
        assert!(svg.starts_with("<svg"));
        assert!(svg.trim_end().ends_with("</svg>"));
        assert_eq!(joint_lines(&svg).len(), 2);
        assert!(dashes(&svg, 0) > 10 && dashes(&svg, 1) > 10, "{svg}");
        assert!(svg.contains("run &lt;1&gt;"));
        let labels = texts(&svg);
        assert!(labels.contains(&"joint 1") && labels.contains(&"commanded"));
        // No NaN coordinates.
        assert!(!svg.contains("NaN"));
    }

    #[test]
    fn axis_ticks_are_round_numbers() {
        let samples: Vec<Sample> = [(0.004, 3), (1.874, 250), (9.354, -17)]
            .iter()
            .map(|&(time_s, p)| Sample {
                time_s,
                state: 2,
                position: vec![p],
            })
            .collect();
        let svg = svg(&samples, None, "ticks");
        let numbers: Vec<f64> = texts(&svg).iter().filter_map(|t| t.parse().ok()).collect();
        assert!(numbers.len() >= 8, "{numbers:?}");
        for n in numbers {
            // Whole thousandths (of seconds or steps), printed without float noise.
            let thousandths = n * 1000.0;
            assert!((thousandths - thousandths.round()).abs() < 1e-6, "tick {n}");
            assert!(n.to_string().len() <= 5, "tick {n}");
        }
    }

    #[test]
    fn a_trace_draws_the_joints_that_stepped_and_ends_at_their_final_position() {
        let text = "$timescale 1us $end\n$var wire 1 a step0 $end\n$var wire 1 b dir0 $end\n\
                    $var wire 1 c step2 $end\n$var wire 1 d step1 $end\n$enddefinitions $end\n\
                    #0\n1b\n#1000\n1a\n#1500\n0a\n#2000\n1a\n1c\n#4000\n";
        let trace = crate::vcd::parse(text.as_bytes(), "t.vcd").unwrap();
        let svg = trace_svg(&trace, None, "trace");
        // Joints 0 and 2 stepped; joint 1 did not.
        assert_eq!(joint_lines(&svg).len(), 2);
        let labels = texts(&svg);
        assert!(
            labels.contains(&"joint 0")
                && labels.contains(&"joint 2")
                && !labels.contains(&"joint 1")
        );
        // Time axis to the trace's end (4 ms), positions -1..2.
        assert!(labels.contains(&"0.004") && labels.contains(&"2"), "{svg}");
        // Joint 0's line ends at the right edge (the 4 ms tick) at its top (+2 steps).
        let tick_x = |label: &str| -> String {
            let lines: Vec<&str> = svg.lines().collect();
            let at = lines.iter().position(|l| *l == label).unwrap();
            let x = lines[at - 1].split("x=\"").nth(1).unwrap();
            x[..x.find('"').unwrap()].to_string()
        };
        let (right, top) = (tick_x("0.004"), {
            let lines: Vec<&str> = svg.lines().collect();
            let at = lines.iter().position(|l| *l == "2").unwrap();
            let y = lines[at - 1].split("y=\"").nth(1).unwrap();
            y[..y.find('"').unwrap()].to_string()
        });
        let joint0 = joint_lines(&svg)
            .into_iter()
            .find(|l| l.contains("#1F77B4"))
            .unwrap();
        assert!(
            joint0.ends_with(&format!("{right},{top} \"/>")),
            "{joint0} should end at {right},{top}"
        );

        let commanded = Commanded {
            times_s: vec![0.0, 0.002],
            positions: vec![vec![0.0, 0.0], vec![2.0, 4.0]],
            offset_s: 0.0,
        };
        // Joint 1 is commanded: drawn (flat) with its dashed line.
        let svg = trace_svg(&trace, Some(&commanded), "trace");
        assert!(texts(&svg).contains(&"joint 1"));
        assert_eq!(joint_lines(&svg).len(), 3);
        assert!(dashes(&svg, 0) > 0 && dashes(&svg, 1) > 0 && dashes(&svg, 2) == 0);
        assert!(!svg.contains("NaN"));
    }

    #[test]
    fn first_commanded_step_is_where_a_joint_is_half_a_step_out() {
        let commanded = Commanded {
            times_s: vec![0.0, 1.0, 2.0, 3.0],
            positions: vec![
                vec![10.0, 0.0],
                vec![10.0, 0.0],
                vec![10.0, -0.25],
                vec![14.0, -1.25],
            ],
            offset_s: 0.0,
        };
        // Joint 0 is 0.5 out at 2.125 s, joint 1 at 2.25 s.
        let t = commanded.first_step_s().unwrap();
        assert!((t - 2.125).abs() < 1e-9, "{t}");
        let still = Commanded {
            times_s: vec![0.0, 1.0],
            positions: vec![vec![3.0], vec![3.2]],
            offset_s: 0.0,
        };
        assert_eq!(still.first_step_s(), None);
    }
}
