//! A control loop calls the resolvers every tick: once warmed up for a chain, neither strategy
//! may allocate. A counting global allocator checks it.
// The one place the crate allows unsafe code: a global allocator must implement an unsafe trait.
// It only counts calls and delegates every one to the system allocator.
#![allow(clippy::unwrap_used, unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use snakectl::chain::{Chain, JointLimit, Vec2};
use snakectl::resolve::overall::{Overall, OverallOptions};
use snakectl::resolve::sequential::Sequential;
use snakectl::resolve::Resolver;

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call is forwarded unchanged to `System`, which upholds the `GlobalAlloc`
// contract; the counter has no effect on memory.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller's layout is passed on as received.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` was allocated by `System` with `layout` (every allocation goes there).
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: as for `dealloc`; the new size is the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `f`.
fn allocations(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    f();
    ALLOCATIONS.load(Ordering::Relaxed) - before
}

/// Runs 200 ticks of 1 mm along a 5 mm circle through `resolver::resolve` after one warm-up tick.
fn ticks(resolver: &mut dyn Resolver, chain: &Chain) -> usize {
    let n = chain.len();
    let mut theta: Vec<f64> = (0..n).map(|i| 0.3 * ((i as f64) * 0.7).sin()).collect();
    let centre = chain.tip(&theta) - Vec2::new(0.005, 0.0);
    let target = |k: usize| {
        let a = k as f64 * 0.2;
        centre + Vec2::new(0.005 * a.cos(), 0.005 * a.sin())
    };
    resolver.resolve(chain, &mut theta, target(1)).unwrap();
    allocations(|| {
        for k in 2..200 {
            resolver.resolve(chain, &mut theta, target(k)).unwrap();
        }
    })
}

#[test]
fn warm_ticks_allocate_nothing() {
    for n in [8, 64] {
        let lim = Some(JointLimit { lo: -3.0, hi: 3.0 });
        let chain = Chain::new(vec![1.0 / n as f64; n], Vec2::zeros(), 0.0, vec![lim; n]).unwrap();
        let mut sequential = Sequential::default();
        assert_eq!(ticks(&mut sequential, &chain), 0, "sequential, n = {n}");
        let mut overall = Overall::new(OverallOptions::default());
        assert_eq!(ticks(&mut overall, &chain), 0, "overall, n = {n}");
    }
}
