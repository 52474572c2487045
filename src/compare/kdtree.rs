//! A static 3D k-d tree for exact nearest-neighbour queries over `f32` points.
//!
//! The tree is implicit: the points are permuted so that every node is a range
//! `lo..hi` of the array whose middle element `mid = lo + (hi - lo) / 2` is the
//! splitting point, with smaller coordinates on the left along the node's axis (the axis
//! of largest extent, stored at `axes[mid]`). Ranges of at most `LEAF` (8) points are
//! searched by brute force. No pointers, no per-node allocation; building is
//! `O(n log n)` with `select_nth_unstable`, and large subtrees are built in parallel.
//!
//! Nodes of more than `BOXED` (32) points also keep the tight bounding box of their points,
//! indexed in heap order (root 1, children `2i`, `2i + 1`): a cell's splitting planes
//! alone say nothing about the empty space at the edge of the data, and queries far
//! from the reference (outliers, parts the reference lacks) would otherwise visit
//! thousands of points. The boxes cost about 2.4 bytes per point.

/// Ranges at most this long are leaves.
const LEAF: usize = 8;

/// Nodes with more points than this keep a bounding box.
const BOXED: usize = 32;

/// Depth of the explicit query stack; a balanced tree over `u32` indices needs < 40.
const STACK: usize = 64;

/// Subtrees larger than this are built on two rayon tasks.
const PARALLEL_BUILD: usize = 1 << 15;

/// The nearest reference point of a query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest {
    /// Index of the point in the slice the tree was built from.
    pub index: usize,
    /// Its coordinates.
    pub point: [f32; 3],
    /// Squared Euclidean distance.
    pub distance_sq: f32,
}

#[derive(Clone, Debug)]
pub struct KdTree {
    points: Vec<[f32; 3]>,
    /// Original index of each permuted point.
    indices: Vec<u32>,
    /// Split axis of the node whose middle element is at this position (unused in leaves).
    axes: Vec<u8>,
    /// `[min x, min y, min z, max x, max y, max z]` of the nodes of more than [`BOXED`]
    /// points, by heap index.
    boxes: Vec<[f32; 6]>,
}

impl KdTree {
    /// Builds the tree; `None` for more than `u32::MAX` points. Non-finite points are
    /// kept but never returned closer than a finite one.
    pub fn new(points: &[[f32; 3]]) -> Option<Self> {
        let n = points.len();
        if n > u32::MAX as usize {
            return None;
        }
        let mut items: Vec<([f32; 3], u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (*p, i as u32))
            .collect();
        let mut axes = vec![0u8; n];
        build(&mut items, &mut axes);
        let (points, indices): (Vec<_>, Vec<_>) = items.into_iter().unzip();
        let mut boxes = Vec::new();
        if n > BOXED {
            boxes_of(&points, 0, n, 1, &mut boxes);
        }
        Some(Self {
            points,
            indices,
            axes,
            boxes,
        })
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The exact nearest point to `query`; `None` on an empty tree.
    pub fn nearest(&self, query: [f32; 3]) -> Option<Nearest> {
        let n = self.points.len();
        if n == 0 {
            return None;
        }
        let mut best = f32::INFINITY;
        let mut best_at = 0usize;
        // Arya & Mount's incremental distance: each pending range carries the offsets of
        // the query from its cell along each axis and their squared sum, a lower bound
        // on the distance to anything in the range that is much tighter than the
        // distance to the last splitting plane alone.
        let mut stack = [Pending::default(); STACK];
        stack[0] = Pending {
            lo: 0,
            hi: n,
            id: 1,
            bound: 0.0,
            offset: [0.0; 3],
        };
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let Pending {
                lo,
                hi,
                id,
                mut bound,
                offset,
            } = stack[top];
            if bound > best {
                continue;
            }
            if let Some(b) = self.boxes.get(id) {
                bound = bound.max(box_dist_sq(b, &query));
                if bound > best {
                    continue;
                }
            }
            if hi - lo <= LEAF {
                for i in lo..hi {
                    let d = dist_sq(&self.points[i], &query);
                    if d < best {
                        best = d;
                        best_at = i;
                    }
                }
                continue;
            }
            let mid = lo + (hi - lo) / 2;
            let p = &self.points[mid];
            let d = dist_sq(p, &query);
            if d < best {
                best = d;
                best_at = mid;
            }
            let axis = self.axes[mid] as usize;
            let diff = query[axis] - p[axis];
            let (near, far) = if diff < 0.0 {
                ((lo, mid, 2 * id), (mid + 1, hi, 2 * id + 1))
            } else {
                ((mid + 1, hi, 2 * id + 1), (lo, mid, 2 * id))
            };
            let far_bound = bound - offset[axis] * offset[axis] + diff * diff;
            // Far first, so the near side is popped next. The stack cannot overflow: a
            // balanced tree over at most u32::MAX points is < 33 levels deep and each
            // level leaves at most one far range pending.
            if far.1 > far.0 && far_bound <= best && top < STACK {
                let mut far_offset = offset;
                far_offset[axis] = diff;
                stack[top] = Pending {
                    lo: far.0,
                    hi: far.1,
                    id: far.2,
                    bound: far_bound,
                    offset: far_offset,
                };
                top += 1;
            }
            if near.1 > near.0 && top < STACK {
                stack[top] = Pending {
                    lo: near.0,
                    hi: near.1,
                    id: near.2,
                    bound,
                    offset,
                };
                top += 1;
            }
        }
        // With only non-finite points or a non-finite query, `best` stays infinite and
        // the first stored point is reported.
        Some(Nearest {
            index: self.indices[best_at] as usize,
            point: self.points[best_at],
            distance_sq: best,
        })
    }
}

#[derive(Clone, Copy, Default)]
struct Pending {
    lo: usize,
    hi: usize,
    /// Heap index of the node.
    id: usize,
    bound: f32,
    offset: [f32; 3],
}

/// Squared distance from `q` to the box (0 inside).
#[inline]
fn box_dist_sq(b: &[f32; 6], q: &[f32; 3]) -> f32 {
    let mut d = 0.0;
    for k in 0..3 {
        let e = (b[k] - q[k]).max(q[k] - b[k + 3]).max(0.0);
        d += e * e;
    }
    d
}

/// Fills `boxes[id]` for the node `lo..hi` and its boxed descendants; returns its box.
fn boxes_of(
    points: &[[f32; 3]],
    lo: usize,
    hi: usize,
    id: usize,
    boxes: &mut Vec<[f32; 6]>,
) -> [f32; 6] {
    let mut b = [
        f32::INFINITY,
        f32::INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NEG_INFINITY,
        f32::NEG_INFINITY,
    ];
    let add = |b: &mut [f32; 6], p: &[f32; 3]| {
        for k in 0..3 {
            b[k] = b[k].min(p[k]);
            b[k + 3] = b[k + 3].max(p[k]);
        }
    };
    if hi - lo <= BOXED {
        for p in &points[lo..hi] {
            add(&mut b, p);
        }
        return b;
    }
    let mid = lo + (hi - lo) / 2;
    let l = boxes_of(points, lo, mid, 2 * id, boxes);
    let r = boxes_of(points, mid + 1, hi, 2 * id + 1, boxes);
    for k in 0..3 {
        b[k] = l[k].min(r[k]);
        b[k + 3] = l[k + 3].max(r[k + 3]);
    }
    add(&mut b, &points[mid]);
    if boxes.len() <= id {
        // Unboxed slots are infinite boxes: never pruned by them.
        boxes.resize(
            id + 1,
            [
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
                f32::INFINITY,
                f32::INFINITY,
                f32::INFINITY,
            ],
        );
    }
    boxes[id] = b;
    b
}

#[inline]
fn dist_sq(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    let dx = a[0] - b[0];
    let dy = a[1] - b[1];
    let dz = a[2] - b[2];
    dx * dx + dy * dy + dz * dz
}

fn build(items: &mut [([f32; 3], u32)], axes: &mut [u8]) {
    let n = items.len();
    if n <= LEAF {
        return;
    }
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for (p, _) in items.iter() {
        for k in 0..3 {
            // min/max ignore NaN, so a NaN point cannot poison the extent.
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let extent = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    let mut axis = 0;
    for k in 1..3 {
        if extent[k] > extent[axis] {
            axis = k;
        }
    }
    let mid = n / 2;
    items.select_nth_unstable_by(mid, |a, b| a.0[axis].total_cmp(&b.0[axis]));
    axes[mid] = axis as u8;
    let (left, rest) = items.split_at_mut(mid);
    let right = &mut rest[1..];
    let (axes_left, axes_rest) = axes.split_at_mut(mid);
    let axes_right = &mut axes_rest[1..];
    if n > PARALLEL_BUILD {
        rayon::join(|| build(left, axes_left), || build(right, axes_right));
    } else {
        build(left, axes_left);
        build(right, axes_right);
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// SplitMix64: a tiny deterministic generator for tests and benches.
    pub(crate) struct Rng(pub u64);

    impl Rng {
        pub(crate) fn next_u64(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }

        /// Uniform in [0, 1).
        pub(crate) fn uniform(&mut self) -> f64 {
            (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
        }

        /// Standard normal (Box–Muller).
        pub(crate) fn normal(&mut self) -> f64 {
            let u = self.uniform().max(1e-300);
            let v = self.uniform();
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        }
    }

    fn brute(points: &[[f32; 3]], q: [f32; 3]) -> f32 {
        points
            .iter()
            .map(|p| dist_sq(p, &q))
            .fold(f32::INFINITY, f32::min)
    }

    #[test]
    fn nearest_equals_brute_force_over_seeds_and_shapes() {
        for seed in 0..12u64 {
            let mut rng = Rng(seed);
            let n = [0, 1, 5, 9, 100, 3000][seed as usize % 6];
            // Clustered, flat and duplicated points stress ties and degenerate extents.
            let points: Vec<[f32; 3]> = (0..n)
                .map(|i| {
                    let flat = seed % 3 == 0;
                    let c = if i % 7 == 0 { 0.0 } else { 1.0 };
                    [
                        (rng.uniform() * 10.0 * c) as f32,
                        (rng.normal() * c) as f32,
                        if flat {
                            2.0
                        } else {
                            (rng.uniform() * 0.1) as f32
                        },
                    ]
                })
                .collect();
            let tree = KdTree::new(&points).expect("tree");
            assert_eq!(tree.len(), n);
            for _ in 0..300 {
                let q = [
                    (rng.uniform() * 12.0 - 1.0) as f32,
                    (rng.normal() * 1.5) as f32,
                    (rng.uniform() * 3.0 - 0.5) as f32,
                ];
                match tree.nearest(q) {
                    None => assert_eq!(n, 0),
                    Some(nn) => {
                        assert_eq!(nn.distance_sq, brute(&points, q), "seed {seed}");
                        assert_eq!(dist_sq(&points[nn.index], &q), nn.distance_sq);
                        assert_eq!(points[nn.index], nn.point);
                    }
                }
            }
        }
    }

    #[test]
    fn query_on_a_point_returns_it() {
        let points: Vec<[f32; 3]> = (0..1000)
            .map(|i| {
                [
                    (i % 10) as f32,
                    (i / 10 % 10) as f32,
                    (i / 100) as f32 * 0.5,
                ]
            })
            .collect();
        let tree = KdTree::new(&points).expect("tree");
        for (i, p) in points.iter().enumerate() {
            let nn = tree.nearest(*p).expect("non-empty");
            assert_eq!(nn.distance_sq, 0.0);
            assert_eq!(nn.index, i);
        }
    }
}
