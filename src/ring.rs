//! Preallocated frame slots between the capture thread and the workers.
//!
//! The ring owns a fixed number of buffers, allocated once. Two bounded lock-free
//! queues (crossbeam-channel's array flavour) move them around: `free` holds empty
//! slots, `ready` holds filled ones in capture order. The capture side never waits:
//! [`Producer::try_claim`] returns `None` when every slot is still with the workers,
//! and the caller drops that frame and counts it. Workers block on
//! [`Consumer::recv_timeout`]; a slot goes back to `free` when its [`Slot`] is dropped,
//! so a panicking or erroring worker cannot leak capacity. Memory stays
//! `slots × slot_bytes` however long the dive.
//!
//! Ownership of a buffer moves through the queues with the `Slot` value itself, so no
//! two threads can ever see the same buffer and the module needs no `unsafe`.

use std::time::Duration;

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, Sender, TrySendError};

/// Metadata of one captured frame, as the driver reported it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameMeta {
    /// Position of the frame in the pipeline: consecutive over accepted frames, so a
    /// replay with any number of workers numbers frames identically.
    pub index: u64,
    /// The driver's sequence number.
    pub sequence: u32,
    /// The driver's timestamp, nanoseconds.
    pub timestamp_nanos: u64,
    pub flags: u32,
    /// Where in the source the frame came from (the record index of a dump), for
    /// resuming a replay.
    pub source_position: u64,
    /// Monotonic time the capture thread received the frame, nanoseconds since the
    /// daemon started: the start of the latency measurement.
    pub received_nanos: u64,
}

/// One preallocated buffer, with the frame it currently holds.
#[derive(Debug)]
pub struct Slot {
    pub meta: FrameMeta,
    /// Raw bytes as the driver delivered them (`len()` = bytes used).
    pub bytes: Vec<u8>,
    home: Option<Sender<Slot>>,
}

impl Slot {
    /// Replaces the content with `payload`, reusing the allocation when it is large
    /// enough (it always is after the first frames of a stream).
    pub fn fill(&mut self, meta: FrameMeta, payload: &[u8]) {
        self.meta = meta;
        self.bytes.clear();
        self.bytes.extend_from_slice(payload);
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        if let Some(home) = self.home.take() {
            let slot = Slot {
                meta: FrameMeta::default(),
                bytes: std::mem::take(&mut self.bytes),
                home: Some(home.clone()),
            };
            // The free queue has room for every slot, so this only fails when the
            // ring itself is gone; then the buffer is freed (without coming here
            // again: the returned slot has no home).
            if let Err(e) = home.try_send(slot) {
                e.into_inner().home = None;
            }
        }
    }
}

/// Capture side of the ring.
pub struct Producer {
    free: Receiver<Slot>,
    ready: Sender<Slot>,
}

/// Worker side of the ring; clone it for each worker.
#[derive(Clone)]
pub struct Consumer {
    ready: Receiver<Slot>,
}

/// A ring of `slots` buffers of `slot_bytes` capacity each.
pub fn ring(slots: usize, slot_bytes: usize) -> (Producer, Consumer) {
    let slots = slots.max(1);
    let (free_tx, free_rx) = bounded(slots);
    let (ready_tx, ready_rx) = bounded(slots);
    for _ in 0..slots {
        let slot = Slot {
            meta: FrameMeta::default(),
            bytes: Vec::with_capacity(slot_bytes),
            home: Some(free_tx.clone()),
        };
        // Cannot fail: the queue was made with room for exactly these slots.
        let _ = free_tx.try_send(slot);
    }
    (
        Producer {
            free: free_rx,
            ready: ready_tx,
        },
        Consumer { ready: ready_rx },
    )
}

impl Drop for Producer {
    fn drop(&mut self) {
        // Free slots hold senders to their own queue; cut them loose so the buffers
        // are freed with the ring. Slots still with workers are freed when dropped,
        // since the queue's receiver (this producer's) is gone by then.
        while let Ok(mut slot) = self.free.try_recv() {
            slot.home = None;
        }
    }
}

impl Producer {
    /// An empty slot, or `None` when all are in use (the frame must be dropped).
    pub fn try_claim(&self) -> Option<Slot> {
        self.free.try_recv().ok()
    }

    /// An empty slot, waiting up to `timeout` (for lossless replay only: a camera
    /// never waits).
    pub fn claim_timeout(&self, timeout: Duration) -> Option<Slot> {
        self.free.recv_timeout(timeout).ok()
    }

    /// Hands a filled slot to the workers. Never blocks: the ready queue has room for
    /// every slot. Returns the slot back if every worker is gone.
    pub fn publish(&self, slot: Slot) -> Result<(), Slot> {
        match self.ready.try_send(slot) {
            Ok(()) => Ok(()),
            Err(TrySendError::Full(s)) | Err(TrySendError::Disconnected(s)) => Err(s),
        }
    }

    /// Filled slots waiting for a worker.
    pub fn depth(&self) -> usize {
        self.ready.len()
    }
}

/// What a worker got from the ring.
#[derive(Debug)]
pub enum Recv {
    Frame(Slot),
    /// Nothing arrived within the timeout.
    Idle,
    /// The producer is gone and every frame has been taken: time to stop.
    Closed,
}

impl Consumer {
    pub fn recv_timeout(&self, timeout: Duration) -> Recv {
        match self.ready.recv_timeout(timeout) {
            Ok(slot) => Recv::Frame(slot),
            Err(RecvTimeoutError::Timeout) => Recv::Idle,
            Err(RecvTimeoutError::Disconnected) => Recv::Closed,
        }
    }

    pub fn depth(&self) -> usize {
        self.ready.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta(index: u64) -> FrameMeta {
        FrameMeta {
            index,
            ..Default::default()
        }
    }

    #[test]
    fn full_ring_refuses_instead_of_blocking() {
        let (producer, consumer) = ring(2, 16);
        let mut a = producer.try_claim().expect("slot a");
        a.fill(meta(0), b"aa");
        producer.publish(a).expect("publish a");
        let mut b = producer.try_claim().expect("slot b");
        b.fill(meta(1), b"bb");
        producer.publish(b).expect("publish b");
        assert!(producer.try_claim().is_none(), "third claim must fail");
        assert_eq!(producer.depth(), 2);
        // A worker takes one and drops it: the slot is free again.
        match consumer.recv_timeout(Duration::from_millis(10)) {
            Recv::Frame(s) => {
                assert_eq!(s.meta.index, 0);
                assert_eq!(s.bytes, b"aa");
            }
            other => panic!("expected a frame, got {other:?}"),
        }
        assert!(producer.try_claim().is_some());
    }

    #[test]
    fn buffers_are_reused_not_reallocated() {
        let (producer, consumer) = ring(1, 1024);
        let mut s = producer.try_claim().expect("slot");
        let ptr = s.bytes.as_ptr();
        s.fill(meta(0), &[7u8; 1000]);
        producer.publish(s).expect("publish");
        let Recv::Frame(s) = consumer.recv_timeout(Duration::from_millis(10)) else {
            panic!("no frame");
        };
        drop(s);
        let s = producer.try_claim().expect("slot back");
        assert_eq!(s.bytes.as_ptr(), ptr, "the same allocation comes back");
        assert!(s.bytes.is_empty() || s.bytes.len() == 1000);
    }

    #[test]
    fn slots_outliving_the_ring_are_freed() {
        let (producer, consumer) = ring(2, 4);
        let mut s = producer.try_claim().expect("slot");
        s.fill(meta(1), b"x");
        producer.publish(s).expect("publish");
        drop(producer);
        let Recv::Frame(s) = consumer.recv_timeout(Duration::from_millis(10)) else {
            panic!("no frame");
        };
        drop(consumer);
        drop(s); // must not recurse or panic
    }

    #[test]
    fn closed_after_producer_goes_and_queue_drains() {
        let (producer, consumer) = ring(2, 4);
        let mut s = producer.try_claim().expect("slot");
        s.fill(meta(5), b"x");
        producer.publish(s).expect("publish");
        drop(producer);
        assert!(matches!(
            consumer.recv_timeout(Duration::from_millis(10)),
            Recv::Frame(_)
        ));
        assert!(matches!(
            consumer.recv_timeout(Duration::from_millis(10)),
            Recv::Closed
        ));
    }

    #[test]
    fn many_workers_see_every_frame_once() {
        let (producer, consumer) = ring(4, 8);
        let seen = std::sync::Mutex::new(Vec::new());
        let mut dropped = 0u64;
        std::thread::scope(|s| {
            for _ in 0..3 {
                let c = consumer.clone();
                let seen = &seen;
                s.spawn(move || loop {
                    match c.recv_timeout(Duration::from_millis(50)) {
                        Recv::Frame(slot) => seen.lock().expect("lock").push(slot.meta.index),
                        Recv::Idle => {}
                        Recv::Closed => break,
                    }
                });
            }
            drop(consumer);
            for i in 0..2000u64 {
                match producer.try_claim() {
                    Some(mut slot) => {
                        slot.fill(meta(i), &i.to_le_bytes());
                        producer.publish(slot).expect("publish");
                    }
                    None => dropped += 1,
                }
            }
            drop(producer);
        });
        let mut seen = seen.into_inner().expect("lock");
        assert_eq!(seen.len() as u64 + dropped, 2000);
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(
            seen.len() as u64 + dropped,
            2000,
            "no frame delivered twice"
        );
    }
}
