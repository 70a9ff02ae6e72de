//! SVG plots of a recorded run: joint positions (steps) over time, one colour per joint,
//! with the commanded trajectory dashed when given.

use std::fmt::Write as _;

use crate::record::Sample;
use crate::trajectory::Waypoints;

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
}

/// Draws the recording (and the commanded trajectory) as an SVG document.
pub fn svg(samples: &[Sample], commanded: Option<&Commanded>, title: &str) -> String {
    let joints = samples.iter().map(|s| s.position.len()).max().unwrap_or(0);
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
    for s in samples {
        for &p in &s.position {
            widen(s.time_s, f64::from(p));
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
    for j in 0..joints {
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
        let path: Vec<String> = samples
            .iter()
            .filter_map(|s| s.position.get(j).map(|&p| (s.time_s, f64::from(p))))
            .map(|(t, p)| format!("{:.2},{:.2}", x(t), y(p)))
            .collect();
        let _ = writeln!(
            out,
            r#"<polyline fill="none" stroke="{colour}" stroke-width="1.5" points="{}"/>"#,
            path.join(" ")
        );
        let ly = TOP + 10.0 + 18.0 * j as f64;
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
        let ly = TOP + 10.0 + 18.0 * joints as f64;
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
}
