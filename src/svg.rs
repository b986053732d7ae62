//! A few SVG primitives: enough for line plots in data coordinates (the lab's reports, the
//! calibration's residual plot).

use crate::Point;
use std::fmt::Write as _;

#[derive(Debug)]
pub struct Svg {
    pub width: f64,
    pub height: f64,
    body: String,
}

impl Svg {
    pub fn new(width: f64, height: f64) -> Self {
        Self { width, height, body: String::new() }
    }
    pub fn text(&mut self, x: f64, y: f64, text: &str, anchor: &str, size: f64, color: &str) {
        let text = text.replace('&', "&amp;").replace('<', "&lt;");
        let _ = writeln!(
            self.body,
            r#"<text x="{x:.1}" y="{y:.1}" text-anchor="{anchor}" font-size="{size}" fill="{color}" font-family="sans-serif">{text}</text>"#
        );
    }
    pub fn rect(&mut self, x: f64, y: f64, w: f64, h: f64, color: &str) {
        let _ = writeln!(self.body, r#"<rect x="{x:.1}" y="{y:.1}" width="{w:.1}" height="{h:.1}" fill="{color}"/>"#);
    }
    pub fn finish(self) -> String {
        format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n{}</svg>\n",
            self.body,
            w = self.width,
            h = self.height
        )
    }
}

/// A plot area: data rectangle `lo..hi` mapped into the SVG minus margins (left, top, bottom, right).
#[derive(Debug)]
pub struct Axes {
    lo: Point,
    hi: Point,
    x0: f64,
    y0: f64,
    w: f64,
    h: f64,
}

impl Axes {
    pub fn new(svg: &Svg, lo: Point, hi: Point, margins: (f64, f64, f64, f64)) -> Self {
        let (l, t, b, r) = margins;
        Self { lo, hi, x0: l, y0: t, w: svg.width - l - r, h: svg.height - t - b }
    }

    /// Like `new`, with equal scales on both axes (the data range grows to fit).
    pub fn equal(svg: &Svg, lo: Point, hi: Point, margins: (f64, f64, f64, f64)) -> Self {
        let mut a = Self::new(svg, lo, hi, margins);
        let span = hi - lo;
        let scale = (a.w / span.re).min(a.h / span.im);
        let centre = (lo + hi) * 0.5;
        let half = Point::new(a.w / scale, a.h / scale) * 0.5;
        a.lo = centre - half;
        a.hi = centre + half;
        a
    }

    fn px(&self, p: Point) -> (f64, f64) {
        let x = self.x0 + (p.re - self.lo.re) / (self.hi.re - self.lo.re) * self.w;
        let y = self.y0 + (self.hi.im - p.im) / (self.hi.im - self.lo.im) * self.h;
        (x, y)
    }

    pub fn frame(&self, svg: &mut Svg, xlabel: &str, ylabel: &str) {
        let _ = writeln!(
            svg.body,
            r##"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="none" stroke="#888"/>"##,
            self.x0, self.y0, self.w, self.h
        );
        for (lo, hi, horizontal) in [(self.lo.re, self.hi.re, true), (self.lo.im, self.hi.im, false)] {
            let step = nice_step((hi - lo) / 6.0);
            let mut v = (lo / step).ceil() * step;
            while v <= hi + 1e-12 {
                let decimals = (-step.log10().floor()).max(0.0) as usize;
                let label = format!("{:.*}", decimals, (v / step).round() * step);
                if horizontal {
                    let (x, y) = self.px(Point::new(v, self.lo.im));
                    let _ = writeln!(
                        svg.body,
                        r##"<line x1="{x:.1}" y1="{y:.1}" x2="{x:.1}" y2="{:.1}" stroke="#ccc"/>"##,
                        self.y0
                    );
                    svg.text(x, y + 14.0, &label, "middle", 10.0, "#333");
                } else {
                    let (x, y) = self.px(Point::new(self.lo.re, v));
                    let _ = writeln!(
                        svg.body,
                        r##"<line x1="{x:.1}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#eee"/>"##,
                        self.x0 + self.w
                    );
                    svg.text(x - 4.0, y + 3.0, &label, "end", 10.0, "#333");
                }
                v += step;
            }
        }
        svg.text(self.x0 + self.w / 2.0, self.y0 + self.h + 30.0, xlabel, "middle", 12.0, "#000");
        let (x, y) = (self.x0 - 45.0, self.y0 + self.h / 2.0);
        let _ = writeln!(
            svg.body,
            r#"<text x="{x:.1}" y="{y:.1}" transform="rotate(-90 {x:.1} {y:.1})" text-anchor="middle" font-size="12" font-family="sans-serif">{ylabel}</text>"#
        );
    }

    pub fn polyline(&self, svg: &mut Svg, pts: &[Point], color: &str, width: f64, dash: Option<&str>) {
        if pts.len() < 2 {
            return;
        }
        let mut d = String::with_capacity(pts.len() * 16);
        for p in pts {
            let (x, y) = self.px(*p);
            let _ = write!(d, "{x:.1},{y:.1} ");
        }
        let dash = dash.map_or(String::new(), |d| format!(r#" stroke-dasharray="{d}""#));
        let _ =
            writeln!(svg.body, r#"<polyline points="{d}" fill="none" stroke="{color}" stroke-width="{width}"{dash}/>"#);
    }

    pub fn circle(&self, svg: &mut Svg, c: Point, r: f64, color: &str, width: f64, fill_opacity: f64) {
        let (x, y) = self.px(c);
        let rpx = r / (self.hi.re - self.lo.re) * self.w;
        let _ = writeln!(
            svg.body,
            r#"<circle cx="{x:.1}" cy="{y:.1}" r="{rpx:.1}" fill="{color}" fill-opacity="{fill_opacity}" stroke="{color}" stroke-width="{width}"/>"#
        );
    }

    pub fn label(&self, svg: &mut Svg, at: Point, text: &str, color: &str) {
        let (x, y) = self.px(at);
        svg.text(x, y - 4.0, text, "middle", 9.0, color);
    }

    pub fn marker(&self, svg: &mut Svg, at: Point, color: &str, text: &str) {
        let (x, y) = self.px(at);
        let _ = writeln!(svg.body, r#"<circle cx="{x:.1}" cy="{y:.1}" r="5" fill="{color}"/>"#);
        svg.text(x + 8.0, y - 8.0, text, "start", 12.0, color);
    }
}

fn nice_step(raw: f64) -> f64 {
    let mag = 10f64.powf(raw.abs().max(1e-12).log10().floor());
    let n = raw / mag;
    mag * if n < 1.5 {
        1.0
    } else if n < 3.5 {
        2.0
    } else if n < 7.5 {
        5.0
    } else {
        10.0
    }
}
