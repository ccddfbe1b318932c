//! A ray-casting scene over triangles that holds on any real mesh: obvhs 0.4's compressed wide
//! BVH (CWBVH), built so that its two assumptions hold.
//!
//! - **Depth.** obvhs's CWBVH traversal keeps a fixed 32-entry stack (its
//!   `TRAVERSAL_STACK_SIZE`); a deeper tree overwrites the stack's top in release builds (rays
//!   then miss triangles they hit) and fails the crate's debug-only `validate()`. Its PLOC builder
//!   bounds nothing: Sweet Home 3D's cartoon biplane (many thin nested triangles) gave a CWBVH
//!   deeper than 32. [`build`] builds with PLOC and reinsertion as obvhs's own
//!   `build_cwbvh_from_tris` does ("medium" parameters), measures the CWBVH's depth, and when it
//!   is 32 or more rebuilds the binary tree top-down with [`balanced_bvh2`], whose depth is at
//!   most 31 by construction (a CWBVH is never deeper than the binary tree it is collapsed from).
//! - **Scale.** The CWBVH stores child boxes quantised to 8 bits against a power-of-two scale per
//!   node, and `validate()` checks them against the exact boxes with an *absolute* tolerance of
//!   10⁻⁵; on a model in millimetres (the Khronos 2CylinderEngine, coordinates in the hundreds)
//!   float rounding alone is 1.5·10⁻⁵. [`RayScene`] therefore builds over the triangles moved and
//!   scaled into the box [−1, 1]³ (its longest side) and moves the rays' origins the same way;
//!   directions are unchanged (a uniform scale), so hits and misses are the same.
//!
//! In debug builds the tree is validated here (obvhs's `validate()`, on the scaled triangles).
//! Cost: O(T log T) build; the fallback is single-threaded binned SAH (16 bins) and allocates
//! O(T).

use glam::Vec3A;
use obvhs::aabb::Aabb;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh;
use obvhs::cwbvh::CwBvh;
use obvhs::ploc::PlocBuilder;
use obvhs::ray::Ray;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

/// obvhs 0.4's CWBVH traversal stack: a tree whose deepest node is at this depth (root 0) or
/// deeper overflows it.
pub const CWBVH_STACK: usize = 32;

/// Node levels below the root the fallback tree may use: its leaves are at depth ≤ 31.
const MAX_BVH2_DEPTH: usize = CWBVH_STACK - 1;

/// SAH bins of the fallback builder.
const BINS: usize = 16;

/// The deepest node's depth of `bvh` (root 0), as obvhs's `validate()` measures it.
pub fn cwbvh_depth(bvh: &CwBvh) -> usize {
    if bvh.nodes.is_empty() {
        return 0;
    }
    let mut deepest = 0;
    let mut stack = vec![(0usize, 0usize)];
    while let Some((i, d)) = stack.pop() {
        deepest = deepest.max(d);
        let node = &bvh.nodes[i];
        for ch in 0..8 {
            if !node.is_child_empty(ch) && !node.is_leaf(ch) {
                stack.push((node.child_node_index(ch) as usize, d + 1));
            }
        }
    }
    deepest
}

/// ⌈log₂ n⌉ for n ≥ 1.
fn ceil_log2(n: usize) -> usize {
    (usize::BITS - (n.max(1) - 1).leading_zeros()) as usize
}

/// A binary BVH over `tris` (one triangle per leaf) built top down: binned SAH splits along the
/// longest axis of the centroids' box while both children can still be finished within
/// [`MAX_BVH2_DEPTH`] levels, else the object median (which halves the count, so a node of n
/// triangles at depth d needs ⌈log₂ n⌉ more levels; the root's ⌈log₂ T⌉ ≤ 31 holds for
/// T ≤ 2³¹). Triangles whose centroids coincide are split by the median too.
pub fn balanced_bvh2(tris: &[Triangle]) -> Bvh2 {
    let n = tris.len();
    if n == 0 {
        return Bvh2::default();
    }
    let boxes: Vec<Aabb> = tris.iter().map(|t| t.aabb()).collect();
    let centres: Vec<Vec3A> = boxes.iter().map(|b| b.center()).collect();
    let mut idx: Vec<u32> = (0..n as u32).collect();
    let mut nodes = vec![Bvh2Node::default(); 2 * n - 1];
    let mut next = 1usize;
    let mut stack = vec![(0usize, 0usize, n, 0usize)];
    while let Some((node, s, e, d)) = stack.pop() {
        let mut bounds = Aabb::empty();
        let mut cbounds = Aabb::empty();
        for &i in &idx[s..e] {
            bounds = bounds.union(&boxes[i as usize]);
            cbounds.extend(centres[i as usize]);
        }
        if e - s == 1 {
            nodes[node] = Bvh2Node::new(bounds, 1, s as u32);
            continue;
        }
        let part = &mut idx[s..e];
        let extent = cbounds.diagonal();
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        let budget = MAX_BVH2_DEPTH - (d + 1);
        let fits = |m: usize| ceil_log2(m) <= budget;
        let mut mid = None;
        if extent[axis] > 0.0 {
            let lo = cbounds.min[axis];
            let scale = BINS as f32 / extent[axis];
            let bin = |i: u32| (((centres[i as usize][axis] - lo) * scale) as usize).min(BINS - 1);
            let mut counts = [0usize; BINS];
            let mut bin_boxes = [Aabb::empty(); BINS];
            for &i in part.iter() {
                let b = bin(i);
                counts[b] += 1;
                bin_boxes[b] = bin_boxes[b].union(&boxes[i as usize]);
            }
            // Sweep from the right for the right-hand areas and counts.
            let mut right = [(0f32, 0usize); BINS];
            let (mut acc, mut cnt) = (Aabb::empty(), 0usize);
            for k in (1..BINS).rev() {
                acc = acc.union(&bin_boxes[k]);
                cnt += counts[k];
                right[k] = (acc.half_area(), cnt);
            }
            let (mut acc, mut cnt) = (Aabb::empty(), 0usize);
            let mut best = (f32::INFINITY, 0usize);
            for k in 0..BINS - 1 {
                acc = acc.union(&bin_boxes[k]);
                cnt += counts[k];
                let (ra, rc) = right[k + 1];
                if cnt == 0 || rc == 0 || !fits(cnt) || !fits(rc) {
                    continue;
                }
                let cost = acc.half_area() * cnt as f32 + ra * rc as f32;
                if cost < best.0 {
                    best = (cost, k);
                }
            }
            if best.0.is_finite() {
                // Partition: bins ≤ best.1 to the left.
                let mut l = 0;
                for j in 0..part.len() {
                    if bin(part[j]) <= best.1 {
                        part.swap(l, j);
                        l += 1;
                    }
                }
                mid = Some(l);
            }
        }
        let mid = mid.unwrap_or_else(|| {
            let m = part.len() / 2;
            part.select_nth_unstable_by(m, |&a, &b| {
                centres[a as usize][axis].total_cmp(&centres[b as usize][axis])
            });
            m
        });
        let left = next;
        next += 2;
        nodes[node] = Bvh2Node::new(bounds, 0, left as u32);
        stack.push((left, s, s + mid, d + 1));
        stack.push((left + 1, s + mid, e, d + 1));
    }
    Bvh2 {
        nodes,
        primitive_indices: idx,
        ..Bvh2::default()
    }
}

/// The CWBVH over `tris`: obvhs's PLOC build (module doc), rebuilt with [`balanced_bvh2`] when
/// it is too deep for the traversal stack. Validated in debug builds.
pub fn build(tris: &[Triangle]) -> CwBvh {
    if tris.is_empty() {
        return CwBvh::default();
    }
    let p = BvhBuildParams::medium_build();
    let mut bvh2 = PlocBuilder::with_capacity(tris.len()).build(
        p.ploc_search_distance,
        tris,
        (0..tris.len() as u32).collect(),
        p.sort_precision,
        p.search_depth_threshold,
    );
    ReinsertionOptimizer::default().run(&mut bvh2, p.reinsertion_batch_ratio, None);
    let leaf = p.max_prims_per_leaf.clamp(1, 3);
    let mut cw = bvh2_to_cwbvh(&bvh2, leaf, true, false);
    if cwbvh_depth(&cw) >= CWBVH_STACK {
        bvh2 = balanced_bvh2(tris);
        cw = bvh2_to_cwbvh(&bvh2, leaf, true, false);
    }
    #[cfg(debug_assertions)]
    {
        bvh2.validate(tris, false, false);
        cw.validate(tris, false);
    }
    cw
}

/// Triangles for any-hit rays, in the unit box (module doc).
pub struct RayScene {
    bvh: CwBvh,
    triangles: Vec<Triangle>,
    /// World → scene: p ↦ (p − centre) · scale.
    centre: Vec3A,
    scale: f32,
}

impl std::fmt::Debug for RayScene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RayScene")
            .field("triangles", &self.triangles.len())
            .field("depth", &cwbvh_depth(&self.bvh))
            .finish()
    }
}

impl RayScene {
    /// The scene over `triangles` (world coordinates, finite). Triangles of zero area are left
    /// out: they stop no ray.
    pub fn new(triangles: impl IntoIterator<Item = [Vec3A; 3]>) -> Self {
        let world: Vec<[Vec3A; 3]> = triangles
            .into_iter()
            .filter(|[a, b, c]| (*b - *a).cross(*c - *a).length_squared() > 0.0)
            .collect();
        let mut bounds = Aabb::empty();
        for t in &world {
            for p in t {
                bounds.extend(*p);
            }
        }
        let (centre, scale) = if world.is_empty() {
            (Vec3A::ZERO, 1.0)
        } else {
            let half = 0.5 * bounds.diagonal().max_element();
            (
                bounds.center(),
                if half > 0.0 && half.is_finite() {
                    1.0 / half
                } else {
                    1.0
                },
            )
        };
        let triangles: Vec<Triangle> = world
            .iter()
            .map(|t| {
                let [v0, v1, v2] = t.map(|p| (p - centre) * scale);
                Triangle { v0, v1, v2 }
            })
            .filter(|t| (t.v1 - t.v0).cross(t.v2 - t.v0).length_squared() > 0.0)
            .collect();
        Self {
            bvh: build(&triangles),
            triangles,
            centre,
            scale,
        }
    }

    /// How many triangles the scene holds (zero-area ones left out).
    pub fn len(&self) -> usize {
        self.triangles.len()
    }

    /// Whether the scene holds no triangle.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// The depth of the scene's CWBVH (root 0): below [`CWBVH_STACK`].
    pub fn depth(&self) -> usize {
        cwbvh_depth(&self.bvh)
    }

    /// Whether the ray from `origin` (world) along `dir` (any length > 0) hits nothing.
    #[inline]
    pub fn escapes(&self, origin: Vec3A, dir: Vec3A) -> bool {
        if self.triangles.is_empty() {
            return true;
        }
        // `+ 0.0` turns −0 into +0: obvhs 0.4's CWBVH traversal misses every hit for a direction
        // with a −0 component (found by the snow-cover baseline tests).
        let d = dir + Vec3A::ZERO;
        let o = (origin - self.centre) * self.scale;
        let tris = &self.triangles;
        let prim = &self.bvh.primitive_indices;
        self.bvh.ray_traverse_miss(Ray::new_inf(o, d), |ray, id| {
            tris[prim[id] as usize].intersect(ray)
        })
    }
}
