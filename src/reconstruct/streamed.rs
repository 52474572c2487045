//! A video file through [`super::reconstruct_files`]: frames decoded in order by one
//! FFmpeg child per pass, a few frames ahead of the rayon workers, where files and
//! dumps are decoded at random in parallel. Owns nothing else.

use image::RgbImage;
use rayon::prelude::*;

use super::ReconstructError;
use crate::camera::Camera;
use crate::capture::video::{VideoFile, VideoReader};

/// One pass over a video: successive [`VideoPass::map_frames`] calls go on where the
/// last one stopped, so a recording taken block by block is decoded once.
pub(super) struct VideoPass<'a> {
    file: &'a VideoFile,
    reader: VideoReader,
    ended: bool,
}

impl<'a> VideoPass<'a> {
    pub(super) fn new(file: &'a VideoFile, camera: &Camera) -> Result<Self, ReconstructError> {
        check_video_size(file, camera)?;
        Ok(Self {
            file,
            reader: file.reader()?,
            ended: false,
        })
    }

    /// `f(state, i, frame i)` for every `i` of `wanted` (ascending, after any frame of
    /// an earlier call), the results in order, shorter than `wanted` when the file ends
    /// early (cut off).
    pub(super) fn map_frames<S: Send, T: Send>(
        &mut self,
        wanted: &[usize],
        init: impl Fn() -> S + Sync + Send,
        f: impl Fn(&mut S, usize, Result<RgbImage, ReconstructError>) -> Result<T, ReconstructError>
            + Sync
            + Send,
    ) -> Result<Vec<T>, ReconstructError> {
        let states = std::sync::Mutex::new(Vec::<S>::new());
        let take = || states.lock().unwrap_or_else(|e| e.into_inner()).pop();
        let batch_len = 2 * rayon::current_num_threads().max(1);
        let (mut out, mut next) = (Vec::with_capacity(wanted.len()), wanted.iter().peekable());
        loop {
            let mut batch = Vec::with_capacity(batch_len);
            while batch.len() < batch_len && !self.ended {
                let Some(&&i) = next.peek() else { break };
                let Some(frame) = self.reader.next_frame()? else {
                    self.ended = true;
                    break;
                };
                if frame.position == i {
                    batch.push((i, video_image(self.file, frame.rgb)));
                    next.next();
                }
            }
            if batch.is_empty() {
                return Ok(out);
            }
            let results = batch
                .into_par_iter()
                .map(|(i, image)| {
                    let mut state = take().unwrap_or_else(&init);
                    let result = f(&mut state, i, image);
                    states.lock().unwrap_or_else(|e| e.into_inner()).push(state);
                    result
                })
                .collect::<Result<Vec<T>, _>>()?;
            out.extend(results);
        }
    }
}

pub(super) fn check_video_size(file: &VideoFile, camera: &Camera) -> Result<(), ReconstructError> {
    if (file.width, file.height) != (camera.width, camera.height) {
        return Err(ReconstructError::VideoSize {
            path: file.path.clone(),
            got_w: file.width,
            got_h: file.height,
            want_w: camera.width,
            want_h: camera.height,
        });
    }
    Ok(())
}

pub(super) fn video_image(file: &VideoFile, rgb: Vec<u8>) -> Result<RgbImage, ReconstructError> {
    RgbImage::from_raw(file.width, file.height, rgb).ok_or(ReconstructError::Internal(
        "a decoded video frame of the wrong size",
    ))
}
