//! Large arrays on transparent huge pages.
//!
//! A build writes hundreds of megabytes of arrays it has just allocated
//! (the builder's primitive references, the triangle rows, the nodes), and
//! on Linux every 4 KiB page of fresh memory costs a page fault the first
//! time it is written: on this project's VM about 3 µs a page, and 45,000
//! faults a 2M-triangle `bvh8` build (`perf stat -e page-faults`). Embree
//! asks for transparent huge pages (`madvise(MADV_HUGEPAGE)`) on its large
//! allocations for the same reason; [`PagesMut`] does the same through
//! `memmap2`'s safe anonymous maps: one fault per 2 MiB, and fewer TLB
//! misses once built. Elsewhere, and for arrays under 32 MiB (see
//! [`MAP_AT_LEAST`]), it is a `Vec`.
//!
//! A map is viewed as an array of `T` through `bytemuck`'s checked casts,
//! which cost a few branches at each access; the traversals read the rows
//! and nodes at every leaf and node, so a finished array is a [`Pages`]:
//! the [`PagesMut`] boxed, with the slice it derefs to made once and kept
//! beside it (`yoke`), so that reading it costs what reading a `Vec` does.

use bytemuck::Pod;
use std::fmt;
use std::ops::{Deref, DerefMut};
use yoke::Yoke;

/// Size of a transparent huge page on x86-64 and most aarch64 kernels.
#[cfg(target_os = "linux")]
const HUGE_PAGE: usize = 2 << 20;

/// Arrays of at least this many bytes are mapped: glibc's largest mmap
/// threshold. glibc maps allocations above it afresh each time, so a map
/// of our own costs nothing more and gets huge pages; smaller ones it
/// serves from memory it holds, already faulted in, which a build
/// repeated in one process (as the benchmarks do) reuses. Mapped from 8
/// MiB, a 300K-triangle sphere's builds took 68.5–69.6 ms on one thread
/// and 37.3–39.4 on two, against 66.7–67.1 and 34.9–36.8
/// (`raymesh-peers --peers embree`, three alternations); mapped from 2
/// MiB, bunny00's one-thread builds 17.6–17.9 ms against 16.8–17.3.
#[cfg(all(target_os = "linux", not(test)))]
const MAP_AT_LEAST: usize = 16 * HUGE_PAGE;

/// In this crate's unit tests arrays from 64 KiB on are mapped, so that
/// the tests of the rows, the builders and the walks run on maps too.
#[cfg(all(target_os = "linux", test))]
const MAP_AT_LEAST: usize = 64 << 10;

/// A fixed-length array of `T`, zeroed when made, whose memory sits on
/// transparent huge pages where the system has them (see the module's
/// doc), for building; it dereferences to a slice. `T: Pod`, so that a
/// zeroed map is an array of valid `T`s, viewed as one without `unsafe`.
pub(crate) struct PagesMut<T: Pod> {
    store: Store<T>,
}

enum Store<T> {
    Heap(Vec<T>),
    #[cfg(target_os = "linux")]
    Map {
        map: memmap2::MmapMut,
        /// Byte offset of the array in `map`: its first 2 MiB boundary,
        /// since only whole aligned huge pages can back it.
        start: usize,
        len: usize,
    },
}

impl<T: Pod> PagesMut<T> {
    /// `len` zeroed elements.
    pub(crate) fn zeroed(len: usize) -> Self {
        #[cfg(target_os = "linux")]
        if let Some(store) = Self::mapped(len) {
            return Self { store };
        }
        Self {
            store: Store::Heap(bytemuck::zeroed_vec(len)),
        }
    }

    /// `len` elements, element `i` being `f(i)`, made in parallel, each
    /// task making at least `min_len` of them.
    pub(crate) fn from_fn_par(
        len: usize,
        min_len: usize,
        f: impl Fn(usize) -> T + Sync + Send,
    ) -> Self
    where
        T: Send,
    {
        use rayon::prelude::*;
        #[cfg(target_os = "linux")]
        if let Some(store) = Self::mapped(len) {
            let mut p = Self { store };
            p.par_iter_mut()
                .enumerate()
                .with_min_len(min_len)
                .for_each(|(i, x)| *x = f(i));
            return p;
        }
        // Collected, not zeroed and then written: a `Vec` this size may
        // reuse memory the allocator holds, which zeroing would pass over
        // once more (a 300K-triangle build took 3% longer).
        let mut v = Vec::with_capacity(len);
        (0..len)
            .into_par_iter()
            .with_min_len(min_len)
            .map(f)
            .collect_into_vec(&mut v);
        v.into()
    }

    /// A map for `len` elements with huge pages advised, or `None` where
    /// the array is small, its size overflows, or the system refuses.
    #[cfg(target_os = "linux")]
    fn mapped(len: usize) -> Option<Store<T>> {
        let bytes = len.checked_mul(std::mem::size_of::<T>())?;
        if bytes < MAP_AT_LEAST || std::mem::align_of::<T>() > HUGE_PAGE {
            return None;
        }
        // Room to start at a 2 MiB boundary and to end on one.
        let whole = bytes.checked_next_multiple_of(HUGE_PAGE)?;
        let map = memmap2::MmapMut::map_anon(whole.checked_add(HUGE_PAGE)?).ok()?;
        let addr = map.as_ptr() as usize;
        let start = addr.next_multiple_of(HUGE_PAGE) - addr;
        // Advice only: where the system has no transparent huge pages the
        // map still works, on small pages.
        let _ = map.advise_range(memmap2::Advice::HugePage, start, whole);
        Some(Store::Map { map, start, len })
    }

    /// Whether the array is mapped for huge pages (tests).
    #[cfg(test)]
    pub(crate) fn is_mapped(&self) -> bool {
        !matches!(self.store, Store::Heap(_))
    }
}

impl<T: Pod> Deref for PagesMut<T> {
    type Target = [T];
    #[inline]
    fn deref(&self) -> &[T] {
        match &self.store {
            Store::Heap(v) => v,
            #[cfg(target_os = "linux")]
            Store::Map { map, start, len } => {
                bytemuck::cast_slice(&map[*start..*start + len * std::mem::size_of::<T>()])
            }
        }
    }
}

impl<T: Pod> DerefMut for PagesMut<T> {
    #[inline]
    fn deref_mut(&mut self) -> &mut [T] {
        match &mut self.store {
            Store::Heap(v) => v,
            #[cfg(target_os = "linux")]
            Store::Map { map, start, len } => {
                bytemuck::cast_slice_mut(&mut map[*start..*start + *len * std::mem::size_of::<T>()])
            }
        }
    }
}

impl<T: Pod> From<Vec<T>> for PagesMut<T> {
    fn from(v: Vec<T>) -> Self {
        Self {
            store: Store::Heap(v),
        }
    }
}

/// A finished [`PagesMut`]: read-only, and as cheap to read as a `Vec`
/// (the slice is made once, see the module's doc). [`Pages::modify`]
/// writes to it in place.
pub(crate) struct Pages<T: Pod> {
    view: Yoke<&'static [T], Box<PagesMut<T>>>,
}

impl<T: Pod> Pages<T> {
    /// `pages`, finished.
    pub(crate) fn new(pages: PagesMut<T>) -> Self {
        Self {
            view: Yoke::attach_to_cart(Box::new(pages), |p: &PagesMut<T>| &**p),
        }
    }

    /// Runs `f` on the array, writable; the array stays where it is.
    pub(crate) fn modify<R>(&mut self, f: impl FnOnce(&mut [T]) -> R) -> R {
        let view = std::mem::take(self).view;
        let mut pages = view.into_backing_cart();
        let r = f(&mut pages);
        *self = Self::new(*pages);
        r
    }
}

#[cfg(test)]
impl<T: Pod> Pages<T> {
    /// Whether the array is mapped for huge pages.
    pub(crate) fn is_mapped(&self) -> bool {
        self.view.backing_cart().is_mapped()
    }
}

impl<T: Pod> Deref for Pages<T> {
    type Target = [T];
    #[inline(always)]
    fn deref(&self) -> &[T] {
        self.view.get()
    }
}

impl<T: Pod> From<PagesMut<T>> for Pages<T> {
    fn from(p: PagesMut<T>) -> Self {
        Self::new(p)
    }
}

impl<T: Pod> From<Vec<T>> for Pages<T> {
    fn from(v: Vec<T>) -> Self {
        Self::new(v.into())
    }
}

impl<T: Pod> Default for Pages<T> {
    fn default() -> Self {
        Vec::new().into()
    }
}

impl<T: Pod> Clone for Pages<T> {
    fn clone(&self) -> Self {
        // A map comes zeroed from the system; a `Vec` is copied in one
        // pass (zeroed first, it would pass over reused memory twice).
        #[cfg(target_os = "linux")]
        if let Some(store) = PagesMut::mapped(self.len()) {
            let mut p = PagesMut { store };
            p.copy_from_slice(self);
            return p.into();
        }
        self.to_vec().into()
    }
}

impl<T: Pod + fmt::Debug> fmt::Debug for Pages<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

impl<T: Pod + PartialEq> PartialEq for Pages<T> {
    fn eq(&self, other: &Self) -> bool {
        **self == **other
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_arrays_stay_on_the_heap_and_large_ones_read_back() {
        let small = PagesMut::<u32>::from_fn_par(1000, 1, |i| i as u32 * 3);
        assert!(!small.is_mapped());
        assert_eq!(small.len(), 1000);
        assert!(small.iter().enumerate().all(|(i, &x)| x == i as u32 * 3));
        // 3 MiB and a bit: a whole huge page and part of another.
        let n = (3 << 20) / 16 + 5;
        let mut big = PagesMut::<[u32; 4]>::zeroed(n);
        #[cfg(target_os = "linux")]
        assert!(big.is_mapped());
        assert_eq!(big.len(), n);
        assert!(big.iter().all(|x| *x == [0; 4]));
        for (i, x) in big.iter_mut().enumerate() {
            *x = [i as u32, 1, 2, !(i as u32)];
        }
        let want: Vec<[u32; 4]> = big.to_vec();
        let mut done = Pages::new(big);
        assert_eq!(*done, *want);
        // Aligned for any element.
        assert_eq!(done.as_ptr() as usize % 64, 0);
        let copy = done.clone();
        assert_eq!(copy, done);
        let at = done.as_ptr();
        done.modify(|a| a[n - 1][1] = 7);
        assert_eq!(done[n - 1], [n as u32 - 1, 7, 2, !(n as u32 - 1)]);
        assert_eq!(done.as_ptr(), at, "modified in place");
        assert_eq!(copy[n - 1][1], 1, "the copy is its own");
        let empty = Pages::<u64>::default();
        assert!(empty.is_empty());
        assert!(PagesMut::<u64>::zeroed(0).is_empty());
    }
}
