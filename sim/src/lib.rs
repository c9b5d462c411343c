//! Virtual Dynamixel X-series servos speaking Protocol 2.0 over a pseudo-terminal.
