//! Charts for `reframe compare`: written as SVG by hand (a chart is a few dozen elements) and
//! rasterised to PNG with resvg, so that both files show the same drawing.
use crate::util::fs::write_atomic;
use anyhow::{anyhow, Context, Result};
use base64::Engine as _;
use std::fmt::Write as _;
use std::path::Path;

/// One colour per method, in the order independent, havran, mis, mis-exact, mis-cv, then their
/// denoised lines (`compare::Candidate`), and the charts' other lines (Okabe-Ito palette and
/// Tol's, readable with colour-blindness).
pub const COLOURS: [&str; 10] = [
    "#000000", "#E69F00", "#56B4E9", "#009E73", "#CC79A7", "#D55E00", "#0072B2", "#882255",
    "#44AA99", "#999933",
];

/// A polyline with markers.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub colour: &'static str,
    pub dashed: bool,
    pub points: Vec<(f64, f64)>,
}

/// A line chart, either axis linear or logarithmic.
#[derive(Clone, Debug)]
pub struct LineChart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub log_y: bool,
    pub series: Vec<Series>,
}

const W: f64 = 720.0;
const H: f64 = 480.0;
const LEFT: f64 = 80.0;
const RIGHT: f64 = 210.0;
const TOP: f64 = 44.0;
const BOTTOM: f64 = 56.0;
const FONT: &str = "font-family=\"DejaVu Sans, sans-serif\"";

fn header(w: f64, h: f64) -> String {
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" \
         viewBox=\"0 0 {w} {h}\">\n<rect width=\"{w}\" height=\"{h}\" fill=\"white\"/>\n"
    )
}

/// Text from input (a scene's name in a title) as SVG text: shown as messages show it
/// (`printable`: control characters, which XML forbids and which made the chart fail to parse
/// after a whole `compare` had run, are written as escapes, `\u{1}`), with XML's markup escaped.
fn escape(s: &str) -> String {
    crate::util::text::printable(s)
        .replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// The chart's title, centred over a plot area `pw` wide.
fn title(s: &mut String, pw: f64, text: &str) {
    let _ = writeln!(
        s,
        "<text x=\"{}\" y=\"26\" {FONT} font-size=\"16\" text-anchor=\"middle\">{}</text>",
        LEFT + pw / 2.0,
        escape(text)
    );
}

/// A horizontal grid line at height `y` across a plot area `pw` wide, labelled on the left.
fn y_gridline(s: &mut String, y: f64, pw: f64, label: &str) {
    let _ = writeln!(
        s,
        "<line x1=\"{LEFT}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"#ddd\"/>\
         <text x=\"{:.1}\" y=\"{:.1}\" {FONT} font-size=\"11\" text-anchor=\"end\">{label}</text>",
        LEFT + pw,
        LEFT - 6.0,
        y + 4.0
    );
}

/// The frame of a `pw` x `ph` plot area and the rotated y-axis label beside it.
fn frame(s: &mut String, pw: f64, ph: f64, y_label: &str) {
    let _ = writeln!(
        s,
        "<rect x=\"{LEFT}\" y=\"{TOP}\" width=\"{pw}\" height=\"{ph}\" fill=\"none\" stroke=\"#333\"/>\n\
         <text x=\"18\" y=\"{:.1}\" {FONT} font-size=\"13\" text-anchor=\"middle\" \
         transform=\"rotate(-90 18 {:.1})\">{}</text>",
        TOP + ph / 2.0,
        TOP + ph / 2.0,
        escape(y_label)
    );
}

/// Tick positions (in data units) and labels for an axis spanning `lo..hi`.
fn ticks(lo: f64, hi: f64, log: bool) -> Vec<(f64, String)> {
    if log {
        let (a, b) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
        let mut t = Vec::new();
        for e in a..=b {
            for m in [1.0, 2.0, 5.0] {
                let v = m * 10f64.powi(e);
                if v >= lo * 0.999 && v <= hi * 1.001 {
                    t.push((v, format_number(v)));
                }
            }
        }
        t
    } else {
        let span = (hi - lo).max(1e-12);
        let raw = span / 6.0;
        let mag = 10f64.powf(raw.log10().floor());
        let step = [1.0, 2.0, 5.0, 10.0]
            .iter()
            .map(|m| m * mag)
            .find(|s| *s >= raw)
            .unwrap_or(10.0 * mag);
        let mut v = (lo / step).ceil() * step;
        let mut t = Vec::new();
        while v <= hi + 1e-9 * span {
            t.push((v, format_number(v)));
            v += step;
        }
        t
    }
}

/// Short labels: 0.001, 0.02, 5, 300, 2e+04.
fn format_number(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e4).contains(&a) {
        format!("{v:.0e}")
    } else {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

impl LineChart {
    /// The chart as an SVG document.
    pub fn svg(&self) -> String {
        let pts = || self.series.iter().flat_map(|s| s.points.iter());
        let ok = |v: f64, log: bool| v.is_finite() && (!log || v > 0.0);
        let xs: Vec<f64> = pts().map(|p| p.0).filter(|&v| ok(v, self.log_x)).collect();
        let ys: Vec<f64> = pts().map(|p| p.1).filter(|&v| ok(v, self.log_y)).collect();
        let range = |v: &[f64], log: bool| {
            let (mut lo, mut hi) = v
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                    (a.min(x), b.max(x))
                });
            if !lo.is_finite() {
                (lo, hi) = (1.0, 10.0);
            }
            if log {
                // Pad to the surrounding 1-2-5 ticks so that every point sits inside the frame.
                let down = |x: f64| {
                    let e = 10f64.powf(x.log10().floor());
                    [5.0, 2.0, 1.0]
                        .iter()
                        .map(|m| m * e)
                        .find(|&t| t <= x)
                        .unwrap_or(e)
                };
                let up = |x: f64| {
                    let e = 10f64.powf(x.log10().floor());
                    [1.0, 2.0, 5.0, 10.0]
                        .iter()
                        .map(|m| m * e)
                        .find(|&t| t >= x)
                        .unwrap_or(10.0 * e)
                };
                (down(lo), up(hi))
            } else {
                let pad = ((hi - lo) * 0.05).max(1e-9);
                (lo.min(0.0).min(lo - pad), hi + pad)
            }
        };
        let (x0, x1) = range(&xs, self.log_x);
        let (y0, y1) = range(&ys, self.log_y);
        let map = |v: f64, lo: f64, hi: f64, log: bool| {
            if log {
                (v.log10() - lo.log10()) / (hi.log10() - lo.log10()).max(1e-12)
            } else {
                (v - lo) / (hi - lo).max(1e-12)
            }
        };
        let (pw, ph) = (W - LEFT - RIGHT, H - TOP - BOTTOM);
        let px = |v: f64| LEFT + pw * map(v, x0, x1, self.log_x);
        let py = |v: f64| TOP + ph * (1.0 - map(v, y0, y1, self.log_y));
        let mut s = header(W, H);
        title(&mut s, pw, &self.title);
        // Grid and ticks.
        for (v, label) in ticks(x0, x1, self.log_x) {
            let x = px(v);
            let _ = writeln!(
                s,
                "<line x1=\"{x:.1}\" y1=\"{TOP}\" x2=\"{x:.1}\" y2=\"{:.1}\" stroke=\"#ddd\"/>\
                 <text x=\"{x:.1}\" y=\"{:.1}\" {FONT} font-size=\"11\" text-anchor=\"middle\">{label}</text>",
                TOP + ph,
                TOP + ph + 16.0
            );
        }
        for (v, label) in ticks(y0, y1, self.log_y) {
            y_gridline(&mut s, py(v), pw, &label);
        }
        frame(&mut s, pw, ph, &self.y_label);
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" {FONT} font-size=\"13\" text-anchor=\"middle\">{}</text>",
            LEFT + pw / 2.0,
            H - 14.0,
            escape(&self.x_label)
        );
        // Series and legend.
        for (i, se) in self.series.iter().enumerate() {
            let p: Vec<(f64, f64)> = se
                .points
                .iter()
                .copied()
                .filter(|&(x, y)| ok(x, self.log_x) && ok(y, self.log_y))
                .map(|(x, y)| (px(x), py(y)))
                .collect();
            let dash = if se.dashed {
                " stroke-dasharray=\"6 4\""
            } else {
                ""
            };
            let path: Vec<String> = p.iter().map(|(x, y)| format!("{x:.1},{y:.1}")).collect();
            let _ = writeln!(
                s,
                "<polyline points=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"2\"{dash}/>",
                path.join(" "),
                se.colour
            );
            for (x, y) in &p {
                let _ = writeln!(
                    s,
                    "<circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"3.5\" fill=\"{}\"/>",
                    se.colour
                );
            }
            let ly = TOP + 10.0 + 20.0 * i as f64;
            let lx = W - RIGHT + 14.0;
            let _ = writeln!(
                s,
                "<line x1=\"{lx}\" y1=\"{ly}\" x2=\"{}\" y2=\"{ly}\" stroke=\"{}\" stroke-width=\"2\"{dash}/>\
                 <text x=\"{}\" y=\"{}\" {FONT} font-size=\"12\">{}</text>",
                lx + 24.0,
                se.colour,
                lx + 30.0,
                ly + 4.0,
                escape(&se.name)
            );
        }
        s.push_str("</svg>\n");
        s
    }
}

/// A bar chart: one bar per (label, value, colour).
pub fn bar_chart(chart_title: &str, y_label: &str, bars: &[(String, f64, &str)]) -> String {
    let (pw, ph) = (W - LEFT - 40.0, H - TOP - BOTTOM - 20.0);
    let hi = bars.iter().map(|b| b.1).fold(0.0f64, f64::max).max(1e-12) * 1.1;
    let mut s = header(W, H);
    title(&mut s, pw, chart_title);
    for (v, label) in ticks(0.0, hi, false) {
        y_gridline(&mut s, TOP + ph * (1.0 - v / hi), pw, &label);
    }
    let slot = pw / bars.len().max(1) as f64;
    for (i, (label, v, colour)) in bars.iter().enumerate() {
        let bh = ph * (v / hi).clamp(0.0, 1.0);
        let x = LEFT + slot * (i as f64 + 0.2);
        let _ = writeln!(
            s,
            "<rect x=\"{x:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{bh:.1}\" fill=\"{colour}\"/>\
             <text x=\"{:.1}\" y=\"{:.1}\" {FONT} font-size=\"11\" text-anchor=\"middle\">{}</text>\
             <text x=\"{:.1}\" y=\"{:.1}\" {FONT} font-size=\"12\" text-anchor=\"middle\">{}</text>",
            TOP + ph - bh,
            slot * 0.6,
            x + slot * 0.3,
            TOP + ph - bh - 5.0,
            format_number((v * 1e4).round() / 1e4),
            x + slot * 0.3,
            TOP + ph + 18.0,
            escape(label)
        );
    }
    frame(&mut s, pw, ph, y_label);
    s.push_str("</svg>\n");
    s
}

/// Images side by side (PNG bytes, width, height) under their captions, each scaled by `zoom`
/// with nearest-neighbour sampling so that the noise stays visible.
pub fn image_strip(title: &str, tiles: &[(String, Vec<u8>, u32, u32)], zoom: u32) -> String {
    let gap = 12.0;
    let tw = tiles.iter().map(|t| t.2).max().unwrap_or(1) as f64 * zoom as f64;
    let th = tiles.iter().map(|t| t.3).max().unwrap_or(1) as f64 * zoom as f64;
    let (w, h) = (gap + (tw + gap) * tiles.len() as f64, 40.0 + th + 44.0);
    let mut s = header(w, h);
    let _ = writeln!(
        s,
        "<text x=\"{}\" y=\"26\" {FONT} font-size=\"15\" text-anchor=\"middle\">{}</text>",
        w / 2.0,
        escape(title)
    );
    for (i, (caption, png, iw, ih)) in tiles.iter().enumerate() {
        let x = gap + (tw + gap) * i as f64;
        let data = base64::engine::general_purpose::STANDARD.encode(png);
        let _ = writeln!(
            s,
            "<image x=\"{x:.1}\" y=\"40\" width=\"{}\" height=\"{}\" image-rendering=\"pixelated\" \
             style=\"image-rendering:pixelated\" href=\"data:image/png;base64,{data}\"/>",
            *iw as f64 * zoom as f64,
            *ih as f64 * zoom as f64
        );
        for (j, line) in caption.split('\n').enumerate() {
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" {FONT} font-size=\"12\" text-anchor=\"middle\">{}</text>",
                x + tw / 2.0,
                40.0 + th + 17.0 + 15.0 * j as f64,
                escape(line)
            );
        }
    }
    s.push_str("</svg>\n");
    s
}

/// Write `svg` to `stem.svg` and its rasterisation to `stem.png`, both atomically.
/// Nothing is written where the drawing does not parse.
pub fn write_svg_png(svg: &str, stem: &Path) -> Result<()> {
    let svg_path = stem.with_extension("svg");
    let mut opt = resvg::usvg::Options::default();
    opt.fontdb_mut().load_system_fonts();
    let tree = resvg::usvg::Tree::from_str(svg, &opt)
        .with_context(|| format!("{}: not a valid SVG", svg_path.display()))?;
    write_atomic(&svg_path, svg.as_bytes())?;
    let size = tree.size().to_int_size();
    let mut pixmap = resvg::tiny_skia::Pixmap::new(size.width(), size.height())
        .ok_or_else(|| anyhow!("{}: empty drawing", svg_path.display()))?;
    resvg::render(&tree, Default::default(), &mut pixmap.as_mut());
    let png = pixmap
        .encode_png()
        .with_context(|| format!("encoding {}", stem.with_extension("png").display()))?;
    write_atomic(&stem.with_extension("png"), &png)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_cover_the_range() {
        let t = ticks(0.01, 1.0, true);
        let v: Vec<f64> = t.iter().map(|t| t.0).collect();
        assert_eq!(v.first(), Some(&0.01));
        assert_eq!(v.last(), Some(&1.0));
        assert!(v.contains(&0.05) && v.contains(&0.2));
        let l = ticks(0.0, 7.3, false);
        assert_eq!(l[0].1, "0");
        assert!(l.iter().any(|t| t.1 == "6"));
        assert_eq!(format_number(0.02), "0.02");
        assert_eq!(format_number(30000.0), "3e4");
    }

    #[test]
    fn a_chart_parses_and_rasterises() {
        let chart = LineChart {
            title: "t <&>".into(),
            x_label: "seconds".into(),
            y_label: "relMSE".into(),
            log_x: true,
            log_y: true,
            series: vec![Series {
                name: "a".into(),
                colour: COLOURS[0],
                dashed: true,
                points: vec![(1.0, 0.1), (2.0, 0.05), (4.0, 0.0)],
            }],
        };
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("c");
        write_svg_png(&chart.svg(), &stem).unwrap();
        let png = std::fs::read(stem.with_extension("png")).unwrap();
        assert_eq!(&png[1..4], b"PNG");
        let bars = bar_chart("b", "flicker", &[("x".into(), 0.5, COLOURS[1])]);
        write_svg_png(&bars, &stem).unwrap();
    }
}
