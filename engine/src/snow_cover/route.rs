//! One accumulation step's stabilization in two ordered passes: **erosion, then routing** (our
//! scheme for the model's time loop; it reaches a state with the paper's repose property,
//! journal §2.4.1–2.4.2, without the paper's many levelling iterations).
//!
//! Why: the height-ordered sweep of [`super::settle`] levels a cell against its neighbours as
//! they are *now*; when a neighbour below later passes snow on, the cell above is steeper again
//! and goes back into the queue. On a snow slope at the repose angle every give re-opens the cell
//! above it, so a parcel arriving at the top of a slope crosses it in many small parts (measured on
//! the Stanford bunny: 19–71 M visits per step, 72 % of them moving nothing, ~0.25 mm per useful
//! visit; the cost grew like side⁴; BENCHMARKS.md, "why the bunny's snowfall is slow"). Here each
//! cell is settled against a **lower bound of its neighbours' final surfaces** instead, so what it
//! keeps never has to be revisited.
//!
//! With `T' = T + SLOPE_TOLERANCE · cell / 2` (T = cell · tan repose; half the tolerance left as a
//! margin for `f32` rounding) and D = the snow surface after this step's deposit:
//!
//! 1. **Erosion** (a Dijkstra pass, lowest surface first). `U = max(base, min(D, min U(n) + T'))`
//!    over the linked neighbours n that have room (over the scene's edge, `U(n) = base`, so a rim
//!    cell keeps at most `T'` of snow): the highest surface below D that has the repose property.
//!    It starts at the cells of D that are too steep and spreads only uphill, to the cells whose
//!    link leads into a lowered cell, so snow that need not move (a uniform deposit on a slope
//!    at the repose angle) is not touched. Cost: O(m log m) for the m cells it lowers.
//! 2. **Routing** (a max-heap on the resting snow surface, highest first, as hydrological flow
//!    accumulation orders its cells). A cell takes in the snow *in transit* to it, keeps
//!    `K = min(its snow surface, min U(n) + T')` and passes the rest on, in transit, to the
//!    neighbours whose resting surface is below K (so they come later), split by
//!    **water-filling** their resting surfaces (the lowest takes most; none past its ceiling;
//!    over the scene's edge counts as a neighbour at the cell's base that never fills: what
//!    the level would put above it is lost). Snow in transit does not raise a cell's surface
//!    until its turn, so a whole flank's snow runs down in one visit per cell whatever its
//!    amount (a first version added it to the receiver at once and capped receivers at K:
//!    on the bunny 60–98 k cells per step found no room and waited). Each cell's final surface
//!    is at least its U (it keeps at least that, and a receiver only gains until its turn), so
//!    what a cell kept has at most the slope `T'` toward every neighbour's *final* surface:
//!    nothing needs revisiting. What finds no room below K goes on, in transit too, to the
//!    neighbours still waiting in the heap whose U lies below K (their resting surface is
//!    higher only because their own excess has not left yet), split by water-filling their U
//!    surfaces: when a step's deposit on a steep flank exceeds `T'`, nearly every flank cell
//!    would otherwise wait a round for the cell below it (BENCHMARKS.md, snow cover session 21).
//! 3. **Check**: a cell whose excess found no lower neighbour (snow arriving in a pit, where a
//!    pile must build up) keeps it for now; the stuck cells get further rounds while rounds
//!    move snow (their neighbours may have passed their own excess on meanwhile), then the
//!    cells the routing touched and their neighbours are checked with the sweep's own rule
//!    ([`super::settle`]'s outflow); any that would still move snow seed the height-ordered
//!    sweep, which settles them (the paper's levelling) and confirms. A safety net bounds the
//!    visits of one call (`MAX_VISITS_PER_CELL` per cell and layer): past it the snow still in
//!    transit rests where it is and the check and the sweep take over, so no input can keep a
//!    step routing for ever (a unit swapped between two pit cells did, until the levelling
//!    stopped ending a receiver above its giver: [`level_pit`]).
//!
//! **Seed search** (which cells start the erosion). A seed is a cell with snow above what it
//! could keep against its neighbours' D. Instead of testing every cell each step, each test
//! (integer pre-tests, then the exact cap only over the links that fail them:
//! [`Router::seed_test`]) also yields how much more snow may fall before its answer can change:
//! a step's deposit is `round(P·b′) − round(P·b)` units, so over any run of steps the drop toward
//! a neighbour grows by at most `(P − P₂)·Δb + 2`. The cell is tested again at the first step
//! past that, or at the next step when it or a neighbour was moved (the routing's touched cells
//! and their neighbours), or when it was a seed; every cell is tested on the first step, after P
//! changes, after a fallback sweep, and when the moved cells are a large share of all. The seeds
//! found are the same as testing every cell (bit-identical outputs; BENCHMARKS.md, session 17).
//!
//! Mass: integer units throughout ([`super::maps::SNOW_UNIT_M`]); every transfer is exact, so
//! `fallen = resting + lost` to the unit. Both passes are serial with a total order (surface,
//! then cell and layer index), so the result does not depend on the thread count; the seed
//! searches, the sort of each pass's seeds ([`super::queue`]) and the check run on rayon. The state reached is *a* fixed point of the paper's rule
//! (no cell with snow steeper than the repose angle, plus the tolerance), not necessarily the one
//! the sweep alone reaches: snow arriving at a slope already at the repose angle runs down to its
//! toe in one visit instead of being levelled over it.

use rayon::prelude::*;

use super::maps::{opposite, SnowMaps, LINK_LOST, LINK_WALL, NEIGHBOURS, SNOW_UNIT_M};
use super::queue::{Order, SeededQueue};
use super::settle::{heap_key, key_index, outflow};

/// What one [`Router::route`] did.
#[derive(Debug, Clone, Default)]
pub(super) struct RouteReport {
    /// Snow moved between cells (including over the edge), units.
    pub moved_units: u64,
    /// Snow lost over the scene's edge, units.
    pub lost_units: u64,
    /// Cells (indices `j · nx + i`) that would still move snow by the sweep's rule after the
    /// routing (the check of the module doc, step 3); sorted.
    pub unsettled: Vec<u32>,
    /// Routing rounds run (module doc), and cells left with an excess after the first.
    pub rounds: usize,
    pub stuck_first: usize,
    /// The visits ran over [`MAX_VISITS_PER_CELL`]: the rest of the snow in transit was left
    /// where it was, for the check and the sweep.
    pub over_budget: bool,
}

/// U is copied in full ([`Bound`]) when the seeds are more than 1 / this of the cells and layers.
const EAGER_SEED_SHARE: usize = 32;

/// Most routing rounds per step (module doc, step 3).
const MAX_ROUNDS: usize = 64;

/// Most heap visits of one [`Router::route`] call, per cell and layer (module doc, step 3: a
/// safety net; a default run visits a cell a few times).
const MAX_VISITS_PER_CELL: usize = 16;

/// Workspace of the erosion and routing passes for maps of one shape.
#[derive(Debug, Clone)]
pub(super) struct Router {
    nx: usize,
    nz: usize,
    nl: usize,
    /// The eroded snow U, units, per `c · layers + k` (written lazily: see [`Bound`]).
    lb: Bound,
    /// Per `c · layers + k`: the cell's capacity ([`super::maps::MapLayer::capacity`]; static).
    cap: Vec<u32>,
    /// The `c · layers + k` with room (capacity > 0; static), in index order, and where each
    /// row's start in it (`nz + 1` offsets): the cells a full seed search tests (a cell with no
    /// room never holds snow: deposits and moves stop at the capacity).
    room: Vec<u32>,
    room_rows: Vec<usize>,
    /// The seed search's integer pre-tests (see [`Router::seed_test`]).
    filter: SeedFilter,
    /// Per `c · layers + k`: the step at which the seed test must run again ([`NEVER`]: only
    /// when the cell or a neighbour is moved).
    due: Vec<u32>,
    /// Per step: the `c · layers + k` due then (stale entries are skipped: `due` decides).
    buckets: Vec<Vec<u32>>,
    /// Cells whose snow, or a neighbour's, was moved since the last seed search.
    moved: Vec<u32>,
    /// False: the next seed search tests every cell (first step, or P changed).
    scheduled: bool,
    /// The cells and layers tested in this step, and each one's (seed keep, next due step).
    tests: Vec<(u32, Option<u32>, u32)>,
    /// Cells (of any layer) the last full seed search tested, about.
    tests_full: usize,
    /// The seed search's list of cells and layers to test, and per `c · layers + k`: on it.
    list: Vec<u32>,
    listed: Vec<bool>,
    /// Per `c · layers + k`: in the routing heap.
    queued: Vec<bool>,
    /// Per cell: touched by the routing (or a neighbour of a touched cell), to be checked.
    check: Vec<bool>,
    check_list: Vec<u32>,
    /// The cells the erosion lowered (their snow exceeds U: the routing's seeds).
    eroded: Vec<u32>,
    /// The erosion's queue (lowest surface first) and the routing's (highest first).
    min_heap: SeededQueue,
    max_heap: SeededQueue,
    /// Per `c · layers + k`: snow in transit, given to the cell but not yet resting there (it
    /// does not raise the cell's surface until the cell's turn).
    pending: Vec<u32>,
}

/// The erosion's U per `c · layers + k`, written lazily: U starts each [`Router::route`] as D (the
/// snow after the step's deposit), so instead of copying every cell's snow at the start of a
/// step (a pass over all cells and layers per step), a value counts only when it was written in
/// the current call (`epoch`); elsewhere U is the cell's snow. The routing changes a cell's snow
/// only at its own turn, after [`Bound::materialize`] has fixed its U, so an unwritten U always
/// reads D.
///
/// When a step's seeds are many (the Stanford bunny: most of its flanks move every step), the
/// erosion and routing read U at most cells, and the lazy read (an epoch array, then a layer's
/// snow array) costs more memory traffic than a copy: [`Bound::reset`] then copies D once
/// (`eager`), and U is read from one array.
#[derive(Debug, Clone)]
struct Bound {
    lb: Vec<u32>,
    written: Vec<u32>,
    epoch: u32,
    /// This call's U was copied from D in full: `written` is not used.
    eager: bool,
}

impl Bound {
    fn new(n: usize) -> Self {
        Self {
            lb: vec![0; n],
            written: vec![0; n],
            epoch: 0,
            eager: false,
        }
    }

    /// A new call: every U is D again; copied at once when `eager` (rayon over cells), else
    /// lazily.
    fn reset(&mut self, maps: &SnowMaps, eager: bool) {
        if self.epoch == u32::MAX {
            self.written.iter_mut().for_each(|w| *w = 0);
            self.epoch = 0;
        }
        self.epoch += 1;
        self.eager = eager;
        if eager {
            let nl = maps.layers.len();
            self.lb
                .par_chunks_mut(nl.max(1) * 1024)
                .enumerate()
                .for_each(|(b, chunk)| {
                    let c0 = b * 1024;
                    for (k, l) in maps.layers.iter().enumerate() {
                        for (n, &s) in l.snow[c0..c0 + chunk.len() / nl].iter().enumerate() {
                            chunk[n * nl + k] = s;
                        }
                    }
                });
        }
    }

    /// U at `idx` = (c, k).
    #[inline(always)]
    fn get(&self, maps: &SnowMaps, idx: usize, c: usize, k: usize) -> u32 {
        if self.eager || self.written[idx] == self.epoch {
            self.lb[idx]
        } else {
            maps.layers[k].snow[c]
        }
    }

    #[inline]
    fn set(&mut self, idx: usize, v: u32) {
        self.lb[idx] = v;
        if !self.eager {
            self.written[idx] = self.epoch;
        }
    }

    /// Fix U at `idx` before the cell's snow changes.
    #[inline]
    fn materialize(&mut self, maps: &SnowMaps, idx: usize, c: usize, k: usize) {
        if !self.eager && self.written[idx] != self.epoch {
            let v = maps.layers[k].snow[c];
            self.set(idx, v);
        }
    }
}

/// A cheap exact pre-test of the seed search ([`Router::may_seed`]), for one `t'`.
#[derive(Debug, Clone)]
struct SeedFilter {
    /// The `t'` (bits) it was built for; NaN: not built.
    t_prime: f64,
    /// Per `c · layers + k`: `min(capacity, ⌊t' / unit⌋ if a link leads over the edge)`.
    lim: Vec<u32>,
    /// Per `c · layers + k` and direction: `⌊G⌋ − 2` with `G = (base₂ − base + t') / unit` for a
    /// link to a layer (`i32::MIN`: test exactly; saturated at `i32::MAX`).
    thr: Vec<[i32; 4]>,
}

/// The deposit rate of probability `p` per unit of open-ground snowfall (what
/// [`super::snowfall`]'s deposit rounds: `p` where positive, else none lands).
#[inline]
fn rate(p: f32) -> f64 {
    if p > 0.0 {
        f64::from(p)
    } else {
        0.0
    }
}

/// How far the cumulative open-ground snowfall (units) may grow while a margin of `slack` units
/// shrinks by at most `rate` per unit of it: negative when the margin is already gone.
#[inline]
fn allowance(slack: i64, rate: f64) -> f64 {
    if slack < 0 {
        -1.0
    } else if rate <= 0.0 {
        f64::INFINITY
    } else {
        slack as f64 / rate
    }
}

/// Where the model's time loop stands, for the seed search's schedule ([`Router::route`]).
pub(super) struct Clock<'a> {
    /// Cumulative snowfall on open ground at the end of each step, in snow units (the deposit's
    /// `after / SNOW_UNIT_M`); index n − 1 for step n.
    pub cum: &'a [f64],
    /// This step, 1-based.
    pub step: usize,
}

/// [`Router::due`]: not before the cell or a neighbour changes.
const NEVER: u32 = u32::MAX;

/// The links of cell (i, j) (`links`, on a grid `nx` wide) that lead to a layer of a neighbour
/// (not a wall, not over the edge): `(direction, neighbour cell, its layer)`, in link order.
#[inline(always)]
fn layer_links(
    links: [u8; 4],
    i: usize,
    j: usize,
    nx: usize,
) -> impl Iterator<Item = (usize, usize, usize)> {
    (0..4).filter_map(move |d| {
        let k2 = links[d];
        if k2 == LINK_WALL || k2 == LINK_LOST {
            return None;
        }
        let (di, dj) = NEIGHBOURS[d];
        let c2 = (j as isize + dj) as usize * nx + (i as isize + di) as usize;
        Some((d, c2, usize::from(k2)))
    })
}

/// A receiver of snow in transit: (`c · layers + k`, cell, floor surface in metres, room in
/// units).
type Receiver = (usize, usize, f64, u32);

/// The pit's levelling (module doc, step 2): a cell whose excess found no neighbour below K
/// levels `left` units of it with the receivers `c2s` (floor surface and room, in transit)
/// toward a common level ℓ in [K = `top`, its full surface `hfull`]: each receiver takes up to
/// ℓ, the cell keeps what lies between K and ℓ (a bisection on ℓ). Returns each receiver's units.
///
/// No receiver ends above the giver (the giver keeps `top + (left − t)` units' height): the
/// floors let a receiver end up to a unit above the level the giver keeps, and two cells a unit
/// apart in a pit then swapped that unit back and forth for ever (held-out `sh3d_deer` at ≤ 24
/// steps; BENCHMARKS.md, snow cover session 22). Taking units back only raises the giver, so
/// the correction ends; with it each levelling lowers the sum of squared surfaces, so
/// levellings cannot cycle.
fn level_pit(c2s: &[Receiver], top: f64, hfull: f64, left: u64) -> [u32; 4] {
    let share = |lev: f64| -> (u64, [u32; 4]) {
        let mut g = [0u32; 4];
        let mut t = 0u64;
        for (x, m) in g.iter_mut().zip(c2s.iter()) {
            if lev > m.2 {
                *x = units_floor((lev - m.2) / SNOW_UNIT_M).min(m.3);
                t += u64::from(*x);
            }
        }
        (t, g)
    };
    let own = |lev: f64| units_floor((lev - top) / SNOW_UNIT_M) as u64;
    let (mut lo, mut up) = (top, hfull);
    for _ in 0..60 {
        let mid = 0.5 * (lo + up);
        if share(mid).0 + own(mid) <= left {
            lo = mid;
        } else {
            up = mid;
        }
    }
    let (_, mut g) = share(lo);
    let mut rest = left;
    for x in g.iter_mut() {
        *x = u64::from(*x).min(rest) as u32;
        rest -= u64::from(*x);
    }
    loop {
        let t: u64 = g.iter().map(|&x| u64::from(x)).sum();
        let giver = top + (left - t) as f64 * SNOW_UNIT_M;
        let mut changed = false;
        for (x, m) in g.iter_mut().zip(c2s.iter()) {
            let allowed = units_floor((giver - m.2) / SNOW_UNIT_M);
            if *x > allowed {
                *x = allowed;
                changed = true;
            }
        }
        if !changed {
            return g;
        }
    }
}

/// Splits `e` units among `cands` by **water-filling** their floor surfaces (the lowest takes
/// most; none past its room) to the level the excess needs, or to `sink` (the cell's base, when
/// it has an edge: the level stops there and the sink takes the rest). Returns each candidate's
/// units, their sum and what the sink takes; `e` minus both is what found no room.
fn water_fill(cands: &[Receiver], e: u64, sink: Option<f64>) -> ([u32; 4], u64, u64) {
    // Units that raising to level `lev` gives each candidate.
    let give_at = |lev: f64, m: &Receiver| -> u32 {
        if lev <= m.2 {
            0
        } else {
            units_floor((lev - m.2) / SNOW_UNIT_M).min(m.3)
        }
    };
    let total_at = |lev: f64| -> u64 { cands.iter().map(|m| u64::from(give_at(lev, m))).sum() };
    // The level (above K too: the snow is in transit, not resting), or the cell's base when it
    // has an edge (the sink takes the rest).
    let hi = sink.unwrap_or_else(|| {
        cands.iter().map(|m| m.2).fold(f64::NEG_INFINITY, f64::max) + e as f64 * SNOW_UNIT_M + 1.0
    });
    let lev = if sink.is_some() && total_at(hi) <= e {
        hi
    } else {
        // Closed form (no room limit reached): the r lowest floors h₁ ≤ … ≤ h_r at a common
        // level ℓ = (Σ h + e·unit) / r, the first r for which ℓ ≤ h_{r+1}.
        let mut hs = [0f64; 4];
        for (h, m) in hs.iter_mut().zip(cands.iter()) {
            *h = m.2;
        }
        let hs = &mut hs[..cands.len()];
        hs.sort_unstable_by(f64::total_cmp);
        let mut lev = hi;
        let mut sum = 0.0;
        for r in 0..hs.len() {
            sum += hs[r];
            let l = (sum + e as f64 * SNOW_UNIT_M) / (r + 1) as f64;
            if r + 1 == hs.len() || l <= hs[r + 1] {
                lev = l;
                break;
            }
        }
        lev.min(hi)
    };
    let mut gives = [0u32; 4];
    let mut given = 0u64;
    for (g, m) in gives.iter_mut().zip(cands.iter()) {
        *g = give_at(lev, m);
        given += u64::from(*g);
    }
    // Float rounding may overshoot by a unit or so: take it back from the largest.
    while given > e {
        if let Some(g) = gives.iter_mut().max() {
            *g -= 1;
            given -= 1;
        }
    }
    let mut left = e - given;
    let mut lost = 0;
    if sink.is_some() {
        // The level reached the cell's base: the rest goes over the edge.
        lost = left;
        left = 0;
    }
    // The rounding remainder (a few units): one each to the candidates with room left, in the
    // order of the links.
    while left > 0 {
        let open = gives
            .iter()
            .zip(cands.iter())
            .filter(|(g, m)| **g < m.3)
            .count();
        if open == 0 {
            break;
        }
        let each = left.div_ceil(open as u64);
        for (g, m) in gives.iter_mut().zip(cands.iter()) {
            let add = each.min(left).min(u64::from(m.3 - *g)) as u32;
            *g += add;
            left -= u64::from(add);
            given += u64::from(add);
        }
    }
    (gives, given, lost)
}

/// `⌊x⌋` as units in `[0, u32::MAX]`.
#[inline]
fn units_floor(x: f64) -> u32 {
    if x.is_nan() || x <= 0.0 {
        0
    } else if x >= f64::from(u32::MAX) {
        u32::MAX
    } else {
        x as u32
    }
}

impl Router {
    pub(super) fn new(maps: &SnowMaps) -> Self {
        let n = maps.nx * maps.nz;
        let nl = maps.layers.len();
        let cap: Vec<u32> = (0..n * nl)
            .map(|idx| maps.layers[idx % nl].capacity(idx / nl))
            .collect();
        let mut room = Vec::new();
        let mut room_rows = vec![0];
        for row in cap.chunks(maps.nx * nl) {
            let start = room_rows.len() - 1;
            let base = (start * maps.nx * nl) as u32;
            room.extend(
                (0..row.len() as u32)
                    .filter(|&o| row[o as usize] > 0)
                    .map(|o| base + o),
            );
            room_rows.push(room.len());
        }
        Self {
            nx: maps.nx,
            nz: maps.nz,
            nl,
            lb: Bound::new(n * nl),
            cap,
            room,
            room_rows,
            filter: SeedFilter {
                t_prime: f64::NAN,
                lim: Vec::new(),
                thr: Vec::new(),
            },
            due: vec![NEVER; n * nl],
            buckets: Vec::new(),
            moved: Vec::new(),
            scheduled: false,
            tests: Vec::new(),
            tests_full: 0,
            list: Vec::new(),
            listed: vec![false; n * nl],
            queued: vec![false; n * nl],
            check: vec![false; n],
            check_list: Vec::new(),
            eroded: Vec::new(),
            min_heap: SeededQueue::new(Order::Min),
            max_heap: SeededQueue::new(Order::Max),
            pending: vec![0; n * nl],
        }
    }

    /// The most snow (units) cell-and-layer (c, k) can keep with the repose property `t_prime`
    /// toward neighbours whose surfaces are given by `lb` (U, units per `c · layers + k`),
    /// skipping neighbours full to their ceiling in the *current* state (walls for now, as the
    /// sweep's rule has it); at most the cell's capacity (`cap`, per `c · layers + k`).
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn keep_cap(
        maps: &SnowMaps,
        lb: &Bound,
        cap: &[u32],
        nl: usize,
        k: usize,
        i: usize,
        j: usize,
        t_prime: f64,
    ) -> u32 {
        let nx = maps.nx;
        let c = j * nx + i;
        let l = &maps.layers[k];
        let bc = f64::from(l.base[c]);
        let mut keep = cap[c * nl + k];
        let links = l.links[c];
        if links.contains(&LINK_LOST) {
            keep = keep.min(units_floor(t_prime / SNOW_UNIT_M));
        }
        for (_, c2, k2) in layer_links(links, i, j, nx) {
            let l2 = &maps.layers[k2];
            let idx2 = c2 * nl + k2;
            let cap2 = cap[idx2];
            if l2.snow[c2] >= cap2 {
                continue;
            }
            let s2 = lb.get(maps, idx2, c2, k2).min(cap2);
            keep = keep.min(units_floor(
                (f64::from(l2.base[c2]) - bc + f64::from(s2) * SNOW_UNIT_M + t_prime) / SNOW_UNIT_M,
            ));
        }
        keep
    }

    /// Build the seed filter for `t_prime` (once per run: the geometry is fixed).
    fn build_filter(&mut self, maps: &SnowMaps, t_prime: f64) {
        if self.filter.t_prime.to_bits() == t_prime.to_bits() {
            return;
        }
        let (nx, nl) = (self.nx, self.nl);
        let edge = units_floor(t_prime / SNOW_UNIT_M);
        let cap = &self.cap;
        let (lim, thr): (Vec<u32>, Vec<[i32; 4]>) = (0..cap.len())
            .into_par_iter()
            .map(|idx| {
                let (c, k) = (idx / nl, idx % nl);
                let (i, j) = (c % nx, c / nx);
                let l = &maps.layers[k];
                let bc = f64::from(l.base[c]);
                let mut lim = cap[idx];
                let mut thr = [i32::MAX; 4];
                for (d, &link) in l.links[c].iter().enumerate() {
                    match link {
                        LINK_WALL => {}
                        LINK_LOST => lim = lim.min(edge),
                        k2 => {
                            let (di, dj) = NEIGHBOURS[d];
                            let c2 = (j as isize + dj) as usize * nx + (i as isize + di) as usize;
                            let b2 = f64::from(maps.layers[usize::from(k2)].base[c2]);
                            let t = ((b2 - bc + t_prime) / SNOW_UNIT_M).floor() - 2.0;
                            thr[d] = if t.is_nan() || t <= f64::from(i32::MIN) {
                                i32::MIN
                            } else if t >= f64::from(i32::MAX) {
                                i32::MAX
                            } else {
                                t as i32
                            };
                        }
                    }
                }
                (lim, thr)
            })
            .unzip();
        self.filter = SeedFilter { t_prime, lim, thr };
    }

    /// The seed test of cell-and-layer `idx` = (c, k) at cell (i, j) in the current state (U =
    /// D): `Some(keep)` when it is a seed (`s > keep`, `keep` = [`Router::keep_cap`]), and how much
    /// more snow may fall on open ground (units of `C / unit`) before the test can change its
    /// answer without the cell or a linked neighbour being moved (module doc, "Seed search").
    ///
    /// Integer tests first: `s > lim` is the capacity and edge part of [`Router::keep_cap`]
    /// itself, and toward a layer link whose neighbour has room and snow `s₂` the cap is `⌊x⌋`,
    /// `x = s₂ + G` up to rounding far below a unit (`G` as in [`SeedFilter::thr`]), so while `s −
    /// s₂ ≤ ⌊G⌋ − 2` that link does not bind (`x > s + 1`). Only a cell failing one of them is
    /// tested exactly. The allowance: a step from cumulative amount `b` to `b′` deposits
    /// `round(P·b′) − round(P·b)` units ([`super::snowfall`]), so over any run of steps `s − s₂`
    /// grows by at most `(P − P₂)·(b′ − b) + 2` (one unit of rounding at each end, both
    /// cells; less where a deposit stops at the ceiling, and a neighbour stopped there is full, no
    /// longer a constraint), and `s` toward the edge limit by `P·(b′ − b) + 1`; a link's
    /// allowance keeps one unit of margin more. Without `ALLOWANCE` (a search that keeps no
    /// schedule) the allowance is not computed and reads infinite.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn seed_test<const ALLOWANCE: bool>(
        maps: &SnowMaps,
        filter: &SeedFilter,
        cap: &[u32],
        nl: usize,
        idx: usize,
        i: usize,
        j: usize,
        t_prime: f64,
    ) -> (Option<u32>, f64) {
        let (c, k) = (idx / nl, idx % nl);
        let nx = maps.nx;
        let l = &maps.layers[k];
        let s = l.snow[c];
        let p = if ALLOWANCE {
            rate(l.probability[c])
        } else {
            0.0
        };
        let lim = filter.lim[idx];
        let mut test = s > lim;
        let mut allowed = f64::INFINITY;
        if ALLOWANCE && lim < cap[idx] {
            allowed = allowed.min(allowance(i64::from(lim) - i64::from(s) - 2, p));
        }
        let links = l.links[c];
        let thr = filter.thr[idx];
        // `keep` as `keep_cap` computes it (U = D = the snow here: nothing is eroded yet), but
        // only over the links that fail their pre-test: the others give more than `s`, so they
        // do not lower the minimum when the cell is a seed (and `keep` is not used otherwise).
        let mut keep = lim;
        let bc = f64::from(l.base[c]);
        for (d, c2, k2) in layer_links(links, i, j, nx) {
            let l2 = &maps.layers[k2];
            let s2 = l2.snow[c2];
            let cap2 = cap[c2 * nl + k2];
            if s2 >= cap2 {
                continue;
            }
            let slack = if thr[d] == i32::MIN {
                -1
            } else {
                i64::from(thr[d]) - (i64::from(s) - i64::from(s2))
            };
            if slack < 0 {
                test = true;
                keep = keep.min(units_floor(
                    (f64::from(l2.base[c2]) - bc + f64::from(s2.min(cap2)) * SNOW_UNIT_M + t_prime)
                        / SNOW_UNIT_M,
                ));
            }
            if ALLOWANCE {
                allowed = allowed.min(allowance(slack - 3, p - rate(l2.probability[c2])));
            }
        }
        let seed = (s > 0 && test && s > keep).then_some(keep);
        (seed, allowed)
    }

    #[inline]
    fn surface_key(
        maps: &SnowMaps,
        cap: &[u32],
        k: usize,
        c: usize,
        units: u32,
        idx: usize,
    ) -> u64 {
        let l = &maps.layers[k];
        let s = (f64::from(l.base[c]) + f64::from(units.min(cap[idx])) * SNOW_UNIT_M) as f32;
        heap_key(s, idx)
    }

    /// The erosion's seeds, `(c · layers + k, keep)` in index order: every cell and layer
    /// with snow above [`Router::keep_cap`] (U = D). Tests the cells due at this step, those
    /// moved (or beside one moved) since the last search, and last step's seeds (a seed that
    /// found no room moved nothing and is still one); every cell when the schedule does not
    /// hold. Rayon over rows (all cells) or over the tested cells; the result does not depend on
    /// the thread count.
    fn seed_search(&mut self, maps: &SnowMaps, t_prime: f64, clock: &Clock) -> Vec<(u32, u32)> {
        let (nx, nl) = (self.nx, self.nl);
        let n = clock.step;
        // The cumulative snowfall's running maximum (monotone, for a binary search; the bound
        // holds for it too).
        let mut cum = Vec::with_capacity(clock.cum.len());
        let mut hi = f64::NEG_INFINITY;
        for &b in clock.cum {
            hi = hi.max(b);
            cum.push(hi);
        }
        let now = clock
            .cum
            .get(n.wrapping_sub(1))
            .copied()
            .unwrap_or(f64::NAN);
        let due_after = |allowed: f64, seed: bool| -> u32 {
            if seed || !now.is_finite() || allowed.is_nan() || allowed < 0.0 {
                return (n + 1) as u32;
            }
            let later = cum.get(n..).unwrap_or(&[]);
            let off = later.partition_point(|&b| b - now <= allowed);
            if off == later.len() {
                NEVER
            } else {
                (n + 1 + off) as u32
            }
        };
        let (cap, filter) = (&self.cap, &self.filter);
        let (room, room_rows) = (&self.room, &self.room_rows);
        // Every cell when the moved cells are a large share of them (the Stanford bunny: most
        // of its flanks move every step): a pass in row order costs less than the list.
        let many = self.moved.len().saturating_mul(2) > self.tests_full;
        // A schedule is kept only when this step's moves were few: after a step that moved many
        // cells the next one likely does too, and then a full pass without the bookkeeping
        // (a due step per cell, the buckets) costs less.
        let record = !many;
        if !record {
            // Every cell (rayon over rows), keeping no schedule: only the seeds are kept, and
            // no allowance is computed (the next search tests every cell again).
            let rows: Vec<(Vec<(u32, u32)>, usize)> = (0..self.nz)
                .into_par_iter()
                .map(|j| {
                    let mut seeds = Vec::new();
                    let row = &room[room_rows[j]..room_rows[j + 1]];
                    for &idx in row {
                        let idx = idx as usize;
                        let i = (idx / nl) % nx;
                        if let (Some(keep), _) =
                            Self::seed_test::<false>(maps, filter, cap, nl, idx, i, j, t_prime)
                        {
                            seeds.push((idx as u32, keep));
                        }
                    }
                    (seeds, row.len())
                })
                .collect();
            self.tests_full = rows.iter().map(|r| r.1).sum::<usize>() / nl.max(1);
            self.moved.clear();
            self.scheduled = false;
            let seeds: Vec<(u32, u32)> = rows.into_iter().flat_map(|r| r.0).collect();
            // The scheduled search lists last step's seeds from `tests`.
            self.tests.clear();
            self.tests
                .extend(seeds.iter().map(|&(idx, keep)| (idx, Some(keep), NEVER)));
            return seeds;
        }
        if !self.scheduled || self.buckets.len() != cum.len() + 2 {
            // Every cell (rayon over rows).
            let tests: Vec<(u32, Option<u32>, u32)> = (0..self.nz)
                .into_par_iter()
                .flat_map_iter(|j| {
                    let mut row = Vec::new();
                    for &idx in &room[room_rows[j]..room_rows[j + 1]] {
                        let idx = idx as usize;
                        let i = (idx / nl) % nx;
                        let (seed, allowed) =
                            Self::seed_test::<true>(maps, filter, cap, nl, idx, i, j, t_prime);
                        row.push((idx as u32, seed, due_after(allowed, seed.is_some())));
                    }
                    row
                })
                .collect();
            self.tests = tests;
            self.tests_full = self.tests.len() / nl.max(1);
            self.moved.clear();
            self.scheduled = true;
            self.due.iter_mut().for_each(|d| *d = NEVER);
            self.buckets.iter_mut().for_each(Vec::clear);
            self.buckets.resize(cum.len() + 2, Vec::new());
        } else {
            // The cells due now, the moved ones and last step's seeds, each once (`listed`).
            let mut list = std::mem::take(&mut self.list);
            list.clear();
            let bucket = std::mem::take(&mut self.buckets[n.min(cum.len() + 1)]);
            let moved = std::mem::take(&mut self.moved);
            let seeds = self.tests.iter().filter(|t| t.1.is_some()).map(|t| t.0);
            let moved_idx = moved
                .iter()
                .flat_map(|&c| (0..nl).map(move |k| c as usize * nl + k));
            for idx in bucket
                .iter()
                .filter(|&&idx| self.due[idx as usize] == n as u32)
                .map(|&idx| idx as usize)
                .chain(moved_idx)
                .chain(seeds.map(|idx| idx as usize))
            {
                // A cell and layer with no room holds no snow and never will (deposits and
                // moves stop at the capacity): never a seed.
                if !self.listed[idx] && (cap[idx] > 0 || maps.layers[idx % nl].snow[idx / nl] > 0) {
                    self.listed[idx] = true;
                    list.push(idx as u32);
                }
            }
            for &idx in &list {
                self.listed[idx as usize] = false;
            }
            self.moved = moved;
            self.moved.clear();
            self.buckets[n.min(cum.len() + 1)] = bucket;
            self.buckets[n.min(cum.len() + 1)].clear();
            self.tests = list
                .par_iter()
                .with_min_len(256)
                .map(|&idx| {
                    let c = idx as usize / nl;
                    let (seed, allowed) = Self::seed_test::<true>(
                        maps,
                        filter,
                        cap,
                        nl,
                        idx as usize,
                        c % nx,
                        c / nx,
                        t_prime,
                    );
                    (idx, seed, due_after(allowed, seed.is_some()))
                })
                .collect();
            self.list = list;
        }
        for &(idx, _, due) in &self.tests {
            self.due[idx as usize] = due;
            if let Some(b) = self.buckets.get_mut(due as usize) {
                b.push(idx);
            }
        }
        self.tests
            .iter()
            .filter_map(|&(idx, seed, _)| seed.map(|keep| (idx, keep)))
            .collect()
    }

    /// The seed search's schedule no longer holds (P changed): the next search tests every cell.
    pub(super) fn reschedule(&mut self) {
        self.scheduled = false;
    }

    /// Erosion then routing (module doc) with repose drop `t_drop` and tolerance `tol` (metres),
    /// at the time loop's `clock` (the seed search's schedule).
    pub(super) fn route(
        &mut self,
        maps: &mut SnowMaps,
        t_drop: f32,
        tol: f32,
        clock: &Clock,
    ) -> RouteReport {
        assert!(maps.nx == self.nx && maps.nz == self.nz && maps.layers.len() == self.nl);
        let (nx, nz, nl) = (self.nx, self.nz, self.nl);
        let t_prime = f64::from(t_drop) + 0.5 * f64::from(tol);
        let mut rep = RouteReport::default();

        self.build_filter(maps, t_prime);

        // 1. Erosion. Seeds: the cells of D that are too steep (module doc, "Seed search").
        let seeds = self.seed_search(maps, t_prime, clock);
        // U starts as D: copied when the seeds are many, else lazily (see `Bound`).
        let eager = seeds.len().saturating_mul(EAGER_SEED_SHARE) > self.cap.len();
        self.lb.reset(maps, eager);
        self.eroded.clear();
        self.min_heap.clear();
        for &(idx, cap) in &seeds {
            let idx = idx as usize;
            self.lb.set(idx, cap);
            self.eroded.push(idx as u32);
            let (c, k) = (idx / nl, idx % nl);
            self.min_heap
                .seed(Self::surface_key(maps, &self.cap, k, c, cap, idx));
        }
        self.min_heap.sort_seeds();
        while let Some(key) = self.min_heap.pop() {
            let idx = key_index(key);
            let (c, k) = (idx / nl, idx % nl);
            if Self::surface_key(maps, &self.cap, k, c, self.lb.get(maps, idx, c, k), idx) != key {
                continue; // stale
            }
            let l = &maps.layers[k];
            if l.snow[c] >= self.cap[idx] {
                // Full to its ceiling: a wall for its neighbours for now (no constraint).
                continue;
            }
            let (i, j) = (c % nx, c / nx);
            let top = f64::from(l.base[c])
                + f64::from(self.lb.get(maps, idx, c, k).min(self.cap[idx])) * SNOW_UNIT_M
                + t_prime;
            for (d, &(di, dj)) in NEIGHBOURS.iter().enumerate() {
                let (i2, j2) = (i as isize + di, j as isize + dj);
                if i2 < 0 || j2 < 0 || i2 as usize >= nx || j2 as usize >= nz {
                    continue;
                }
                let c2 = j2 as usize * nx + i2 as usize;
                let back = opposite(d);
                for k3 in 0..nl {
                    let l3 = &maps.layers[k3];
                    let idx3 = c2 * nl + k3;
                    let lb3 = self.lb.get(maps, idx3, c2, k3);
                    if lb3 == 0 || usize::from(l3.links[c2][back]) != k {
                        continue;
                    }
                    let cand = units_floor((top - f64::from(l3.base[c2])) / SNOW_UNIT_M);
                    if cand < lb3 {
                        if lb3 == l3.snow[c2] {
                            self.eroded.push(idx3 as u32);
                        }
                        self.lb.set(idx3, cand);
                        self.min_heap
                            .push(Self::surface_key(maps, &self.cap, k3, c2, cand, idx3));
                    }
                }
            }
        }

        // 2. Routing, highest surface first.
        self.max_heap.clear();
        for n in 0..self.eroded.len() {
            let idx = self.eroded[n] as usize;
            let (c, k) = (idx / nl, idx % nl);
            if self.queued[idx] || maps.layers[k].snow[c] <= self.lb.get(maps, idx, c, k) {
                continue;
            }
            self.queued[idx] = true;
            let s = maps.layers[k].snow[c];
            self.max_heap
                .seed(Self::surface_key(maps, &self.cap, k, c, s, idx));
        }
        self.max_heap.sort_seeds();
        self.check_list.clear();
        let mut stuck: Vec<u32> = Vec::new();
        let mut rounds = 0;
        let mut stuck_first = 0;
        // A bound on the visits of one call (module doc, step 3: the safety net).
        let budget = (MAX_VISITS_PER_CELL * self.queued.len()) as u64;
        let mut visits = 0u64;
        loop {
            let moved_before = rep.moved_units;
            while let Some(key) = self.max_heap.pop() {
                let idx = key_index(key);
                self.queued[idx] = false;
                let (c, k) = (idx / nl, idx % nl);
                let (i, j) = (c % nx, c / nx);
                // The snow in transit arrives (it rests here from now on, or moves on); U here
                // is fixed first (it was D, the snow before this call).
                self.lb.materialize(maps, idx, c, k);
                let s = maps.layers[k].snow[c].saturating_add(self.pending[idx]);
                maps.layers[k].snow[c] = s;
                self.pending[idx] = 0;
                visits += 1;
                if visits > budget {
                    // Past the safety net the snow rests where it arrived; the check below
                    // finds what is too steep and the sweep settles it.
                    Self::mark(&mut self.check, &mut self.check_list, c);
                    rep.over_budget = true;
                    continue;
                }
                let cap = Self::keep_cap(maps, &self.lb, &self.cap, nl, k, i, j, t_prime);
                if s <= cap {
                    // It keeps all it has, for good (a lower bound of its final snow).
                    let v = self.lb.get(maps, idx, c, k).max(s);
                    self.lb.set(idx, v);
                    continue;
                }
                let excess = s - cap;
                let bc = f64::from(maps.layers[k].base[c]);
                let top = bc + f64::from(cap) * SNOW_UNIT_M;
                // Candidates: the neighbours whose resting surface is below K (so they come
                // later): (idx2, cell2, resting surface, room in units, snow in transit
                // included); over the edge: a sink at the cell's base.
                let mut buf: [Receiver; 4] = [(0, 0, 0.0, 0); 4];
                let mut n = 0;
                let links = maps.layers[k].links[c];
                let sink: Option<f64> = links.contains(&LINK_LOST).then_some(bc);
                for (_, c2, k2) in layer_links(links, i, j, nx) {
                    let l2 = &maps.layers[k2];
                    let idx2 = c2 * nl + k2;
                    let s2 = l2.snow[c2];
                    let room = self.room(s2, idx2);
                    if room == 0 {
                        continue;
                    }
                    let h = f64::from(l2.base[c2]) + f64::from(s2) * SNOW_UNIT_M;
                    if h < top {
                        buf[n] = (idx2, c2, h, room);
                        n += 1;
                    }
                }
                let e = u64::from(excess);
                let (mut gives, mut given, lost) = water_fill(&buf[..n], e, sink);
                rep.lost_units += lost;
                rep.moved_units += lost;
                let mut left = e - given - lost;
                // Downstream in transit: what found no room below K goes on to the neighbours
                // still waiting in the heap (so they come later) whose bound U is below K: their
                // resting surface is at K or above only because their own excess has not left
                // yet (the erosion lowered them), and they pass on at their turn whatever they
                // cannot keep. Split by water-filling their U surfaces. Without this the cell
                // waited a round for each such neighbour, and when a step's deposit exceeds T'
                // on a steep flank most flank cells did (BENCHMARKS.md, snow cover session 21).
                let n1 = n;
                if left > 0 && sink.is_none() {
                    for (_, c2, k2) in layer_links(links, i, j, nx) {
                        let idx2 = c2 * nl + k2;
                        if !self.queued[idx2] || buf[..n1].iter().any(|m| m.0 == idx2) {
                            continue;
                        }
                        let l2 = &maps.layers[k2];
                        let room = self.room(l2.snow[c2], idx2);
                        if room == 0 {
                            continue;
                        }
                        let u2 = self.lb.get(maps, idx2, c2, k2);
                        let f = f64::from(l2.base[c2]) + f64::from(u2) * SNOW_UNIT_M;
                        if f < top {
                            buf[n] = (idx2, c2, f, room);
                            n += 1;
                        }
                    }
                    if n > n1 {
                        let (g2, given2, _) = water_fill(&buf[n1..n], left, None);
                        gives[n1..n].copy_from_slice(&g2[..n - n1]);
                        given += given2;
                        left -= given2;
                    }
                }
                let cands = &buf[..n];
                // A pit (no neighbour below K could take it all): level the rest with the
                // neighbours below the cell's full surface (the paper's levelling, to a common
                // level), in transit too; the cell keeps its share for now and tries again in
                // the next round, when the pile around it has grown (and with it U there).
                let mut extra: [(usize, usize, u32); 4] = [(0, 0, 0); 4];
                let mut n_extra = 0;
                if left > 0 && sink.is_none() {
                    let hfull = bc + f64::from(s.min(self.cap[idx])) * SNOW_UNIT_M;
                    let mut c2s: [(usize, usize, f64, u32); 4] = [(0, 0, 0.0, 0); 4];
                    for (_, c2, k2) in layer_links(links, i, j, nx) {
                        let idx2 = c2 * nl + k2;
                        let l2 = &maps.layers[k2];
                        let already: u32 = cands
                            .iter()
                            .zip(gives.iter())
                            .filter(|(m, _)| m.0 == idx2)
                            .map(|(_, g)| *g)
                            .sum();
                        let held = l2.snow[c2]
                            .saturating_add(self.pending[idx2])
                            .saturating_add(already);
                        let room = self.cap[idx2].saturating_sub(held);
                        let h = f64::from(l2.base[c2]) + f64::from(held) * SNOW_UNIT_M;
                        if room > 0 && h < hfull {
                            c2s[n_extra] = (idx2, c2, h, room);
                            n_extra += 1;
                        }
                    }
                    let c2s = &c2s[..n_extra];
                    let g = level_pit(c2s, top, hfull, left);
                    let mut t = 0u64;
                    for ((x, m), slot) in g.iter().zip(c2s.iter()).zip(extra.iter_mut()) {
                        t += u64::from(*x);
                        *slot = (m.0, m.1, *x);
                    }
                    left -= t;
                    given += t;
                }
                if left > 0 {
                    stuck.push(idx as u32);
                }
                let gone = (e - left) as u32;
                // What it keeps (up to K) it keeps for good: a lower bound of its final snow.
                let v = self.lb.get(maps, idx, c, k).max(cap);
                self.lb.set(idx, v);
                if gone == 0 {
                    continue;
                }
                maps.layers[k].snow[c] -= gone;
                rep.moved_units += given;
                Self::mark(&mut self.check, &mut self.check_list, c);
                let tier2 = extra.iter().filter(|x| x.2 > 0).map(|x| (x.2, x.0, x.1));
                for (g, idx2, c2) in gives
                    .iter()
                    .zip(cands.iter())
                    .map(|(g, m)| (*g, m.0, m.1))
                    .chain(tier2)
                {
                    let g = &g;
                    if *g == 0 {
                        continue;
                    }
                    let k2 = idx2 % nl;
                    self.pending[idx2] += *g;
                    Self::mark(&mut self.check, &mut self.check_list, c2);
                    if !self.queued[idx2] {
                        self.queued[idx2] = true;
                        let s2 = maps.layers[k2].snow[c2];
                        self.max_heap
                            .push(Self::surface_key(maps, &self.cap, k2, c2, s2, idx2));
                    }
                }
            }

            // A cell whose excess found no room may have been waiting on a lower neighbour that had
            // an excess of its own (not yet passed on when the cell's turn came): another round
            // from the stuck cells, as long as rounds move snow.
            rounds += 1;
            if rounds == 1 {
                stuck_first = stuck.len();
            }
            if stuck.is_empty()
                || rep.moved_units == moved_before
                || rounds >= MAX_ROUNDS
                || rep.over_budget
            {
                break;
            }
            for idx in stuck.drain(..) {
                let idx = idx as usize;
                if !self.queued[idx] {
                    self.queued[idx] = true;
                    let (c, k) = (idx / nl, idx % nl);
                    let s = maps.layers[k].snow[c];
                    self.max_heap
                        .push(Self::surface_key(maps, &self.cap, k, c, s, idx));
                }
            }
        }
        rep.rounds = rounds;
        rep.stuck_first = stuck_first;

        // 3. Check the touched cells and their neighbours with the sweep's rule.
        let touched = std::mem::take(&mut self.check_list);
        for &c in &touched {
            let c = c as usize;
            let (i, j) = (c % nx, c / nx);
            for d in 0..4 {
                if let Some(c2) = maps.neighbour(i, j, d) {
                    Self::mark(&mut self.check, &mut self.check_list, c2);
                }
            }
        }
        let mut all = touched;
        all.append(&mut self.check_list);
        // In cell order, each once (`check` marks them once): a pass over the marks when they
        // are many (the bunny: 70–96 k cells a step), else a sort of the list.
        if all.len().saturating_mul(8) > self.check.len() {
            all.clear();
            for (c, f) in self.check.iter_mut().enumerate() {
                if *f {
                    *f = false;
                    all.push(c as u32);
                }
            }
        } else {
            for &c in &all {
                self.check[c as usize] = false;
            }
            all.sort_unstable();
        }
        // The moved cells and their neighbours: tested at the next seed search.
        self.moved.extend_from_slice(&all);
        let maps_ref: &SnowMaps = maps;
        rep.unsettled = all
            .par_iter()
            .copied()
            .filter(|&c| {
                let c = c as usize;
                let (i, j) = (c % nx, c / nx);
                (0..nl).any(|k| {
                    maps_ref.layers[k].snow[c] != 0 && {
                        let (o, _) = outflow(maps_ref, k, i, j, t_drop, tol, 1.0);
                        o.iter().any(|&v| v != 0)
                    }
                })
            })
            .collect();
        all.clear();
        self.check_list = all;
        rep
    }

    /// Units a cell-layer holding `snow` can still take in transit: its capacity less what it
    /// holds and what is already on its way to it.
    #[inline]
    fn room(&self, snow: u32, idx: usize) -> u32 {
        self.cap[idx].saturating_sub(snow.saturating_add(self.pending[idx]))
    }

    #[inline]
    fn mark(check: &mut [bool], list: &mut Vec<u32>, c: usize) {
        if !check[c] {
            check[c] = true;
            list.push(c as u32);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Receivers' and the giver's surfaces after a levelling.
    fn after(c2s: &[Receiver], g: &[u32; 4], top: f64, left: u64) -> (Vec<f64>, f64) {
        let t: u64 = g.iter().map(|&x| u64::from(x)).sum();
        let r = c2s
            .iter()
            .zip(g)
            .map(|(m, &x)| m.2 + f64::from(x) * SNOW_UNIT_M)
            .collect();
        (r, top + (left - t) as f64 * SNOW_UNIT_M)
    }

    #[test]
    fn a_pit_levelling_never_swaps_a_unit_between_cells_a_unit_apart() {
        // The held-out deer's cycle: a cell of 8273 units (K = 1838) beside one of 8272, same
        // base: giving the unit would only swap the two surfaces.
        let bc = -0.074_171_975_255_012_51;
        let top = bc + 1838.0 * SNOW_UNIT_M;
        let hfull = bc + 8273.0 * SNOW_UNIT_M;
        let c2s = [(1, 1, bc + 8272.0 * SNOW_UNIT_M, 1_000_000)];
        assert_eq!(level_pit(&c2s, top, hfull, 8273 - 1838), [0; 4]);
    }

    #[test]
    fn a_pit_levelling_levels_conserves_and_never_ends_a_receiver_above_the_giver() {
        // Two units apart: one moves, and both end level.
        let c2s = [(1, 1, 0.0, 1_000)];
        let g = level_pit(&c2s, 0.0, 2.0 * SNOW_UNIT_M, 2);
        assert_eq!(g, [1, 0, 0, 0]);
        // Pseudo-random cases: within `left`, within each room, no receiver that took snow above
        // the giver,
        // and the giver not far above the lowest receiver that still had room (it levelled as far
        // as the integers allow: a unit per receiver's floor, one for its own, one for the
        // bisection's level landing a rounding below a unit boundary).
        let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
        let mut next = |m: u64| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x % m
        };
        for _ in 0..20_000 {
            let n = 1 + next(4) as usize;
            let top = next(1000) as f64 * SNOW_UNIT_M;
            let left = 1 + next(5000);
            let hfull = top + left as f64 * SNOW_UNIT_M;
            let c2s: Vec<Receiver> = (0..n)
                .map(|i| {
                    let h = top + next(left + 1000) as f64 * SNOW_UNIT_M - 500.0 * SNOW_UNIT_M;
                    (i, i, h.min(hfull - SNOW_UNIT_M), 1 + next(3000) as u32)
                })
                .collect();
            let g = level_pit(&c2s, top, hfull, left);
            let t: u64 = g.iter().map(|&v| u64::from(v)).sum();
            assert!(t <= left);
            let (r, giver) = after(&c2s, &g, top, left);
            for ((m, &v), h) in c2s.iter().zip(&g).zip(&r) {
                assert!(v <= m.3, "within room");
                assert!(
                    v == 0 || *h <= giver + 1e-12,
                    "a receiver of {v} units ends at {h}, above the giver at {giver}"
                );
            }
            let open = c2s
                .iter()
                .zip(&g)
                .zip(&r)
                .filter(|((m, &v), _)| v < m.3)
                .map(|(_, h)| *h)
                .fold(f64::INFINITY, f64::min);
            if open.is_finite() && t < left {
                assert!(
                    giver <= open + (n as f64 + 2.0) * SNOW_UNIT_M + 1e-12,
                    "left {left} top {top} {c2s:?} {g:?}: giver {giver}, lowest open receiver {open}"
                );
            }
        }
    }
}
