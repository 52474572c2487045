//! Choice of the well-connected subset of curves for the global solve.

use crate::intersect::Crossing;
use std::collections::BinaryHeap;

/// The curves of the global solve and the crossings among them.
#[derive(Clone, Debug, Default)]
pub struct Subset {
    /// Curve ids, ascending; local index = position.
    pub curves: Vec<u32>,
    /// Per curve id, its local index, or `None` outside the subset.
    pub local: Vec<Option<usize>>,
    /// Indices into the problem's crossings whose both curves are in the subset.
    pub crossings: Vec<usize>,
}

impl Subset {
    /// Builds the index maps of a set of curve ids over the active crossings.
    pub fn from_curves(
        num_curves: usize,
        mut curves: Vec<u32>,
        crossings: &[Crossing],
        active: &[bool],
    ) -> Self {
        curves.sort_unstable();
        curves.dedup();
        let mut local = vec![None; num_curves];
        for (k, &c) in curves.iter().enumerate() {
            local[c as usize] = Some(k);
        }
        let crossings = (0..crossings.len())
            .filter(|&k| {
                active[k]
                    && local[crossings[k].a as usize].is_some()
                    && local[crossings[k].b as usize].is_some()
            })
            .collect();
        Self {
            curves,
            local,
            crossings,
        }
    }
}

/// What a global subset must satisfy.
#[derive(Clone, Copy, Debug)]
pub struct SubsetLimits {
    pub max_planes: usize,
    /// Least number of crossings with other curves of the subset.
    pub min_crossings: usize,
    /// Least [`bend`] of a curve's crossings inside the subset.
    pub min_bend: f64,
}

/// Adjacency lists: per curve, `(other curve, crossing index)` over active crossings.
pub fn adjacency(
    num_curves: usize,
    crossings: &[Crossing],
    active: &[bool],
) -> Vec<Vec<(u32, usize)>> {
    let mut adj = vec![Vec::new(); num_curves];
    for (k, c) in crossings.iter().enumerate() {
        if active[k] && c.a != c.b && (c.a as usize) < num_curves && (c.b as usize) < num_curves {
            adj[c.a as usize].push((c.b, k));
            adj[c.b as usize].push((c.a, k));
        }
    }
    adj
}

/// Greedy choice of at most `max_planes` curves (among those whose crossings are off
/// one line by at least `min_bend`, see [`bend`]), grown from the cross with the most
/// crossings by always adding the cross (a curve and its partner, or a lone curve)
/// with the most crossings into the chosen set, which keeps the set connected. Then
/// pruned to its `min_crossings`-core (every curve with at least `min_crossings`
/// crossings with other chosen curves, removed iteratively) and to the largest
/// connected component of what remains.
pub fn select_global(
    num_curves: usize,
    crossings: &[Crossing],
    active: &[bool],
    partner: &[Option<u32>],
    excluded: &[bool],
    limits: &SubsetLimits,
) -> Subset {
    let SubsetLimits {
        max_planes,
        min_crossings,
        min_bend,
    } = *limits;
    let adj = adjacency(num_curves, crossings, active);
    let bent: Vec<bool> = (0..num_curves)
        .map(|c| bend(adj[c].iter().map(|&(_, k)| crossings[k].u)) >= min_bend)
        .collect();
    let usable = |c: usize| !excluded[c] && !adj[c].is_empty() && bent[c];
    // The unit of choice is the cross, represented by its smaller curve id.
    let unit_of = |c: usize| -> usize {
        match partner.get(c).copied().flatten() {
            Some(p) if (p as usize) < num_curves && usable(p as usize) => c.min(p as usize),
            _ => c,
        }
    };
    let members = |u: usize| -> Vec<usize> {
        let mut m = vec![u];
        if let Some(Some(p)) = partner.get(u) {
            let p = *p as usize;
            if p != u && p < num_curves && usable(p) && unit_of(p) == u {
                m.push(p);
            }
        }
        m
    };
    let mut chosen = vec![false; num_curves];
    let mut score = vec![0usize; num_curves];
    // Start in the largest connected component, at its best-connected cross.
    let component = components(num_curves, &adj, usable);
    let mut size = vec![0usize; num_curves];
    for c in (0..num_curves).filter(|&c| usable(c)) {
        size[component[c]] += 1;
    }
    let Some(start) = (0..num_curves).filter(|&c| usable(c)).max_by_key(|&c| {
        let crossings: usize = members(unit_of(c)).iter().map(|&m| adj[m].len()).sum();
        (size[component[c]], crossings, c)
    }) else {
        return Subset::from_curves(num_curves, Vec::new(), crossings, active);
    };
    let mut heap = BinaryHeap::new();
    heap.push((usize::MAX, unit_of(start)));
    let mut count = 0;
    while let Some((s, u)) = heap.pop() {
        if count >= max_planes {
            break;
        }
        let m = members(u);
        if m.iter().any(|&c| chosen[c]) || (s != usize::MAX && s != score[u]) {
            continue;
        }
        if count + m.len() > max_planes && count > 0 {
            continue;
        }
        for &c in &m {
            chosen[c] = true;
            count += 1;
        }
        for &c in &m {
            for &(o, _) in &adj[c] {
                let o = o as usize;
                if !chosen[o] && usable(o) {
                    let uo = unit_of(o);
                    score[uo] += 1;
                    heap.push((score[uo], uo));
                }
            }
        }
    }
    prune(
        num_curves,
        &adj,
        chosen,
        min_crossings,
        min_bend,
        crossings,
        active,
    )
}

/// The `min_crossings`-core of `chosen` without curves whose crossings inside it lie on
/// one line (within `min_bend`), restricted to its largest connected component.
pub fn prune(
    num_curves: usize,
    adj: &[Vec<(u32, usize)>],
    mut chosen: Vec<bool>,
    min_crossings: usize,
    min_bend: f64,
    crossings: &[Crossing],
    active: &[bool],
) -> Subset {
    loop {
        core(num_curves, adj, &mut chosen, min_crossings);
        // Crossings on one image line leave a plane free to turn about its 3D line.
        let flat: Vec<usize> = (0..num_curves)
            .filter(|&c| {
                chosen[c]
                    && bend(
                        adj[c]
                            .iter()
                            .filter(|(o, _)| chosen[*o as usize])
                            .map(|&(_, k)| crossings[k].u),
                    ) < min_bend
            })
            .collect();
        if flat.is_empty() {
            break;
        }
        for c in flat {
            chosen[c] = false;
        }
    }
    let comp = components(num_curves, adj, |c| chosen[c]);
    let mut size = vec![0usize; num_curves];
    for c in (0..num_curves).filter(|&c| chosen[c]) {
        size[comp[c]] += 1;
    }
    let best = (0..num_curves)
        .filter(|&c| chosen[c])
        .max_by_key(|&c| (size[comp[c]], c));
    let curves = match best {
        Some(b) => (0..num_curves)
            .filter(|&c| chosen[c] && comp[c] == comp[b])
            .map(|c| c as u32)
            .collect(),
        None => Vec::new(),
    };
    Subset::from_curves(num_curves, curves, crossings, active)
}

/// Root-free component labels (the smallest member's id) of the curves with `keep`.
pub fn components(
    num_curves: usize,
    adj: &[Vec<(u32, usize)>],
    keep: impl Fn(usize) -> bool,
) -> Vec<usize> {
    let mut comp = vec![usize::MAX; num_curves];
    let mut queue = Vec::new();
    for s in 0..num_curves {
        if !keep(s) || comp[s] != usize::MAX {
            continue;
        }
        comp[s] = s;
        queue.clear();
        queue.push(s);
        while let Some(c) = queue.pop() {
            for &(o, _) in &adj[c] {
                let o = o as usize;
                if keep(o) && comp[o] == usize::MAX {
                    comp[o] = s;
                    queue.push(o);
                }
            }
        }
    }
    comp
}

/// How far image points are from lying on one line, robustly: `sqrt(l_min / m)`,
/// `l_min` the smallest eigenvalue of `Σ ũ ũᵀ` over the `m` points, `ũ = u / |u|`
/// (about the RMS distance, in normalised units, of the points from their best line),
/// after leaving out the point farthest from that line. A plane is held against turning
/// about its 3D line only by its off-line crossings; leaving one out means a single
/// wrong crossing can never be the only one that holds it. Zero for fewer than four
/// points.
pub fn bend(points: impl Iterator<Item = [f64; 2]>) -> f64 {
    let rays: Vec<nalgebra::Vector3<f64>> = points
        .map(|p| nalgebra::Vector3::new(p[0], p[1], 1.0).normalize())
        .collect();
    if rays.len() < 4 {
        return 0.0;
    }
    let smallest = |skip: Option<usize>| {
        let mut m = nalgebra::Matrix3::zeros();
        for (i, u) in rays.iter().enumerate() {
            if Some(i) != skip {
                m += u * u.transpose();
            }
        }
        let e = nalgebra::SymmetricEigen::new(m);
        let k = e.eigenvalues.imin();
        (
            e.eigenvalues[k].max(0.0),
            e.eigenvectors.column(k).into_owned(),
        )
    };
    let (_, normal) = smallest(None);
    let far = (0..rays.len()).max_by(|&a, &b| {
        rays[a]
            .dot(&normal)
            .abs()
            .total_cmp(&rays[b].dot(&normal).abs())
    });
    let (l, _) = smallest(far);
    (l / (rays.len() - 1) as f64).sqrt()
}

/// Removes, iteratively, chosen curves with fewer than `min_crossings` chosen neighbours.
fn core(num_curves: usize, adj: &[Vec<(u32, usize)>], chosen: &mut [bool], min_crossings: usize) {
    let mut degree: Vec<usize> = (0..num_curves)
        .map(|c| {
            if chosen[c] {
                adj[c].iter().filter(|(o, _)| chosen[*o as usize]).count()
            } else {
                0
            }
        })
        .collect();
    let mut stack: Vec<usize> = (0..num_curves)
        .filter(|&c| chosen[c] && degree[c] < min_crossings)
        .collect();
    while let Some(c) = stack.pop() {
        if !chosen[c] {
            continue;
        }
        chosen[c] = false;
        for &(o, _) in &adj[c] {
            let o = o as usize;
            if chosen[o] {
                degree[o] -= 1;
                if degree[o] < min_crossings {
                    stack.push(o);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn x(a: u32, b: u32) -> Crossing {
        Crossing {
            a,
            b,
            u: [0.0, 0.0],
            sin_angle: 1.0,
        }
    }

    #[test]
    fn the_larger_of_two_disconnected_groups_is_kept() {
        // Group A: curves 0..5 all crossing each other; group B: 5..8 likewise.
        let mut cr = Vec::new();
        for i in 0..5 {
            for j in i + 1..5 {
                cr.push(x(i, j));
            }
        }
        for i in 5..8 {
            for j in i + 1..8 {
                cr.push(x(i, j));
                cr.push(x(i, j));
            }
        }
        let active = vec![true; cr.len()];
        let partner = vec![None; 8];
        let s = select_global(
            8,
            &cr,
            &active,
            &partner,
            &[false; 8],
            &SubsetLimits {
                max_planes: 100,
                min_crossings: 3,
                min_bend: 0.0,
            },
        );
        assert_eq!(s.curves, vec![0, 1, 2, 3, 4]);
        assert_eq!(s.crossings.len(), 10);
        // A curve with only two crossings inside the set is pruned.
        cr.push(x(4, 9));
        cr.push(x(3, 9));
        let active = vec![true; cr.len()];
        let s = select_global(
            10,
            &cr,
            &active,
            &[None; 10],
            &[false; 10],
            &SubsetLimits {
                max_planes: 100,
                min_crossings: 3,
                min_bend: 0.0,
            },
        );
        assert!(!s.curves.contains(&9));
    }

    #[test]
    fn budget_is_respected_and_partners_come_in_pairs() {
        let mut cr = Vec::new();
        for i in 0..20 {
            for j in i + 1..20 {
                cr.push(x(i, j));
            }
        }
        let active = vec![true; cr.len()];
        let partner: Vec<Option<u32>> = (0..20).map(|i| Some(i ^ 1)).collect();
        let s = select_global(
            20,
            &cr,
            &active,
            &partner,
            &[false; 20],
            &SubsetLimits {
                max_planes: 10,
                min_crossings: 3,
                min_bend: 0.0,
            },
        );
        assert_eq!(s.curves.len(), 10);
        for &c in &s.curves {
            assert!(s.curves.contains(&(c ^ 1)), "partner of {c} missing");
        }
    }

    #[test]
    fn bend_needs_two_points_off_the_line() {
        let line: Vec<[f64; 2]> = (0..10)
            .map(|k| [-0.4 + 0.08 * k as f64, 0.1 + 0.03 * k as f64])
            .collect();
        assert!(bend(line.iter().copied()) < 1e-6);
        // One point 0.1 off the line: left out, so still no bend.
        let mut one = line.clone();
        one.push([0.0, 0.35]);
        assert!(bend(one.iter().copied()) < 1e-6);
        // Two points off it: a bend of the order of their distance / sqrt(m).
        let mut two = one.clone();
        two.push([0.2, 0.1]);
        let b = bend(two.iter().copied());
        assert!(b > 0.01 && b < 0.1, "bend {b}");
    }
}
