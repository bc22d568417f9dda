//! Uniform grid traversed by 3D-DDA (Amanatides & Woo, "A fast voxel
//! traversal algorithm for ray tracing", 1987), crossing empty space in
//! skips by each cell's distance to the nearest cell that lists anything
//! (Cohen & Sheffer, "Proximity clouds: an acceleration technique for 3D
//! grid traversal", 1994).

use crate::{each_id, AccelStats, BuildConfig, Clip, Leaf, RayCounter, BLOCK};
use raymesh_geometry::{cull_bound, Aabb, Ray, Vec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};

/// Most cells a grid may have, whatever the density asks: keeps the cell
/// table within a few hundred MB for any input.
const MAX_CELLS: usize = 1 << 26;

/// A uniform grid over the primitives' bounds. Each cell lists the
/// primitives whose (slightly padded) box overlaps it, in CSR form; or,
/// built with a [`Clip`] ([`Self::build_clipped`]), those whose shape's
/// part in the cell's slab does.
///
/// A ray steps through cells in order and stops at the first cell whose
/// exit lies beyond the best hit: any closer hit would lie in a cell already
/// visited. Boxes are padded by a small fraction of a cell when binned, so
/// rounding in the hit point cannot move a hit out of the cells that hold
/// its primitive. A primitive in several cells is tested once per ray, as
/// a rule (a small hashed mailbox on the ray's stack).
///
/// Where the cells around a ray's cell are empty for some way (its
/// clearance: the distance to the nearest cell that lists anything), the
/// ray moves to the last of them it reaches in one skip, through the same
/// cells the steps would have crossed: `raymesh-ab --accel grid` against
/// the grid without skips (2a6d663, each build once as the other's
/// baseline on the small meshes), primary rays 1.17-1.66x (bunny00, the
/// dragon) and 1.56-1.99x (a 2M-triangle terrain, bunny00 subdivided
/// twice), random rays 0.99-1.17x, diffuse 0.96-1.16x (the dragon's
/// 0.96-0.99x), shadow 0.99-1.20x; for a byte a cell (about 2 a
/// triangle) and builds 7-13% longer (`raymesh scale --accel grid`, 1M
/// and 10M triangles).
///
/// A cell that lists [`BuildConfig::grid_subgrid_min`] primitives or more
/// (64 by default), and [`BuildConfig::grid_subgrid_ratio`] times the mean
/// of the cells that list any (4), gets a grid of its own, walked in turn
/// when a ray meets the cell: a two-level grid, which adapts to a dense
/// object in a large sparse scene where one level cannot (the bunny on
/// the field of a stadium: 0.0074 -> 1.1 Mrays/s, docs/measurements.md,
/// *The teapot in a stadium*). Where no cell has a grid, the walk is
/// compiled without the steps into them and costs what a one-level walk
/// does.
#[derive(Clone, Debug)]
pub struct Grid {
    bounds: Aabb,
    res: [u32; 3],
    cell_size: Vec3,
    inv_cell_size: Vec3,
    cell_starts: Vec<u32>,
    cell_prims: Vec<u32>,
    /// Cell `c`'s clearance: 0 if it lists anything, else its distance
    /// in cells (the most of its three axes' distances) to the nearest
    /// cell that does, at most [`MAX_CLEARANCE`]. Every cell closer than
    /// that is empty, so a ray crosses them in one skip.
    clearance: Vec<u8>,
    /// The grids of the cells whose clearance is [`SUBGRID`], each listed
    /// by its index in its cell's list (see [`Self::split_dense_cells`]).
    /// Their own cells have none.
    subgrids: Vec<Grid>,
    len: usize,
}

/// [`Grid::clearance`] of a cell whose primitives lie in a grid of its own
/// ([`Grid::subgrids`]): beyond [`MAX_CLEARANCE`], which no empty cell
/// exceeds.
const SUBGRID: u8 = u8::MAX;

/// The fewest cells (or references, or bytes) a parallel pass of a build
/// gives each of its tasks: a cell's own grid (a few hundred cells) is
/// built in one, on the thread that builds it, not split into tasks of a
/// few cells each (10M triangles of terrain gave 85,000 cells grids of
/// their own, which took 1.4 s with tasks that small).
const PAR_MIN: usize = 4096;

/// [`PAR_MIN`] for the passes over primitives, each of which visits its
/// cells.
const PAR_MIN_PRIMS: usize = 256;

/// The most references a cell's grid may make a primitive of the cell on
/// average ([`Grid::split_dense_cells`]).
const SUBGRID_MAX_REFS: u64 = 8;

/// The fewest cells a primitive's box must span for a clipped build
/// ([`Grid::build_clipped`]) to clip it: 3 × 3 × 3. From 8, a 2 × 2 × 2
/// box (what most triangles of a scanned mesh span at 2 cells a
/// triangle) was clipped too, for about as many triangles tested a ray
/// and builds 1.4 to 2.2 times as long (`raymesh bench --accel grid`,
/// bunny00, the dragon, the pig, polygon_mesh). Long triangles, which fill
/// cubes of cells, are clipped either way.
const CLIP_MIN_CELLS: u64 = 27;

/// Slots of a ray's mailbox (see [`Grid::dda`]): 1 KiB on the stack,
/// zeroed a ray. It replaced a per-thread array of a stamp per primitive
/// (4 bytes a primitive in every thread that traced, read at random on
/// large meshes): `raymesh-ab --accel grid`, random rays, bunny00
/// subdivided twice (1.2M triangles) 1.06-1.14x, a 700K-triangle sphere
/// 1.10x, bunny00 and the dragon 0.97-1.03x (primary rays 0.99-1.01x). 64
/// slots read 0.94-0.97x on the dragon's primary rays.
const MAILBOX_SLOTS: usize = 256;

/// The most [`Grid::clearance`] says: a ray skips at most this many
/// cells less one along an axis at a time.
const MAX_CLEARANCE: u8 = 16;

/// The least [`Grid::clearance`] at which a ray skips cells instead of
/// stepping: from 3, a skip crosses at least two cells. From 2 (one
/// cell), `raymesh-ab --accel grid` against 3 read 0.96-0.99x on random
/// rays and 1.0-1.05x on primary ones (bunny00, the dragon): the skip's
/// set-up and its unpredictable loops cost more than a step or two.
const MIN_SKIP: u8 = 3;

/// [`Grid::clearance`] for the cells of a grid of `res` cells whose list
/// bounds are `starts` (one more than the cells).
///
/// The distance to the nearest listing cell by the most of the three
/// axes' distances is `min over q of max(|dx|, |dy|, |dz|)`, which three
/// passes along the axes compute in turn (`max` distributes over `min`):
/// each takes, for each cell, the least of `max(k, before)` over the
/// cells `k` away on its axis, `before` what the previous pass found
/// there. With the distances capped at [`MAX_CLEARANCE`], `k` runs to it,
/// and each pass is a few vector operations on rows of bytes.
fn clearance(starts: &[u32], res: [u32; 3]) -> Vec<u8> {
    let [rx, ry, rz] = res.map(|r| r as usize);
    let mut from: Vec<u8> = starts
        .par_windows(2)
        .with_min_len(PAR_MIN)
        .map(|w| if w[1] > w[0] { 0 } else { MAX_CLEARANCE })
        .collect();
    let mut to = from.clone();
    // Within lines of `len` cells `stride` apart, in runs of `run`
    // consecutive cells (the lines' own layout): `to[i] = min(to[i],
    // max(k, from[i ± k * stride]))` for k up to the cap.
    let pass = |from: &[u8], to: &mut [u8], run: usize, stride: usize, len: usize| {
        to.par_chunks_mut(run)
            .zip(from.par_chunks(run))
            .with_min_len(PAR_MIN.div_ceil(run))
            .for_each(|(to, from)| {
                for k in 1..(MAX_CLEARANCE as usize).min(len) {
                    let off = k * stride;
                    let kk = k as u8;
                    for (t, &f) in to[off..].iter_mut().zip(&from[..from.len() - off]) {
                        *t = (*t).min(f.max(kk));
                    }
                    let n = to.len();
                    for (t, &f) in to[..n - off].iter_mut().zip(&from[off..]) {
                        *t = (*t).min(f.max(kk));
                    }
                }
            });
    };
    // Along x within each row, then along y within each slice.
    pass(&from, &mut to, rx, 1, rx);
    from.copy_from_slice(&to);
    pass(&from, &mut to, rx * ry, rx, ry);
    from.copy_from_slice(&to);
    // Along z, slice by slice: each slice reads the slices `k` away.
    let slice = rx * ry;
    to.par_chunks_mut(slice)
        .enumerate()
        .with_min_len(PAR_MIN.div_ceil(slice))
        .for_each(|(z, to)| {
            for k in 1..(MAX_CLEARANCE as usize).min(rz) {
                let kk = k as u8;
                for zz in [z.checked_sub(k), Some(z + k).filter(|&zz| zz < rz)]
                    .into_iter()
                    .flatten()
                {
                    for (t, &f) in to.iter_mut().zip(&from[zz * slice..(zz + 1) * slice]) {
                        *t = (*t).min(f.max(kk));
                    }
                }
            }
        });
    to
}

impl Grid {
    /// Builds a grid of about `density × N` cells shaped like the bounds.
    #[must_use]
    pub fn build(boxes: &[Aabb], config: &BuildConfig) -> Self {
        Self::build_by(boxes.len(), &|i| boxes[i as usize], None, config).0
    }

    /// [`Self::build`], a primitive listed only in the cells its shape
    /// reaches, not every cell its box does: `clip` cuts it to each slab
    /// of cells it spans (see [`Clip`]; for triangles,
    /// [`raymesh_geometry::clip_triangle`]). A diagonal triangle's box
    /// spans cells it never touches.
    #[must_use]
    pub fn build_clipped(boxes: &[Aabb], clip: &Clip<'_>, config: &BuildConfig) -> Self {
        Self::build_by(boxes.len(), &|i| boxes[i as usize], Some(clip), config).0
    }

    /// [`Self::build`] over `n` primitives whose boxes `box_of(i)` gives,
    /// asked for again in each pass rather than kept in an array (24 bytes
    /// a primitive less at the peak: 2.4 GB at 100M triangles); also
    /// returns the union of the boxes (the grid's own box is padded).
    pub(crate) fn build_by(
        n: usize,
        box_of: &(dyn Fn(u32) -> Aabb + Sync),
        clip: Option<&Clip<'_>>,
        config: &BuildConfig,
    ) -> (Self, Aabb) {
        assert!(
            n <= u32::MAX as usize,
            "too many primitives for u32 indices"
        );
        // In parallel: unions are exact, so any order gives the same box.
        let union = (0..n as u32)
            .into_par_iter()
            .map(box_of)
            .reduce(|| Aabb::EMPTY, Aabb::union);
        let grid = Self::build_in(n, box_of, clip, union, config);
        (grid, union)
    }

    /// [`Self::build_by`] once the union of the boxes, `bounds`, is known:
    /// one level of cells, then a grid of its own in each crowded cell
    /// ([`Self::split_dense_cells`]).
    fn build_in(
        n: usize,
        box_of: &(dyn Fn(u32) -> Aabb + Sync),
        clip: Option<&Clip<'_>>,
        bounds: Aabb,
        config: &BuildConfig,
    ) -> Self {
        let mut g = Self::build_level(n, box_of, clip, bounds, config, None)
            .expect("a build without a reference budget");
        if config.grid_subgrid_min > 0 {
            g.split_dense_cells(box_of, clip, config);
        }
        g
    }

    /// One level of cells over `bounds` (see [`Self::build_in`]); `None`
    /// when the primitives would be listed more than `max_refs` times.
    fn build_level(
        n: usize,
        box_of: &(dyn Fn(u32) -> Aabb + Sync),
        clip: Option<&Clip<'_>>,
        bounds: Aabb,
        config: &BuildConfig,
        max_refs: Option<u64>,
    ) -> Option<Self> {
        if n == 0 || bounds.is_empty() {
            return Some(Self {
                bounds: Aabb::EMPTY,
                res: [1; 3],
                cell_size: Vec3::ONE,
                inv_cell_size: Vec3::ONE,
                cell_starts: vec![0, 0],
                cell_prims: Vec::new(),
                clearance: vec![MAX_CLEARANCE],
                subgrids: Vec::new(),
                len: n,
            });
        }
        // Flat boxes get a thickness so cells have volume, and the grid's box
        // is padded so it holds every primitive strictly (`min + (max - min)`
        // can round below `max`, which would lose hits on the boundary).
        let ext = bounds.extent();
        let floor = ext.max_element().max(f32::MIN_POSITIVE) * 1e-3;
        let pad =
            ext * 1e-5 + Vec3::splat(bounds.min.abs().max(bounds.max.abs()).max_element() * 1e-6);
        let bounds = Aabb::new(bounds.min - pad, bounds.max + pad);
        let ext = bounds.extent().max(Vec3::splat(floor));
        let target = (config.grid_density.max(1e-3) as f64 * n as f64).clamp(1.0, MAX_CELLS as f64);
        let k = (target / (ext.x as f64 * ext.y as f64 * ext.z as f64)).cbrt();
        let mut res = [0u32; 3];
        for a in 0..3 {
            res[a] = ((ext[a] as f64 * k).round() as u32).clamp(1, 1 << 12);
        }
        while res.iter().map(|&r| r as usize).product::<usize>() > MAX_CELLS {
            let a = (0..3).max_by_key(|&a| res[a]).unwrap();
            res[a] = (res[a] / 2).max(1);
        }
        let resv = Vec3::new(res[0] as f32, res[1] as f32, res[2] as f32);
        let cell_size = ext / resv;
        let inv_cell_size = resv / ext;
        let bounds = Aabb::new(bounds.min, bounds.max.max(bounds.min + ext));
        let mut g = Self {
            bounds,
            res,
            cell_size,
            inv_cell_size,
            cell_starts: Vec::new(),
            cell_prims: Vec::new(),
            clearance: Vec::new(),
            subgrids: Vec::new(),
            len: n,
        };
        // Two parallel passes, count per cell then fill (CSR), with atomic
        // counters; then each cell's list is sorted, which gives the lists
        // a one-thread build makes (primitives in increasing order).
        let ncells = res.iter().map(|&r| r as usize).product::<usize>();
        // Every pass over cells or references runs in parallel: at 100M
        // triangles the sequential ones were most of the build.
        let counts: Vec<AtomicU32> = (0..ncells + 1)
            .into_par_iter()
            .with_min_len(PAR_MIN)
            .map(|_| AtomicU32::new(0))
            .collect();
        (0..n as u32)
            .into_par_iter()
            .with_min_len(PAR_MIN_PRIMS)
            .for_each(|i| {
                g.for_cells_of(i, &box_of(i), clip, |c| {
                    counts[c].fetch_add(1, Ordering::Relaxed);
                });
            });
        let mut counts: Vec<u32> = counts
            .into_par_iter()
            .with_min_len(PAR_MIN)
            .map(AtomicU32::into_inner)
            .collect();
        if let Some(most) = max_refs {
            let refs: u64 = counts
                .par_iter()
                .with_min_len(PAR_MIN)
                .map(|&c| u64::from(c))
                .sum();
            if refs > most {
                return None;
            }
        }
        let mut total = 0u32;
        for c in counts.iter_mut() {
            let here = *c;
            *c = total;
            total = total
                .checked_add(here)
                .expect("a grid of more than 2^32 cell references");
        }
        let fill: Vec<AtomicU32> = counts
            .par_iter()
            .with_min_len(PAR_MIN)
            .map(|&c| AtomicU32::new(c))
            .collect();
        let prims: Vec<AtomicU32> = (0..total)
            .into_par_iter()
            .with_min_len(PAR_MIN)
            .map(|_| AtomicU32::new(0))
            .collect();
        (0..n as u32)
            .into_par_iter()
            .with_min_len(PAR_MIN_PRIMS)
            .for_each(|i| {
                g.for_cells_of(i, &box_of(i), clip, |c| {
                    let k = fill[c].fetch_add(1, Ordering::Relaxed);
                    prims[k as usize].store(i, Ordering::Relaxed);
                });
            });
        drop(fill);
        let mut prims: Vec<u32> = prims
            .into_par_iter()
            .with_min_len(PAR_MIN)
            .map(AtomicU32::into_inner)
            .collect();
        // Sort each cell's list, in parallel over runs of cells.
        const RUN: usize = 4096;
        let mut runs = Vec::with_capacity(ncells / RUN + 1);
        let mut rest = &mut prims[..];
        for first in (0..ncells).step_by(RUN) {
            let last = (first + RUN).min(ncells);
            let len = (counts[last] - counts[first]) as usize;
            let (run, tail) = rest.split_at_mut(len);
            runs.push((first, run));
            rest = tail;
        }
        runs.into_par_iter().for_each(|(first, run)| {
            let base = counts[first];
            for c in first..(first + RUN).min(ncells) {
                let (a, b) = (counts[c] - base, counts[c + 1] - base);
                run[a as usize..b as usize].sort_unstable();
            }
        });
        g.clearance = clearance(&counts, res);
        g.cell_starts = counts;
        g.cell_prims = prims;
        Some(g)
    }

    /// Gives each cell that lists [`BuildConfig::grid_subgrid_min`]
    /// primitives or more, and [`BuildConfig::grid_subgrid_ratio`] times
    /// as many as the cells that list any do on average, a grid of its
    /// own over the part of the cell its
    /// primitives fill, as many cells as [`BuildConfig::grid_density`]
    /// asks for them (Jevans & Wyvill, "Adaptive voxel subdivision for ray
    /// tracing", 1989; Kalojanov, Billeter & Slusallek, "Two-level grids
    /// for ray tracing on GPUs", 2011). A uniform grid sizes its cells for
    /// the whole scene, so a dense object in a large sparse scene (a
    /// teapot in a stadium) falls in a few cells of thousands of
    /// primitives each. A cell whose grid would list its primitives more
    /// than [`SUBGRID_MAX_REFS`] times each (long primitives that cross
    /// the whole cell, which a finer grid cannot separate) keeps its list.
    ///
    /// The cell's list becomes one entry, the index of its grid in
    /// [`Self::subgrids`], and its clearance [`SUBGRID`]; the clearance of
    /// the cells around is that of a listing cell, as before.
    fn split_dense_cells(
        &mut self,
        box_of: &(dyn Fn(u32) -> Aabb + Sync),
        clip: Option<&Clip<'_>>,
        config: &BuildConfig,
    ) {
        let starts = &self.cell_starts;
        let ncells = starts.len() - 1;
        let listing = self
            .clearance
            .par_iter()
            .with_min_len(PAR_MIN)
            .filter(|&&c| c == 0)
            .count();
        let mean = self.cell_prims.len() as f64 / listing.max(1) as f64;
        let min = (config.grid_subgrid_min as f64)
            .max(f64::from(config.grid_subgrid_ratio) * mean)
            .ceil()
            .min(f64::from(u32::MAX)) as u32;
        let dense: Vec<usize> = (0..ncells)
            .into_par_iter()
            .with_min_len(PAR_MIN)
            .filter(|&c| starts[c + 1] - starts[c] >= min)
            .collect();
        let subs: Vec<(usize, Grid)> = dense
            .into_par_iter()
            .filter_map(|c| Some((c, self.subgrid(c, box_of, clip, config)?)))
            .collect();
        if subs.is_empty() {
            return;
        }
        // The lists again, each dense cell's replaced by its grid's index:
        // runs of cells between dense ones are copied whole, and their
        // starts move down by what the dense cells before them gave up.
        let old = std::mem::take(&mut self.cell_prims);
        let mut prims = Vec::with_capacity(old.len());
        // What the dense cells so far gave up, and the first cell whose
        // start has not moved yet (the starts from it on are the old ones).
        let mut removed = 0u32;
        let mut next = 0usize;
        for (k, (c, _)) in subs.iter().enumerate() {
            let starts = &mut self.cell_starts;
            let (a, b) = (starts[*c] as usize, starts[c + 1] as usize);
            prims.extend_from_slice(&old[starts[next] as usize..a]);
            prims.push(k as u32);
            for s in &mut starts[next..=*c] {
                *s -= removed;
            }
            removed += (b - a) as u32 - 1;
            next = c + 1;
        }
        prims.extend_from_slice(&old[self.cell_starts[next] as usize..]);
        for s in &mut self.cell_starts[next..] {
            *s -= removed;
        }
        drop(old);
        self.cell_prims = prims;
        for (c, sub) in subs {
            self.clearance[c] = SUBGRID;
            self.subgrids.push(sub);
        }
        debug_assert_eq!(
            self.cell_starts.last().map(|&s| s as usize),
            Some(self.cell_prims.len())
        );
    }

    /// The grid of cell `c`'s primitives (see [`Self::split_dense_cells`]),
    /// over the part of the cell (padded as [`Self::cell_range`] pads it)
    /// their boxes fill, listing each primitive by its box cut to that
    /// part; `None` past [`SUBGRID_MAX_REFS`] references a primitive.
    fn subgrid(
        &self,
        c: usize,
        box_of: &(dyn Fn(u32) -> Aabb + Sync),
        clip: Option<&Clip<'_>>,
        config: &BuildConfig,
    ) -> Option<Grid> {
        let ids = &self.cell_prims[self.cell_starts[c] as usize..self.cell_starts[c + 1] as usize];
        let (rx, ry) = (self.res[0] as usize, self.res[1] as usize);
        let at = Vec3::new(
            (c % rx) as f32,
            (c / rx % ry) as f32,
            (c / (rx * ry)) as f32,
        );
        let min = self.bounds.min + at * self.cell_size;
        let pad = self.cell_size * 1e-3;
        let cell = Aabb::new(min - pad, min + self.cell_size + pad);
        let within = ids
            .iter()
            .fold(Aabb::EMPTY, |b, &i| b.union(box_of(i)))
            .intersection(cell);
        if within.is_empty() {
            // (Each box reaches into the padded cell, or it would not be
            // listed there: this is for boxes of NaN.)
            return None;
        }
        let local_box = |j: u32| box_of(ids[j as usize]).intersection(within);
        let local_clip =
            clip.map(|clip| move |j: u32, w, axis, pos| clip(ids[j as usize], w, axis, pos));
        let mut sub = Self::build_level(
            ids.len(),
            &local_box,
            local_clip.as_ref().map(|f| f as &Clip<'_>),
            within,
            config,
            Some(SUBGRID_MAX_REFS * ids.len() as u64),
        )?;
        // Local indices to the primitives' own: `ids` is in increasing
        // order, so each cell's list stays so.
        for p in &mut sub.cell_prims {
            *p = ids[*p as usize];
        }
        Some(sub)
    }

    /// Cells per axis.
    #[must_use]
    pub fn resolution(&self) -> [u32; 3] {
        self.res
    }

    pub(crate) fn bounds(&self) -> Aabb {
        self.bounds
    }

    #[inline(always)]
    fn cell_index(&self, c: [u32; 3]) -> usize {
        (c[2] as usize * self.res[1] as usize + c[1] as usize) * self.res[0] as usize
            + c[0] as usize
    }

    /// Cell of a point, clamped into the grid.
    #[inline(always)]
    fn cell_of(&self, p: Vec3, a: usize) -> u32 {
        let f = (p[a] - self.bounds.min[a]) * self.inv_cell_size[a];
        // Clamped into the cells in floats (`max` drops a NaN), then
        // truncated: for `f >= 0` truncation is the floor, so this is the
        // cell `floor(f)` clamped, without a call to `floorf` (x86-64's
        // baseline has no rounding instruction) or a saturating cast.
        f.max(0.0).min((self.res[a] - 1) as f32) as i32 as u32
    }

    /// Calls `f` with the index of every cell of the inclusive range
    /// `lo..=hi` ([`Self::cell_range`]; generic, so that the build's
    /// passes inline it).
    #[inline]
    fn for_cells(&self, (lo, hi): ([u32; 3], [u32; 3]), mut f: impl FnMut(usize)) {
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    f(self.cell_index([x, y, z]));
                }
            }
        }
    }

    /// [`Self::for_cells`] of the cells primitive `i`'s box `b` overlaps,
    /// or with `clip`, of the cells its shape's parts reach: for each slab
    /// of cells along z the box spans, the part inside the slab (padded by the same 1/1000
    /// of a cell as the box), and within it each slab along y, whose
    /// part's box gives the cells along x. Conservative as `clip` is: a
    /// point of the primitive lies in the part of every padded slab that
    /// holds it, so the primitive is listed in every cell the box test
    /// would list it in for that point.
    #[inline]
    fn for_cells_of(&self, i: u32, b: &Aabb, clip: Option<&Clip<'_>>, mut f: impl FnMut(usize)) {
        let (lo, hi) = self.cell_range(b);
        // A box one cell thick on two axes lies in a row of cells, each of
        // which the primitive (convex, as a triangle is) reaches: nothing
        // to clip away. A box of fewer than [`CLIP_MIN_CELLS`] cells is
        // not worth clipping either.
        let spanned = (0..3).filter(|&a| lo[a] != hi[a]).count();
        let cells: u64 = (0..3).map(|a| u64::from(hi[a] - lo[a]) + 1).product();
        let Some(clip) = clip.filter(|_| spanned >= 2 && cells >= CLIP_MIN_CELLS) else {
            return self.for_cells((lo, hi), f);
        };
        for z in lo[2]..=hi[2] {
            let zb = self.slab_part(i, *b, clip, 2, z);
            if zb.is_empty() {
                continue;
            }
            let (zlo, zhi) = self.cell_range(&zb);
            let (y0, y1) = (zlo[1].max(lo[1]), zhi[1].min(hi[1]));
            let (x0, x1) = (zlo[0].max(lo[0]), zhi[0].min(hi[0]));
            for y in y0..=y1 {
                // The part in a slab is convex: one cell thick along x or
                // y, it reaches every cell of its box.
                let (xa, xb) = if y0 == y1 || x0 == x1 {
                    (x0, x1)
                } else {
                    let yb = self.slab_part(i, zb, clip, 1, y);
                    if yb.is_empty() {
                        continue;
                    }
                    let (ylo, yhi) = self.cell_range(&yb);
                    (ylo[0].max(x0), yhi[0].min(x1))
                };
                for x in xa..=xb {
                    f(self.cell_index([x, y, z]));
                }
            }
        }
    }

    /// The box of primitive `i`'s part inside `within` and inside the
    /// slab of cells `k` along `axis`, padded by 1/1000 of a cell on both
    /// sides ([`Self::cell_range`]'s padding); clipped only at a plane
    /// that cuts `within`.
    fn slab_part(&self, i: u32, within: Aabb, clip: &Clip<'_>, axis: usize, k: u32) -> Aabb {
        let pad = self.cell_size[axis] * 1e-3;
        let start = self.bounds.min[axis] + k as f32 * self.cell_size[axis];
        let (a, b) = (start - pad, start + self.cell_size[axis] + pad);
        let mut w = within;
        if w.min[axis] < a {
            w = clip(i, w, axis, a).1;
        }
        if !w.is_empty() && w.max[axis] > b {
            w = clip(i, w, axis, b).0;
        }
        w
    }

    /// Inclusive cell range a box overlaps, padded by 1/1000 of a cell.
    fn cell_range(&self, b: &Aabb) -> ([u32; 3], [u32; 3]) {
        let pad = self.cell_size * 1e-3;
        let (lo, hi) = (b.min - pad, b.max + pad);
        let mut l = [0; 3];
        let mut h = [0; 3];
        for a in 0..3 {
            l[a] = self.cell_of(lo, a);
            h[a] = self.cell_of(hi, a);
        }
        (l, h)
    }

    /// The grid's cells and lists, its cells' grids included: a cell of
    /// each is a node, a cell that lists primitives a leaf, and the SAH
    /// cost adds each cell's grid weighted by the chance that a ray
    /// through the grid meets its box.
    pub(crate) fn stats(&self) -> AccelStats {
        let mut s = self.level_stats();
        let root_area = self.bounds.half_area() as f64;
        for sub in &self.subgrids {
            let t = sub.level_stats();
            s.nodes += t.nodes;
            // The cell that held the grid lists none itself.
            s.leaves += t.leaves - 1;
            s.bytes += t.bytes;
            s.depth = 2;
            if root_area > 0.0 {
                s.sah_cost += t.sah_cost * sub.bounds.half_area() as f64 / root_area;
            }
        }
        s
    }

    /// [`Self::stats`] of this level's cells alone.
    fn level_stats(&self) -> AccelStats {
        let ncells = self.cell_starts.len().saturating_sub(1);
        let nonempty = self.cell_starts.windows(2).filter(|w| w[1] > w[0]).count();
        let root_area = self.bounds.half_area() as f64;
        let c = self.cell_size;
        let cell_area = (c.x * c.y + c.y * c.z + c.z * c.x) as f64;
        let sah_cost = if root_area > 0.0 {
            // Expected cells stepped (one per unit of the grid's mean width)
            // plus the primitives in them, weighted by each cell's area.
            let refs = self.cell_prims.len() as f64;
            ncells as f64 * cell_area / root_area + refs * cell_area / root_area
        } else {
            self.len as f64
        };
        AccelStats {
            nodes: ncells,
            leaves: nonempty,
            depth: 1,
            bytes: self.cell_starts.len() * 4
                + self.cell_prims.len() * 4
                + self.clearance.len()
                + std::mem::size_of::<Self>(),
            sah_cost,
            ..AccelStats::default()
        }
    }

    #[inline]
    pub(crate) fn traverse<C: RayCounter>(&self, ray: &Ray, counter: &mut C, leaf: &mut impl Leaf) {
        self.traverse_lists(ray, counter, &mut each_id(ray, leaf));
    }

    /// Whether some cell has a grid of its own ([`Self::subgrids`]).
    pub(crate) fn two_level(&self) -> bool {
        !self.subgrids.is_empty()
    }

    /// Cell-by-cell traversal calling `list(ids)` with the primitives of
    /// each cell not yet tested for this ray, up to [`BLOCK`] at a time;
    /// it returns the ray's new upper bound (below `tmin` stops), so that
    /// a caller can test them together
    /// ([`crate::Primitives::intersect_ids`]). [`Self::walk`] through one
    /// level or two, as the grid has.
    #[inline]
    pub(crate) fn traverse_lists<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        list: &mut impl FnMut(&[u32]) -> f32,
    ) {
        if self.two_level() {
            self.walk::<true, C>(ray, counter, list);
        } else {
            self.walk::<false, C>(ray, counter, list);
        }
    }

    /// [`Self::traverse_lists`] through the cells of the top grid alone
    /// (`TWO` false: for a grid without [`Self::subgrids`]) or through
    /// the cells' own grids too.
    ///
    /// A cell with a grid of its own is walked through that grid's cells,
    /// from where the ray enters the part of the cell they cover, and
    /// then the walk goes on from the cell. One loop walks both levels, a
    /// [`Cursor`] for the grid it is in (the top one's kept aside
    /// meanwhile), so that the test of the cells' primitives, which the
    /// AVX2 walks inline, appears once in it. The walk of one level
    /// leaves the steps into cells' grids out: the cursor's grid never
    /// changes there, so the walk keeps what it reads of it in registers
    /// (with them, the walk took 3.7% more instructions a ray on the
    /// dragon's primary rays, callgrind, though no cell had a grid).
    #[inline(always)]
    pub(crate) fn walk<const TWO: bool, C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        list: &mut impl FnMut(&[u32]) -> f32,
    ) {
        let Some((t_enter, _)) = self.bounds.intersect_ray(ray, ray.tmax()) else {
            return;
        };
        // The ray's mailbox: the primitives it has tested, each in slot
        // `index % MAILBOX_SLOTS` (as its index plus one; 0 is empty), so
        // that a primitive listed in several cells is tested once, unless
        // another took its slot in between (then it is tested again, with
        // the same answer). Shared by both levels.
        let mut tested = [0u32; MAILBOX_SLOTS];
        let d = ray.dir();
        // Arrays, not `Vec3`s: `Vec3`'s `Index` is a `match` on the axis,
        // which changes from step to step, and mispredicted (as in the k-d
        // tree's walk).
        let mut axes = Axes {
            o: ray.origin().to_array(),
            inv: ray.inv_dir().to_array(),
            step: [0; 3],
        };
        // Loops, not `[0, 1, 2].map(..)`, here and in `Cursor::start`
        // (see `Cursor::skip`).
        for a in 0..3 {
            axes.step[a] = if d[a] > 0.0 {
                1
            } else if d[a] < 0.0 {
                -1
            } else {
                0
            };
        }
        let mut at = Cursor::start(self, &axes, ray.at(t_enter));
        // The top grid's cursor while the walk is in a cell's own grid.
        let mut top: Option<Cursor<'_>> = None;
        // `cull_bound` of the best hit's `t` so far, updated where it
        // changes (after a cell's tests) rather than at every step.
        let mut bound = cull_bound(ray.tmax());
        loop {
            counter.node();
            // Most cells a ray steps through are empty: the clearance
            // says so from a byte a cell, where the lists' bounds take 4
            // and leave the caches on large meshes (a bitmap of the cells
            // that list anything did the same before, 85e07a5: random
            // rays on bunny00 subdivided twice, 1.2M triangles,
            // 1.16-1.57x), and how far the empty space around reaches.
            let (g, c) = (at.grid, at.c);
            let clear = g.clearance[c];
            let here: &[u32] = if clear == 0 {
                &g.cell_prims[g.cell_starts[c] as usize..g.cell_starts[c + 1] as usize]
            } else if TWO && clear == SUBGRID {
                // The cell's own grid (only the top grid's cells have
                // one), from where the ray enters the part of the cell
                // its primitives fill; a miss: the ray meets none of them
                // in this cell.
                let sub = &g.subgrids[g.cell_prims[g.cell_starts[c] as usize] as usize];
                if let Some(inner) = Cursor::enter(sub, ray, &axes, bound) {
                    top = Some(std::mem::replace(&mut at, inner));
                    continue;
                }
                &[]
            } else {
                if clear >= MIN_SKIP {
                    at.skip(&axes, clear);
                }
                &[]
            };
            // Blocks of up to `BLOCK` untested primitives, each filled by
            // a loop with no call in it (the test comes after; from the
            // portable walk it is a call): with the call inside, the walk
            // reloaded five of its values at every primitive. Callgrind,
            // bunny00's random rays, 2,434 -> 2,168 instructions a ray in
            // the walk without the test; `raymesh-ab --accel grid`,
            // bunny00 and the dragon, both ways, 1.02-1.15x.
            let mut rest = here.iter();
            loop {
                let mut block = [0u32; BLOCK];
                let mut n = 0;
                for &p in rest.by_ref() {
                    // (`p` is below the count of primitives, at most `u32::MAX`.)
                    let key = p.wrapping_add(1);
                    let seen =
                        std::mem::replace(&mut tested[p as usize % MAILBOX_SLOTS], key) == key;
                    if !seen {
                        counter.prim();
                        block[n] = p;
                        n += 1;
                        if n == BLOCK {
                            break;
                        }
                    }
                }
                if n == 0 {
                    break;
                }
                let tmax = list(&block[..n]);
                if tmax < ray.tmin() {
                    return;
                }
                bound = cull_bound(tmax);
            }
            // The next cell, or back in the top grid once the ray leaves a
            // cell's grid (or the bound ends the walk there), to step on
            // from that cell (or end too).
            while !at.step(&axes, bound) {
                match top.take() {
                    Some(t) => at = t,
                    None => return,
                }
            }
        }
    }
}

/// What a ray's walk through grid cells keeps of it: its origin, the
/// reciprocals of its direction, and the way it steps along each axis.
struct Axes {
    o: [f32; 3],
    inv: [f32; 3],
    step: [i32; 3],
}

/// A ray's place in one grid's cells (3D-DDA, Amanatides & Woo): its cell,
/// by coordinates and by index, and the distance at which it leaves the
/// cell along each axis.
struct Cursor<'g> {
    grid: &'g Grid,
    lo: [f32; 3],
    size: [f32; 3],
    /// What a step along each axis adds to the cell's index (wrapping: a
    /// step down adds the stride's negation).
    delta: [usize; 3],
    cell: [u32; 3],
    c: usize,
    next: [f32; 3],
}

impl<'g> Cursor<'g> {
    /// The cursor in `grid`'s cell of point `p` on the ray (clamped into
    /// the grid).
    #[inline(always)]
    fn start(grid: &'g Grid, axes: &Axes, p: Vec3) -> Self {
        let res = grid.res;
        let stride = [1usize, res[0] as usize, res[0] as usize * res[1] as usize];
        let mut cur = Self {
            grid,
            lo: grid.bounds.min.to_array(),
            size: grid.cell_size.to_array(),
            delta: stride,
            cell: [0; 3],
            c: 0,
            next: [0.0; 3],
        };
        for a in 0..3 {
            cur.cell[a] = grid.cell_of(p, a);
            if axes.step[a] < 0 {
                cur.delta[a] = stride[a].wrapping_neg();
            }
        }
        cur.c = grid.cell_index(cur.cell);
        // Written out per axis (see `skip`).
        cur.next = [
            cur.boundary_t(axes, 0, cur.cell[0]),
            cur.boundary_t(axes, 1, cur.cell[1]),
            cur.boundary_t(axes, 2, cur.cell[2]),
        ];
        cur
    }

    /// Exit distance of cell `k` along axis `a`, computed from the
    /// boundary itself (not accumulated) so it does not drift.
    #[inline(always)]
    fn boundary_t(&self, axes: &Axes, a: usize, k: u32) -> f32 {
        if axes.step[a] == 0 {
            return f32::INFINITY;
        }
        let edge = k + (axes.step[a] > 0) as u32;
        (self.lo[a] + edge as f32 * self.size[a] - axes.o[a]) * axes.inv[a]
    }

    /// Every cell fewer than `clear` cells away is empty: the walk moves
    /// to the last of them the ray reaches, taking every crossing before
    /// it leaves them, as the steps would (the same cells and distances,
    /// whatever the order), and the step after goes on from there.
    /// `boundary_t` grows along an axis, so no axis passes its last cell
    /// of them, nor the grid's.
    #[inline(always)]
    fn skip(&mut self, axes: &Axes, clear: u8) {
        let r = u32::from(clear) - 1;
        let res = self.grid.res;
        // Written out per axis: as `[0, 1, 2].map(..)` it was a call,
        // which made the walk spill its values.
        let last = |a: usize| {
            if axes.step[a] > 0 {
                (self.cell[a] + r).min(res[a] - 1)
            } else {
                self.cell[a].saturating_sub(r)
            }
        };
        let exit = f32::INFINITY
            .min(self.boundary_t(axes, 0, last(0)))
            .min(self.boundary_t(axes, 1, last(1)))
            .min(self.boundary_t(axes, 2, last(2)));
        for a in 0..3 {
            while self.next[a] < exit {
                self.cell[a] = self.cell[a].wrapping_add_signed(axes.step[a]);
                self.c = self.c.wrapping_add(self.delta[a]);
                self.next[a] = self.boundary_t(axes, a, self.cell[a]);
            }
        }
        debug_assert_eq!(self.c, self.grid.cell_index(self.cell));
    }

    /// The cursor where the ray enters `grid` (a cell's own grid, see
    /// [`Grid::traverse_lists`]) before `bound`, if it does. Out of line:
    /// it is seldom called.
    #[inline(never)]
    fn enter(grid: &'g Grid, ray: &Ray, axes: &Axes, bound: f32) -> Option<Self> {
        let (t0, _) = grid.bounds.intersect_ray(ray, bound)?;
        Some(Self::start(grid, axes, ray.at(t0)))
    }

    /// Steps to the next cell along the ray; false where the walk through
    /// this grid ends: the ray leaves it, or the cell's exit lies beyond
    /// `bound` (any closer hit would lie in a cell already visited).
    #[inline(always)]
    fn step(&mut self, axes: &Axes, bound: f32) -> bool {
        // (Read in place: a copy of the three was a store and loads a
        // step, 9% of the dragon's primary rays.)
        let next = &self.next;
        let a = if next[0] <= next[1] && next[0] <= next[2] {
            0
        } else if next[1] <= next[2] {
            1
        } else {
            2
        };
        let exit = next[a];
        if bound < exit || exit.is_infinite() {
            return false;
        }
        if axes.step[a] > 0 {
            if self.cell[a] + 1 >= self.grid.res[a] {
                return false;
            }
            self.cell[a] += 1;
        } else {
            if self.cell[a] == 0 {
                return false;
            }
            self.cell[a] -= 1;
        }
        self.c = self.c.wrapping_add(self.delta[a]);
        debug_assert_eq!(self.c, self.grid.cell_index(self.cell));
        self.next[a] = self.boundary_t(axes, a, self.cell[a]);
        true
    }
}

/// A grid walked through one level of cells or two ([`Grid::walk`]),
/// fixed where the walk is compiled: the AVX2 walks take one or the other
/// in a region of its own (both in one made the region too large for
/// LLVM to inline the kernels into).
pub(crate) struct Levels<'a, const TWO: bool>(pub(crate) &'a Grid);

impl<const TWO: bool> Levels<'_, TWO> {
    /// [`Grid::walk`].
    #[inline(always)]
    pub(crate) fn traverse_lists<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        list: &mut impl FnMut(&[u32]) -> f32,
    ) {
        self.0.walk::<TWO, C>(ray, counter, list);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Whether the cell of point `q` lists primitive `i`.
    fn lists(g: &Grid, q: Vec3, i: u32) -> bool {
        let c = g.cell_index([0, 1, 2].map(|a| g.cell_of(q, a)));
        g.cell_prims[g.cell_starts[c] as usize..g.cell_starts[c + 1] as usize].contains(&i)
    }

    /// Diagonal slivers across the grid: listed by their boxes, each fills
    /// a cube of cells; clipped, only the cells along it, and each cell a
    /// sliver passes through or comes within the padding of still lists it
    /// (the cells of points sampled on it, and moved by half the padding),
    /// in a build that is the same on any number of threads.
    #[test]
    fn clipped_slivers_fill_only_their_cells() {
        let tris: Vec<[Vec3; 3]> = (0..300)
            .map(|i| {
                let x = (i % 20) as f32;
                let z = (i / 20) as f32;
                [
                    Vec3::new(x, 0.0, z),
                    Vec3::new(x + 0.05, 0.0, z),
                    Vec3::new(x + 9.0, 9.0, z + 9.0),
                ]
            })
            .collect();
        let boxes: Vec<Aabb> = tris.iter().map(|t| Aabb::from_points(*t)).collect();
        let config = BuildConfig::default();
        let clip = |i: u32, within, axis, pos| {
            raymesh_geometry::clip_triangle(tris[i as usize], within, axis, pos)
        };
        let by_box = Grid::build(&boxes, &config);
        let clipped = Grid::build_clipped(&boxes, &clip, &config);
        assert_eq!(by_box.res, clipped.res);
        assert!(
            4 * clipped.cell_prims.len() < by_box.cell_prims.len(),
            "{} references clipped against {} by box",
            clipped.cell_prims.len(),
            by_box.cell_prims.len()
        );
        for (i, t) in tris.iter().enumerate() {
            for k in 0..=64 {
                let (a, b) = (k as f32 / 64.0, (k % 7) as f32 / 7.0);
                let p = t[0] + (t[2] - t[0]) * a + (t[1] - t[0]) * (b * (1.0 - a));
                // As with boxes, a cell lists what comes within 1/1000 of
                // a cell of it: the cells of points moved half that way
                // list the sliver too.
                for (axis, side) in [
                    (0, 0.0),
                    (0, 1.0),
                    (0, -1.0),
                    (1, 1.0),
                    (1, -1.0),
                    (2, 1.0),
                    (2, -1.0),
                ] {
                    let mut q = p;
                    q[axis] += side * 5e-4 * clipped.cell_size[axis];
                    assert!(
                        lists(&clipped, q, i as u32),
                        "sliver {i} missing from the cell of {q}"
                    );
                }
            }
        }
        for threads in [1, 3] {
            let pool = crate::test_util::pool(threads);
            let again = pool.install(|| Grid::build_clipped(&boxes, &clip, &config));
            assert_eq!(again.cell_starts, clipped.cell_starts);
            assert_eq!(again.cell_prims, clipped.cell_prims, "{threads} threads");
        }
    }

    /// Triangles whose corner stops just short of a cell boundary (a third
    /// of the padding), from below and from above, are listed in the cells
    /// beyond it, clipped as by box: clipping keeps the 1/1000 of a cell
    /// that rounding in a hit point may need.
    #[test]
    fn clipped_cells_keep_the_padding() {
        let mut tris: Vec<[Vec3; 3]> = (0..64)
            .map(|i| {
                let p = Vec3::new((i % 4) as f32, (i / 4 % 4) as f32, (i / 16) as f32) * 3.0;
                [p, p + Vec3::X, p + Vec3::Y]
            })
            .collect();
        let boxes =
            |t: &[[Vec3; 3]]| -> Vec<Aabb> { t.iter().map(|t| Aabb::from_points(*t)).collect() };
        let config = BuildConfig::default();
        let g = Grid::build(&boxes(&tris), &config);
        assert!(g.res.iter().all(|&r| r >= 5), "{:?} cells", g.res);
        let cs = g.cell_size;
        // Diagonal triangles (spanning many cells, so clipped) ending a
        // third of the padding short of a corner of cells inside the grid.
        let probes = [(3.0, 1.0), (2.0, -1.0)].map(|(k, side)| {
            let apex = g.bounds.min + cs * k - cs * 3e-4 * side;
            let back = apex - cs * 2.5 * side;
            ([back, back + Vec3::new(0.01, 0.0, 0.0), apex], side)
        });
        for (i, (t, _)) in probes.iter().enumerate() {
            tris[i] = *t;
        }
        let b = boxes(&tris);
        let clip = |i: u32, within, axis, pos| {
            raymesh_geometry::clip_triangle(tris[i as usize], within, axis, pos)
        };
        let clipped = Grid::build_clipped(&b, &clip, &config);
        assert_eq!((clipped.bounds, clipped.res), (g.bounds, g.res));
        for (i, (t, side)) in probes.iter().enumerate() {
            for step in [Vec3::X, Vec3::Y, Vec3::Z, Vec3::ONE] {
                let q = t[2] + cs * step * 6e-4 * *side;
                assert!(
                    lists(&clipped, q, i as u32),
                    "triangle {i} missing from the cell of {q}"
                );
            }
        }
    }

    /// The lists a walk offers `ray`, in order (the bound never lowered),
    /// and the cells it counted.
    fn walk(g: &Grid, ray: &Ray) -> (Vec<Vec<u32>>, u64) {
        let mut seen = Vec::new();
        let mut count = crate::CountStats::default();
        g.traverse_lists(ray, &mut count, &mut |ids: &[u32]| {
            seen.push(ids.to_vec());
            ray.tmax()
        });
        (seen, count.nodes)
    }

    /// Seven clusters along the diagonal of their box, so that most cells
    /// are far from any listing one; and the same grid with every empty
    /// cell's clearance 1, which walks it cell by cell.
    fn sparse_grids() -> (Grid, Grid) {
        let g = Grid::build(
            &crate::test_util::clustered_boxes(700),
            &BuildConfig::default(),
        );
        let mut no_skips = g.clone();
        for c in &mut no_skips.clearance {
            if *c != SUBGRID {
                *c = (*c).min(1);
            }
        }
        (g, no_skips)
    }

    /// Each cell's clearance is its distance to the nearest listing cell
    /// (the most of the three axes'), capped, as found cell by cell.
    #[test]
    fn clearance_is_the_distance_to_the_nearest_listing_cell() {
        let mut next = crate::test_util::xorshift(0x1234_5679);
        for (res, listing) in [
            ([7, 5, 9], 6),
            ([40, 3, 2], 2),
            ([1, 1, 40], 1),
            ([6, 6, 6], 0),
        ] {
            let n = res.iter().product::<u32>() as usize;
            let full: Vec<usize> = (0..listing)
                .map(|_| (next() * (n - 1) as f32) as usize)
                .collect();
            let mut starts = vec![0u32; n + 1];
            for c in 0..n {
                starts[c + 1] = starts[c] + u32::from(full.contains(&c));
            }
            let got = clearance(&starts, res);
            let at = |c: usize| {
                let c = c as u32;
                [c % res[0], c / res[0] % res[1], c / (res[0] * res[1])].map(|v| v as i64)
            };
            for c in 0..n {
                let want = full
                    .iter()
                    .map(|&f| (0..3).map(|a| (at(c)[a] - at(f)[a]).abs()).max().unwrap())
                    .min()
                    .map_or(MAX_CLEARANCE, |d| d.min(i64::from(MAX_CLEARANCE)) as u8);
                assert_eq!(got[c], want, "cell {c} of {res:?}");
            }
        }
    }

    /// Rays across empty space skip cells (fewer counted) and are offered
    /// the same lists in the same order as cell by cell.
    #[test]
    fn empty_cells_are_skipped() {
        let (g, no_skips) = sparse_grids();
        assert!(
            g.clearance.iter().any(|&c| c >= MIN_SKIP),
            "{:?} cells",
            g.res
        );
        let mut next = crate::test_util::xorshift(0x9e37_79b9);
        let (mut skipped, mut all) = (0, 0);
        for _ in 0..2000 {
            let o = Vec3::new(next(), next(), next()) * 24.0 - 2.0;
            let d = Vec3::new(next(), next(), next()) * 2.0 - 1.0;
            let ray = Ray::infinite(o, d);
            let (a, n) = walk(&g, &ray);
            let (b, m) = walk(&no_skips, &ray);
            assert_eq!(a, b, "{ray:?}");
            (skipped, all) = (skipped + n, all + m);
        }
        assert!(skipped < all, "{skipped} cells against {all}");
    }

    proptest! {
        /// Skipping offers the same lists in the same order as walking
        /// cell by cell, for rays along axes, through cell corners
        /// (lattice points of the clusters' box) and with hard values.
        #[test]
        fn skips_match_cell_steps(
            o in prop_oneof![
                (0i32..=40, 0i32..=40, 0i32..=40)
                    .prop_map(|(x, y, z)| Vec3::new(x as f32, y as f32, z as f32) * 0.5),
                crate::test_util::hard_vec3(),
            ],
            d in prop_oneof![
                (-2i32..=2, -2i32..=2, -2i32..=2)
                    .prop_map(|(x, y, z)| Vec3::new(x as f32, y as f32, z as f32)),
                crate::test_util::hard_vec3(),
            ],
        ) {
            let (g, no_skips) = sparse_grids();
            let ray = Ray::infinite(o, d);
            prop_assert_eq!(walk(&g, &ray).0, walk(&no_skips, &ray).0);
        }
    }

    /// The default settings, but a grid of its own in every cell of 64
    /// primitives or more, however full the others are.
    fn split_config() -> BuildConfig {
        BuildConfig {
            grid_subgrid_ratio: 0.0,
            ..BuildConfig::default()
        }
    }

    /// Every level's cell lists, the top grid's first, each cell's by
    /// its index.
    fn levels(g: &Grid) -> Vec<(&[u32], &[u32])> {
        std::iter::once(g)
            .chain(&g.subgrids)
            .map(|g| (&g.cell_starts[..], &g.cell_prims[..]))
            .collect()
    }

    /// The parallel passes give the cell lists of a one-thread build:
    /// each cell's primitives in increasing order, whatever the threads,
    /// in the top grid and in the cells' own grids; every primitive is
    /// listed somewhere.
    #[test]
    fn parallel_build_is_identical_to_sequential() {
        let b = crate::test_util::clustered_boxes(20_000);
        for config in [
            split_config(),
            BuildConfig {
                grid_subgrid_min: 0,
                ..BuildConfig::default()
            },
        ] {
            let build = |threads| {
                let pool = crate::test_util::pool(threads);
                pool.install(|| Grid::build(&b, &config))
            };
            let one = build(1);
            assert_eq!(
                one.subgrids.is_empty(),
                config.grid_subgrid_min == 0,
                "{} cells' grids",
                one.subgrids.len()
            );
            let mut listed = vec![false; b.len()];
            for (level, (starts, prims)) in levels(&one).into_iter().enumerate() {
                for (c, w) in starts.windows(2).enumerate() {
                    let cell = &prims[w[0] as usize..w[1] as usize];
                    assert!(
                        cell.windows(2).all(|p| p[0] < p[1]),
                        "cell {c} of level {level} out of order"
                    );
                    if level > 0 || one.clearance[c] != SUBGRID {
                        for &p in cell {
                            listed[p as usize] = true;
                        }
                    }
                }
            }
            assert!(listed.iter().all(|&l| l), "a primitive listed nowhere");
            for threads in [2, 4] {
                let many = build(threads);
                assert_eq!(levels(&many), levels(&one), "{threads} threads");
                assert_eq!(many.clearance, one.clearance);
            }
        }
    }

    /// Clusters of a few thousand boxes each fill a few cells of a grid
    /// sized for their whole diagonal: those cells get grids of their
    /// own (with the default settings, none: the cells that list anything
    /// are all about as full), and each box's part in such a cell lies in
    /// cells of its grid that list it (points sampled over the part,
    /// corners included). The cells of the top grid keep their
    /// clearance, a subgrid's cell counting as one that lists.
    #[test]
    fn dense_cells_get_grids_of_their_own() {
        let b = crate::test_util::clustered_boxes(20_000);
        let even = Grid::build(&b, &BuildConfig::default());
        assert!(even.subgrids.is_empty(), "{}", even.subgrids.len());
        let g = Grid::build(&b, &split_config());
        let flat = Grid::build(
            &b,
            &BuildConfig {
                grid_subgrid_min: 0,
                ..BuildConfig::default()
            },
        );
        assert!(!g.subgrids.is_empty());
        for (c, (&cl, &fl)) in g.clearance.iter().zip(&flat.clearance).enumerate() {
            let n = flat.cell_starts[c + 1] - flat.cell_starts[c];
            if cl == SUBGRID {
                assert!(n as usize >= BuildConfig::default().grid_subgrid_min);
                assert_eq!(g.cell_starts[c + 1] - g.cell_starts[c], 1);
            } else {
                assert_eq!(cl, fl, "cell {c}");
                assert_eq!(
                    &g.cell_prims[g.cell_starts[c] as usize..g.cell_starts[c + 1] as usize],
                    &flat.cell_prims
                        [flat.cell_starts[c] as usize..flat.cell_starts[c + 1] as usize]
                );
            }
        }
        let mut next = crate::test_util::xorshift(0x0bad_cafe);
        for (c, &cl) in g.clearance.iter().enumerate() {
            if cl != SUBGRID {
                continue;
            }
            let sub = &g.subgrids[g.cell_prims[g.cell_starts[c] as usize] as usize];
            let (rx, ry) = (g.res[0] as usize, g.res[1] as usize);
            let at = Vec3::new(
                (c % rx) as f32,
                (c / rx % ry) as f32,
                (c / (rx * ry)) as f32,
            );
            let cell = Aabb::new(
                g.bounds.min + at * g.cell_size,
                g.bounds.min + (at + 1.0) * g.cell_size,
            );
            for &i in
                &flat.cell_prims[flat.cell_starts[c] as usize..flat.cell_starts[c + 1] as usize]
            {
                let part = b[i as usize].intersection(cell);
                if part.is_empty() {
                    continue; // listed for the padding only
                }
                for k in 0..10 {
                    let f = if k < 8 {
                        Vec3::new((k & 1) as f32, (k >> 1 & 1) as f32, (k >> 2) as f32)
                    } else {
                        Vec3::new(next(), next(), next())
                    };
                    let q = part.min + part.extent() * f;
                    assert!(
                        lists(sub, q, i),
                        "box {i} missing from cell {c}'s grid at {q}"
                    );
                }
            }
        }
        // A ray through the clusters meets the cells' grids.
        let ray = Ray::infinite(Vec3::splat(-1.0), Vec3::ONE);
        let (lists_two, cells_two) = walk(&g, &ray);
        let (lists_one, _) = walk(&flat, &ray);
        assert!(cells_two > 0 && !lists_two.is_empty() && !lists_one.is_empty());
    }

    /// A cell crossed whole by many long boxes keeps its list, however
    /// full the others are: a finer grid would list each of them in all
    /// of its cells.
    #[test]
    fn cells_of_long_boxes_keep_their_lists() {
        let mut b: Vec<Aabb> = (0..200)
            .map(|i| {
                let y = i as f32 * 1e-4;
                Aabb::new(Vec3::new(0.0, 0.5 + y, 0.0), Vec3::new(10.0, 0.5 + y, 10.0))
            })
            .collect();
        // Small boxes elsewhere, for a grid of many cells.
        let mut next = crate::test_util::xorshift(0x5eed_1234);
        b.extend((0..2000).map(|_| {
            let p = Vec3::new(next(), next() * 0.3 + 2.0, next()) * 10.0;
            Aabb::new(p, p + Vec3::splat(0.01))
        }));
        let g = Grid::build(&b, &split_config());
        assert!(g.res.iter().product::<u32>() > 100, "{:?} cells", g.res);
        assert!(g.subgrids.is_empty(), "{} cells' grids", g.subgrids.len());
    }
}
