//! Bilinear sampling of an RGB frame at a sub-pixel position, shared by extraction's
//! checks and the cloud's colours. Here, below both, so that `extract` does not depend
//! on `cloud`.

use image::RgbImage;

/// The three channels at `(u, v)` (pixel centres at integer coordinates), bilinear,
/// clamped at the border; zero for an empty image.
pub fn rgb_f32(img: &RgbImage, u: f32, v: f32) -> [f32; 3] {
    let (w, h) = (img.width() as i64, img.height() as i64);
    if w == 0 || h == 0 {
        return [0.0; 3];
    }
    let u = u.clamp(0.0, (w - 1) as f32);
    let v = v.clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (u.floor() as i64, v.floor() as i64);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (u - x0 as f32, v - y0 as f32);
    let at = |x: i64, y: i64| img.get_pixel(x as u32, y as u32).0;
    let (a, b, c, d) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
    let mut out = [0.0f32; 3];
    for k in 0..3 {
        let top = a[k] as f32 * (1.0 - fx) + b[k] as f32 * fx;
        let bottom = c[k] as f32 * (1.0 - fx) + d[k] as f32 * fx;
        out[k] = top * (1.0 - fy) + bottom * fy;
    }
    out
}
