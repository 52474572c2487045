//! The RGB input's response: laser `k`'s response to the positive part of
//! `frame − background`, per row of a tile, for the detector (step 1 of the module doc
//! of `extract`).

use image::RgbImage;

use super::{colour::ColourLut, detect, faint};

/// Per cell of `faint::BLOCK · faint::DARK_CELL` px (`cells_x` per row), per channel:
/// the grey levels the frame is lifted by before the background is subtracted; empty
/// for no lift.
#[derive(Default)]
pub(super) struct DarkCells {
    pub(super) lift: Vec<[u8; 3]>,
    pub(super) cells_x: usize,
}

/// The RGB input's response filler for [`Detector::prepare`]: laser `laser`'s response
/// to the positive part of `frame − background`, the frame lifted per cell by `dark`,
/// and the other-laser mask. Another input
/// format (YUYV) needs its own filler and activation pass; the rest is shared.
pub(super) fn response_rgb<'a>(
    lut: &'a ColourLut,
    laser: u8,
    frame: &'a RgbImage,
    background: &'a RgbImage,
    dark: &'a DarkCells,
    local: bool,
) -> impl FnMut(usize, usize, &mut [f32], &mut [u8]) + 'a {
    let width = frame.width() as usize;
    let (fr, bg) = (frame.as_raw(), background.as_raw());
    const CELL_PX: usize = faint::BLOCK * faint::DARK_CELL;
    let (dark, cells_x) = (&dark.lift[..], dark.cells_x);
    move |y, x0, row, masked| {
        let start = 3 * (y * width + x0);
        let f = &fr[start..start + 3 * row.len()];
        let b = &bg[start..start + 3 * row.len()];
        let cell_row = (y / CELL_PX) * cells_x;
        // Cell by cell, so the inner loop has one lift.
        let mut i = 0;
        while i < row.len() {
            let (lift, end) = if dark.is_empty() {
                ([0; 3], row.len())
            } else {
                let cx = ((x0 + i) / CELL_PX).min(cells_x - 1);
                let end = if cx + 1 == cells_x {
                    row.len()
                } else {
                    ((cx + 1) * CELL_PX - x0).min(row.len())
                };
                (dark.get(cell_row + cx).copied().unwrap_or([0; 3]), end)
            };
            for (((o, m), f), b) in row[i..end]
                .iter_mut()
                .zip(masked[i..end].iter_mut())
                .zip(f[3 * i..3 * end].chunks_exact(3))
                .zip(b[3 * i..3 * end].chunks_exact(3))
            {
                let (dr, dg, db) = (
                    f[0].saturating_add(lift[0]).saturating_sub(b[0]),
                    f[1].saturating_add(lift[1]).saturating_sub(b[1]),
                    f[2].saturating_add(lift[2]).saturating_sub(b[2]),
                );
                let clipped = local && lut.own_clipped(laser, f);
                let (r, hole, share) = if local {
                    lut.response_local(laser, [dr, dg, db], f, clipped)
                } else {
                    // Against a laser-off frame the difference is the laser's
                    // light alone, clipped cores included (a wide clipped top is
                    // centred by the automatic scale), but for what changed since.
                    let (r, hole) = lut.response_off(laser, [dr, dg, db], f);
                    (r, hole, 0)
                };
                // Bit 1: the own channel clipped, which a flat top may be
                // (`detect::width::FLAT_RATIO`); bits 2-7: the chromatic share.
                *m = u8::from(hole) | (u8::from(clipped) << 1) | (share << detect::SHARE_SHIFT);
                *o = r as f32;
            }
            i = end;
        }
    }
}
