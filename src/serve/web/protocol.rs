//! The live view's WebSocket protocol, version 1: the cloud stream
//! ([`crate::serve::stream`]) and the status lines ([`crate::serve::status`]) as a
//! browser page reads them, on `ws://<http_listen>/ws`.
//!
//! The socket flows one way, daemon to page (the page sends nothing; what it sends
//! is read and ignored). Text messages are JSON objects with `"type"` and
//! `"version"`; binary messages are batches of points.
//!
//! | message | kind | content |
//! |---|---|---|
//! | `hello` | text | `{"type":"hello","version":1,"scan":..,"daemon":"crossline x.y.z","width":..,"height":..,"fx":..,"fy":..,"cx":..,"cy":..}`: the camera's image size (the coverage map) and intrinsics (pixels); the first message of every connection |
//! | `epoch` | text | `{"type":"epoch","version":1,"epoch":3,"reason":"first"\|"reestimate"\|"final"\|"resync"}`: the page drops every point it holds; the points of this epoch follow |
//! | points | binary | epoch u32, count u32, then `count` records of 20 bytes (below); all little-endian |
//! | `end` | text | `{"type":"end","version":1,"epoch":..,"total":..}`: the scan is finished; the page holds the final cloud |
//! | `bye` | text | `{"type":"bye","version":1,"reason":".."}`: the daemon drops this page (it fell behind twice); it may reconnect |
//! | `status` | text | a status line of [`crate::serve::status`] as it is (its own `"type":"status"` and `"version"`), once per interval; the newest one on connecting |
//! | `event` | text | an event line of [`crate::serve::status`] as it is |
//!
//! A point record: x, y, z f32 (camera frame, OpenCV axes: x right, y down, z forward,
//! in the epoch's scale), red, green, blue u8, laser u8, then the point's pixel u, v
//! as u16 (the camera file's projection, lens distortion included, rounded), or
//! `0xFFFF` for both when it projects outside the image. The pixel is what the
//! coverage map marks; under a focal length that the solver re-estimated it may be a
//! few pixels off at the edges of the image, which a coverage map does not mind.
//!
//! The order and the rules are the cloud stream's: a page that connects gets `hello`,
//! the current epoch from its `epoch` on, and everything after; a page that falls
//! behind by more than `[serve] client_queue_mib` gets the epoch again (reason
//! `resync`), and one that reads nothing between two resynchronisations gets `bye`.

use nalgebra::Vector3;
use serde::Serialize;

use crate::camera::Camera;
use crate::serve::stream::{self, EpochReason};

pub const VERSION: u32 = 1;
/// Bytes per point record of a binary message.
pub const RECORD_BYTES: usize = 20;
/// Bytes before the first record of a binary message.
pub const HEADER_BYTES: usize = 8;
/// The pixel of a point that projects outside the image.
pub const NO_PIXEL: u16 = u16::MAX;

/// The text messages the daemon sends (status and event lines are passed on as they
/// are and are not listed here).
#[derive(Debug, Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum Text {
    Hello {
        version: u32,
        scan: String,
        daemon: String,
        width: u32,
        height: u32,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
    },
    Epoch {
        version: u32,
        epoch: u32,
        reason: &'static str,
    },
    End {
        version: u32,
        epoch: u32,
        total: u64,
    },
    Bye {
        version: u32,
        reason: String,
    },
}

impl Text {
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }

    pub fn bye(reason: &str) -> Self {
        Self::Bye {
            version: VERSION,
            reason: reason.to_string(),
        }
    }
}

/// One WebSocket message to send.
#[derive(Debug, PartialEq)]
pub enum Outgoing {
    Text(String),
    Binary(Vec<u8>),
}

fn reason_name(reason: u8) -> &'static str {
    match reason {
        r if r == EpochReason::First as u8 => "first",
        r if r == EpochReason::Reestimate as u8 => "reestimate",
        r if r == EpochReason::Final as u8 => "final",
        _ => "resync",
    }
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?))
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    b.get(at..at + 4)
        .and_then(|s| s.try_into().ok())
        .map_or(f32::NAN, f32::from_le_bytes)
}

/// Turns the hub's cloud-stream messages into the page's, one connection at a time.
pub struct Translator {
    camera: Camera,
}

impl Translator {
    pub fn new(camera: Camera) -> Self {
        Self { camera }
    }

    /// The page's message for one framed cloud-stream message; `None` for a message
    /// that is not one the hub sends (nothing is sent for it).
    pub fn translate(&self, message: &[u8]) -> Option<Outgoing> {
        let kind = *message.get(4)?;
        let body = message.get(5..)?;
        match kind {
            stream::HELLO => {
                let info: serde_json::Value =
                    serde_json::from_slice(body.get(12..)?).unwrap_or_default();
                let text = |k: &str| info.get(k).and_then(|v| v.as_str()).unwrap_or("");
                Some(Outgoing::Text(
                    Text::Hello {
                        version: VERSION,
                        scan: text("scan").to_string(),
                        daemon: text("daemon").to_string(),
                        width: self.camera.width,
                        height: self.camera.height,
                        fx: self.camera.fx,
                        fy: self.camera.fy,
                        cx: self.camera.cx,
                        cy: self.camera.cy,
                    }
                    .to_json(),
                ))
            }
            stream::EPOCH => Some(Outgoing::Text(
                Text::Epoch {
                    version: VERSION,
                    epoch: u32_at(body, 0)?,
                    reason: reason_name(*body.get(4)?),
                }
                .to_json(),
            )),
            stream::POINTS => self.points(body).map(Outgoing::Binary),
            stream::END => Some(Outgoing::Text(
                Text::End {
                    version: VERSION,
                    epoch: u32_at(body, 0)?,
                    total: u64_at(body, 4)?,
                }
                .to_json(),
            )),
            _ => None,
        }
    }

    /// A `POINTS` body (epoch, capture time, count, records) as a binary message.
    fn points(&self, body: &[u8]) -> Option<Vec<u8>> {
        let epoch = u32_at(body, 0)?;
        let count = u32_at(body, 12)? as usize;
        let records = body.get(16..)?;
        if records.len() != count.checked_mul(stream::POINT_BYTES)? {
            return None;
        }
        let mut out = Vec::with_capacity(HEADER_BYTES + count * RECORD_BYTES);
        out.extend_from_slice(&epoch.to_le_bytes());
        out.extend_from_slice(&(count as u32).to_le_bytes());
        for rec in records.chunks_exact(stream::POINT_BYTES) {
            let xyz = [f32_at(rec, 0), f32_at(rec, 4), f32_at(rec, 8)];
            out.extend_from_slice(&rec[..16]);
            let [u, v] = self.pixel_of(xyz);
            out.extend_from_slice(&u.to_le_bytes());
            out.extend_from_slice(&v.to_le_bytes());
        }
        Some(out)
    }

    /// The pixel a point projects to, or [`NO_PIXEL`] twice.
    pub fn pixel_of(&self, point_in_camera: [f32; 3]) -> [u16; 2] {
        let p = Vector3::new(
            f64::from(point_in_camera[0]),
            f64::from(point_in_camera[1]),
            f64::from(point_in_camera[2]),
        );
        match self.camera.pixel_from_camera(&p) {
            Some([u, v]) if self.camera.contains_pixel(u, v) => {
                [u.round().max(0.0) as u16, v.round().max(0.0) as u16]
            }
            _ => [NO_PIXEL; 2],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::serve::stream::Point;

    fn camera() -> Camera {
        Camera::with_fov(640, 480, 1.0)
    }

    fn text(out: Option<Outgoing>) -> serde_json::Value {
        match out {
            Some(Outgoing::Text(t)) => serde_json::from_str(&t).expect("JSON"),
            other => panic!("expected text, got {other:?}"),
        }
    }

    #[test]
    fn control_messages_become_versioned_json() {
        let t = Translator::new(camera());
        let hello = text(t.translate(&stream::hello(
            r#"{"width":640,"height":480,"scan":"S1","daemon":"crossline 9"}"#,
        )));
        assert_eq!(hello["type"], "hello");
        assert_eq!(hello["version"], VERSION);
        assert_eq!(hello["scan"], "S1");
        assert_eq!(hello["width"], 640);
        assert_eq!(hello["height"], 480);
        assert!((hello["fx"].as_f64().unwrap_or(0.0) - camera().fx).abs() < 1e-9);
        for (reason, name) in [
            (EpochReason::First, "first"),
            (EpochReason::Reestimate, "reestimate"),
            (EpochReason::Final, "final"),
            (EpochReason::Resync, "resync"),
        ] {
            let e = text(t.translate(&stream::epoch(7, reason)));
            assert_eq!(
                (e["type"].as_str(), e["epoch"].as_u64()),
                (Some("epoch"), Some(7))
            );
            assert_eq!(e["reason"], name);
        }
        let end = text(t.translate(&stream::end(7, 12_345)));
        assert_eq!(end["type"], "end");
        assert_eq!(end["total"], 12_345);
        let bye: serde_json::Value =
            serde_json::from_str(&Text::bye("slow").to_json()).expect("JSON");
        assert_eq!(
            (bye["type"].as_str(), bye["reason"].as_str()),
            (Some("bye"), Some("slow"))
        );
    }

    #[test]
    fn points_carry_their_pixel() {
        let cam = camera();
        let t = Translator::new(cam.clone());
        // Points placed on known pixels: the ray of (u, v) at depth 2.
        let at = |u: f64, v: f64, rgb: [u8; 3]| {
            let ray = cam.ray_from_pixel(u, v).expect("ray");
            Point {
                xyz: [(2.0 * ray.x) as f32, (2.0 * ray.y) as f32, 2.0],
                rgb,
                laser: 1,
                frame: 9,
            }
        };
        let behind = Point {
            xyz: [0.0, 0.0, -1.0],
            rgb: [1, 2, 3],
            laser: 0,
            frame: 1,
        };
        let pts = [
            at(10.0, 20.0, [200, 0, 0]),
            at(600.0, 470.0, [0, 90, 0]),
            behind,
        ];
        let msg = stream::points(4, 99, &pts).remove(0);
        let Some(Outgoing::Binary(b)) = t.translate(&msg) else {
            panic!("expected a binary message");
        };
        assert_eq!(b.len(), HEADER_BYTES + 3 * RECORD_BYTES);
        assert_eq!(u32_at(&b, 0), Some(4));
        assert_eq!(u32_at(&b, 4), Some(3));
        let rec = |i: usize| &b[HEADER_BYTES + i * RECORD_BYTES..][..RECORD_BYTES];
        let pixel = |i: usize| {
            let r = rec(i);
            [
                u16::from_le_bytes([r[16], r[17]]),
                u16::from_le_bytes([r[18], r[19]]),
            ]
        };
        assert_eq!(pixel(0), [10, 20]);
        assert_eq!(pixel(1), [600, 470]);
        assert_eq!(pixel(2), [NO_PIXEL; 2]);
        assert_eq!(&rec(0)[12..16], &[200, 0, 0, 1]);
        assert!((f32_at(rec(1), 8) - 2.0).abs() < 1e-6);
    }

    #[test]
    fn damaged_or_unknown_messages_send_nothing() {
        let t = Translator::new(camera());
        assert_eq!(t.translate(&[]), None);
        assert_eq!(t.translate(&stream::bye("x")), None);
        let mut cut = stream::points(
            1,
            0,
            &[Point {
                xyz: [0.0, 0.0, 1.0],
                rgb: [0; 3],
                laser: 0,
                frame: 0,
            }],
        )
        .remove(0);
        cut.truncate(cut.len() - 1);
        assert_eq!(t.translate(&cut), None);
    }
}
