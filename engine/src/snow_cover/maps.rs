//! Snow maps (journal §2.1 "積雪量マップ"): the layered, top-down grids on which snow lands, rests
//! and moves.
//!
//! The paper keeps one top-down orthographic z-buffer per hand-made group of polygons that do not
//! overlap seen from above. We keep the same grid for every group and index the groups by *depth
//! order per cell* instead: layer 0 at a cell is the topmost snow-possible surface seen from above,
//! layer 1 the next one below it, and so on (see [`super::region`] for the peeling). So one physical
//! surface can be layer 0 in some cells and layer 1 in others (the floor outside and under a
//! table); what ties it together is the per-cell-and-direction [`MapLayer::links`] table that says
//! which layer of the neighbouring cell snow moves to (see [`super::region`] for the rule).
//!
//! **Grid.** `nx × nz` square cells of `cell` metres, row-major (`j * nx + i`), cell (i, j) centred
//! at world `x = origin[0] + (i + ½)·cell`, `z = origin[1] + (j + ½)·cell`; Y is up.
//!
//! **Snow amounts are integers**: [`MapLayer::snow`] holds the depth of snow in units of
//! [`SNOW_UNIT_M`] (1 µm) as `u32` (up to 4.29 km). Moves between cells are integer transfers, so
//! mass is conserved *exactly* (fallen = resting + lost, to the unit) and totals do not depend on
//! the order of summation, hence not on the number of threads. Rejected: `f32` depths (the total
//! drifts by ~1e-7 relative per move, and thousands of moves per cell add up past the 1e-6 budget)
//! and `f64` depths (exact enough, but sums then depend on the reduction order).

/// One snow amount unit: 1 µm of snow depth (metres).
pub const SNOW_UNIT_M: f64 = 1e-6;

/// [`MapLayer::links`] value: the neighbour is a wall (only higher, unconnected surfaces there); no
/// snow moves that way.
pub const LINK_WALL: u8 = 254;
/// [`MapLayer::links`] value: beyond the neighbour is the edge of the scene (off the map, or a column
/// with no geometry at all); snow moved that way leaves the scene and is counted as lost.
pub const LINK_LOST: u8 = 255;

/// The four neighbours in a fixed order: −X, +X, −Z, +Z (as `(di, dj)`).
pub const NEIGHBOURS: [(isize, isize); 4] = [(-1, 0), (1, 0), (0, -1), (0, 1)];

/// The direction index opposite to `d` in [`NEIGHBOURS`].
#[inline]
pub const fn opposite(d: usize) -> usize {
    d ^ 1
}

/// `⌊(ceiling − base) / unit⌋` in snow units, saturating (see [`MapLayer::capacity`]).
#[inline]
pub fn capacity_units(base: f32, ceiling: f32) -> u32 {
    if base.is_nan() {
        return 0;
    }
    let room = (f64::from(ceiling) - f64::from(base)) / SNOW_UNIT_M;
    if room >= f64::from(u32::MAX) {
        u32::MAX
    } else if room > 0.0 {
        room as u32
    } else {
        0
    }
}

/// One depth layer of the snow maps (see the module doc for the indexing).
#[derive(Debug, Clone, PartialEq)]
pub struct MapLayer {
    /// Base height (world Y, metres) of the snow-possible surface at each cell centre; NaN where
    /// this layer has no surface at the cell.
    pub base: Vec<f32>,
    /// Unit normal of that surface (the triangle's), `[0, 0, 0]` where `base` is NaN.
    pub normal: Vec<[f32; 3]>,
    /// Height of the underside of the next geometry above the surface (metres), `+∞` under open
    /// sky, NaN where `base` is NaN. Snow is clipped at it (our addition; the paper's hand-made
    /// groups never overlap): a cell holds at most [`MapLayer::capacity`] units; accumulation does
    /// not deposit beyond it, and stabilization treats snow that does not fit like snow on a wall:
    /// it moves on (see [`super::settle`]).
    pub ceiling: Vec<f32>,
    /// Snow probability P in [0, 1] (journal §2.2), 0 where `base` is NaN.
    pub probability: Vec<f32>,
    /// Snow depth in units of [`SNOW_UNIT_M`] (0 where `base` is NaN).
    pub snow: Vec<u32>,
    /// Per cell, for each direction of [`NEIGHBOURS`], the layer index in the neighbouring cell that
    /// snow moving that way lands on, or [`LINK_WALL`] / [`LINK_LOST`]. Meaningless where `base` is
    /// NaN.
    pub links: Vec<[u8; 4]>,
}

impl MapLayer {
    /// An empty layer of `n` cells (no surface anywhere).
    pub fn empty(n: usize) -> Self {
        Self {
            base: vec![f32::NAN; n],
            normal: vec![[0.0; 3]; n],
            ceiling: vec![f32::NAN; n],
            probability: vec![0.0; n],
            snow: vec![0; n],
            links: vec![[LINK_WALL; 4]; n],
        }
    }

    /// Snow depth at cell `c`, metres.
    #[inline]
    pub fn depth_m(&self, c: usize) -> f32 {
        (self.snow[c] as f64 * SNOW_UNIT_M) as f32
    }

    /// Snow surface height (base + depth, clipped at the ceiling) at cell `c`, metres; NaN where
    /// there is no surface.
    #[inline]
    pub fn surface(&self, c: usize) -> f32 {
        let s = self.base[c] + self.depth_m(c);
        if s > self.ceiling[c] {
            self.ceiling[c]
        } else {
            s
        }
    }

    /// Most snow (units) that fits between the base and the ceiling at cell `c`: `⌊(ceiling −
    /// base) / unit⌋`, `u32::MAX` under open sky (or a gap of more than 4.29 km), 0 where there is
    /// no surface.
    #[inline]
    pub fn capacity(&self, c: usize) -> u32 {
        capacity_units(self.base[c], self.ceiling[c])
    }

    /// Total snow in this layer, in units.
    pub fn total_units(&self) -> u64 {
        self.snow.iter().map(|&s| u64::from(s)).sum()
    }

    /// Number of cells where this layer has a surface.
    pub fn cells(&self) -> usize {
        self.base.iter().filter(|b| !b.is_nan()).count()
    }
}

/// The layered snow maps of a scene (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct SnowMaps {
    /// Cells along X.
    pub nx: usize,
    /// Cells along Z.
    pub nz: usize,
    /// Cell side, metres.
    pub cell: f32,
    /// World (x, z) of the corner of cell (0, 0), metres.
    pub origin: [f32; 2],
    /// Depth layers, topmost first; at least one.
    pub layers: Vec<MapLayer>,
    /// Length (metres) of the scene's bounding-box diagonal; scales depth epsilons and biases.
    pub extent: f32,
}

impl SnowMaps {
    /// Number of cells per layer.
    #[inline]
    pub fn len(&self) -> usize {
        self.nx * self.nz
    }

    /// True when the grid has no cells.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// World (x, z) of the centre of cell (i, j).
    #[inline]
    pub fn centre(&self, i: usize, j: usize) -> [f32; 2] {
        [
            self.origin[0] + (i as f32 + 0.5) * self.cell,
            self.origin[1] + (j as f32 + 0.5) * self.cell,
        ]
    }

    /// The neighbour of cell (i, j) in direction `d` of [`NEIGHBOURS`], if on the map.
    #[inline]
    pub fn neighbour(&self, i: usize, j: usize, d: usize) -> Option<usize> {
        let (di, dj) = NEIGHBOURS[d];
        let (i2, j2) = (i as isize + di, j as isize + dj);
        if i2 < 0 || j2 < 0 || i2 as usize >= self.nx || j2 as usize >= self.nz {
            None
        } else {
            Some(j2 as usize * self.nx + i2 as usize)
        }
    }

    /// Volume of one snow unit over one cell, m³.
    #[inline]
    pub fn unit_volume_m3(&self) -> f64 {
        SNOW_UNIT_M * f64::from(self.cell) * f64::from(self.cell)
    }

    /// Snow resting on the maps, in units (all layers).
    pub fn total_units(&self) -> u64 {
        self.layers.iter().map(MapLayer::total_units).sum()
    }

    /// Snow resting on each layer, m³.
    pub fn resting_m3(&self) -> Vec<f64> {
        let v = self.unit_volume_m3();
        self.layers
            .iter()
            .map(|l| l.total_units() as f64 * v)
            .collect()
    }

    /// Snow depth of layer `k` as metres (allocates one `f32` grid).
    pub fn depth_grid(&self, k: usize) -> Vec<f32> {
        let l = &self.layers[k];
        (0..self.len()).map(|c| l.depth_m(c)).collect()
    }

    /// Remove all snow (keeps geometry and probabilities).
    pub fn clear_snow(&mut self) {
        for l in &mut self.layers {
            l.snow.iter_mut().for_each(|s| *s = 0);
        }
    }
}
