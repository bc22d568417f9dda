//! Rays with the per-ray values every traversal needs, computed once.

use glam::{BVec3A, Mat4, Vec3, Vec3A, Vec3Swizzles, Vec4};

/// A ray `origin + t * dir` restricted to `t` in `[tmin, tmax]`.
///
/// The constructor precomputes the reciprocal direction (for the slab test)
/// and the shear of the watertight triangle test (Woop, Benthin & Wald,
/// "Watertight Ray/Triangle Intersection", JCGT 2013), so a traversal pays
/// for them once per ray rather than once per node or triangle.
///
/// A ray whose origin or direction is not finite, whose direction is zero,
/// or whose interval is NaN or empty is *invalid*: it keeps its values but its
/// interval is set empty, so every test in this crate reports a miss for it.
///
/// The fields lie in the order declared (`#[repr(C)]`: origin at byte 0,
/// direction 12, reciprocal 24, `tmin` 36, `tmax` 40, shear 44, axes 56;
/// 60 bytes), so that SIMD kernels may load several fields at once: the
/// stream set-up of `raymesh-accel` transposes eight rays' origins,
/// reciprocals and intervals into a group's rows that way (a test below
/// checks the offsets).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct Ray {
    origin: Vec3,
    dir: Vec3,
    inv_dir: Vec3,
    tmin: f32,
    tmax: f32,
    /// Shear constants `(dx * (1/dz), dy * (1/dz), 1/dz)` in the permuted
    /// axes (`1/dz` the same quotient as `inv_dir`'s).
    shear: Vec3,
    /// Axis permutation `(kx, ky, kz)`: `kz` is the dominant axis of `dir`.
    k: [u8; 3],
}

impl Ray {
    /// Makes a ray over `[tmin, tmax]`; `tmax` may be `f32::INFINITY`.
    ///
    /// Inlined where it is called (every query starts with it): as a call
    /// across the crate boundary it returned the ray through memory for
    /// the traversal to read back, 40 instructions a query more
    /// (callgrind, `bvh8` on bunny00).
    #[inline]
    #[must_use]
    pub fn new(origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Self {
        // Without a branch: a ray is made per query (camera sample, shadow
        // ray, instance, and each of a benchmark's rays), and random
        // directions made the short-circuit checks and the sign test below
        // mispredict. The lane masks take the three axes at once; `tmin <=
        // tmax` is false when either is NaN.
        let (o, d) = (Vec3A::from(origin), Vec3A::from(dir));
        let valid = (o.is_finite_mask() & d.is_finite_mask()).all()
            & d.cmpne(Vec3A::ZERO).any()
            & (tmin <= tmax);
        // 1/±0 is ±inf, which the slab test handles; see `Aabb::intersect_ray`.
        // Divisions lane by lane in one SIMD division each (the same IEEE
        // quotients as one by one).
        let inv = Vec3A::ONE / d;
        let inv_dir = Vec3::from(inv);
        let abs = dir.abs();
        // `&`, not `&&`: no branch on the direction (NaN falls to kz = 2).
        let xdom = (abs.x >= abs.y) & (abs.x >= abs.z);
        let ydom = !xdom & (abs.y >= abs.z);
        let kz = if xdom { 0 } else { 2 - usize::from(ydom) };
        // The direction and its reciprocal with their axes in the order
        // `(kx, ky, kz)`, chosen among rotations in registers by lane
        // masks: as stack arrays indexed by the axes, each value waited on
        // a chain of dependent loads (the axis from a table, then the
        // value from the array just stored), 23% of `Ray::new`'s samples
        // on rays that miss the mesh (`perf record -e cpu-clock`).
        let pick = |m: bool, a: Vec3A, b: Vec3A| Vec3A::select(BVec3A::splat(m), a, b);
        let pd = pick(xdom, d.yzx(), pick(ydom, d.zxy(), d));
        let rz = pick(xdom, inv.yzx(), pick(ydom, inv.zxy(), inv)).z;
        // Keep the winding of the projected triangle independent of the
        // sign of dz: the other two axes swapped where it is negative.
        let neg = pd.z < 0.0;
        let pd = pick(neg, pd.yxz(), pd);
        const KX: [[u8; 3]; 2] = [[1, 2, 0], [2, 0, 1]];
        const KY: [[u8; 3]; 2] = [[2, 0, 1], [1, 2, 0]];
        let (kx, ky) = (KX[usize::from(neg)][kz], KY[usize::from(neg)][kz]);
        // The shear by the reciprocal just computed, not by a second
        // division: one division a ray (`raymesh-ab --rows`, pig, pinned:
        // primary rays +2-3%, random +2%). Each constant is consistent
        // for every triangle the ray meets, which is all watertightness
        // asks of it; `1/dz` is the same quotient as before.
        let shear = Vec3::new(pd.x * rz, pd.y * rz, rz);
        let (tmin, tmax) = if valid {
            (tmin, tmax)
        } else {
            (f32::INFINITY, f32::NEG_INFINITY)
        };
        Self {
            origin,
            dir,
            inv_dir,
            tmin,
            tmax,
            shear,
            k: [kx, ky, kz as u8],
        }
    }

    /// Makes the ray of row `r`, laid out `[ox, oy, oz, tmin, dx, dy, dz,
    /// tmax]` (BENCH.md's rays, as numpy arrays and Embree's `RTCRay`
    /// hold them): `Ray::new(origin, dir, tmin, tmax)`.
    #[inline]
    #[must_use]
    pub fn from_row(r: &[f32; 8]) -> Self {
        Self::new(
            Vec3::new(r[0], r[1], r[2]),
            Vec3::new(r[4], r[5], r[6]),
            r[3],
            r[7],
        )
    }

    /// The row of this ray, `[ox, oy, oz, tmin, dx, dy, dz, tmax]`: the
    /// inverse of [`Self::from_row`] for a valid ray (an invalid one holds
    /// an empty interval, not the one it was made with).
    #[inline]
    #[must_use]
    pub fn row(&self) -> [f32; 8] {
        let (o, d) = (self.origin, self.dir);
        [o.x, o.y, o.z, self.tmin, d.x, d.y, d.z, self.tmax]
    }

    /// Makes a ray over `[0, +inf)`.
    #[inline]
    #[must_use]
    pub fn infinite(origin: Vec3, dir: Vec3) -> Self {
        Self::new(origin, dir, 0.0, f32::INFINITY)
    }

    /// The same ray with another upper bound (an invalid ray stays invalid).
    #[inline]
    #[must_use]
    pub fn with_tmax(mut self, tmax: f32) -> Self {
        if self.is_valid() && !tmax.is_nan() {
            self.tmax = tmax;
        }
        self
    }

    /// Origin of the ray.
    #[inline]
    #[must_use]
    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    /// Direction of the ray, as given (not normalized).
    #[inline]
    #[must_use]
    pub fn dir(&self) -> Vec3 {
        self.dir
    }

    /// Componentwise `1 / dir`; a zero component gives an infinity of its sign.
    #[inline]
    #[must_use]
    pub fn inv_dir(&self) -> Vec3 {
        self.inv_dir
    }

    /// Lower end of the ray's interval.
    #[inline]
    #[must_use]
    pub fn tmin(&self) -> f32 {
        self.tmin
    }

    /// Upper end of the ray's interval.
    #[inline]
    #[must_use]
    pub fn tmax(&self) -> f32 {
        self.tmax
    }

    /// Whether the ray can hit anything (finite input and a non-empty interval).
    #[inline]
    #[must_use]
    pub fn is_valid(&self) -> bool {
        self.tmin <= self.tmax
    }

    /// The point at parameter `t`.
    #[inline]
    #[must_use]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + t * self.dir
    }

    /// Shear constants `(dx * (1/dz), dy * (1/dz), 1/dz)` and axis permutation
    /// `(kx, ky, kz)` of the watertight triangle test, for batched versions
    /// of [`crate::intersect_triangle`] that must compute the same values.
    #[inline]
    #[must_use]
    pub fn shear(&self) -> (Vec3, [usize; 3]) {
        (
            self.shear,
            [self.k[0] as usize, self.k[1] as usize, self.k[2] as usize],
        )
    }

    /// `v` with its axes in the order `(kx, ky, kz)` of [`Self::shear`].
    ///
    /// Indexing an array, not `Vec3`'s `Index`, whose `match` compiles to
    /// branches: those mispredict whenever the dominant axis changes from
    /// one ray to the next (2.8 a ray on random rays, by callgrind).
    #[inline(always)]
    #[must_use]
    pub fn permute(&self, v: Vec3) -> Vec3 {
        let a = v.to_array();
        let k = self.k;
        Vec3::new(a[k[0] as usize], a[k[1] as usize], a[k[2] as usize])
    }

    /// Index `0..8` of the direction's octant: bit `i` set when `dir[i]` is negative (or -0.0).
    /// Traversals use it to visit nearer children first.
    #[inline]
    #[must_use]
    pub fn octant(&self) -> usize {
        // The sign bit, not `< 0.0`: a direction of -0.0 has a reciprocal of -inf.
        self.dir.x.is_sign_negative() as usize
            | (self.dir.y.is_sign_negative() as usize) << 1
            | (self.dir.z.is_sign_negative() as usize) << 2
    }
}

/// Eight rays as structure of arrays: each component a row of eight
/// lanes, the layout of Embree's `RTCRay8`. Packet queries take it so that
/// what [`Ray::new`] computes is computed for the eight lanes at once, row
/// by row ([`Rays8::lanes`]), instead of ray by ray and then transposed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Rays8 {
    /// Origins by axis: `origin[a][i]` is lane `i`'s coordinate `a`.
    pub origin: [[f32; 8]; 3],
    /// Directions by axis, as given (not normalized).
    pub dir: [[f32; 8]; 3],
    /// Lower ends of the intervals.
    pub tmin: [f32; 8],
    /// Upper ends of the intervals (`f32::INFINITY` for none).
    pub tmax: [f32; 8],
}

/// What [`Ray::new`] computes of each of the eight rays of a [`Rays8`]
/// whose directions share their octant and dominant axis, beyond what the
/// rays hold, by rows: the reciprocal directions and shear constants that
/// packet traversals test with (each lane's bit for bit), and the shared
/// axis order and octant. (A valid ray keeps its origin and interval.)
/// No `Ray` is made: a traversal that needs one of a lane (a rare case of
/// the triangle test) makes it with [`Rays8::ray`].
#[derive(Clone, Debug)]
pub struct RayLanes8 {
    /// Reciprocal directions by axis (each lane's [`Ray::inv_dir`]).
    pub inv_dir: [[f32; 8]; 3],
    /// Shear constants by component (each lane's [`Ray::shear`]).
    pub shear: [[f32; 8]; 3],
    /// The axis order `(kx, ky, kz)` of every lane's [`Ray::shear`].
    pub k: [usize; 3],
    /// The direction's octant, every lane's [`Ray::octant`].
    pub octant: usize,
}

impl Rays8 {
    /// The rays of `rays`, by rows.
    #[must_use]
    pub fn from_rays(rays: &[Ray; 8]) -> Self {
        Self {
            origin: std::array::from_fn(|a| std::array::from_fn(|i| rays[i].origin[a])),
            dir: std::array::from_fn(|a| std::array::from_fn(|i| rays[i].dir[a])),
            tmin: std::array::from_fn(|i| rays[i].tmin),
            tmax: std::array::from_fn(|i| rays[i].tmax),
        }
    }

    /// Eight rays given as rows `[ox, oy, oz, tmin, dx, dy, dz, tmax]`
    /// (BENCH.md's layout, [`Ray::from_row`]'s), one a lane: lane `i`'s
    /// ray is `Ray::from_row(&rows[i])`, whatever the rows hold (invalid
    /// rows stay as given, for the queries to refuse).
    ///
    /// Transposed as four 4 × 4 blocks ([`Mat4::transpose`]: SSE shuffles
    /// on x86-64, NEON on aarch64), whose rows are stored whole: element
    /// by element, the 64 stores of 4 bytes made the packet's 16- and
    /// 32-byte loads of the rows wait on them (`raymesh raycast
    /// --packets`, the pig's primary rays: 4.6% of the samples here).
    #[inline]
    #[must_use]
    pub fn from_rows(rows: &[[f32; 8]; 8]) -> Self {
        let mut cols = [[0.0f32; 8]; 8];
        for b in [0, 4] {
            for c in [0, 4] {
                let m = Mat4::from_cols(
                    Vec4::from_slice(&rows[b][c..c + 4]),
                    Vec4::from_slice(&rows[b + 1][c..c + 4]),
                    Vec4::from_slice(&rows[b + 2][c..c + 4]),
                    Vec4::from_slice(&rows[b + 3][c..c + 4]),
                )
                .transpose();
                // Column `j` of the transpose: element `c + j` of the rows
                // `b..b + 4`.
                for j in 0..4 {
                    m.col(j).write_to_slice(&mut cols[c + j][b..b + 4]);
                }
            }
        }
        let [ox, oy, oz, tmin, dx, dy, dz, tmax] = cols;
        Self {
            origin: [ox, oy, oz],
            dir: [dx, dy, dz],
            tmin,
            tmax,
        }
    }

    /// Lane `i` as a row, `[ox, oy, oz, tmin, dx, dy, dz, tmax]`: the
    /// inverse of [`Self::from_rows`], whose ray ([`Ray::from_row`]) is
    /// [`Self::ray`]`(i)`.
    #[inline]
    #[must_use]
    pub fn row(&self, i: usize) -> [f32; 8] {
        let (o, d) = (&self.origin, &self.dir);
        [
            o[0][i],
            o[1][i],
            o[2][i],
            self.tmin[i],
            d[0][i],
            d[1][i],
            d[2][i],
            self.tmax[i],
        ]
    }

    /// Lane `i`'s ray: [`Ray::new`] of its origin, direction and interval.
    #[inline]
    #[must_use]
    pub fn ray(&self, i: usize) -> Ray {
        let [o, d] = [&self.origin, &self.dir].map(|v| Vec3::new(v[0][i], v[1][i], v[2][i]));
        Ray::new(o, d, self.tmin[i], self.tmax[i])
    }

    /// The eight rays, each [`Self::ray`]'s bit for bit: by rows
    /// ([`Self::lanes`]: three rows of quotients, a SIMD division or two
    /// each for the eight) where the rays are valid and share their octant
    /// and axis order, as a camera's neighbouring rays do, else one by
    /// one. A stream's maker (the renderer's camera) makes its rays so,
    /// with a fraction of the divisions of eight [`Ray::new`]s.
    #[inline]
    #[must_use]
    pub fn rays(&self) -> [Ray; 8] {
        let Some(l) = self.lanes() else {
            return std::array::from_fn(|i| self.ray(i));
        };
        let row = |v: &[[f32; 8]; 3], i: usize| Vec3::new(v[0][i], v[1][i], v[2][i]);
        // `RayLanes8::k` holds axes, each below 3.
        let k = l.k.map(|a| a as u8);
        std::array::from_fn(|i| Ray {
            origin: row(&self.origin, i),
            dir: row(&self.dir, i),
            inv_dir: row(&l.inv_dir, i),
            // Valid rays keep their intervals.
            tmin: self.tmin[i],
            tmax: self.tmax[i],
            shear: row(&l.shear, i),
            k,
        })
    }

    /// What [`Self::ray`] of each lane computes, by rows, when every ray
    /// is valid and all share their direction's octant and axis order (the
    /// rays of a packet: a camera's neighbouring pixels, shadow rays toward
    /// one light); else `None`, and the caller makes them one by one.
    ///
    /// Row by row, so that the compiler makes each step one SIMD operation
    /// for the eight (or two for four): the checks, the three reciprocal
    /// rows, whose divisions are the IEEE quotients [`Ray::new`]'s give
    /// lane by lane, and the three shear rows, products of those. With one
    /// axis order the shear's factors are whole rows, not a choice a lane.
    #[inline(always)]
    #[must_use]
    pub fn lanes(&self) -> Option<RayLanes8> {
        let (o, d) = (&self.origin, &self.dir);
        // Lane 0's dominant axis (chosen as `Ray::new` chooses it) and
        // octant, which every lane must share.
        let (x, y, z) = (d[0][0].abs(), d[1][0].abs(), d[2][0].abs());
        let kz = if (x >= y) & (x >= z) {
            0
        } else {
            2 - usize::from(y >= z)
        };
        let octant = usize::from(d[0][0].is_sign_negative())
            | usize::from(d[1][0].is_sign_negative()) << 1
            | usize::from(d[2][0].is_sign_negative()) << 2;
        // Four lanes at a time (glam's `Vec4`: SSE2 or NEON), each
        // condition a mask: a lane shares `kz` when `x` dominates exactly
        // where it does in lane 0, and else `y >= z` exactly where it does.
        let mut ok = true;
        for h in [0, 4] {
            let row = |r: &[f32; 8]| Vec4::from_slice(&r[h..h + 4]);
            let (x, y, z) = (row(&d[0]).abs(), row(&d[1]).abs(), row(&d[2]).abs());
            let xd = x.cmpge(y) & x.cmpge(z);
            let yz = y.cmpge(z);
            ok &= match kz {
                0 => xd.all(),
                1 => !xd.any() & yz.all(),
                _ => !xd.any() & !yz.any(),
            };
            // Every lane's sign bits those of lane 0.
            for (a, r) in d.iter().enumerate() {
                let neg = octant >> a & 1 != 0;
                ok &= row(r).is_negative_bitmask() == if neg { 0b1111 } else { 0 };
            }
            let finite = row(&o[0]).is_finite_mask()
                & row(&o[1]).is_finite_mask()
                & row(&o[2]).is_finite_mask()
                & row(&d[0]).is_finite_mask()
                & row(&d[1]).is_finite_mask()
                & row(&d[2]).is_finite_mask();
            let nonzero = x.cmpne(Vec4::ZERO) | y.cmpne(Vec4::ZERO) | z.cmpne(Vec4::ZERO);
            let interval = row(&self.tmin).cmple(row(&self.tmax));
            ok &= (finite & nonzero & interval).all();
        }
        if !ok {
            return None;
        }
        // As in `Ray::new`: the two other axes in the order that keeps the
        // projected winding, by the sign of the dominant component (the
        // octant's bit, shared: that component is nonzero in a valid ray).
        const KX: [[u8; 3]; 2] = [[1, 2, 0], [2, 0, 1]];
        const KY: [[u8; 3]; 2] = [[2, 0, 1], [1, 2, 0]];
        let neg = octant >> kz & 1;
        let k = [KX[neg][kz] as usize, KY[neg][kz] as usize, kz];
        let mut inv_dir = [[0.0f32; 8]; 3];
        for a in 0..3 {
            for i in 0..8 {
                inv_dir[a][i] = 1.0 / d[a][i];
            }
        }
        let (dx, dy, rz) = (&d[k[0]], &d[k[1]], &inv_dir[kz]);
        let mut shear = [[0.0f32; 8]; 3];
        for i in 0..8 {
            shear[0][i] = dx[i] * rz[i];
            shear[1][i] = dy[i] * rz[i];
            shear[2][i] = rz[i];
        }
        Some(RayLanes8 {
            inv_dir,
            shear,
            k,
            octant,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// `Rays8::from_rows` is a transposition: every element lands in its
    /// lane and field, every bit kept (NaN payloads and signed zeros
    /// among them).
    #[test]
    fn rows_transpose_bit_for_bit() {
        let rows: [[f32; 8]; 8] = std::array::from_fn(|i| {
            std::array::from_fn(|c| match (i + c) % 5 {
                0 => f32::from_bits(0x7fc0_0000 | (i * 8 + c) as u32),
                1 => -0.0,
                _ => (i * 8 + c) as f32 * 0.25 - 3.0,
            })
        });
        let r = Rays8::from_rows(&rows);
        let bits = |x: f32| x.to_bits();
        for (i, row) in rows.iter().enumerate() {
            for a in 0..3 {
                assert_eq!(bits(r.origin[a][i]), bits(row[a]));
                assert_eq!(bits(r.dir[a][i]), bits(row[4 + a]));
            }
            assert_eq!(bits(r.tmin[i]), bits(row[3]));
            assert_eq!(bits(r.tmax[i]), bits(row[7]));
            assert_eq!(r.row(i).map(bits), row.map(bits));
        }
    }

    /// The constructor as it was written first (scalar divisions, the
    /// dominant axis chosen with branches): the fields must not change by
    /// a bit, or every hit would.
    fn reference(origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Ray {
        let valid = origin.is_finite()
            && dir.is_finite()
            && dir != Vec3::ZERO
            && !tmin.is_nan()
            && !tmax.is_nan()
            && tmin <= tmax;
        let inv_dir = Vec3::ONE / dir;
        let abs = dir.abs();
        let kz = if abs.x >= abs.y && abs.x >= abs.z {
            0
        } else if abs.y >= abs.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        let d = dir.to_array();
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let rz = 1.0 / d[kz];
        let shear = Vec3::new(d[kx] * rz, d[ky] * rz, rz);
        let (tmin, tmax) = if valid {
            (tmin, tmax)
        } else {
            (f32::INFINITY, f32::NEG_INFINITY)
        };
        Ray {
            origin,
            dir,
            inv_dir,
            tmin,
            tmax,
            shear,
            k: [kx as u8, ky as u8, kz as u8],
        }
    }

    /// The layout the doc comment promises (`raymesh-accel`'s stream
    /// set-up kernel loads fields by these offsets).
    #[test]
    fn fields_lie_where_the_doc_says() {
        use std::mem::{offset_of, size_of};
        assert_eq!(offset_of!(Ray, origin), 0);
        assert_eq!(offset_of!(Ray, dir), 12);
        assert_eq!(offset_of!(Ray, inv_dir), 24);
        assert_eq!(offset_of!(Ray, tmin), 36);
        assert_eq!(offset_of!(Ray, tmax), 40);
        assert_eq!(offset_of!(Ray, shear), 44);
        assert_eq!(offset_of!(Ray, k), 56);
        assert_eq!(size_of::<Ray>(), 60);
    }

    fn bits(r: &Ray) -> Vec<u32> {
        let v = |v: Vec3| v.to_array().map(f32::to_bits);
        [v(r.origin), v(r.dir), v(r.inv_dir), v(r.shear)]
            .concat()
            .into_iter()
            .chain([r.tmin.to_bits(), r.tmax.to_bits()])
            .chain(r.k.map(u32::from))
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 20_000, failure_persistence: None, ..ProptestConfig::default() })]
        /// The constructor gives the reference's fields bit for bit, on
        /// any input: zeros of both signs, ties between axes, infinities,
        /// NaN, huge and tiny values.
        #[test]
        fn constructor_matches_the_reference(
            o in prop::array::uniform3(coord()), d in prop::array::uniform3(coord()),
            tmin in coord(), tmax in coord(),
        ) {
            let (o, d) = (Vec3::from_array(o), Vec3::from_array(d));
            prop_assert_eq!(bits(&Ray::new(o, d, tmin, tmax)), bits(&reference(o, d, tmin, tmax)));
            // A row's ray is the same, each part from its column.
            let row = [o.x, o.y, o.z, tmin, d.x, d.y, d.z, tmax];
            let ray = Ray::new(o, d, tmin, tmax);
            prop_assert_eq!(bits(&Ray::from_row(&row)), bits(&ray));
            if ray.is_valid() {
                prop_assert_eq!(bits(&Ray::from_row(&ray.row())), bits(&ray));
            }
        }
    }

    fn coord() -> impl Strategy<Value = f32> {
        prop_oneof![
            4 => -4.0f32..4.0,
            2 => (-2i32..3).prop_map(|i| i as f32),
            1 => Just(-0.0f32),
            1 => Just(f32::INFINITY),
            1 => Just(f32::NEG_INFINITY),
            1 => Just(f32::NAN),
            1 => Just(1e30f32),
            1 => Just(-1e-38f32),
            1 => Just(f32::MIN_POSITIVE / 4.0),
        ]
    }

    /// A value for a packet test: near `base`, or about once in `odd / 2`
    /// its opposite or one of the hard cases (zeros of both signs, ties,
    /// infinities, NaN, huge and tiny values).
    fn lane_value(next: &mut impl FnMut() -> u32, base: f32, odd: u32) -> f32 {
        const HARD: [f32; 9] = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            1e30,
            f32::MIN_POSITIVE / 4.0,
        ];
        let r = next();
        match r % odd {
            0 => HARD[(r >> 8) as usize % HARD.len()],
            1 => -base,
            _ => base + ((r >> 8) as f32 / (1 << 24) as f32 - 0.5) * 0.3,
        }
    }

    /// `Rays8::lanes` makes the rows of each lane's `Ray::new` bit for bit, and
    /// declines exactly the packets with an invalid ray or two lanes of
    /// another octant or axis order: over packets of near-parallel rays
    /// (most coherent) with hard values mixed in.
    #[test]
    fn lanes_are_each_rays_constructor() {
        let mut state = 0x9e37_79b9_u32;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        let (mut made, mut declined) = (0, 0);
        for _ in 0..40_000 {
            let base = [0, 1, 2].map(|_| (next() % 2000) as f32 / 500.0 - 2.0);
            // Packets with an odd value in about one of every 16 to 1,024.
            let odd = 16 << (next() % 7);
            let mut p = Rays8::default();
            for i in 0..8 {
                for a in 0..3 {
                    p.origin[a][i] = lane_value(&mut next, 1.0, odd);
                    p.dir[a][i] = lane_value(&mut next, base[a], odd);
                }
                p.tmin[i] = lane_value(&mut next, 0.0, odd);
                p.tmax[i] = lane_value(&mut next, 10.0, odd);
            }
            let rays: [Ray; 8] = std::array::from_fn(|i| p.ray(i));
            let coherent = rays
                .iter()
                .all(|r| r.is_valid() && r.octant() == rays[0].octant() && r.k == rays[0].k);
            match p.lanes() {
                Some(l) => {
                    assert!(coherent, "{p:?}");
                    made += 1;
                    for (i, r) in rays.iter().enumerate() {
                        for a in 0..3 {
                            assert_eq!(l.inv_dir[a][i].to_bits(), r.inv_dir[a].to_bits());
                            assert_eq!(l.shear[a][i].to_bits(), r.shear[a].to_bits());
                        }
                        // What the packet takes from the rays themselves.
                        assert_eq!(p.tmin[i].to_bits(), r.tmin.to_bits());
                        assert_eq!(p.tmax[i].to_bits(), r.tmax.to_bits());
                        for a in 0..3 {
                            assert_eq!(p.origin[a][i].to_bits(), r.origin[a].to_bits());
                        }
                        assert_eq!(l.k, r.shear().1);
                        assert_eq!(l.octant, r.octant());
                    }
                }
                None => {
                    assert!(!coherent, "{p:?}");
                    declined += 1;
                }
            }
            assert_eq!(Rays8::from_rays(&rays).lanes().is_some(), coherent);
            // Given as rows, the same packet: each lane its row's ray.
            let rows: [[f32; 8]; 8] = std::array::from_fn(|i| {
                let (o, d) = (
                    [0, 1, 2].map(|a| p.origin[a][i]),
                    [0, 1, 2].map(|a| p.dir[a][i]),
                );
                [o[0], o[1], o[2], p.tmin[i], d[0], d[1], d[2], p.tmax[i]]
            });
            let by_rows = Rays8::from_rows(&rows);
            for (i, r) in rays.iter().enumerate() {
                assert_eq!(by_rows.row(i).map(f32::to_bits), rows[i].map(f32::to_bits));
                assert_eq!(bits(&by_rows.ray(i)), bits(r));
                assert_eq!(bits(&Ray::from_row(&rows[i])), bits(r));
            }
            // Made by rows or one by one, the same rays.
            for (a, b) in p.rays().iter().zip(&rays) {
                assert_eq!(bits(a), bits(b));
            }
        }
        // Both outcomes exercised, each often.
        assert!(
            made > 1000 && declined > 1000,
            "{made} made, {declined} declined"
        );
    }

    #[test]
    fn invalid_rays_have_empty_interval() {
        let o = Vec3::ZERO;
        for (origin, dir, tmin, tmax) in [
            (Vec3::new(f32::NAN, 0.0, 0.0), Vec3::X, 0.0, 1.0),
            (o, Vec3::new(0.0, f32::NAN, 0.0), 0.0, 1.0),
            (o, Vec3::ZERO, 0.0, 1.0),
            (o, Vec3::new(f32::INFINITY, 0.0, 0.0), 0.0, 1.0),
            (Vec3::splat(f32::NEG_INFINITY), Vec3::X, 0.0, 1.0),
            (o, Vec3::X, f32::NAN, 1.0),
            (o, Vec3::X, 0.0, f32::NAN),
            (o, Vec3::X, 2.0, 1.0),
        ] {
            let r = Ray::new(origin, dir, tmin, tmax);
            assert!(!r.is_valid(), "{origin:?} {dir:?} {tmin} {tmax}");
            assert!(!r.with_tmax(5.0).is_valid());
        }
        assert!(Ray::new(o, Vec3::X, 0.0, f32::INFINITY).is_valid());
        assert!(Ray::new(o, Vec3::X, 1.0, 1.0).is_valid());
    }

    #[test]
    fn shear_axis_is_dominant() {
        let r = Ray::infinite(Vec3::ZERO, Vec3::new(0.1, -3.0, 0.5));
        let (_, k) = r.shear();
        assert_eq!(k[2], 1);
        assert_eq!(r.octant(), 0b010);
    }
}
