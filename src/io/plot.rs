//! PNG line plots of plain data (fabric-test curves): panels stacked
//! vertically, each with its axes, ticks, labels and one or more series.
//!
//! Lines, markers and the coordinate mapping are drawn by `plotters` into an
//! RGB buffer; the PNG is encoded by `png`. Text: the released `plotters`
//! (0.3.7) renders text only through its `ttf` feature (font-kit, which looks
//! fonts up through the system's fontconfig); CI is a bare Debian that must
//! work offline with no guaranteed fonts, so labels are rasterized here with
//! `ab_glyph` from DejaVu Sans Mono embedded in the binary (Bitstream Vera
//! licence, which allows redistribution inside a larger package:
//! src/io/fonts/LICENSE-DejaVu.txt). Output depends on the data only.

use ab_glyph::{Font, FontRef, PxScale, ScaleFont};
use plotters::prelude::*;

/// The embedded label font.
const FONT: &[u8] = include_bytes!("fonts/DejaVuSansMono.ttf");

/// One curve of a panel.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// `(x, y)` points in drawing order.
    pub points: Vec<[f64; 2]>,
    /// Line colour (RGB).
    pub color: [u8; 3],
}

/// One chart: axis labels and its series.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
}

/// A figure: a title over panels stacked top to bottom.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    pub title: String,
    pub panels: Vec<Panel>,
    /// Image size in pixels (width, height).
    pub size: (u32, u32),
}

/// Why a plot could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlotError {
    #[error("plot data: {0}")]
    Data(String),
    #[error("drawing the plot: {0}")]
    Draw(String),
    #[error("encoding the PNG: {0}")]
    Encode(String),
}

/// Colours for successive series.
pub const PALETTE: [[u8; 3]; 4] = [
    [31, 119, 180],
    [214, 39, 40],
    [44, 160, 44],
    [148, 103, 189],
];

/// Space (pixels) around each panel's plotting area: left (tick labels),
/// right, top (axis label), bottom (tick labels and axis label).
const MARGIN: (i32, i32, i32, i32) = (80, 20, 34, 56);
const TITLE_H: i32 = 30;
const TEXT_PX: f32 = 15.0;

/// Renders `fig` as PNG bytes.
pub fn render_png(fig: &Figure) -> Result<Vec<u8>, PlotError> {
    let (w, h) = fig.size;
    if !(200..=8000).contains(&w) || !(150..=8000).contains(&h) || fig.panels.is_empty() {
        return Err(PlotError::Data(format!(
            "size {w} x {h} px (200-8000 x 150-8000) with {} panels (at least 1)",
            fig.panels.len()
        )));
    }
    let ranges: Vec<_> = fig
        .panels
        .iter()
        .map(data_range)
        .collect::<Result<_, _>>()?;
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let panel_h = (h as i32 - TITLE_H) / fig.panels.len() as i32;
    let mut texts: Vec<Text> = vec![Text {
        s: fig.title.clone(),
        x: w as i32 / 2,
        y: TITLE_H - 8,
        align: Align::Center,
    }];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        for (k, (panel, range)) in fig.panels.iter().zip(&ranges).enumerate() {
            let top = TITLE_H + k as i32 * panel_h;
            let area = [
                MARGIN.0,
                top + MARGIN.2,
                w as i32 - MARGIN.1,
                top + panel_h - MARGIN.3,
            ];
            draw_panel(&root, panel, range, area, &mut texts)?;
        }
        root.present().map_err(|e| PlotError::Draw(e.to_string()))?;
    }
    let font = FontRef::try_from_slice(FONT).map_err(|e| PlotError::Draw(e.to_string()))?;
    for t in &texts {
        draw_text(&mut buf, (w, h), &font, t);
    }
    encode_png(&buf, w, h)
}

/// Data bounds of a panel `[x0, x1, y0, y1]`, y widened to include 0 and
/// padded; every value must be finite.
fn data_range(panel: &Panel) -> Result<[f64; 4], PlotError> {
    let pts = panel.series.iter().flat_map(|s| s.points.iter());
    let mut r = [f64::INFINITY, f64::NEG_INFINITY, 0.0f64, 0.0f64];
    let mut any = false;
    for p in pts {
        if !(p[0].is_finite() && p[1].is_finite()) {
            return Err(PlotError::Data(format!(
                "{}: non-finite point ({}, {})",
                panel.y_label, p[0], p[1]
            )));
        }
        any = true;
        r = [
            r[0].min(p[0]),
            r[1].max(p[0]),
            r[2].min(p[1]),
            r[3].max(p[1]),
        ];
    }
    if !any {
        return Err(PlotError::Data(format!("{}: no points", panel.y_label)));
    }
    let pad = |lo: f64, hi: f64| {
        if hi - lo > 0.0 {
            (lo, hi)
        } else {
            let d = lo.abs().max(1.0) * 0.1;
            (lo - d, hi + d)
        }
    };
    let (x0, x1) = pad(r[0], r[1]);
    let (y0, y1) = pad(r[2], r[3]);
    let m = 0.05 * (y1 - y0);
    Ok([x0, x1, if y0 < 0.0 { y0 - m } else { y0 }, y1 + m])
}

/// Tick values: steps of 1, 2 or 5 x 10^k, about `n` of them in [lo, hi].
fn ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let raw = (hi - lo) / n.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|f| f * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    // Tolerant of rounding: 0.3 / 0.05 is 5.999...
    let first = (lo / step - 1e-9).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    (first..=last).map(|i| i as f64 * step).collect()
}

/// A tick value as short text (no "-0", no float noise).
fn tick_text(v: f64, step: f64) -> String {
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    let s = format!("{:.*}", decimals, v);
    if s.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        "0".into()
    } else {
        s
    }
}

fn rgb(c: [u8; 3]) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

/// Axes, grid, ticks, series and legend of one panel inside `area`
/// ([left, top, right, bottom] px); its text goes to `texts`.
fn draw_panel<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    panel: &Panel,
    r: &[f64; 4],
    area: [i32; 4],
    texts: &mut Vec<Text>,
) -> Result<(), PlotError> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| PlotError::Draw(e.to_string());
    let [l, t, rt, b] = area;
    let sx = |x: f64| l + ((x - r[0]) / (r[1] - r[0]) * (rt - l) as f64).round() as i32;
    let sy = |y: f64| b - ((y - r[2]) / (r[3] - r[2]) * (b - t) as f64).round() as i32;
    let grid = RGBColor(225, 225, 225);
    let xt = ticks(r[0], r[1], 6);
    let yt = ticks(r[2], r[3], 5);
    let step = |v: &[f64]| if v.len() > 1 { v[1] - v[0] } else { 1.0 };
    for &x in &xt {
        root.draw(&PathElement::new(vec![(sx(x), t), (sx(x), b)], grid))
            .map_err(err)?;
        root.draw(&PathElement::new(vec![(sx(x), b), (sx(x), b + 5)], BLACK))
            .map_err(err)?;
        texts.push(Text {
            s: tick_text(x, step(&xt)),
            x: sx(x),
            y: b + 22,
            align: Align::Center,
        });
    }
    for &y in &yt {
        root.draw(&PathElement::new(vec![(l, sy(y)), (rt, sy(y))], grid))
            .map_err(err)?;
        root.draw(&PathElement::new(vec![(l - 5, sy(y)), (l, sy(y))], BLACK))
            .map_err(err)?;
        texts.push(Text {
            s: tick_text(y, step(&yt)),
            x: l - 9,
            y: sy(y) + 5,
            align: Align::Right,
        });
    }
    root.draw(&PathElement::new(
        vec![(l, t), (l, b), (rt, b), (rt, t), (l, t)],
        BLACK,
    ))
    .map_err(err)?;
    for (k, s) in panel.series.iter().enumerate() {
        let color = rgb(s.color);
        let pts: Vec<(i32, i32)> = s.points.iter().map(|p| (sx(p[0]), sy(p[1]))).collect();
        root.draw(&PathElement::new(pts.clone(), color.stroke_width(2)))
            .map_err(err)?;
        for p in pts {
            root.draw(&Circle::new(p, 3, color.filled())).map_err(err)?;
        }
        // Legend: a line sample and the label, top left inside the axes.
        let ly = t + 14 + 18 * k as i32;
        root.draw(&PathElement::new(
            vec![(l + 10, ly), (l + 34, ly)],
            color.stroke_width(2),
        ))
        .map_err(err)?;
        texts.push(Text {
            s: s.label.clone(),
            x: l + 40,
            y: ly + 5,
            align: Align::Left,
        });
    }
    texts.push(Text {
        s: panel.x_label.clone(),
        x: (l + rt) / 2,
        y: b + 44,
        align: Align::Center,
    });
    texts.push(Text {
        s: panel.y_label.clone(),
        x: l,
        y: t - 8,
        align: Align::Left,
    });
    Ok(())
}

/// A histogram of `values` as a step curve over `bins` equal bins between
/// their smallest and largest value: `(x, count)` points tracing each bar's
/// top. Non-finite values are refused.
pub fn histogram_series(
    label: &str,
    values: &[f64],
    bins: usize,
    color: [u8; 3],
) -> Result<Series, PlotError> {
    if values.is_empty() || bins == 0 {
        return Err(PlotError::Data(format!("{label}: no values or no bins")));
    }
    if let Some(v) = values.iter().find(|v| !v.is_finite()) {
        return Err(PlotError::Data(format!("{label}: non-finite value {v}")));
    }
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    // A single value gets a bin of width 1% of it (or 1) around it.
    let (lo, hi) = if hi > lo {
        (lo, hi)
    } else {
        let d = 0.01 * lo.abs().max(1.0);
        (lo - d, hi + d)
    };
    let w = (hi - lo) / bins as f64;
    let mut counts = vec![0usize; bins];
    for v in values {
        let b = (((v - lo) / w) as usize).min(bins - 1);
        counts[b] += 1;
    }
    let mut points = vec![[lo, 0.0]];
    for (b, &c) in counts.iter().enumerate() {
        let x0 = lo + b as f64 * w;
        points.push([x0, c as f64]);
        points.push([x0 + w, c as f64]);
    }
    points.push([hi, 0.0]);
    Ok(Series {
        label: label.to_string(),
        points,
        color,
    })
}

/// A scalar field on a grid of cells (a slice through a voxel field):
/// `values[j * nx + i]` is cell `(i, j)`, `None` where the slice holds no
/// cell. Drawn with `i` to the right and `j` up.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldSlice {
    pub title: String,
    /// Axis names (e.g. "x (voxels)").
    pub x_label: String,
    pub y_label: String,
    pub nx: usize,
    pub ny: usize,
    pub values: Vec<Option<f64>>,
    /// Unit shown beside the colour bar's values.
    pub unit: String,
}

/// Perceptually ordered colour map (viridis, 5 anchors, linear between).
fn viridis(t: f64) -> [u8; 3] {
    const C: [[f64; 3]; 5] = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let t = t.clamp(0.0, 1.0) * 4.0;
    let k = (t.floor() as usize).min(3);
    let f = t - k as f64;
    std::array::from_fn(|c| (C[k][c] * (1.0 - f) + C[k + 1][c] * f).round() as u8)
}

/// Renders `slice` as a PNG of `size` pixels: cells coloured by value
/// (viridis, linear between the slice's smallest and largest value), empty
/// cells light grey, a colour bar with both ends labelled.
pub fn render_field_png(slice: &FieldSlice, size: (u32, u32)) -> Result<Vec<u8>, PlotError> {
    let (w, h) = size;
    if !(200..=8000).contains(&w) || !(150..=8000).contains(&h) {
        return Err(PlotError::Data(format!("size {w} x {h} px")));
    }
    if slice.nx == 0 || slice.ny == 0 || slice.values.len() != slice.nx * slice.ny {
        return Err(PlotError::Data(format!(
            "{}: {} values for {} x {} cells",
            slice.title,
            slice.values.len(),
            slice.nx,
            slice.ny
        )));
    }
    let vals: Vec<f64> = slice.values.iter().flatten().copied().collect();
    if vals.is_empty() {
        return Err(PlotError::Data(format!("{}: no cells", slice.title)));
    }
    if let Some(v) = vals.iter().find(|v| !v.is_finite()) {
        return Err(PlotError::Data(format!(
            "{}: non-finite value {v}",
            slice.title
        )));
    }
    let lo = vals.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = vals.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let span = if hi > lo { hi - lo } else { 1.0 };
    // Plot area: margins for labels and a colour bar on the right.
    let (l, t, r, b) = (60i32, TITLE_H + 10, w as i32 - 150, h as i32 - 50);
    let cell = (((r - l) as f64 / slice.nx as f64).min((b - t) as f64 / slice.ny as f64)).max(1.0);
    let cw = (cell * slice.nx as f64) as i32;
    let ch = (cell * slice.ny as f64) as i32;
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let mut texts = vec![
        Text {
            s: slice.title.clone(),
            x: w as i32 / 2,
            y: TITLE_H - 8,
            align: Align::Center,
        },
        Text {
            s: slice.x_label.clone(),
            x: l + cw / 2,
            y: t + ch + 30,
            align: Align::Center,
        },
        Text {
            s: slice.y_label.clone(),
            x: l,
            y: t - 4,
            align: Align::Left,
        },
    ];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let err = |e: DrawingAreaErrorKind<_>| PlotError::Draw(e.to_string());
        for j in 0..slice.ny {
            for i in 0..slice.nx {
                let color = match slice.values[j * slice.nx + i] {
                    Some(v) => rgb(viridis((v - lo) / span)),
                    None => RGBColor(230, 230, 230),
                };
                let x0 = l + (i as f64 * cell) as i32;
                let y1 = t + ch - (j as f64 * cell) as i32;
                let x1 = l + ((i + 1) as f64 * cell) as i32;
                let y0 = t + ch - ((j + 1) as f64 * cell) as i32;
                root.draw(&Rectangle::new([(x0, y0), (x1, y1)], color.filled()))
                    .map_err(err)?;
            }
        }
        root.draw(&Rectangle::new([(l, t), (l + cw, t + ch)], BLACK))
            .map_err(err)?;
        // Colour bar: bottom = lo, top = hi.
        let bx = r + 20;
        let steps = 64;
        for k in 0..steps {
            let y1 = t + ch - (k * ch) / steps;
            let y0 = t + ch - ((k + 1) * ch) / steps;
            let c = rgb(viridis((k as f64 + 0.5) / steps as f64));
            root.draw(&Rectangle::new([(bx, y0), (bx + 16, y1)], c.filled()))
                .map_err(err)?;
        }
        root.present().map_err(|e| PlotError::Draw(e.to_string()))?;
    }
    for (v, y) in [(hi, t + 12), (lo, t + ch)] {
        texts.push(Text {
            s: format!("{v:.3e} {}", slice.unit),
            x: r + 40,
            y,
            align: Align::Left,
        });
    }
    let font = FontRef::try_from_slice(FONT).map_err(|e| PlotError::Draw(e.to_string()))?;
    for t in &texts {
        draw_text(&mut buf, (w, h), &font, t);
    }
    encode_png(&buf, w, h)
}

#[derive(Debug, Clone, Copy)]
enum Align {
    Left,
    Center,
    Right,
}

/// A line of text: baseline at `y`, anchored at `x` by `align` (px).
struct Text {
    s: String,
    x: i32,
    y: i32,
    align: Align,
}

/// Rasterizes `t` in black over the RGB buffer (coverage-blended).
fn draw_text(buf: &mut [u8], (w, h): (u32, u32), font: &FontRef, t: &Text) {
    let scale = PxScale::from(TEXT_PX);
    let sf = font.as_scaled(scale);
    let width: f32 = t.s.chars().map(|c| sf.h_advance(sf.glyph_id(c))).sum();
    let mut x = t.x as f32
        - match t.align {
            Align::Left => 0.0,
            Align::Center => 0.5 * width,
            Align::Right => width,
        };
    for c in t.s.chars() {
        let id = sf.glyph_id(c);
        let glyph = id.with_scale_and_position(scale, ab_glyph::point(x, t.y as f32));
        x += sf.h_advance(id);
        let Some(outline) = font.outline_glyph(glyph) else {
            continue;
        };
        let bb = outline.px_bounds();
        outline.draw(|gx, gy, cov| {
            let px = bb.min.x as i64 + gx as i64;
            let py = bb.min.y as i64 + gy as i64;
            if px < 0 || py < 0 || px >= w as i64 || py >= h as i64 {
                return;
            }
            let i = 3 * (py as usize * w as usize + px as usize);
            let a = cov.clamp(0.0, 1.0);
            for v in &mut buf[i..i + 3] {
                *v = (*v as f32 * (1.0 - a)).round() as u8;
            }
        });
    }
}

/// 8-bit RGB PNG of the buffer.
fn encode_png(buf: &[u8], w: u32, h: u32) -> Result<Vec<u8>, PlotError> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc
            .write_header()
            .map_err(|e| PlotError::Encode(e.to_string()))?;
        writer
            .write_image_data(buf)
            .map_err(|e| PlotError::Encode(e.to_string()))?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_inside() {
        let t = ticks(0.0, 0.5, 6);
        assert_eq!(t.len(), 6, "{t:?}");
        assert!(t
            .iter()
            .enumerate()
            .all(|(i, v)| (v - 0.1 * i as f64).abs() < 1e-12));
        assert_eq!(ticks(0.0, 0.3, 6).len(), 7);
        let t = ticks(-0.013, 0.21, 5);
        assert!(t.iter().all(|v| (-0.013..=0.21).contains(v)), "{t:?}");
        assert_eq!(tick_text(-1e-17, 0.05), "0");
        assert_eq!(tick_text(0.15, 0.05), "0.15");
    }

    #[test]
    fn bad_data_is_refused() {
        let fig = |pts: Vec<[f64; 2]>| Figure {
            title: "t".into(),
            panels: vec![Panel {
                x_label: "x".into(),
                y_label: "y".into(),
                series: vec![Series {
                    label: "s".into(),
                    points: pts,
                    color: PALETTE[0],
                }],
            }],
            size: (400, 300),
        };
        assert!(matches!(render_png(&fig(vec![])), Err(PlotError::Data(_))));
        assert!(matches!(
            render_png(&fig(vec![[0.0, f64::NAN]])),
            Err(PlotError::Data(_))
        ));
        let png = render_png(&fig(vec![[0.0, 0.0], [1.0, 2.0]])).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    }

    #[test]
    fn histogram_counts_every_value_once() {
        let v = [1.0, 1.0, 2.0, 3.0, 3.0, 3.0];
        let s = histogram_series("h", &v, 2, PALETTE[0]).unwrap();
        // Bars [1, 2) and [2, 3]: 2 and 4 values.
        assert_eq!(s.points[1], [1.0, 2.0]);
        assert_eq!(s.points[3], [2.0, 4.0]);
        assert!(histogram_series("h", &[f64::NAN], 3, PALETTE[0]).is_err());
    }

    #[test]
    fn field_slices_render_and_refuse_bad_data() {
        let mut slice = FieldSlice {
            title: "gamma_s".into(),
            x_label: "x".into(),
            y_label: "z".into(),
            nx: 3,
            ny: 2,
            values: vec![Some(1.0), None, Some(2.0), Some(3.0), Some(4.0), None],
            unit: "Pa".into(),
        };
        let png = render_field_png(&slice, (400, 300)).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        slice.values[0] = Some(f64::INFINITY);
        assert!(render_field_png(&slice, (400, 300)).is_err());
        slice.values.pop();
        assert!(render_field_png(&slice, (400, 300)).is_err());
        assert_eq!(viridis(0.0), [68, 1, 84]);
        assert_eq!(viridis(1.0), [253, 231, 37]);
    }
}
