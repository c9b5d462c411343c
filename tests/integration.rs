//! The integration tests that start no daemon, one module per file beside this one, built as one
//! test binary (one link instead of one per file). Run one file's tests with its module name as
//! the filter: `cargo test --release --test integration servo_bus::`. The tests that start a
//! daemon are binaries of their own (`[[test]]` in `Cargo.toml`): they are timed against the wall
//! clock, and run two at a time with their own kind only.
#![allow(clippy::unwrap_used, clippy::expect_used)]
mod cli_support;
mod servo_support;
mod world_support;

mod connect;
mod control_props;
mod control_world;
mod demo_cli;
mod free_vectors;
mod joystick;
mod layers;
mod obstacle_vectors;
mod overall_vectors;
mod overall_vs_sequential;
mod reach_plan;
mod readme;
mod rope_optimizer;
mod servo_admin;
mod servo_baud;
mod servo_bringup;
mod servo_bus;
mod servo_cli;
mod servo_decode_props;
mod servo_fast_read;
mod servo_fast_wire;
mod sim_cli;
mod simulate_cli;
mod simulate_scenarios;
mod solve_cli;
mod teleop_pty;
mod world_props;
