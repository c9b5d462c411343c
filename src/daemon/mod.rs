//! The control daemon: a fixed-rate loop on its own thread from commanded tip motion to servo
//! goals, and the JSON-lines socket that commands it.
//!
//! - [`link`]: the seam between the loop's thread and the socket side (bounded command queue,
//!   latest-wins telemetry, broadcast events).
//! - [`server`]: the JSON-lines TCP server on the socket side.

pub mod link;
pub mod server;
