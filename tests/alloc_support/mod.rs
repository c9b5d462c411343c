//! A counting global allocator for the allocation tests: it counts the allocations (and
//! reallocations) of each thread, and separately those of the daemon's loop thread (named
//! `snakectl-loop`), and forwards every call unchanged to the system allocator.
//!
//! A test crate installs it with
//! `#[global_allocator] static GLOBAL: alloc_support::Counting = alloc_support::Counting;`.
#![allow(dead_code, unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

/// The allocator; see the module docs.
pub struct Counting;

static LOOP_ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

thread_local! {
    /// Allocations made by this thread (const-initialised: reading it never allocates).
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
    /// Inside the counter already (asking for the thread's name may allocate once).
    static BUSY: Cell<bool> = const { Cell::new(false) };
    /// Whether this thread is the daemon's loop, once known.
    static IS_LOOP: Cell<Option<bool>> = const { Cell::new(None) };
}

fn count() {
    // During thread teardown the slots may be gone: such allocations are nobody's tick.
    let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
    let _ = BUSY.try_with(|busy| {
        if busy.replace(true) {
            return;
        }
        let is_loop = IS_LOOP.try_with(|l| match l.get() {
            Some(v) => v,
            None => {
                let v = std::thread::current().name() == Some("snakectl-loop");
                l.set(Some(v));
                v
            }
        });
        if is_loop == Ok(true) {
            LOOP_ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        busy.set(false);
    });
}

// SAFETY: every call is forwarded unchanged to `System`, which upholds the `GlobalAlloc`
// contract; the counters have no effect on memory.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: the caller's layout is passed on as received.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` was allocated by `System` with `layout` (every allocation goes there).
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: as for `dealloc`; the new size is the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Allocations this thread has made so far.
pub fn this_thread() -> usize {
    ALLOCATIONS.with(Cell::get)
}

/// Allocations `f` makes on this thread.
pub fn during(f: impl FnOnce()) -> usize {
    let before = this_thread();
    f();
    this_thread() - before
}

/// Allocations the daemon's loop thread has made so far.
pub fn loop_thread() -> u64 {
    LOOP_ALLOCATIONS.load(Ordering::Relaxed)
}
