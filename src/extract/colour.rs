//! Colour classes of the background-subtracted difference: an RGB → class look-up table
//! built once from the HSV limits of [`ColourParams`], and the per-laser response.
//!
//! Owns only the colour decision. The input format (RGB here; YUYV later) is the
//! caller's: it hands over the difference `(dr, dg, db)` of one pixel.

use serde::{Deserialize, Serialize};

/// Bits kept per channel when indexing the table: 32 levels, a 32 KiB table.
const LUT_BITS: u32 = 5;
const LUT_SHIFT: u32 = 8 - LUT_BITS;

/// Class of a pixel's difference from the background.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Class {
    /// Laser 0 of the cross.
    Laser0 = 0,
    /// Laser 1 of the cross.
    Laser1 = 1,
    /// Bright but desaturated: a saturated stripe centre, or an ambient change. Counts
    /// for every laser.
    White = 2,
    /// Saturated in a hue that no laser has: not a laser.
    Other = 3,
}

/// One laser of the cross, told apart by the hue of its difference image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserColour {
    /// Name for logs, overlays and the curves file ("red", "green", "blue").
    pub name: String,
    /// Hue range in degrees `[from, to]`, going up from `from`; it wraps through 360
    /// when `from > to` (red is `[300, 40]`).
    pub hue_deg: [f32; 2],
    /// Colour drawn in overlays.
    pub display_rgb: [u8; 3],
}

impl LaserColour {
    /// The lasers of a named preset: `red-green`, `blue-green`, `red`, `green`, `blue`.
    pub fn preset(name: &str) -> Option<Vec<Self>> {
        Some(match name {
            "red-green" => vec![Self::red(), Self::green()],
            "blue-green" => vec![Self::blue(), Self::green()],
            "red" => vec![Self::red()],
            "green" => vec![Self::green()],
            "blue" => vec![Self::blue()],
            _ => return None,
        })
    }

    /// One laser per single-colour name (`red`, `green`, `blue`), in order; other names
    /// are left out. For a projector described by its lasers' colour names.
    pub fn named<'a>(names: impl IntoIterator<Item = &'a str>) -> Vec<Self> {
        names
            .into_iter()
            .filter_map(|n| Self::preset(n).map(|mut v| v.remove(0)))
            .collect()
    }

    pub fn red() -> Self {
        Self {
            name: "red".into(),
            hue_deg: [300.0, 40.0],
            display_rgb: [255, 40, 40],
        }
    }
    pub fn green() -> Self {
        Self {
            name: "green".into(),
            hue_deg: [70.0, 170.0],
            display_rgb: [40, 255, 40],
        }
    }
    pub fn blue() -> Self {
        Self {
            name: "blue".into(),
            hue_deg: [190.0, 280.0],
            display_rgb: [60, 120, 255],
        }
    }

    /// The RGB channels this laser's light is in: those that are the largest channel
    /// of some hue in its range (red for hues 300–60°, green for 60–180°, blue for
    /// 180–300°). Red and green lasers light one channel each; a yellow one both.
    pub fn channels(&self) -> [bool; 3] {
        let mut channels = [false; 3];
        for step in 0..=720 {
            let hue = 0.5 * step as f32;
            if self.contains_hue(hue % 360.0) {
                let c = match hue % 360.0 {
                    h if !(60.0..300.0).contains(&h) => 0,
                    h if h < 180.0 => 1,
                    _ => 2,
                };
                channels[c] = true;
            }
        }
        channels
    }

    fn contains_hue(&self, hue_deg: f32) -> bool {
        let [from, to] = self.hue_deg;
        if from <= to {
            (from..=to).contains(&hue_deg)
        } else {
            hue_deg >= from || hue_deg <= to
        }
    }
}

/// Saturation and brightness limits of the colour decision.
#[derive(Clone, Debug, PartialEq)]
pub struct ColourParams {
    /// Minimum HSV value (max channel, 0–255) of the difference for a pixel to get a
    /// colour at all; dimmer pixels are weak tails and count for every laser.
    pub min_value: u8,
    /// Minimum HSV saturation (0–1) for a hue to mean anything; below it a bright pixel
    /// is [`Class::White`] (stripes saturate to white at their centres).
    pub min_saturation: f32,
    /// Another laser's colour blocks a laser only from this value up: there it is that
    /// laser's stripe. Dimmer pixels of its colour (its faint tails, its backscatter
    /// glow under water) count as weak for every laser, so that the glow of one sheet
    /// does not punch holes beside the other laser's stripe.
    pub mask_value: u8,
}

impl Default for ColourParams {
    fn default() -> Self {
        Self {
            min_value: 16,
            min_saturation: 0.25,
            mask_value: 25,
        }
    }
}

/// HSV hue in degrees `[0, 360)` and saturation `[0, 1]` of an RGB triple.
pub fn hue_saturation(r: f32, g: f32, b: f32) -> (f32, f32) {
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let chroma = max - min;
    if max <= 0.0 || chroma <= 0.0 {
        return (0.0, 0.0);
    }
    let hue = if max == r {
        60.0 * ((g - b) / chroma)
    } else if max == g {
        60.0 * ((b - r) / chroma + 2.0)
    } else {
        60.0 * ((r - g) / chroma + 4.0)
    };
    (hue.rem_euclid(360.0), chroma / max)
}

/// The colour look-up table: quantised difference RGB → [`Class`].
#[derive(Clone, Debug)]
pub struct ColourLut {
    table: Vec<u8>,
    min_value: u8,
    mask_value: u8,
    /// Per laser: the channels its light is in (see [`LaserColour::channels`]).
    channels: Vec<[bool; 3]>,
}

impl ColourLut {
    /// Builds the table; `lasers` holds one or two lasers (a hue in both ranges goes to
    /// the first).
    pub fn new(lasers: &[LaserColour], params: &ColourParams) -> Self {
        let levels = 1usize << LUT_BITS;
        let mut table = vec![Class::Other as u8; levels * levels * levels];
        let centre = |q: usize| ((q << LUT_SHIFT) as f32) + 0.5 * (1u32 << LUT_SHIFT) as f32;
        for qr in 0..levels {
            for qg in 0..levels {
                for qb in 0..levels {
                    let (h, s) = hue_saturation(centre(qr), centre(qg), centre(qb));
                    let class = if s < params.min_saturation {
                        Class::White
                    } else {
                        match lasers.iter().position(|l| l.contains_hue(h)) {
                            Some(0) => Class::Laser0,
                            Some(1) => Class::Laser1,
                            _ => Class::Other,
                        }
                    };
                    table[(qr << (2 * LUT_BITS)) | (qg << LUT_BITS) | qb] = class as u8;
                }
            }
        }
        Self {
            table,
            min_value: params.min_value,
            mask_value: params.mask_value,
            channels: lasers.iter().map(LaserColour::channels).collect(),
        }
    }

    /// Per laser, the channels its light is in ([`LaserColour::channels`]).
    pub fn channels(&self) -> &[[bool; 3]] {
        &self.channels
    }

    /// Class of a difference whose max channel is at least `min_value`; `None` for a
    /// weak pixel (a stripe tail or noise).
    #[inline]
    pub fn classify(&self, dr: u8, dg: u8, db: u8) -> Option<u8> {
        if dr.max(dg).max(db) < self.min_value {
            return None;
        }
        let i = ((dr as usize >> LUT_SHIFT) << (2 * LUT_BITS))
            | ((dg as usize >> LUT_SHIFT) << LUT_BITS)
            | (db as usize >> LUT_SHIFT);
        Some(self.table[i])
    }

    /// Response of laser `laser` to one pixel's difference, and whether the pixel is
    /// a hole in it: the difference in the laser's own channels (the largest of
    /// them) when the pixel is weak, white or of that laser's colour, or of another
    /// laser's colour but below `mask_value`; on a hue no laser has, the same when the
    /// light outside the laser's channels is below `mask_value`, else zero. So the two
    /// stripes of a cross stay apart where they cross (their mix is bright in both),
    /// and the other sheet's glow under water (in its own channels) neither raises nor
    /// hides this laser's faint stripe: a faint red stripe on a green veil of 10–20
    /// grey levels reads orange, outside red's hues.
    ///
    /// A pixel of another laser's colour is zeroed, and it is a hole (the detector
    /// drops the points whose smoothing window reaches it) only where zeroing took
    /// away light: its own channel at `min_value` or more (the other stripe's
    /// crosstalk, this stripe's flank where the two cross). One with noise in its own
    /// channel (a single pixel a JPEG block's ringing turned red beside a green
    /// stripe) loses nothing worth a point.
    #[inline]
    pub fn response(&self, laser: u8, dr: u8, dg: u8, db: u8) -> (u8, bool) {
        self.response_of_class(laser, dr, dg, db, self.classify(dr, dg, db))
    }

    /// [`Self::response`] given the difference's class (`classify(dr, dg, db)`), so that
    /// a caller that has it does not look it up again.
    #[inline]
    fn response_of_class(
        &self,
        laser: u8,
        dr: u8,
        dg: u8,
        db: u8,
        class: Option<u8>,
    ) -> (u8, bool) {
        let [r, g, b] = self.channels[laser as usize];
        let own = (dr * u8::from(r))
            .max(dg * u8::from(g))
            .max(db * u8::from(b));
        match class {
            None => (own, false),
            Some(c) if c == laser || c == Class::White as u8 => (own, false),
            Some(c) if c == Class::Other as u8 => {
                let foreign = (dr * u8::from(!r))
                    .max(dg * u8::from(!g))
                    .max(db * u8::from(!b));
                (if foreign < self.mask_value { own } else { 0 }, false)
            }
            Some(_) if dr.max(dg).max(db) < self.mask_value => (own, false),
            Some(_) => (0, own >= self.min_value),
        }
    }
}

/// A raw channel at or above this grey level is clipped by the sensor: what the laser
/// adds there is lost in that channel.
pub const CLIP_LEVEL: u8 = 250;

/// The chromatic share ([`ColourLut::response_local`]) of a pixel all of whose excess
/// has its laser's colour: the share is kept in 6 bits of the detector's per-pixel
/// flags.
pub const SHARE_FULL: u8 = 63;

impl ColourLut {
    /// Whether laser `laser`'s own channel is clipped in the raw pixel `raw`.
    #[inline]
    pub fn own_clipped(&self, laser: u8, raw: &[u8]) -> bool {
        let [r, g, b] = self.channels[laser as usize];
        (r && raw[0] >= CLIP_LEVEL) || (g && raw[1] >= CLIP_LEVEL) || (b && raw[2] >= CLIP_LEVEL)
    }

    /// [`Self::response`] with the raw pixel `raw` the difference `d` came from, and
    /// whether laser `laser`'s own channel is clipped there ([`Self::own_clipped`], which
    /// the caller has worked out for its mask):
    /// - where it is clipped, the light the laser adds is lost in that channel, and the
    ///   other channels still carry its core (the sensor's crosstalk, the halo's
    ///   gradient): the response is the own channel plus the largest other one, which
    ///   keeps rising to the centre;
    /// - a pixel white in `raw` and white in its difference is not laser light (a lamp,
    ///   a white rim, a white square against a darker background): it keeps only what
    ///   its own channel has beyond the others, nothing for a grey.
    ///
    /// The difference's class is looked up once and handed on.
    #[inline]
    pub fn response_raw(&self, laser: u8, d: [u8; 3], raw: &[u8], own_clipped: bool) -> (u8, bool) {
        let (own, foreign) = self.own_and_foreign(laser, d);
        if own_clipped {
            return (own.saturating_add(foreign), false);
        }
        let class = self.classify(d[0], d[1], d[2]);
        if self.white_in_both(class, raw) {
            return (own.saturating_sub(foreign), false);
        }
        self.response_of_class(laser, d[0], d[1], d[2], class)
    }

    /// Whether a difference of class `class` is white and so is the raw pixel `raw` it
    /// came from: light that is no laser's, whatever else it is.
    #[inline]
    fn white_in_both(&self, class: Option<u8>, raw: &[u8]) -> bool {
        let white = Some(Class::White as u8);
        class == white && self.classify(raw[0], raw[1], raw[2]) == white
    }

    /// [`Self::response`] against a laser-off frame, with the raw pixel `raw` the
    /// difference `d` came from. The difference is the laser's light alone only if
    /// nothing else changed since the laser-off frame: where an object moved away
    /// (a strand, a cable) or a lamp came on, the surface shows through brighter than
    /// its background, in its own colour. A pixel white in `raw` and white in `d`
    /// ([`Self::white_in_both`]) is therefore not laser light (a laser's stripe has its
    /// hue in one of the two) and keeps only what its own channel has beyond the
    /// others, nothing for a grey. Exempt are a clipped own channel (an overexposed
    /// core is white in both) and an own channel `min_value` or more above the others
    /// (the shoulders of an overexposed stripe, which the sensor's crosstalk washes out
    /// to a pale tint): there the difference is read as everywhere else. Where such a
    /// surface's excess fades into the noise, at its edges, the noise lends it a hue
    /// and a pixel cannot tell it from a faint stripe; the own channel of the difference
    /// has no ridge there, and `super::valley` drops those points.
    #[inline]
    pub fn response_off(&self, laser: u8, d: [u8; 3], raw: &[u8]) -> (u8, bool) {
        let class = self.classify(d[0], d[1], d[2]);
        if self.white_in_both(class, raw) && !self.own_clipped(laser, raw) {
            let (own, foreign) = self.own_and_foreign(laser, d);
            let beyond = own.saturating_sub(foreign);
            if beyond < self.min_value {
                return (beyond, false);
            }
        }
        self.response_of_class(laser, d[0], d[1], d[2], class)
    }

    /// [`Self::response_raw`] against a local background, and the pixel's chromatic
    /// share. The excess there still holds the surface's texture, in the surface's
    /// colour, where a laser-off frame would have taken it out; a laser is nearly
    /// monochrome, a grey or pale texture is not. The two jobs are split:
    /// - the response, which locates the stripe, is the laser's own channel as
    ///   [`Self::response_raw`] reads it (own plus the largest other where own is
    ///   clipped; only what own has beyond the others for white in both). Own minus
    ///   foreign would locate it worse: 4:2:0 chroma (MJPEG) spreads a stripe's colour
    ///   over 2×2 blocks, and that difference is all colour, none of the luma that
    ///   keeps a stripe's own channel sharp. On the realistic bench it doubled the
    ///   sub-pixel error (0.0443 against 0.0277 px);
    /// - the share, `(own − foreign) / own` in [`SHARE_FULL`]ths, says how much of that
    ///   light has the laser's colour. The detector scales a ridge point's strength by
    ///   it, so a grey texture gives nothing, as the difference did.
    ///
    /// Clipped in every channel is white in the raw frame and, over a local
    /// background, in the excess too: a lamp or a specular spot as much as a stripe's
    /// core, and only the latter has a laser-coloured flank. There the response is own
    /// minus foreign (next to nothing), and a clipped own channel has the full share
    /// (its colour is lost to the clipping, not absent).
    ///
    /// A pixel is the other laser's (zeroed, and a hole) only where its other colour
    /// stands `min_value` or more above its own channel, the level below which a
    /// difference has no colour at all. The opening keeps what of a stripe's halo is
    /// wider than its window, so the excess of the stripe's pale shoulders has less of
    /// the laser's channel than the truth, and the noise then gives some of them the
    /// other laser's hue; each such hole cut the stripe's points around it.
    #[inline]
    pub fn response_local(
        &self,
        laser: u8,
        d: [u8; 3],
        raw: &[u8],
        own_clipped: bool,
    ) -> (u8, bool, u8) {
        let (r, hole) = self.response_raw(laser, d, raw, own_clipped);
        let (own, foreign) = self.own_and_foreign(laser, d);
        if own_clipped {
            // `response_raw` makes no hole where own is clipped: own plus foreign.
            let all_clipped = raw[..3].iter().all(|&v| v >= CLIP_LEVEL);
            let r = if all_clipped {
                r.saturating_sub(foreign)
            } else {
                r
            };
            return (r, false, SHARE_FULL);
        }
        let (r, hole) = if hole && u16::from(foreign) < u16::from(own) + u16::from(self.min_value) {
            (own, false)
        } else {
            (r, hole)
        };
        let share = if own == 0 {
            0
        } else {
            let beyond = u32::from(own.saturating_sub(foreign));
            ((u32::from(SHARE_FULL) * beyond + u32::from(own) / 2) / u32::from(own)) as u8
        };
        (r, hole, share)
    }

    /// The largest of `d`'s channels that are laser `laser`'s, and of those that are not.
    #[inline]
    fn own_and_foreign(&self, laser: u8, d: [u8; 3]) -> (u8, u8) {
        let [r, g, b] = self.channels[laser as usize];
        let own = (d[0] * u8::from(r))
            .max(d[1] * u8::from(g))
            .max(d[2] * u8::from(b));
        let foreign = (d[0] * u8::from(!r))
            .max(d[1] * u8::from(!g))
            .max(d[2] * u8::from(!b));
        (own, foreign)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hue_of_primaries_and_mixtures() {
        let close =
            |a: (f32, f32), b: (f32, f32)| (a.0 - b.0).abs() < 1e-3 && (a.1 - b.1).abs() < 1e-4;
        assert!(close(hue_saturation(255.0, 0.0, 0.0), (0.0, 1.0)));
        assert!(close(hue_saturation(0.0, 255.0, 0.0), (120.0, 1.0)));
        assert!(close(hue_saturation(0.0, 0.0, 255.0), (240.0, 1.0)));
        assert!(close(hue_saturation(255.0, 0.0, 255.0), (300.0, 1.0)));
        // A pink: hue just below 360, saturation 1 − 64/255.
        let (h, s) = hue_saturation(255.0, 64.0, 128.0);
        assert!((h - (360.0 - 60.0 * 64.0 / 191.0)).abs() < 1e-3, "{h}");
        assert!((s - 191.0 / 255.0).abs() < 1e-5);
    }

    #[test]
    fn red_green_classes() {
        let lut = ColourLut::new(
            &[LaserColour::red(), LaserColour::green()],
            &ColourParams::default(),
        );
        assert_eq!(lut.classify(200, 10, 20), Some(Class::Laser0 as u8));
        assert_eq!(lut.classify(255, 60, 120), Some(Class::Laser0 as u8)); // pinkish red
        assert_eq!(lut.classify(10, 220, 30), Some(Class::Laser1 as u8));
        assert_eq!(lut.classify(250, 250, 240), Some(Class::White as u8));
        assert_eq!(lut.classify(20, 30, 200), Some(Class::Other as u8)); // blue
        assert_eq!(lut.classify(10, 5, 3), None);
        // Red's response keeps red, white and weak pixels and drops green ones.
        assert_eq!(lut.response(0, 200, 10, 20), (200, false));
        assert_eq!(lut.response(0, 10, 220, 30), (0, false));
        // Zeroed where its own channel held light (another stripe's crosstalk, the
        // cross's centre): a hole the detector keeps its windows off. Zeroed where
        // it held noise (a green pixel with red under `min_value`): no hole.
        assert_eq!(lut.response(0, 40, 220, 30), (0, true));
        assert_eq!(lut.response(1, 10, 220, 30), (220, false));
        assert_eq!(lut.response(1, 250, 250, 240), (250, false));
        assert_eq!(lut.response(1, 10, 5, 3), (5, false));
        assert_eq!(lut.response(1, 20, 30, 200), (0, false));
        // Green too dim to be green's stripe (its glow) is a weak pixel for red, which
        // sees only its own channel of it.
        assert_eq!(lut.classify(5, 20, 8), Some(Class::Laser1 as u8));
        assert_eq!(lut.response(0, 5, 20, 8), (5, false));
        // A faint green stripe on the red sheet's glow stands out for green by its
        // green alone.
        assert_eq!(lut.response(1, 9, 13, 0).0 - lut.response(1, 9, 3, 0).0, 10);
        assert_eq!(lut.response(0, 5, 25, 8), (0, false));
        assert_eq!(lut.response(0, 18, 40, 8), (0, true));
        // A faint red stripe on the green sheet's veil under water reads orange, a hue
        // of neither laser: it is red's, as the veil is too dim to be green's stripe.
        // Both dim: weak for both, each sees its own channel. Red brighter than
        // `mask_value`: not green's. Bright in both (where the stripes cross): neither's.
        assert_eq!(lut.classify(22, 17, 1), Some(Class::Other as u8));
        assert_eq!(lut.response(0, 22, 17, 1), (22, false));
        assert_eq!(lut.response(1, 22, 17, 1), (17, false));
        assert_eq!(lut.classify(30, 24, 2), Some(Class::Other as u8));
        assert_eq!(lut.response(0, 30, 24, 2), (30, false));
        assert_eq!(lut.response(1, 30, 24, 2), (0, false));
        assert_eq!(lut.classify(150, 140, 0), Some(Class::Other as u8));
        assert_eq!(lut.response(0, 150, 140, 0), (0, false));
        assert_eq!(lut.response(1, 150, 140, 0), (0, false));
    }

    #[test]
    fn channels_of_laser_hues() {
        assert_eq!(LaserColour::red().channels(), [true, false, false]);
        assert_eq!(LaserColour::green().channels(), [false, true, false]);
        assert_eq!(LaserColour::blue().channels(), [false, false, true]);
        let yellow = LaserColour {
            name: "yellow".into(),
            hue_deg: [40.0, 80.0],
            display_rgb: [255, 255, 0],
        };
        assert_eq!(yellow.channels(), [true, true, false]);
    }

    #[test]
    fn blue_green_and_single_laser() {
        let lut = ColourLut::new(
            &[LaserColour::blue(), LaserColour::green()],
            &ColourParams::default(),
        );
        assert_eq!(lut.classify(20, 60, 230), Some(Class::Laser0 as u8));
        assert_eq!(lut.classify(30, 230, 40), Some(Class::Laser1 as u8));
        assert_eq!(lut.classify(230, 30, 40), Some(Class::Other as u8));
        let lut = ColourLut::new(&[LaserColour::red()], &ColourParams::default());
        assert_eq!(lut.classify(30, 230, 40), Some(Class::Other as u8));
        assert_eq!(lut.response(0, 30, 230, 40), (0, false));
    }
}
