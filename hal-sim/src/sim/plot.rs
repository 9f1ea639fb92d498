//! A small SVG line-plot writer: axes with 1-2-5 ticks (linear or logarithmic x), grid, legend, one polyline per
//! series. Plain SVG 1.1 that any browser opens; no dependencies.

use std::fmt::Write as _;
use std::io;
use std::path::Path;

/// Colours of the series, in order (colour-blind-safe palette).
const COLOURS: [&str; 8] = ["#0072b2", "#d55e00", "#009e73", "#cc79a7", "#e69f00", "#56b4e9", "#000000", "#f0e442"];
/// Canvas size and margins, in px.
const WIDTH: f64 = 960.0;
const HEIGHT: f64 = 540.0;
const LEFT: f64 = 80.0;
const RIGHT: f64 = 30.0;
const TOP: f64 = 50.0;
const BOTTOM: f64 = 60.0;
/// At most this many points are drawn per series (min/max decimation keeps the envelope).
const MAX_POINTS: usize = 4000;

/// One line of a plot.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// (x, y) points; non-finite points are skipped.
    pub points: Vec<(f64, f64)>,
    /// Draw dots at the points (for sparse data such as a frequency sweep).
    pub markers: bool,
}

impl Series {
    /// A series from x and y slices of the same length (the shorter length wins).
    pub fn new(name: &str, x: &[f64], y: &[f64]) -> Self {
        Self { name: name.to_owned(), points: x.iter().copied().zip(y.iter().copied()).collect(), markers: false }
    }

    /// The same series with point markers.
    pub fn with_markers(mut self) -> Self {
        self.markers = true;
        self
    }
}

/// A line plot.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Plot {
    /// Title above the plot area.
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label.
    pub y_label: String,
    /// Logarithmic x axis (x must be positive).
    pub log_x: bool,
    /// The lines.
    pub series: Vec<Series>,
    /// Horizontal reference lines (value, label), drawn dashed.
    pub h_lines: Vec<(f64, String)>,
}

/// Tick positions for a linear axis over [lo, hi]: multiples of 1, 2 or 5 x 10^k, about 5 to 10 of them.
fn linear_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let span = (hi - lo).abs().max(1e-300);
    let raw = span / 8.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|s| *s >= raw).unwrap_or(10.0 * mag);
    let mut ticks = Vec::new();
    let mut v = (lo / step).ceil() * step;
    while v <= hi + step * 1e-9 && ticks.len() < 50 {
        ticks.push(if v.abs() < step * 1e-9 { 0.0 } else { v });
        v += step;
    }
    ticks
}

/// Tick positions for a logarithmic axis over [lo, hi] (both > 0): 1, 2, 5 x 10^k.
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let mut ticks = Vec::new();
    let mut decade = 10f64.powf(lo.log10().floor());
    while decade <= hi && ticks.len() < 60 {
        for m in [1.0, 2.0, 5.0] {
            let v = m * decade;
            if v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9) {
                ticks.push(v);
            }
        }
        decade *= 10.0;
    }
    ticks
}

/// A tick label: short, without trailing zeros.
fn label(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e6).contains(&a) {
        format!("{v:.0e}")
    } else {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if s == "-0" {
            "0".to_owned()
        } else {
            s.to_owned()
        }
    }
}

/// Escapes text for SVG.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// Keeps at most `MAX_POINTS` points, taking the min and max of each bucket so peaks survive.
fn decimate(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    if points.len() <= MAX_POINTS {
        return points.to_vec();
    }
    let bucket = points.len().div_ceil(MAX_POINTS / 2);
    let mut out = Vec::with_capacity(MAX_POINTS + 2);
    for chunk in points.chunks(bucket) {
        let lo = chunk.iter().copied().min_by(|a, b| a.1.total_cmp(&b.1));
        let hi = chunk.iter().copied().max_by(|a, b| a.1.total_cmp(&b.1));
        if let (Some(lo), Some(hi)) = (lo, hi) {
            if lo.0 <= hi.0 {
                out.extend([lo, hi]);
            } else {
                out.extend([hi, lo]);
            }
        }
    }
    out
}

impl Plot {
    /// A plot with a title and axis labels and no series yet.
    pub fn new(title: &str, x_label: &str, y_label: &str) -> Self {
        Self { title: title.to_owned(), x_label: x_label.to_owned(), y_label: y_label.to_owned(), ..Self::default() }
    }

    /// The plot as SVG text.
    pub fn to_svg(&self) -> String {
        let fx = |x: f64| if self.log_x { x.log10() } else { x };
        let finite = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite() && (!self.log_x || p.0 > 0.0);
        let all = self.series.iter().flat_map(|s| s.points.iter().copied().filter(finite));
        let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
        for (x, y) in all {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
        for (v, _) in &self.h_lines {
            y0 = y0.min(*v);
            y1 = y1.max(*v);
        }
        if !x0.is_finite() {
            (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
        }
        if x1 <= x0 {
            x1 = x0 + 1.0;
        }
        let pad = ((y1 - y0) * 0.05).max(1e-9);
        let (y0, y1) = (y0 - pad, y1 + pad);
        let (pw, ph) = (WIDTH - LEFT - RIGHT, HEIGHT - TOP - BOTTOM);
        let (lx0, lx1) = (fx(x0), fx(x1));
        let sx = |x: f64| LEFT + (fx(x) - lx0) / (lx1 - lx0) * pw;
        let sy = |y: f64| TOP + (y1 - y) / (y1 - y0) * ph;

        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{HEIGHT}" viewBox="0 0 {WIDTH} {HEIGHT}" font-family="sans-serif" font-size="13">"#
        );
        let _ = writeln!(s, r#"<rect width="100%" height="100%" fill="white"/>"#);
        let _ = writeln!(
            s,
            r#"<text x="{}" y="28" text-anchor="middle" font-size="16" font-weight="bold">{}</text>"#,
            WIDTH / 2.0,
            esc(&self.title)
        );
        // Grid and ticks.
        let xt = if self.log_x { log_ticks(x0, x1) } else { linear_ticks(x0, x1) };
        for t in xt {
            let x = sx(t);
            let _ =
                writeln!(s, r##"<line x1="{x:.1}" y1="{TOP}" x2="{x:.1}" y2="{:.1}" stroke="#e0e0e0"/>"##, TOP + ph);
            let _ =
                writeln!(s, r#"<text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text>"#, TOP + ph + 18.0, label(t));
        }
        for t in linear_ticks(y0, y1) {
            let y = sy(t);
            let _ =
                writeln!(s, r##"<line x1="{LEFT}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#e0e0e0"/>"##, LEFT + pw);
            let _ =
                writeln!(s, r#"<text x="{:.1}" y="{:.1}" text-anchor="end">{}</text>"#, LEFT - 6.0, y + 4.0, label(t));
        }
        let _ = writeln!(s, r#"<rect x="{LEFT}" y="{TOP}" width="{pw}" height="{ph}" fill="none" stroke="black"/>"#);
        let _ = writeln!(
            s,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
            LEFT + pw / 2.0,
            HEIGHT - 15.0,
            esc(&self.x_label)
        );
        let _ = writeln!(
            s,
            r#"<text x="18" y="{:.1}" text-anchor="middle" transform="rotate(-90 18 {:.1})">{}</text>"#,
            TOP + ph / 2.0,
            TOP + ph / 2.0,
            esc(&self.y_label)
        );
        // Reference lines.
        for (v, text) in &self.h_lines {
            let y = sy(*v);
            let _ = writeln!(
                s,
                r##"<line x1="{LEFT}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#808080" stroke-dasharray="6 4"/>"##,
                LEFT + pw
            );
            let _ =
                writeln!(s, r##"<text x="{:.1}" y="{:.1}" fill="#606060">{}</text>"##, LEFT + 6.0, y - 4.0, esc(text));
        }
        // Series.
        let _ = writeln!(s, r#"<g clip-path="none">"#);
        for (k, series) in self.series.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let pts: Vec<(f64, f64)> = series.points.iter().copied().filter(finite).collect();
            let pts = decimate(&pts);
            let mut path = String::new();
            for (x, y) in &pts {
                let _ = write!(path, "{:.2},{:.2} ", sx(*x), sy(*y));
            }
            let _ = writeln!(
                s,
                r#"<polyline fill="none" stroke="{colour}" stroke-width="1.6" points="{}"/>"#,
                path.trim_end()
            );
            if series.markers {
                for (x, y) in &pts {
                    let _ = writeln!(s, r#"<circle cx="{:.2}" cy="{:.2}" r="3" fill="{colour}"/>"#, sx(*x), sy(*y));
                }
            }
        }
        let _ = writeln!(s, "</g>");
        // Legend, top right inside the plot area.
        let lw = 14.0 + 7.5 * self.series.iter().map(|x| x.name.len()).max().unwrap_or(0) as f64 + 30.0;
        let lx = LEFT + pw - lw - 10.0;
        let n = self.series.len() as f64;
        let _ = writeln!(
            s,
            r#"<rect x="{lx:.1}" y="{:.1}" width="{lw:.1}" height="{:.1}" fill="white" fill-opacity="0.85" stroke="gray"/>"#,
            TOP + 10.0,
            n * 20.0 + 8.0
        );
        for (k, series) in self.series.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let y = TOP + 10.0 + 16.0 + 20.0 * k as f64;
            let _ = writeln!(
                s,
                r#"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{colour}" stroke-width="3"/>"#,
                lx + 8.0,
                y - 4.0,
                lx + 32.0,
                y - 4.0
            );
            let _ = writeln!(s, r#"<text x="{:.1}" y="{y:.1}">{}</text>"#, lx + 38.0, esc(&series.name));
        }
        s.push_str("</svg>\n");
        s
    }

    /// Writes [`Plot::to_svg`] to `path`, creating its directory.
    pub fn write_svg(&self, path: &Path) -> io::Result<()> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        std::fs::write(path, self.to_svg())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_numbers() {
        let t = linear_ticks(0.0, 1.0);
        assert_eq!(t.len(), 6);
        assert!(t.iter().zip([0.0, 0.2, 0.4, 0.6, 0.8, 1.0]).all(|(a, b)| (a - b).abs() < 1e-12), "{t:?}");
        assert_eq!(log_ticks(100.0, 1000.0), vec![100.0, 200.0, 500.0, 1000.0]);
        assert_eq!(label(0.5), "0.5");
        assert_eq!(label(2000.0), "2000");
    }

    #[test]
    fn svg_has_one_polyline_per_series_and_a_legend() {
        let mut p = Plot::new("t", "x", "y");
        p.series.push(Series::new("a", &[0.0, 1.0], &[0.0, 1.0]));
        p.series.push(Series::new("b<c", &[0.0, 1.0], &[1.0, 0.0]).with_markers());
        p.h_lines.push((0.5, "half".into()));
        let svg = p.to_svg();
        assert_eq!(svg.matches("<polyline").count(), 2);
        assert!(svg.contains("b&lt;c"));
        assert!(svg.starts_with("<svg") && svg.ends_with("</svg>\n"));
    }
}
