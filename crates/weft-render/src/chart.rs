//! Line charts drawn into an [`Image`]: stacked panels sharing an x axis,
//! nice tick values (1-2-5 steps), labels in the built-in font, anti-aliased
//! lines and a legend placed where it hides no curve.

use crate::font::{draw_text, text_width, CAP_HEIGHT};
use crate::image::{blend, Image};

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Style {
    /// A 2-pixel anti-aliased polyline; non-finite points break it.
    Line,
    /// A vertical bar from zero to each point (counts per window).
    Stems,
}

/// One named data series.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    pub name: String,
    pub color: [u8; 3],
    pub points: Vec<(f64, f64)>,
    pub style: Style,
}

/// One panel: a title (what is plotted, with units) and its series.
#[derive(Clone, Debug, PartialEq)]
pub struct Panel {
    pub title: String,
    pub series: Vec<Series>,
}

/// A chart: a title, panels stacked top to bottom, one x-axis label.
#[derive(Clone, Debug, PartialEq)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub panels: Vec<Panel>,
}

/// Distinct, colour-blind-friendly line colours (Tableau 10).
pub const COLORS: [[u8; 3]; 6] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
];

/// Chart background.
pub const BACKGROUND: [u8; 3] = [255, 255, 255];
const INK: [u8; 3] = [40, 40, 40];
const GRID: [u8; 3] = [228, 228, 228];
const FRAME: [u8; 3] = [120, 120, 120];
/// Font scale of labels and panel titles.
const S: u32 = 2;
/// Font scale of the chart title.
const T: u32 = 3;

/// An axis: `lo..=hi` with ticks every `step`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Axis {
    pub lo: f64,
    pub hi: f64,
    pub step: f64,
}

impl Axis {
    /// A nice axis covering `[min, max]` with about `target` intervals: the
    /// step is 1, 2 or 5 times a power of ten and the ends are multiples of
    /// it. An empty or single-valued range is widened first.
    pub fn nice(min: f64, max: f64, target: usize) -> Axis {
        let (mut min, mut max) = if min.is_finite() && max.is_finite() && min <= max {
            (min, max)
        } else {
            (0.0, 1.0)
        };
        if max - min <= 1e-12 * max.abs().max(min.abs()) {
            if max == 0.0 {
                max = 1.0;
            } else {
                let pad = 0.1 * max.abs();
                min -= pad;
                max += pad;
            }
        }
        let raw = (max - min) / target.max(1) as f64;
        let e = raw.log10().floor() as i32;
        // Divide by a positive power instead of multiplying by a negative
        // one: 10 / 1e6 is exactly the double nearest 1e-5, 10 * 1e-6 is not.
        let scale = |m: f64| {
            if e >= 0 {
                m * 10f64.powi(e)
            } else {
                m / 10f64.powi(-e)
            }
        };
        let f = raw / scale(1.0);
        let nice = if f <= 1.0 {
            1.0
        } else if f <= 2.0 {
            2.0
        } else if f <= 5.0 {
            5.0
        } else {
            10.0
        };
        let step = scale(nice);
        Axis {
            lo: (min / step + 1e-9).floor() * step,
            hi: (max / step - 1e-9).ceil() * step,
            step,
        }
    }

    /// The tick values: the multiples of `step` in `[lo, hi]`.
    pub fn ticks(&self) -> Vec<f64> {
        let eps = 1e-9;
        let first = (self.lo / self.step - eps).ceil() as i64;
        let last = (self.hi / self.step + eps).floor() as i64;
        (first..=last).map(|k| k as f64 * self.step).collect()
    }

    /// Tick labels: fixed notation for steps from 0.001 and magnitudes below
    /// 10^6 (as many decimals as the step needs), scientific otherwise with
    /// the digits the step needs and no trailing zeros (`2e-4`, `1.5e-3`).
    pub fn labels(&self) -> Vec<String> {
        let k = (self.step.log10() + 1e-9).floor() as i32;
        let big = self.lo.abs().max(self.hi.abs());
        let fixed = k >= -3 && big < 1e6;
        self.ticks()
            .into_iter()
            .map(|v| {
                // Ticks that should be zero come out as tiny multiples of step.
                if v.abs() < 1e-9 * self.step {
                    "0".to_string()
                } else if fixed {
                    format!("{:.*}", (-k).max(0) as usize, v)
                } else {
                    let e = (v.abs().log10() + 1e-9).floor() as i32;
                    let m = format!("{:.*}", (e - k).max(0) as usize, v / 10f64.powi(e));
                    let m = if m.contains('.') {
                        m.trim_end_matches('0').trim_end_matches('.')
                    } else {
                        &m
                    };
                    format!("{m}e{e}")
                }
            })
            .collect()
    }

    /// An axis that spans exactly `[min, max]` (from 0 when the data start
    /// near it), with nice ticks inside: for the x axis, where padding would
    /// only waste width.
    pub fn tight(min: f64, max: f64, target: usize) -> Axis {
        let nice = Axis::nice(min, max, target);
        if !(min.is_finite() && max.is_finite() && max > min) {
            return nice;
        }
        let lo = if min >= 0.0 && min <= 0.1 * (max - min) {
            0.0
        } else {
            min
        };
        Axis {
            lo,
            hi: max,
            step: nice.step,
        }
    }
}

/// The smallest and largest finite value, if any.
fn range(points: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    points
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| match acc {
            None => Some((v, v)),
            Some((a, b)) => Some((a.min(v), b.max(v))),
        })
}

/// Draws `chart` `width` pixels wide; the height follows from the number of
/// panels. A panel with more than one series gets a legend, in the first
/// corner of its plot (top right, top left, bottom right, bottom left) that
/// no curve passes through, or else to the right of the plot.
pub fn draw_chart(chart: &Chart, width: u32) -> Image {
    let layout = layout(chart, width);
    let mut img = Image::new(width, layout.height, BACKGROUND);
    let tw = text_width(&chart.title, T) as i64;
    draw_text(&mut img, (width as i64 - tw) / 2, 16, &chart.title, T, INK);
    let panels = chart.panels.iter().zip(&layout.areas);
    for (((panel, area), curves), legend) in panels.zip(&layout.curves).zip(&layout.legends) {
        let title_y = area.top - (LABEL_LINE + 8) as i64;
        draw_text(&mut img, area.left, title_y, &panel.title, S, INK);
        draw_axes(&mut img, area);
        curves.draw(&mut img, area);
        if let Some(r) = legend {
            draw_legend(&mut img, r, &panel.series);
        }
    }
    let (left, right) = (layout.left, layout.right);
    let lw = text_width(&chart.x_label, S) as i64;
    draw_text(
        &mut img,
        left + (right - left - lw) / 2,
        layout.x_label_y,
        &chart.x_label,
        S,
        INK,
    );
    img
}

/// Where the parts of a chart go.
struct Layout {
    height: u32,
    /// Left and right edges of every plot.
    left: i64,
    right: i64,
    /// Each panel's plot.
    areas: Vec<Area>,
    /// Each panel's curves, rasterized for its plot.
    curves: Vec<Curves>,
    /// Each panel's legend, if it has one.
    legends: Vec<Option<Rect>>,
    x_label_y: i64,
}

/// Height of a line of labels.
const LABEL_LINE: u32 = 10 * S;
/// Space between a legend and the plot frame, or a plot and a legend beside
/// it.
const LEGEND_INSET: i64 = 10;
/// Curves keep at least this far from a legend placed inside a plot.
const LEGEND_CLEARANCE: i64 = 4;
/// Length of the line sample in front of each name of a legend.
const LEGEND_SAMPLE: i64 = 28;
/// A plot is never narrowed below this width to make room for a legend.
const MIN_PLOT_WIDTH: i64 = 200;

/// The layout of `chart` drawn `width` pixels wide: panels stacked under the
/// title, plots sharing their left and right edges, and each legend in a
/// free corner of its plot or beside it.
fn layout(chart: &Chart, width: u32) -> Layout {
    let n = chart.panels.len().max(1) as u32;
    let plot_h: u32 = match n {
        1 => 380,
        2 => 250,
        _ => 200,
    };
    let title_block = 16 + 9 * T + 12;
    let panel_block = LABEL_LINE + 8 + plot_h + 8 + LABEL_LINE + 12;
    let height = title_block + n * panel_block + LABEL_LINE + 16;

    let all = chart.panels.iter().flat_map(|p| &p.series);
    let x_axis = match range(all.flat_map(|s| s.points.iter().map(|p| p.0))) {
        Some((a, b)) => Axis::tight(a, b, 8),
        None => Axis::nice(0.0, 1.0, 8),
    };
    let y_axes: Vec<Axis> = chart
        .panels
        .iter()
        .map(|p| {
            // Zero is always on the axis: magnitudes read honestly.
            let ys = p.series.iter().flat_map(|s| s.points.iter().map(|q| q.1));
            let (a, b) = range(ys.chain([0.0])).unwrap_or((0.0, 1.0));
            Axis::nice(a, b, 5)
        })
        .collect();
    let label_w = y_axes
        .iter()
        .flat_map(|a| a.labels())
        .map(|l| text_width(&l, S))
        .max()
        .unwrap_or(0);
    let left = (16 + label_w + 12) as i64;
    let areas_for = |right: i64| -> Vec<Area> {
        (0..chart.panels.len())
            .map(|k| {
                let top = (title_block + k as u32 * panel_block + LABEL_LINE + 8) as i64;
                Area {
                    left,
                    right,
                    top,
                    bottom: top + plot_h as i64,
                    x: x_axis,
                    y: y_axes[k],
                }
            })
            .collect()
    };
    let legend_sizes: Vec<Option<(i64, i64)>> = chart
        .panels
        .iter()
        .map(|p| (p.series.len() > 1).then(|| legend_size(&p.series)))
        .collect();
    // Each panel's curves, rasterized once for its plot: they find the free
    // corner for its legend, and the chart draws them.
    let rasterize = |areas: &[Area]| -> Vec<Curves> {
        (areas.iter().zip(&chart.panels))
            .map(|(area, panel)| Curves::rasterize(area, &panel.series))
            .collect()
    };
    let free_corners = |areas: &[Area], curves: &[Curves]| -> Vec<Option<Rect>> {
        (areas.iter().zip(curves).zip(&legend_sizes))
            .map(|((area, curves), size)| free_corner(curves, area, (*size)?))
            .collect()
    };
    let mut right = width as i64 - 24;
    let mut areas = areas_for(right);
    let mut curves = rasterize(&areas);
    let mut corners = free_corners(&areas, &curves);
    let crowded = |corners: &[Option<Rect>]| {
        legend_sizes
            .iter()
            .zip(corners)
            .any(|(size, corner)| size.is_some() && corner.is_none())
    };
    // A legend that fits in no corner goes beside its plot; every plot then
    // makes room for the widest legend, so the panels' x axes stay aligned.
    if crowded(&corners) {
        let widest = legend_sizes
            .iter()
            .flatten()
            .map(|s| s.0)
            .max()
            .unwrap_or(0);
        right = (right - widest - LEGEND_INSET).max(left + MIN_PLOT_WIDTH);
        areas = areas_for(right);
        curves = rasterize(&areas);
        corners = free_corners(&areas, &curves);
    }
    let legends = legend_sizes
        .iter()
        .zip(&corners)
        .zip(&areas)
        .map(|((size, corner), area)| {
            let (w, h) = (*size)?;
            let beside = Rect {
                x0: right + LEGEND_INSET,
                y0: area.top,
                x1: right + LEGEND_INSET + w,
                y1: area.top + h,
            };
            Some(corner.unwrap_or(beside))
        })
        .collect();
    Layout {
        height,
        left,
        right,
        areas,
        curves,
        legends,
        x_label_y: (title_block + n * panel_block) as i64,
    }
}

/// A rectangle of pixels `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Rect {
    x0: i64,
    y0: i64,
    x1: i64,
    y1: i64,
}

/// A plot area in pixels and the axes it maps.
#[derive(Clone, Copy, Debug)]
struct Area {
    left: i64,
    right: i64,
    top: i64,
    bottom: i64,
    x: Axis,
    y: Axis,
}

impl Area {
    fn px(&self, x: f64) -> f64 {
        self.left as f64
            + (x - self.x.lo) / (self.x.hi - self.x.lo) * (self.right - self.left) as f64
    }

    fn py(&self, y: f64) -> f64 {
        self.bottom as f64
            - (y - self.y.lo) / (self.y.hi - self.y.lo) * (self.bottom - self.top) as f64
    }
}

fn draw_axes(img: &mut Image, a: &Area) {
    let cap = (CAP_HEIGHT * S) as i64;
    for (v, label) in a.y.ticks().into_iter().zip(a.y.labels()) {
        let y = a.py(v).round() as i64;
        img.fill_rect(a.left, y, a.right, y + 1, GRID);
        img.fill_rect(a.left - 5, y, a.left, y + 1, FRAME);
        let w = text_width(&label, S) as i64;
        draw_text(img, a.left - 10 - w, y - cap / 2, &label, S, INK);
    }
    for (v, label) in a.x.ticks().into_iter().zip(a.x.labels()) {
        let x = a.px(v).round() as i64;
        img.fill_rect(x, a.top, x + 1, a.bottom, GRID);
        img.fill_rect(x, a.bottom, x + 1, a.bottom + 5, FRAME);
        let w = text_width(&label, S) as i64;
        draw_text(img, x - w / 2, a.bottom + 9, &label, S, INK);
    }
    img.fill_rect(a.left, a.top, a.right + 1, a.top + 1, FRAME);
    img.fill_rect(a.left, a.bottom, a.right + 1, a.bottom + 1, FRAME);
    img.fill_rect(a.left, a.top, a.left + 1, a.bottom + 1, FRAME);
    img.fill_rect(a.right, a.top, a.right + 1, a.bottom + 1, FRAME);
}

/// The curves of a panel rasterized for its plot: per series in drawing
/// order, its colour and its coverage of each pixel of the plot area
/// (`[left, right] × [top, bottom]`, row by row).
struct Curves {
    /// Pixels per row of a coverage.
    w: usize,
    layers: Vec<([u8; 3], Vec<f32>)>,
}

impl Curves {
    fn rasterize(a: &Area, series: &[Series]) -> Curves {
        let (w, h) = (
            (a.right - a.left + 1) as usize,
            (a.bottom - a.top + 1) as usize,
        );
        let layers = series
            .iter()
            .map(|s| {
                let mut cov = vec![0f32; w * h];
                match s.style {
                    Style::Line => polyline_coverage(&mut cov, w, h, a, &s.points),
                    Style::Stems => stems_coverage(&mut cov, w, a, &s.points),
                }
                (s.color, cov)
            })
            .collect();
        Curves { w, layers }
    }

    /// Blends each series into `img` in turn.
    fn draw(&self, img: &mut Image, a: &Area) {
        for (color, cov) in &self.layers {
            for (i, &c) in cov.iter().enumerate() {
                if c > 0.0 {
                    let (x, y) = ((i % self.w) as i64, (i / self.w) as i64);
                    img.blend_pixel(a.left + x, a.top + y, *color, c);
                }
            }
        }
    }

    /// Whether the curves leave pixel `(x, y)` of the plot (local to its
    /// top left corner) the background: what [`Curves::draw`] would leave
    /// there on a blank image.
    fn blank_at(&self, x: usize, y: usize) -> bool {
        let i = y * self.w + x;
        let mut pixel = BACKGROUND;
        for (color, cov) in &self.layers {
            if cov[i] > 0.0 {
                pixel = blend(pixel, *color, cov[i]);
            }
        }
        pixel == BACKGROUND
    }
}

/// Anti-aliased polyline, 2 pixels wide, clipped to the plot area: its
/// coverage of each pixel of the `w × h` plot. Coverage is the maximum over
/// segments, so joints are not drawn twice darker.
fn polyline_coverage(cov: &mut [f32], w: usize, h: usize, a: &Area, points: &[(f64, f64)]) {
    let to_local = |&(x, y): &(f64, f64)| (a.px(x) - a.left as f64, a.py(y) - a.top as f64);
    let half = 1.0f64;
    let mut prev: Option<(f64, f64)> = None;
    for p in points {
        if !(p.0.is_finite() && p.1.is_finite()) {
            prev = None;
            continue;
        }
        let q = to_local(p);
        let p0 = prev.unwrap_or(q);
        prev = Some(q);
        let (x0, x1) = (p0.0.min(q.0) - half - 1.0, p0.0.max(q.0) + half + 1.0);
        let (y0, y1) = (p0.1.min(q.1) - half - 1.0, p0.1.max(q.1) + half + 1.0);
        let (d, len2) = (
            (q.0 - p0.0, q.1 - p0.1),
            (q.0 - p0.0).powi(2) + (q.1 - p0.1).powi(2),
        );
        for y in (y0.floor().max(0.0) as usize)..=(y1.ceil().min(h as f64 - 1.0).max(0.0) as usize)
        {
            for x in
                (x0.floor().max(0.0) as usize)..=(x1.ceil().min(w as f64 - 1.0).max(0.0) as usize)
            {
                let (cx, cy) = (x as f64 + 0.5, y as f64 + 0.5);
                let t = if len2 > 0.0 {
                    (((cx - p0.0) * d.0 + (cy - p0.1) * d.1) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let dist = ((cx - p0.0 - t * d.0).powi(2) + (cy - p0.1 - t * d.1).powi(2)).sqrt();
                let c = (half + 0.5 - dist).clamp(0.0, 1.0) as f32;
                let slot = &mut cov[y * w + x];
                *slot = slot.max(c);
            }
        }
    }
}

/// One bar per point from zero (or the axis bottom) to the value, at least
/// one pixel wide, inside the frame of the plot: full coverage of its pixels
/// in the plot's `w`-pixel rows.
fn stems_coverage(cov: &mut [f32], w: usize, a: &Area, points: &[(f64, f64)]) {
    let finite: Vec<_> = points
        .iter()
        .filter(|p| p.0.is_finite() && p.1.is_finite())
        .collect();
    let span = (a.right - a.left) as f64;
    let bar = (0.6 * span / finite.len().max(1) as f64)
        .clamp(1.0, 12.0)
        .round() as i64;
    let zero = a.py(0.0_f64.clamp(a.y.lo, a.y.hi)).round() as i64;
    for p in finite {
        let x = a.px(p.0).round() as i64 - bar / 2;
        let y = a.py(p.1).round() as i64;
        let (y0, y1) = (y.min(zero), y.max(zero));
        for gy in y0.max(a.top + 1)..(y1 + 1).min(a.bottom) {
            for gx in x.max(a.left + 1)..(x + bar).min(a.right) {
                cov[(gy - a.top) as usize * w + (gx - a.left) as usize] = 1.0;
            }
        }
    }
}

/// Width and height of the legend of `series`: a line per series.
fn legend_size(series: &[Series]) -> (i64, i64) {
    let w = series
        .iter()
        .map(|s| text_width(&s.name, S) as i64)
        .max()
        .unwrap_or(0)
        + LEGEND_SAMPLE
        + 28;
    (w, series.len() as i64 * LABEL_LINE as i64 + 12)
}

/// The first corner of plot `a` (top right, top left, bottom right, bottom
/// left) where a legend of `size` leaves every pixel of the `curves` at
/// least [`LEGEND_CLEARANCE`] away; `None` when curves pass through all four
/// (or the plot is too small).
fn free_corner(curves: &Curves, a: &Area, (w, h): (i64, i64)) -> Option<Rect> {
    let (l, r) = (a.left + LEGEND_INSET, a.right - LEGEND_INSET - w);
    let (t, b) = (a.top + LEGEND_INSET, a.bottom - LEGEND_INSET - h);
    [(r, t), (l, t), (r, b), (l, b)]
        .into_iter()
        .map(|(x0, y0)| Rect {
            x0,
            y0,
            x1: x0 + w,
            y1: y0 + h,
        })
        .find(|box_| {
            let c = LEGEND_CLEARANCE;
            let inside = box_.x0 - c > a.left
                && box_.x1 + c <= a.right
                && box_.y0 - c > a.top
                && box_.y1 + c <= a.bottom;
            if !inside {
                return false;
            }
            // Inside the plot: local pixels of the curves.
            let (x0, x1) = (
                (box_.x0 - c - a.left) as usize,
                (box_.x1 + c - a.left) as usize,
            );
            let (y0, y1) = (
                (box_.y0 - c - a.top) as usize,
                (box_.y1 + c - a.top) as usize,
            );
            (y0..y1).all(|y| (x0..x1).all(|x| curves.blank_at(x, y)))
        })
}

fn draw_legend(img: &mut Image, r: &Rect, series: &[Series]) {
    let line = LABEL_LINE as i64;
    let (x0, y0, x1, y1) = (r.x0, r.y0, r.x1, r.y1);
    img.fill_rect(x0, y0, x1, y1, BACKGROUND);
    img.fill_rect(x0, y0, x1, y0 + 1, FRAME);
    img.fill_rect(x0, y1 - 1, x1, y1, FRAME);
    img.fill_rect(x0, y0, x0 + 1, y1, FRAME);
    img.fill_rect(x1 - 1, y0, x1, y1, FRAME);
    for (i, s) in series.iter().enumerate() {
        let y = y0 + 7 + i as i64 * line;
        let mid = y + (CAP_HEIGHT * S) as i64 / 2;
        img.fill_rect(x0 + 8, mid - 1, x0 + 8 + LEGEND_SAMPLE, mid + 1, s.color);
        draw_text(img, x0 + 16 + LEGEND_SAMPLE, y, &s.name, S, INK);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(name: &str, color: [u8; 3], f: impl Fn(f64) -> f64) -> Series {
        let points = (0..=800)
            .map(|i| {
                let x = i as f64 / 800.0;
                (x, f(x))
            })
            .collect();
        Series {
            name: name.into(),
            color,
            points,
            style: Style::Line,
        }
    }

    #[test]
    fn a_legend_with_no_free_corner_goes_beside_the_plot() {
        // A dense wiggle from 0 to 1 fills all four corners of the first
        // panel; the second panel's curves leave its top left free.
        let wiggle = line("wiggle", COLORS[0], |x| 0.5 + 0.5 * (300.0 * x).sin());
        let level = line("level", COLORS[1], |_| 0.5);
        let low = line("low", COLORS[2], |_| 0.1);
        let chart = Chart {
            title: "crowded".into(),
            x_label: "x".into(),
            panels: vec![
                Panel {
                    title: "both".into(),
                    series: vec![wiggle, level.clone()],
                },
                Panel {
                    title: "calm".into(),
                    series: vec![level, low],
                },
            ],
        };
        let width = 1000;
        let l = layout(&chart, width);
        let [a0, a1] = [l.areas[0], l.areas[1]];
        let [Some(beside), Some(inside)] = [l.legends[0], l.legends[1]] else {
            panic!("both panels have a legend")
        };
        // Beside the first plot, within the image; the plots keep one width.
        assert!(
            beside.x0 > a0.right && beside.x1 <= width as i64,
            "{beside:?}"
        );
        assert!((a0.left, a0.right) == (a1.left, a1.right));
        assert!(a0.right < width as i64 - 24 - (beside.x1 - beside.x0));
        // The second legend fits in a corner of its own plot.
        assert!(inside.x0 > a1.left && inside.x1 < a1.right, "{inside:?}");
        assert!(inside.y0 > a1.top && inside.y1 < a1.bottom, "{inside:?}");
        // And the chart draws them there.
        let img = draw_chart(&chart, width);
        assert_eq!(img.height, l.height);
        assert_eq!(img.pixel(beside.x0 as u32, beside.y0 as u32), FRAME);
        assert_eq!(img.pixel(inside.x0 as u32, inside.y0 as u32), FRAME);
    }

    #[test]
    fn nice_axes_use_1_2_5_steps() {
        let a = Axis::nice(0.0, 0.93, 5);
        assert_eq!((a.lo, a.hi, a.step), (0.0, 1.0, 0.2));
        assert_eq!(a.labels(), ["0", "0.2", "0.4", "0.6", "0.8", "1.0"]);
        let a = Axis::nice(-3.2, 47.0, 6);
        assert_eq!((a.lo, a.hi, a.step), (-10.0, 50.0, 10.0));
        let a = Axis::nice(0.0, 3.1e-5, 5);
        assert_eq!(a.step, 1e-5);
        assert_eq!(a.labels(), ["0", "1e-5", "2e-5", "3e-5", "4e-5"]);
        let a = Axis::nice(0.0, 2.4e7, 5);
        assert_eq!(a.labels(), ["0", "5e6", "1e7", "1.5e7", "2e7", "2.5e7"]);
        let a = Axis::nice(0.0, 9.1e-4, 5);
        assert_eq!(a.labels(), ["0", "2e-4", "4e-4", "6e-4", "8e-4", "1e-3"]);
        // A tight axis keeps the data range and puts ticks inside it.
        let a = Axis::tight(0.0166, 1.009, 5);
        assert_eq!((a.lo, a.hi), (0.0, 1.009));
        assert_eq!(a.labels(), ["0", "0.2", "0.4", "0.6", "0.8", "1.0"]);
        let a = Axis::tight(2.5, 4.2, 5);
        assert_eq!(a.labels(), ["2.5", "3.0", "3.5", "4.0"]);
        // A constant series still gets an axis.
        let a = Axis::nice(0.0, 0.0, 5);
        assert_eq!((a.lo, a.hi), (0.0, 1.0));
        let a = Axis::nice(7.0, 7.0, 5);
        assert!(a.lo < 7.0 && a.hi > 7.0);
    }
}
