//! The control daemon: a fixed-rate loop on its own thread from commanded tip motion to servo
//! goals, and the JSON-lines socket that commands it.

pub mod link;
