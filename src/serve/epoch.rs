//! One live epoch, made on a thread of its own (`solver-epoch`) from a snapshot of the
//! scan ([`crate::pipeline::Record`]): the estimator's evidence, its solve (the two cold
//! starts and the last epoch's planes), the triangulation of every plane it determines and the offline
//! checks on them. The solver thread only hands the snapshot over and, later, sends the
//! points: building the evidence and triangulating an epoch of millions of points took
//! it up to 1.7 s at a time, while the workers' queue to it and then the capture ring
//! filled and frames were dropped.

use std::sync::Arc;

use crossbeam_channel::{bounded, Receiver};
use image::RgbImage;
use nalgebra::Vector3;

use crate::camera::Camera;
use crate::cloud::{self, ScaleMode};
use crate::config::Config;
use crate::pipeline::{self, Placing, Record};
use crate::solve::{self, Calibration, SolveError};

use super::stream::{self, Point};

/// The estimate an epoch is built on.
pub(super) struct Estimate {
    pub calibration: Calibration,
    /// Per plane of the scan when it was made, its index in the calibration's evidence.
    pub plane_index: Vec<Option<u32>>,
    /// Frames in the scan when it was made: the later ones are placed against it.
    pub frames: usize,
    pub placing: Placing,
    /// The scale factor of its cloud, which the frames placed against it share.
    pub factor: f64,
}

impl Estimate {
    /// The plane of the scan's plane `i` (`v · r = 1/Z`), where this estimate determines it.
    pub fn scan_plane(&self, i: usize) -> Option<Vector3<f64>> {
        let k = (*self.plane_index.get(i)?)?;
        self.calibration.plane(k as usize)
    }
}

/// An epoch ready to adopt: its estimate and its scaled cloud.
pub(super) struct Answer {
    pub estimate: Arc<Estimate>,
    pub points: Vec<Point>,
    pub planes_with_points: usize,
}

/// Why an epoch's answer is not adopted.
#[derive(Debug, thiserror::Error)]
pub(super) enum NotAdopted {
    #[error("global solve not possible yet: {0}")]
    Solve(#[from] SolveError),
    /// The offline pipeline's checks refused its planes ([`pipeline::refusal`]).
    #[error("epoch not adopted: {0}")]
    Refused(String),
}

/// What an epoch is made of, besides the snapshot.
pub(super) struct Job {
    pub record: Record,
    pub camera: Camera,
    pub config: Config,
    pub scale: ScaleMode,
    pub colour: Option<Arc<RgbImage>>,
    /// The last epoch's estimate, to start from where it has the planes.
    pub warm: Option<Arc<Estimate>>,
}

/// Starts `job` on the `solver-epoch` thread; its answer arrives on the receiver.
/// `cancel` stops it (between the solve's iterations, and before the triangulation).
pub(super) fn start(
    job: Job,
    cancel: solve::Cancel,
) -> std::io::Result<Receiver<Result<Answer, NotAdopted>>> {
    let (tx, rx) = bounded(1);
    std::thread::Builder::new()
        .name("solver-epoch".into())
        .stack_size(super::WORKER_STACK_BYTES)
        .spawn(move || {
            let run = || make(job, &cancel);
            let answer = match epoch_pool() {
                Ok(pool) => pool.install(run),
                Err(e) => {
                    tracing::warn!("no thread pool for the epoch ({e}): running it here");
                    run()
                }
            };
            if matches!(answer, Err(NotAdopted::Solve(SolveError::Cancelled))) {
                tracing::debug!("an epoch stopped: superseded");
            }
            let _ = tx.send(answer);
        })?;
    Ok(rx)
}

/// The epoch of `job` (see the module docs).
fn make(job: Job, cancel: &solve::Cancel) -> Result<Answer, NotAdopted> {
    let Job {
        record,
        camera,
        config,
        scale,
        colour,
        warm,
    } = job;
    let (evidence, plane_index) = record.solve_input(&camera, &config);
    // Warm start: the last epoch's planes where it has them.
    let warm: Option<Vec<Option<Vector3<f64>>>> = warm.map(|e| {
        let mut start = vec![None; evidence.planes.len()];
        for (i, k) in plane_index.iter().enumerate() {
            if let Some(k) = k {
                start[*k as usize] = e.scan_plane(i);
            }
        }
        start
    });
    let calibration = solve::calibrate_until(&evidence, &config.solve, warm.as_deref(), cancel)?;
    drop(evidence);
    cancel.check()?;
    tracing::debug!(alternatives = ?calibration.summary.alternatives, planes = plane_index.len(), "an epoch's solve");
    let (out, fit) = record.epoch_cloud(
        &calibration,
        &plane_index,
        &camera,
        &config,
        colour.as_deref(),
    );
    // The offline pipeline's checks: planes that most curves contradict, or that fit the
    // crossings far worse than the curves place them, give no cloud, and no epoch.
    if let Some(reason) = pipeline::refusal(&out.stats, fit) {
        return Err(NotAdopted::Refused(reason));
    }
    let factor = cloud::scale_for(&scale, &out.cloud, &out.pixels).unwrap_or(1.0);
    let mut points = out.cloud;
    cloud::apply_scale(&mut points, factor);
    Ok(Answer {
        estimate: Arc::new(Estimate {
            placing: Placing::new(&calibration, &config),
            calibration,
            plane_index,
            frames: record.frames(),
            factor,
        }),
        points: stream::points_of(&points, 0..points.len()),
        planes_with_points: out.planes_with_points,
    })
}

/// The epoch runs on a one-thread pool of its own: its parallel parts (the centre
/// search, the poses fitted against the anchors, the triangulation) would otherwise take
/// the global pool's threads beside its own, and with them the extraction workers'
/// cores. It keeps the normal priority: at nice 19 (tried) a loaded machine starved it,
/// and the unit tests' epochs never came while frames were fed. The final solve
/// ([`super::incremental::Incremental::finish`]) runs after the last frame and keeps
/// every core.
fn epoch_pool() -> Result<rayon::ThreadPool, rayon::ThreadPoolBuildError> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .thread_name(|_| "solver-epoch-pool".into())
        .stack_size(super::WORKER_STACK_BYTES)
        .build()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An epoch (and anything it runs in parallel) stays on one thread.
    #[test]
    fn the_epoch_pool_is_one_named_thread() {
        let pool = epoch_pool().expect("pool");
        let (threads, name) = pool.install(|| {
            (
                rayon::current_num_threads(),
                std::thread::current().name().map(str::to_owned),
            )
        });
        assert_eq!(threads, 1);
        assert_eq!(name.as_deref(), Some("solver-epoch-pool"));
    }
}
