//! The allocation tests, one module per file beside this one, built as one test binary under a
//! counting global allocator (`alloc_support`), which no other test binary carries.
#![allow(clippy::unwrap_used, clippy::expect_used)]
mod alloc_support;
mod daemon_support;

#[global_allocator]
static GLOBAL: alloc_support::Counting = alloc_support::Counting;

mod control_no_alloc;
mod daemon_no_alloc;
mod no_alloc;
mod overall_world_no_alloc;
