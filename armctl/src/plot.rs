//! SVG plots of a recorded run (LOCATION reports, or a simulator trace): joint positions
//! (steps) over time, one colour per joint, with the commanded trajectory dashed when given.

use std::fmt::Write as _;

use crate::record::Sample;
use crate::trajectory::Waypoints;
use crate::vcd::Trace;

/// Plot size in pixels.
const WIDTH: f64 = 960.0;
const HEIGHT: f64 = 540.0;
/// Margins: left for the step labels, bottom for the time labels.
const LEFT: f64 = 80.0;
const RIGHT: f64 = 120.0;
const TOP: f64 = 40.0;
const BOTTOM: f64 = 50.0;
/// One colour per joint (8 joints at most).
const COLOURS: [&str; 8] = [
    "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf",
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
    let joints = samples.iter().map(|s| s.position.len()).max().unwrap_or(0);
    let lines: Vec<Line> = (0..joints)
        .map(|joint| Line {
            joint,
            points: samples
                .iter()
                .filter_map(|s| s.position.get(joint).map(|&p| (s.time_s, f64::from(p))))
                .collect(),
        })
        .collect();
    draw(&lines, commanded, title)
}

/// Draws a simulator trace (and the commanded trajectory) as an SVG document: the joints
/// that stepped or are commanded (joint 0 when none did), each at most about two corners
/// per bucket of its [`crate::vcd::Track`], ending exactly at its final position.
pub fn trace_svg(trace: &Trace, commanded: Option<&Commanded>, title: &str) -> String {
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
    draw(&lines, commanded, title)
}

fn draw(lines: &[Line], commanded: Option<&Commanded>, title: &str) -> String {
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
    let plot_w = WIDTH - LEFT - RIGHT;
    let plot_h = HEIGHT - TOP - BOTTOM;
    let x = |t: f64| LEFT + (t - t_min) / (t_max - t_min) * plot_w;
    let y = |p: f64| TOP + (p_max - p) / (p_max - p_min) * plot_h;

    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{HEIGHT}" viewBox="0 0 {WIDTH} {HEIGHT}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(
        out,
        r#"<rect width="100%" height="100%" fill="white"/><text x="{}" y="24" text-anchor="middle" font-size="16">{}</text>"#,
        WIDTH / 2.0,
        escape(title)
    );
    // Axes and grid with five ticks each way.
    for i in 0..=5 {
        let f = f64::from(i) / 5.0;
        let t = t_min + f * (t_max - t_min);
        let p = p_min + f * (p_max - p_min);
        let _ = writeln!(
            out,
            r##"<line x1="{0:.1}" y1="{TOP}" x2="{0:.1}" y2="{1:.1}" stroke="#ddd"/><text x="{0:.1}" y="{2:.1}" text-anchor="middle">{3:.3}</text>"##,
            x(t),
            TOP + plot_h,
            TOP + plot_h + 18.0,
            t
        );
        let _ = writeln!(
            out,
            r##"<line x1="{LEFT}" y1="{0:.1}" x2="{1:.1}" y2="{0:.1}" stroke="#ddd"/><text x="{2:.1}" y="{3:.1}" text-anchor="end">{4:.0}</text>"##,
            y(p),
            LEFT + plot_w,
            LEFT - 6.0,
            y(p) + 4.0,
            p
        );
    }
    let _ = writeln!(
        out,
        r#"<rect x="{LEFT}" y="{TOP}" width="{plot_w}" height="{plot_h}" fill="none" stroke="black"/><text x="{}" y="{}" text-anchor="middle">time (s)</text><text x="16" y="{}" transform="rotate(-90 16 {})" text-anchor="middle">position (steps)</text>"#,
        LEFT + plot_w / 2.0,
        HEIGHT - 10.0,
        TOP + plot_h / 2.0,
        TOP + plot_h / 2.0
    );
    for (slot, line) in lines.iter().enumerate() {
        let j = line.joint;
        let colour = COLOURS[j % COLOURS.len()];
        if let Some(c) = commanded {
            let path: Vec<String> = c
                .times_s
                .iter()
                .zip(&c.positions)
                .filter_map(|(t, row)| row.get(j).map(|&p| (t + c.offset_s, p)))
                .filter(|(_, p)| p.is_finite())
                .map(|(t, p)| format!("{:.2},{:.2}", x(t), y(p)))
                .collect();
            if path.len() > 1 {
                let _ = writeln!(
                    out,
                    r#"<polyline fill="none" stroke="{colour}" stroke-width="1.5" stroke-dasharray="6 4" opacity="0.7" points="{}"/>"#,
                    path.join(" ")
                );
            }
        }
        let mut path: Vec<String> = Vec::with_capacity(line.points.len());
        for &(t, p) in &line.points {
            let corner = format!("{:.2},{:.2}", x(t), y(p));
            // Corners closer than the printed precision are one corner.
            if path.last() != Some(&corner) {
                path.push(corner);
            }
        }
        let _ = writeln!(
            out,
            r#"<polyline fill="none" stroke="{colour}" stroke-width="1.5" points="{}"/>"#,
            path.join(" ")
        );
        let ly = TOP + 10.0 + 18.0 * slot as f64;
        let _ = writeln!(
            out,
            r#"<line x1="{0:.1}" y1="{ly:.1}" x2="{1:.1}" y2="{ly:.1}" stroke="{colour}" stroke-width="3"/><text x="{2:.1}" y="{3:.1}">joint {j}</text>"#,
            LEFT + plot_w + 10.0,
            LEFT + plot_w + 34.0,
            LEFT + plot_w + 40.0,
            ly + 4.0
        );
    }
    if commanded.is_some() {
        let ly = TOP + 10.0 + 18.0 * lines.len() as f64;
        let _ = writeln!(
            out,
            r#"<line x1="{0:.1}" y1="{ly:.1}" x2="{1:.1}" y2="{ly:.1}" stroke="black" stroke-dasharray="6 4"/><text x="{2:.1}" y="{3:.1}">commanded</text>"#,
            LEFT + plot_w + 10.0,
            LEFT + plot_w + 34.0,
            LEFT + plot_w + 40.0,
            ly + 4.0
        );
    }
    out.push_str("</svg>\n");
    out
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(svg.matches("<polyline").count(), 4);
        assert_eq!(svg.matches("stroke-dasharray=\"6 4\" opacity").count(), 2);
        assert!(svg.contains("run &lt;1&gt;"));
        assert!(svg.contains("joint 1"));
        // No NaN coordinates.
        assert!(!svg.contains("NaN"));
    }

    #[test]
    fn a_trace_draws_the_joints_that_stepped_and_ends_at_their_final_position() {
        let text = "$timescale 1us $end\n$var wire 1 a step0 $end\n$var wire 1 b dir0 $end\n\
                    $var wire 1 c step2 $end\n$var wire 1 d step1 $end\n$enddefinitions $end\n\
                    #0\n1b\n#1000\n1a\n#1500\n0a\n#2000\n1a\n1c\n#4000\n";
        let trace = crate::vcd::parse(text.as_bytes(), "t.vcd").unwrap();
        let svg = trace_svg(&trace, None, "trace");
        // Joints 0 and 2 stepped; joint 1 did not.
        assert_eq!(svg.matches("<polyline").count(), 2);
        assert!(svg.contains("joint 0") && svg.contains("joint 2") && !svg.contains("joint 1"));
        // Time axis to the trace's end (4 ms), positions -1..2.
        assert!(svg.contains(">0.004<"), "{svg}");
        // Joint 0's line ends at the right edge at its top (+2 steps).
        let joint0 = svg
            .lines()
            .find(|l| l.contains("#1f77b4\" stroke-width=\"1.5\" points"))
            .unwrap();
        assert!(
            joint0.ends_with(&format!("{:.2},{:.2}\"/>", WIDTH - RIGHT, TOP)),
            "{joint0}"
        );

        let commanded = Commanded {
            times_s: vec![0.0, 0.002],
            positions: vec![vec![0.0, 0.0], vec![2.0, 4.0]],
            offset_s: 0.0,
        };
        // Joint 1 is commanded: drawn (flat) with its dashed line.
        let svg = trace_svg(&trace, Some(&commanded), "trace");
        assert!(svg.contains("joint 1"));
        assert_eq!(svg.matches("stroke-dasharray=\"6 4\" opacity").count(), 2);
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
