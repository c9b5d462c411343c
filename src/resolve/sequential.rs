//! The sequential strategy.
