//! The distance histogram as a PNG (bars, axes, ticks, labels), like the paper's
//! histogram of point-to-point distances to the LiDAR reference, and the colour map of
//! the distance-coloured cloud. Text uses a built-in 5×7 bitmap font (digits, capitals
//! and a little punctuation; lower case is drawn as capitals), so no font file is
//! needed.

use image::{Rgb, RgbImage};

const BACKGROUND: Rgb<u8> = Rgb([255, 255, 255]);
const INK: Rgb<u8> = Rgb([20, 20, 20]);
const BAR: Rgb<u8> = Rgb([70, 110, 190]);
const GRID: Rgb<u8> = Rgb([225, 225, 225]);

/// 5×7 glyphs, one byte per row, bit 4 the leftmost column.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        '.' => [0, 0, 0, 0, 0, 0x0C, 0x0C],
        ',' => [0, 0, 0, 0, 0x0C, 0x04, 0x08],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        '+' => [0, 0x04, 0x04, 0x1F, 0x04, 0x04, 0],
        '=' => [0, 0, 0x1F, 0, 0x1F, 0, 0],
        ':' => [0, 0x0C, 0x0C, 0, 0x0C, 0x0C, 0],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        '/' => [0, 0x01, 0x02, 0x04, 0x08, 0x10, 0],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        ' ' => [0; 7],
        _ => [0x0E, 0x11, 0x01, 0x02, 0x04, 0, 0x04], // '?'
    }
}

/// Horizontal advance of one character at font scale 1.
const ADVANCE: i64 = 6;

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && x < img.width() as i64 && y < img.height() as i64 {
        img.put_pixel(x as u32, y as u32, c);
    }
}

fn fill(img: &mut RgbImage, x0: i64, y0: i64, x1: i64, y1: i64, c: Rgb<u8>) {
    for y in y0.min(y1)..=y0.max(y1) {
        for x in x0.min(x1)..=x0.max(x1) {
            put(img, x, y, c);
        }
    }
}

/// Width in pixels of `text` at `scale`.
pub fn text_width(text: &str, scale: i64) -> i64 {
    text.chars().count() as i64 * ADVANCE * scale
}

/// Draws `text` with its top-left corner at `(x, y)`; `vertical` runs it bottom to top
/// with `(x, y)` the bottom-left corner.
pub fn draw_text(
    img: &mut RgbImage,
    text: &str,
    x: i64,
    y: i64,
    scale: i64,
    vertical: bool,
    c: Rgb<u8>,
) {
    for (i, ch) in text.chars().enumerate() {
        let rows = glyph(ch);
        let offset = i as i64 * ADVANCE * scale;
        for (gy, row) in rows.iter().enumerate() {
            for gx in 0..5 {
                if row & (0x10 >> gx) == 0 {
                    continue;
                }
                for sy in 0..scale {
                    for sx in 0..scale {
                        let (u, v) = (gx * scale + sx, gy as i64 * scale + sy);
                        if vertical {
                            put(img, x + v, y - offset - u, c);
                        } else {
                            put(img, x + offset + u, y + v, c);
                        }
                    }
                }
            }
        }
    }
}

/// The smallest `{1, 2, 5} · 10^k` at least `x` (for `x > 0`).
pub fn nice_step(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(x.log10().floor());
    for m in [1.0, 2.0, 5.0, 10.0] {
        if m * p >= x * (1.0 - 1e-12) {
            return m * p;
        }
    }
    10.0 * p
}

/// A tick label with as many decimals as the step needs, or an exponent for extremes.
pub fn tick_label(value: f64, step: f64) -> String {
    if value == 0.0 {
        return "0".into();
    }
    if !(1e-4..1e5).contains(&step) {
        return format!("{value:.1e}").to_uppercase();
    }
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    format!("{value:.decimals$}")
}

/// A vertical marker line with its label, e.g. the median.
#[derive(Clone, Debug)]
pub struct Marker {
    pub label: String,
    pub value: f64,
    pub colour: [u8; 3],
}

#[derive(Clone, Debug)]
pub struct HistogramStyle {
    pub width: u32,
    pub height: u32,
    pub bins: usize,
    pub title: String,
    pub x_label: String,
    pub y_label: String,
}

impl Default for HistogramStyle {
    fn default() -> Self {
        Self {
            width: 900,
            height: 560,
            bins: 60,
            title: String::new(),
            x_label: "DISTANCE (SCENE UNITS)".into(),
            y_label: "POINTS".into(),
        }
    }
}

/// Bin counts of the finite `values` in `[0, x_max)` and how many fell at or beyond
/// `x_max`.
pub fn bin_counts(values: &[f32], x_max: f64, bins: usize) -> (Vec<u64>, u64) {
    let mut counts = vec![0u64; bins.max(1)];
    let mut over = 0;
    let k = counts.len() as f64 / x_max;
    for &v in values.iter().filter(|v| v.is_finite()) {
        let b = (v as f64 * k).floor();
        if b >= counts.len() as f64 {
            over += 1;
        } else {
            counts[b.max(0.0) as usize] += 1;
        }
    }
    (counts, over)
}

/// Draws the histogram of `values` over `[0, x_max]` (rounded up to a tick) with
/// `markers`. Values beyond the range are counted in the title.
pub fn histogram_image(
    values: &[f32],
    x_max: f64,
    markers: &[Marker],
    style: &HistogramStyle,
) -> RgbImage {
    let mut img = RgbImage::from_pixel(style.width.max(200), style.height.max(150), BACKGROUND);
    let (w, h) = (img.width() as i64, img.height() as i64);
    let (left, right, top, bottom) = (110i64, 30i64, 56i64, 70i64);
    let (x0, x1, y0, y1) = (left, w - right, h - bottom, top);
    let x_step = nice_step(if x_max > 0.0 { x_max } else { 1.0 } / 5.0);
    let x_max = (x_max.max(f64::MIN_POSITIVE) / x_step).ceil().max(1.0) * x_step;
    let (counts, over) = bin_counts(values, x_max, style.bins);
    let peak = counts.iter().copied().max().unwrap_or(0).max(1) as f64;
    let y_step = nice_step(peak / 5.0).max(1.0);
    let y_max = (peak / y_step).ceil() * y_step;
    let px = |x: f64| x0 + ((x / x_max) * (x1 - x0) as f64).round() as i64;
    let py = |c: f64| y0 - ((c / y_max) * (y0 - y1) as f64).round() as i64;

    // Grid and y ticks.
    let mut c = 0.0;
    while c <= y_max * (1.0 + 1e-9) {
        let y = py(c);
        fill(&mut img, x0 + 1, y, x1, y, GRID);
        fill(&mut img, x0 - 6, y, x0, y, INK);
        let label = tick_label(c, y_step);
        draw_text(
            &mut img,
            &label,
            x0 - 10 - text_width(&label, 2),
            y - 7,
            2,
            false,
            INK,
        );
        c += y_step;
    }
    // Bars.
    let n = counts.len() as f64;
    for (i, &count) in counts.iter().enumerate() {
        if count == 0 {
            continue;
        }
        let (a, b) = (px(i as f64 * x_max / n), px((i + 1) as f64 * x_max / n));
        fill(
            &mut img,
            a + 1,
            py(count as f64),
            (b - 1).max(a + 1),
            y0 - 1,
            BAR,
        );
    }
    // Axes and x ticks.
    fill(&mut img, x0, y1, x0 + 1, y0, INK);
    fill(&mut img, x0, y0, x1, y0 + 1, INK);
    let mut x = 0.0;
    while x <= x_max * (1.0 + 1e-9) {
        let u = px(x);
        fill(&mut img, u, y0, u, y0 + 6, INK);
        let label = tick_label(x, x_step);
        draw_text(
            &mut img,
            &label,
            u - text_width(&label, 2) / 2,
            y0 + 12,
            2,
            false,
            INK,
        );
        x += x_step;
    }
    // Markers, labelled along the top of the plot area.
    for (i, m) in markers.iter().enumerate() {
        if !(m.value.is_finite() && m.value <= x_max) {
            continue;
        }
        let u = px(m.value.max(0.0));
        let colour = Rgb(m.colour);
        for y in (y1..y0).step_by(2) {
            fill(&mut img, u, y, u + 1, y, colour);
        }
        draw_text(
            &mut img,
            &m.label,
            u + 5,
            y1 + 4 + 16 * i as i64,
            2,
            false,
            colour,
        );
    }
    // Axis labels and title.
    draw_text(
        &mut img,
        &style.x_label,
        (x0 + x1) / 2 - text_width(&style.x_label, 2) / 2,
        h - 28,
        2,
        false,
        INK,
    );
    draw_text(
        &mut img,
        &style.y_label,
        12,
        (y0 + y1) / 2 + text_width(&style.y_label, 2) / 2,
        2,
        true,
        INK,
    );
    draw_text(&mut img, &style.title, x0, 8, 2, false, INK);
    if over > 0 {
        let note = format!("{over} BEYOND {}", tick_label(x_max, x_step));
        draw_text(
            &mut img,
            &note,
            x1 - text_width(&note, 2),
            30,
            2,
            false,
            INK,
        );
    }
    img
}

/// Viridis-like colour of `t` in `[0, 1]` (clamped; `NaN` is grey).
pub fn colour_map(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 5] = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    if t.is_nan() {
        return [128, 128, 128];
    }
    let s = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f64;
    let i = (s.floor() as usize).min(STOPS.len() - 2);
    let f = s - i as f64;
    [0, 1, 2].map(|k| (STOPS[i][k] + f * (STOPS[i + 1][k] - STOPS[i][k])).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_steps_and_labels() {
        assert_eq!(nice_step(0.0031), 0.005);
        assert_eq!(nice_step(7.0), 10.0);
        assert_eq!(nice_step(2.0), 2.0);
        assert_eq!(tick_label(0.015, 0.005), "0.015");
        assert_eq!(tick_label(40.0, 20.0), "40");
        assert_eq!(tick_label(3e-5, 1e-5), "3.0E-5");
    }

    #[test]
    fn bins_count_every_finite_value_once() {
        let v = [0.0, 0.05, 0.1, 0.95, 1.0, 2.0, f32::NAN];
        let (c, over) = bin_counts(&v, 1.0, 10);
        assert_eq!(c[0], 2);
        assert_eq!(c[1], 1);
        assert_eq!(c[9], 1);
        assert_eq!(over, 2);
        assert_eq!(c.iter().sum::<u64>() + over, 6);
    }

    #[test]
    fn histogram_has_the_size_and_bars_where_the_data_is() {
        // All values in the first tenth of the range: bars on the left only.
        let v: Vec<f32> = (0..1000).map(|i| (i % 100) as f32 * 1e-3).collect();
        let style = HistogramStyle {
            title: "N=1000".into(),
            ..Default::default()
        };
        let marker = Marker {
            label: "MEDIAN".into(),
            value: 0.05,
            colour: [200, 0, 0],
        };
        let img = histogram_image(&v, 1.0, &[marker], &style);
        assert_eq!((img.width(), img.height()), (900, 560));
        let bar_pixels = |x_range: std::ops::Range<u32>| {
            x_range
                .flat_map(|x| (60..480).map(move |y| (x, y)))
                .filter(|&(x, y)| *img.get_pixel(x, y) == BAR)
                .count()
        };
        let plot_width = 900 - 110 - 30;
        assert!(bar_pixels(112..110 + plot_width / 10) > 10_000);
        assert_eq!(bar_pixels(110 + plot_width / 5..870), 0);
        assert!(img.pixels().any(|p| *p == Rgb([200, 0, 0])));
        // Title text is drawn.
        assert!((8..22).any(|y| (110..200).any(|x| *img.get_pixel(x, y) == INK)));
    }

    #[test]
    fn glyphs_render_their_bits() {
        let mut img = RgbImage::from_pixel(12, 8, BACKGROUND);
        draw_text(&mut img, "1-", 0, 0, 1, false, INK);
        // '1' has its stem in column 2; '-' is a full row 3 of the second cell.
        assert_eq!(*img.get_pixel(2, 3), INK);
        assert_eq!(*img.get_pixel(0, 3), BACKGROUND);
        assert!((6..11).all(|x| *img.get_pixel(x, 3) == INK));
        assert_eq!(*img.get_pixel(6, 2), BACKGROUND);
    }

    #[test]
    fn colour_map_ends_and_nan() {
        assert_eq!(colour_map(0.0), [68, 1, 84]);
        assert_eq!(colour_map(5.0), [253, 231, 37]);
        assert_eq!(colour_map(f64::NAN), [128, 128, 128]);
    }
}
