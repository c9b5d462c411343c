//! The servo layer: units and calibration now; the bus trait and the Dynamixel driver later.

pub mod units;
