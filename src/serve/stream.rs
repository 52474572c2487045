//! The cloud stream protocol, version 1: how the daemon sends its growing cloud to
//! clients (TCP, by default on 127.0.0.1, and/or a Unix socket).
//!
//! The stream flows one way, server to client. All integers and floats are
//! little-endian. Every message is framed as
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | length `L` of the rest of the message (type + body), at most 64 MiB |
//! | 4 | 1 | message type |
//! | 5 | L−1 | body |
//!
//! Message types:
//!
//! | type | name | body |
//! |---|---|---|
//! | 1 | `HELLO` | magic `CRSLSTRM` (8), protocol version u32 (= 1), then UTF-8 JSON describing the scan (`{"width":..,"height":..,"daemon":"crossline x.y.z"}`) |
//! | 2 | `EPOCH` | epoch u32, reason u8 (0 first solve, 1 re-estimate, 2 final, 3 resync): the client drops every point it holds; the points of this epoch follow |
//! | 3 | `POINTS` | epoch u32, capture time of the newest frame in the batch u64 (ns, daemon clock), count u32, then `count` point records |
//! | 4 | `END` | epoch u32, total points u64: the scan is finished; the client holds exactly the cloud the daemon wrote |
//! | 5 | `BYE` | UTF-8 reason: the daemon is dropping this client (e.g. it read nothing for too long) |
//!
//! A point record is 20 bytes: x, y, z f32 (camera frame, OpenCV axes, the epoch's
//! scale), red, green, blue u8, laser u8, frame u32.
//!
//! A client that connects at any moment first gets `HELLO`, then the current epoch
//! from its `EPOCH` on, then everything after: following the stream to `END` leaves
//! it with exactly the final cloud. A client that falls behind by more than its
//! queue bound is resynchronised: its queued messages are dropped and it is sent the
//! current epoch again, starting with an `EPOCH` of reason 3. A client that reads
//! nothing between two resynchronisations is sent `BYE` and closed.

use std::io::Read;

use crate::ply::Cloud;

pub const MAGIC: &[u8; 8] = b"CRSLSTRM";
pub const VERSION: u32 = 1;
/// Largest message a client accepts.
pub const MAX_MESSAGE: u32 = 64 << 20;
/// Bytes per point record.
pub const POINT_BYTES: usize = 20;
/// Most points in one `POINTS` message.
pub const MAX_POINTS_PER_MESSAGE: usize = 1 << 16;

pub const HELLO: u8 = 1;
pub const EPOCH: u8 = 2;
pub const POINTS: u8 = 3;
pub const END: u8 = 4;
pub const BYE: u8 = 5;

/// Why a new epoch begins.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum EpochReason {
    First = 0,
    Reestimate = 1,
    Final = 2,
    Resync = 3,
}

/// One point as it travels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point {
    pub xyz: [f32; 3],
    pub rgb: [u8; 3],
    pub laser: u8,
    pub frame: u32,
}

fn frame(kind: u8, body: &[u8]) -> Vec<u8> {
    let mut m = Vec::with_capacity(5 + body.len());
    m.extend_from_slice(&(body.len() as u32 + 1).to_le_bytes());
    m.push(kind);
    m.extend_from_slice(body);
    m
}

pub fn hello(info_json: &str) -> Vec<u8> {
    let mut body = Vec::with_capacity(12 + info_json.len());
    body.extend_from_slice(MAGIC);
    body.extend_from_slice(&VERSION.to_le_bytes());
    body.extend_from_slice(info_json.as_bytes());
    frame(HELLO, &body)
}

pub fn epoch(epoch: u32, reason: EpochReason) -> Vec<u8> {
    let mut body = epoch.to_le_bytes().to_vec();
    body.push(reason as u8);
    frame(EPOCH, &body)
}

/// `POINTS` messages for `points` (split at [`MAX_POINTS_PER_MESSAGE`]).
pub fn points(epoch: u32, captured_nanos: u64, points: &[Point]) -> Vec<Vec<u8>> {
    points
        .chunks(MAX_POINTS_PER_MESSAGE)
        .map(|chunk| {
            let mut body = Vec::with_capacity(16 + chunk.len() * POINT_BYTES);
            body.extend_from_slice(&epoch.to_le_bytes());
            body.extend_from_slice(&captured_nanos.to_le_bytes());
            body.extend_from_slice(&(chunk.len() as u32).to_le_bytes());
            for p in chunk {
                for c in p.xyz {
                    body.extend_from_slice(&c.to_le_bytes());
                }
                body.extend_from_slice(&p.rgb);
                body.push(p.laser);
                body.extend_from_slice(&p.frame.to_le_bytes());
            }
            frame(POINTS, &body)
        })
        .collect()
}

pub fn end(epoch: u32, total: u64) -> Vec<u8> {
    let mut body = epoch.to_le_bytes().to_vec();
    body.extend_from_slice(&total.to_le_bytes());
    frame(END, &body)
}

pub fn bye(reason: &str) -> Vec<u8> {
    frame(BYE, reason.as_bytes())
}

/// The capture time carried by a `POINTS` message (for latency measurement), if it
/// is one.
pub fn captured_nanos(message: &[u8]) -> Option<u64> {
    if message.len() >= 17 && message[4] == POINTS {
        Some(u64::from_le_bytes(message[9..17].try_into().ok()?))
    } else {
        None
    }
}

#[derive(Debug, thiserror::Error)]
pub enum StreamError {
    #[error("reading the stream: {0}")]
    Io(#[from] std::io::Error),
    #[error("not a crossline cloud stream (bad HELLO)")]
    NotAStream,
    #[error("cloud stream version {0}, this crossline reads version {VERSION}")]
    Version(u32),
    #[error("malformed {kind} message: {why}")]
    Malformed { kind: &'static str, why: String },
    #[error("the daemon dropped this client: {0}")]
    Bye(String),
    #[error("the stream closed before END (after {points} points of epoch {epoch})")]
    Closed { epoch: u32, points: usize },
}

/// What a client learnt from one message.
#[derive(Debug, PartialEq)]
pub enum Event {
    Hello { info: String },
    Epoch { epoch: u32, reason: u8 },
    Points { count: usize },
    End { epoch: u32, total: u64 },
}

/// A client's copy of the cloud, kept up to date message by message.
#[derive(Debug, Default)]
pub struct Follower {
    pub epoch: u32,
    pub points: Vec<Point>,
    pub hello: Option<String>,
    pub ended: bool,
    /// Epoch messages seen, by reason (first, re-estimate, final, resync).
    pub epochs_by_reason: [usize; 4],
}

fn read_message(r: &mut impl Read) -> Result<Option<(u8, Vec<u8>)>, StreamError> {
    let mut len = [0u8; 4];
    let mut got = 0;
    while got < 4 {
        match r.read(&mut len[got..]) {
            Ok(0) if got == 0 => return Ok(None),
            Ok(0) => {
                return Err(StreamError::Malformed {
                    kind: "frame",
                    why: "cut off inside a length".into(),
                })
            }
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e.into()),
        }
    }
    let len = u32::from_le_bytes(len);
    if len == 0 || len > MAX_MESSAGE {
        return Err(StreamError::Malformed {
            kind: "frame",
            why: format!("length {len}"),
        });
    }
    // Grown as bytes arrive, not sized by the length: a damaged or hostile length
    // costs what the stream actually carries.
    let mut msg = Vec::new();
    r.take(u64::from(len)).read_to_end(&mut msg)?;
    if msg.len() < len as usize {
        return Err(StreamError::Malformed {
            kind: "frame",
            why: format!("cut off after {} of {len} bytes", msg.len()),
        });
    }
    let kind = msg[0];
    msg.remove(0);
    Ok(Some((kind, msg)))
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?))
}

impl Follower {
    /// Reads and applies one message; `Ok(None)` when the stream closed cleanly.
    pub fn step(&mut self, r: &mut impl Read) -> Result<Option<Event>, StreamError> {
        let Some((kind, body)) = read_message(r)? else {
            return Ok(None);
        };
        let bad = |kind: &'static str, why: &str| StreamError::Malformed {
            kind,
            why: why.to_string(),
        };
        match kind {
            HELLO => {
                if body.len() < 12 || &body[..8] != MAGIC {
                    return Err(StreamError::NotAStream);
                }
                let version = u32_at(&body, 8).ok_or(StreamError::NotAStream)?;
                if version != VERSION {
                    return Err(StreamError::Version(version));
                }
                let info = String::from_utf8_lossy(&body[12..]).into_owned();
                self.hello = Some(info.clone());
                Ok(Some(Event::Hello { info }))
            }
            EPOCH => {
                let epoch = u32_at(&body, 0).ok_or_else(|| bad("EPOCH", "short"))?;
                let reason = *body.get(4).ok_or_else(|| bad("EPOCH", "short"))?;
                self.epoch = epoch;
                self.points.clear();
                self.ended = false;
                if let Some(n) = self.epochs_by_reason.get_mut(reason as usize) {
                    *n += 1;
                }
                Ok(Some(Event::Epoch { epoch, reason }))
            }
            POINTS => {
                let epoch = u32_at(&body, 0).ok_or_else(|| bad("POINTS", "short"))?;
                let count = u32_at(&body, 12).ok_or_else(|| bad("POINTS", "short"))? as usize;
                if body.len() != 16 + count * POINT_BYTES {
                    return Err(bad("POINTS", "length does not match the count"));
                }
                if epoch != self.epoch {
                    return Err(bad("POINTS", "points of another epoch than the last EPOCH"));
                }
                for rec in body[16..].chunks_exact(POINT_BYTES) {
                    let f =
                        |i: usize| f32::from_le_bytes([rec[i], rec[i + 1], rec[i + 2], rec[i + 3]]);
                    self.points.push(Point {
                        xyz: [f(0), f(4), f(8)],
                        rgb: [rec[12], rec[13], rec[14]],
                        laser: rec[15],
                        frame: u32::from_le_bytes([rec[16], rec[17], rec[18], rec[19]]),
                    });
                }
                Ok(Some(Event::Points { count }))
            }
            END => {
                let epoch = u32_at(&body, 0).ok_or_else(|| bad("END", "short"))?;
                let total = u64_at(&body, 4).ok_or_else(|| bad("END", "short"))?;
                if total != self.points.len() as u64 {
                    return Err(bad(
                        "END",
                        &format!(
                            "says {total} points, the stream carried {}",
                            self.points.len()
                        ),
                    ));
                }
                self.ended = true;
                Ok(Some(Event::End { epoch, total }))
            }
            BYE => Err(StreamError::Bye(
                String::from_utf8_lossy(&body).into_owned(),
            )),
            other => Err(StreamError::Malformed {
                kind: "frame",
                why: format!("unknown message type {other}"),
            }),
        }
    }

    /// Follows the stream to `END` (or to a clean close when `until_end` is false).
    pub fn follow(&mut self, r: &mut impl Read, until_end: bool) -> Result<(), StreamError> {
        loop {
            match self.step(r)? {
                Some(Event::End { .. }) if until_end => return Ok(()),
                Some(_) => {}
                None if until_end => {
                    return Err(StreamError::Closed {
                        epoch: self.epoch,
                        points: self.points.len(),
                    })
                }
                None => return Ok(()),
            }
        }
    }

    /// The held points as a cloud (colours, frames and lasers included).
    pub fn cloud(&self) -> Cloud {
        Cloud {
            points: self.points.iter().map(|p| p.xyz).collect(),
            colors: Some(self.points.iter().map(|p| p.rgb).collect()),
            frames: Some(self.points.iter().map(|p| p.frame).collect()),
            lasers: Some(self.points.iter().map(|p| p.laser).collect()),
            distances: None,
            depth_sigmas: None,
        }
    }
}

/// The points of a cloud, for sending.
pub fn points_of(cloud: &Cloud, range: std::ops::Range<usize>) -> Vec<Point> {
    range
        .map(|i| Point {
            xyz: cloud.points[i],
            rgb: cloud.colors.as_ref().map_or([255; 3], |c| c[i]),
            laser: cloud.lasers.as_ref().map_or(0, |l| l[i]),
            frame: cloud.frames.as_ref().map_or(0, |f| f[i]),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pt(i: u32) -> Point {
        Point {
            xyz: [i as f32, -(i as f32), 0.5 * i as f32],
            rgb: [i as u8, 2, 3],
            laser: (i % 2) as u8,
            frame: i * 10,
        }
    }

    #[test]
    fn follower_rebuilds_the_cloud_across_epochs() {
        let mut wire = Vec::new();
        wire.extend(hello("{\"width\":4}"));
        wire.extend(epoch(1, EpochReason::First));
        for m in points(1, 7, &[pt(1), pt(2)]) {
            wire.extend(m);
        }
        wire.extend(epoch(2, EpochReason::Reestimate));
        let many: Vec<Point> = (0..70_000).map(pt).collect();
        let msgs = points(2, 9, &many);
        assert_eq!(msgs.len(), 2, "split at the per-message bound");
        assert_eq!(captured_nanos(&msgs[0]), Some(9));
        for m in msgs {
            wire.extend(m);
        }
        wire.extend(end(2, 70_000));
        let mut f = Follower::default();
        f.follow(&mut wire.as_slice(), true).expect("follow");
        assert!(f.ended);
        assert_eq!(f.epoch, 2);
        assert_eq!(f.points, many);
        assert_eq!(f.epochs_by_reason, [1, 1, 0, 0]);
        assert_eq!(f.hello.as_deref(), Some("{\"width\":4}"));
    }

    #[test]
    fn bad_streams_are_named() {
        let mut f = Follower::default();
        let junk = frame(HELLO, b"NOTSTRM!\x01\0\0\0{}");
        assert!(matches!(
            f.step(&mut junk.as_slice()),
            Err(StreamError::NotAStream)
        ));
        let mut v2 = frame(HELLO, b"CRSLSTRM\x02\0\0\0{}");
        assert!(matches!(
            Follower::default().step(&mut v2.as_slice()),
            Err(StreamError::Version(2))
        ));
        v2 = bye("too slow");
        match Follower::default().step(&mut v2.as_slice()) {
            Err(StreamError::Bye(why)) => assert_eq!(why, "too slow"),
            other => panic!("{other:?}"),
        }
        let mut cut = epoch(1, EpochReason::First);
        cut.extend(points(1, 0, &[pt(1)]).remove(0));
        cut.truncate(cut.len() - 3);
        let mut f = Follower::default();
        assert!(f.follow(&mut cut.as_slice(), true).is_err());
        // END that disagrees with what arrived.
        let mut lie = epoch(1, EpochReason::First);
        lie.extend(end(1, 5));
        assert!(Follower::default()
            .follow(&mut lie.as_slice(), true)
            .is_err());
        // Closed before END.
        let open = epoch(1, EpochReason::First);
        assert!(matches!(
            Follower::default().follow(&mut open.as_slice(), true),
            Err(StreamError::Closed { .. })
        ));
    }
}
